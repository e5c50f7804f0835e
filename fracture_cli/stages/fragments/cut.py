"""The ``fragments`` stage's work: the input intersected with each piece region, split into bodies, checked.

:func:`fracture_cli.stages.fragments.fragments_with_split` is the stage's entry point (its docstring says what is
made); this module cuts, so that the package itself loads neither manifold3d nor the repair steps.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import manifold3d
import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.mass import mass_properties
from fracture_cli.geometry.rows import unique_rows, used_vertices
from fracture_cli.geometry.solids import shell_mask
from fracture_cli.geometry.uvs import box_uvs
from fracture_cli.stages.fragments.bodies import SplitReport, body_faces, split_fragments, stable_order
from fracture_cli.stages.fragments.options import STAGE, FragmentOptions
from fracture_cli.stages.fragments.resolve import resolve_pinches
from fracture_cli.stages.fragments.solids import input_solids
from fracture_cli.system import parallel
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Fragment, Fragments, Material, Regions, SurfaceMesh

log = logging.getLogger(__name__)

# Vertex property layout carried through the booleans: position, uv, normal.
_UV = slice(3, 5)
_NORMAL = slice(5, 8)
_NUM_COLUMNS = 8


def cut_fragments(surface: SurfaceMesh, regions: Regions, options: FragmentOptions) -> tuple[Fragments, SplitReport]:
    """The stage's work (:func:`fracture_cli.stages.fragments.fragments_with_split`)."""
    # Bodies that only touch (the repair stage kept them apart) are cut one group at a time, so no fragment joins
    # a wheel to the chassis it rests against.
    solids, id_to_material = input_solids(surface, stage=STAGE)
    input_volume = float(sum(solid.volume() for solid in solids))
    if input_volume <= 0:
        raise StageError("the input encloses no volume; fragments need a solid (closed) mesh", stage=STAGE)
    interior_index, materials = _with_interior(surface.materials, options.interior_color)
    region_id = manifold3d.Manifold.reserve_ids(1)
    id_to_material = dict(id_to_material)
    id_to_material[region_id] = interior_index

    cut = _Cut(tuple(solids), regions.meshes, region_id, id_to_material, interior_index, surface, options,
               tol.SLIVER_VOLUME * input_volume)
    # One boolean per piece, independent of the others: on parallel.current_jobs() processes, results in order.
    if sum(solid.num_tri() for solid in solids) > _CROP_TRIANGLES and len(regions.meshes) > 1:
        groups = _piece_groups(regions.meshes, _CROP_GROUPS)
        done: list[list[_Piece]] = [[] for _ in regions.meshes]
        for group, parts in zip(groups, parallel.ordered_map(_cut_group, groups, cut)):
            for piece, part in zip(group, parts):
                done[piece] = part
    else:
        done = parallel.ordered_map(_cut_piece, range(len(regions.meshes)), cut)
    results = [part[0] for parts in done for part in parts]
    empty = [piece for piece, parts in enumerate(done) if not parts]
    if empty:
        log.warning("%s: %d piece(s) do not reach the input and give no fragment: %s", STAGE, len(empty),
                    ", ".join(map(str, empty[:20])) + (" ..." if len(empty) > 20 else ""))
    if not results:
        raise StageError("no piece region intersects the input; the regions do not belong to this mesh", stage=STAGE)

    order = stable_order(results)
    total = sum(trigeom.signed_volume(f.vertices, f.faces) for f in results)
    log.info("%s: %d fragments from %d regions, volume %.6g of input %.6g (error %.2g)", STAGE, len(results),
             len(regions.meshes), total, input_volume, abs(total - input_volume) / input_volume)
    cut_fragments = Fragments(
        fragments=tuple(results[i] for i in order),
        materials=materials,
        normalization=surface.normalization,
        input_volume=input_volume,
        pivot=options.pivot,
    )

    # The workers found each cut's bodies (body_faces) and their volumes: when there are as many bodies as cuts,
    # none of them tiny, split_fragments returns the fragments as they are (its first test), so it is not run again.
    counts = tuple(len(part[1]) for parts in done for part in parts)
    volumes = np.array([volume for parts in done for part in parts for volume in part[1]])
    if sum(counts) == len(results) and not np.any(volumes < options.min_body_fraction * input_volume):
        split = SplitReport(bodies=counts, source=tuple(range(len(counts))), merged=0, isolated=0)
    else:
        cut_fragments, split = split_fragments(cut_fragments, options.min_body_fraction)
    return _resolve_written(cut_fragments, split, options)


def _resolve_written(frags: Fragments, split: SplitReport,
                     options: FragmentOptions) -> tuple[Fragments, SplitReport]:
    """Split the fragments that pinch as the GLB will store them into their closed bodies
    (:func:`~fracture_cli.stages.fragments.resolve.resolve_pinches`), then merge tiny ones (where that stays
    closed), in the stable order."""
    resolved_frags, resolved = resolve_pinches(frags)
    if not resolved.split:
        return frags, split
    log.warning("%s: %d fragment(s) pinched as written (parts touching along an edge or at a point) and were "
                "split into %d closed bodies, each a fragment of its own%s", STAGE, resolved.split, resolved.bodies,
                f" ({resolved.slivers} sliver(s) of no volume left out)" if resolved.slivers else "")
    again, merged = split_fragments(resolved_frags, options.min_body_fraction)
    return again, SplitReport(bodies=split.bodies, source=merged.source, merged=split.merged + merged.merged,
                              isolated=split.isolated + merged.isolated,
                              pinched=split.pinched + resolved.bodies - resolved.split)


@dataclass(frozen=True)
class _Cut:
    """What cutting one piece needs (shared with the worker processes)."""

    solids: tuple[manifold3d.Manifold, ...]
    meshes: tuple
    region_id: int
    id_to_material: dict
    interior_index: int
    surface: SurfaceMesh
    options: FragmentOptions
    min_volume: float


# Inputs above this many triangles are first cropped to a box around each group of nearby pieces, so a piece's
# boolean reads a part of the input, not all of it (the cost of a boolean grows with both operands). Cropping
# changes no geometry (each region lies inside its group's box) but may triangulate a fragment differently,
# so small inputs, whose booleans are cheap anyway, are cut from the whole input.
_CROP_TRIANGLES = 200_000
# ... into this many groups of pieces (a k-d split of the regions' box centres).
_CROP_GROUPS = 16
# How far a group's box reaches beyond its regions' boxes (normalized units: bbox diagonal 1).
_CROP_MARGIN = 1e-3


def _piece_groups(meshes: tuple, count: int) -> list[list[int]]:
    """Pieces in about ``count`` spatial groups: halve the set at the median box centre along its widest axis."""
    centres = np.array([(V.min(axis=0) + V.max(axis=0)) / 2 if len(V) else np.zeros(3) for V, _ in meshes])
    groups = [np.arange(len(meshes))]
    while len(groups) < count:
        big = max(range(len(groups)), key=lambda g: (len(groups[g]), -g))
        members = groups[big]
        if len(members) < 2:
            break
        spread = np.ptp(centres[members], axis=0)
        order = members[np.lexsort((members, centres[members, int(np.argmax(spread))]))]
        groups[big:big + 1] = [np.sort(order[:len(order) // 2]), np.sort(order[len(order) // 2:])]
    return [g.tolist() for g in groups]


# A cut fragment and the volume of each of its closed bodies (gameready.components.body_faces).
_Piece = tuple[Fragment, list[float]]


def _cut_group(cut: _Cut, pieces: list[int]) -> list[list[_Piece]]:
    """The fragments of ``pieces``, cut from the input cropped to a box around their regions."""
    boxes = [(V.min(axis=0), V.max(axis=0)) for V, _ in (cut.meshes[p] for p in pieces) if len(V)]
    if not boxes:
        return [[] for _ in pieces]
    lo = np.min([b[0] for b in boxes], axis=0) - _CROP_MARGIN
    hi = np.max([b[1] for b in boxes], axis=0) + _CROP_MARGIN
    box = manifold3d.Manifold.cube(tuple(hi - lo)).translate(tuple(lo))
    crop = tuple(solid ^ box for solid in cut.solids)
    return [_cut_piece(cut, piece, crop) for piece in pieces]


def _cut_piece(cut: _Cut, piece: int, solids: tuple[manifold3d.Manifold, ...] | None = None) -> list[_Piece]:
    """The fragments of ``piece`` (``input ^ region``, one per body group of the input; ``solids``: the groups or
    crops of them around the region) with their bodies' volumes; empty where the region misses the input.

    Body groups that only touch are cut apart and never welded into one fragment: where a wheel rests on the
    chassis, their faces coincide, and one mesh of both would pair them across the contact.
    """
    rv, rf = cut.meshes[piece]
    region = _region_manifold(rv, rf, cut.region_id, piece)
    bodies = cut.solids if solids is None else solids
    out = []
    for body in bodies:
        if len(bodies) > 1 and _boxes_apart(body, rv):
            continue
        part = body ^ region
        if part.is_empty() or part.volume() <= cut.min_volume:
            continue
        frag = _to_fragment(part, piece, cut.id_to_material, cut.interior_index, cut.surface, cut.options,
                            cut.min_volume)
        # As split_fragments measures them, here on the workers.
        volumes = [mass_properties(frag.vertices, frag.faces[faces]).volume
                   for faces in body_faces(frag.vertices, frag.faces)]
        out.append((frag, volumes))
    return out


def _boxes_apart(body: manifold3d.Manifold, region_vertices: np.ndarray) -> bool:
    """Whether a body's bounding box and a region's vertices' box do not meet."""
    box = np.asarray(body.bounding_box(), dtype=np.float64)
    lo, hi = region_vertices.min(axis=0), region_vertices.max(axis=0)
    return bool(np.any(box[:3] > hi) or np.any(lo > box[3:]))


def _with_interior(materials: tuple[Material, ...], color: list) -> tuple[int, tuple[Material, ...]]:
    """The interior material's slot and the materials with it (the recipe's colour).

    The repair stage may already have given the surface an interior slot (faces
    closing its holes): it is reused, so the asset has one interior material.
    """
    r, g, b, a = (float(c) for c in color)
    interior = Material(INTERIOR_MATERIAL_NAME, base_color=(r, g, b, a))
    names = [m.name for m in materials]
    if INTERIOR_MATERIAL_NAME in names:
        index = names.index(INTERIOR_MATERIAL_NAME)
        return index, tuple(interior if i == index else m for i, m in enumerate(materials))
    return len(names), tuple(materials) + (interior,)


def _region_manifold(vertices: np.ndarray, faces: np.ndarray, region_id: int, piece: int) -> manifold3d.Manifold:
    props = np.zeros((len(vertices), _NUM_COLUMNS))
    props[:, :3] = vertices
    mesh = manifold3d.Mesh64(
        vert_properties=props,
        tri_verts=np.ascontiguousarray(faces, dtype=np.uint64),
        run_index=np.array([0, 3 * len(faces)], dtype=np.uint64),
        run_original_id=np.array([region_id], dtype=np.uint32),
    )
    region = manifold3d.Manifold(mesh)
    if region.status() != manifold3d.Error.NoError:
        raise StageError(f"the region of piece {piece} is not a closed manifold mesh ({region.status()}); "
                         "regions must come from the smooth stage", stage=STAGE)
    return region


def _to_fragment(part: manifold3d.Manifold, piece: int, id_to_material: dict, interior_index: int, surface: SurfaceMesh,
                 options: FragmentOptions, min_shell_volume: float) -> Fragment:
    """Turn a manifold3d result into a Fragment with split interior vertices."""
    mesh = part.to_mesh64()
    props = np.array(mesh.vert_properties, dtype=np.float64)
    tris = np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)
    # Zero-volume shells left where region and input faces coincide are dropped (cavities are kept).
    keep = shell_mask(mesh, min_shell_volume)
    run_index = np.asarray(mesh.run_index, dtype=np.int64) // 3
    run_ids = np.asarray(mesh.run_original_id, dtype=np.int64)
    material = np.empty(len(tris), dtype=np.int32)
    for r, original in enumerate(run_ids.tolist()):
        if original not in id_to_material:
            if run_index[r] == run_index[r + 1]:
                continue  # an operand none of whose faces is left (a crop's box)
            raise StageError(f"a boolean result has faces of unknown origin (id {original})", stage=STAGE)
        material[run_index[r]:run_index[r + 1]] = id_to_material[original]
    tris, material = tris[keep], material[keep]

    inside = material == interior_index
    positions = props[:, :3]
    normals = props[:, _NORMAL].copy()
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > tol.ROUNDOFF, normals / np.maximum(length, tol.SMALLEST_DIVISOR), 0.0)
    uvs = props[:, _UV].copy()

    # Interior faces: one vertex per (vertex, plane) so normals are flat and
    # UVs follow the face's projection axis.
    ti = tris[inside]
    a, b, c = positions[ti[:, 0]], positions[ti[:, 1]], positions[ti[:, 2]]
    fn = np.cross(b - a, c - a)
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    offset = np.einsum("ij,ij->i", fn, a)
    plane_key = np.column_stack([np.round(fn * 1e6), np.round(offset * 1e9)]).astype(np.int64)
    _, plane = unique_rows(plane_key, return_inverse=True)
    plane = plane.reshape(-1)
    corner_key = np.column_stack([ti.reshape(-1), np.repeat(plane, 3)])
    uniq, corner_vertex = unique_rows(corner_key, return_inverse=True)
    corner_vertex = corner_vertex.reshape(-1)
    new_positions = positions[uniq[:, 0]]
    # Each plane's normal: mean of its faces' normals (they agree to 1e-6).
    plane_normal = np.zeros((plane.max() + 1 if len(plane) else 0, 3))
    np.add.at(plane_normal, plane, fn)
    plane_normal /= np.maximum(np.linalg.norm(plane_normal, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    new_normals = plane_normal[uniq[:, 1]]
    new_uvs = box_uvs(surface.normalization.to_world(new_positions), new_normals, options.uv_scale)

    outer_used = used_vertices(tris[~inside], len(props))
    remap = np.full(len(props), -1, dtype=np.int64)
    remap[outer_used] = np.arange(len(outer_used))
    vertices = np.vstack([positions[outer_used], new_positions])
    all_normals = np.vstack([normals[outer_used], new_normals])
    all_uvs = np.vstack([uvs[outer_used], new_uvs])
    faces = np.empty_like(tris)
    faces[~inside] = remap[tris[~inside]]
    faces[inside] = len(outer_used) + corner_vertex.reshape(-1, 3)
    return Fragment(
        vertices=vertices,
        faces=faces,
        uvs=all_uvs,
        normals=all_normals,
        material_ids=material,
        piece=piece,
    )
