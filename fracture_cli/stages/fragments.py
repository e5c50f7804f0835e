"""Fragments: the input mesh intersected with each piece region (ALGORITHM.md section 6)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import manifold3d
import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.options import option
from fracture_cli.stages._solids import shell_mask
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Fragment, Fragments, Material, Regions, SurfaceMesh

log = logging.getLogger(__name__)

STAGE = "fragments"

# Vertex property layout carried through the booleans: position, uv, normal.
_UV = slice(3, 5)
_NORMAL = slice(5, 8)
_NUM_COLUMNS = 8
# Connected parts of a fragment below this fraction of the input volume are
# boolean artefacts (zero-volume shells where faces coincide), not material.
_SHELL_VOLUME = 1e-9
# Rounding of fragment centroids for the export order (normalized units).
_ORDER_DECIMALS = 6


@dataclass(frozen=True)
class FragmentOptions:
    """Options of :func:`fragments`."""

    uv_scale: float = option(
        1.0,
        "interior faces' box-projected UVs: world units (input units) per UV unit",
        min=0.0,
        min_exclusive=True,
    )
    hole_filling: str = option(
        "fan",
        "an input that is still open after welding: 'fan' closes each hole with a fan around its centroid "
        "(interior material), 'error' stops",
        choices=("fan", "error"),
    )


def fragments(surface: SurfaceMesh, regions: Regions, options: FragmentOptions = FragmentOptions()) -> Fragments:
    """Cut the input surface into one closed fragment per piece region.

    Parameters
    ----------
    surface : SurfaceMesh
        The input, normalized coordinates; may have UV seams (split vertices),
        several materials, overlapping closed parts, and (with
        ``hole_filling='fan'``) holes.
    regions : Regions
        One closed region per piece, partitioning a volume that contains the input.
    options : FragmentOptions, optional
        ``uv_scale`` (default 1.0 world unit per UV unit) and ``hole_filling``
        (default ``'fan'``).

    Returns
    -------
    Fragments
        Non-empty fragments sorted by their centroid (x, then y, then z, rounded
        to 1e-6); ``Fragment.piece`` names the piece of each. ``materials`` are
        the input's plus the interior material as the last slot.

    Raises
    ------
    StageError
        If the input cannot be made a closed solid, or a region is not a valid
        closed mesh.

    Notes
    -----
    ALGORITHM.md section 6. Input preparation: vertices at the same position are
    welded topologically (manifold3d merge vectors) while keeping their own UVs
    and normals, then open edges are merged within manifold3d's tolerance
    (``MeshGL.merge``); a mesh of several closed, overlapping bodies is
    replaced by their union. If the surface is still open, each hole is closed
    by a fan around its boundary's centroid (its faces are interior material),
    or the stage stops with ``hole_filling='error'``.

    Each fragment is ``input ^ region`` in manifold3d with UV and normal as
    vertex properties: outer faces keep the input's values (interpolated where
    a face is cut), material ids travel as manifold3d run ids. Faces that come
    from the region are the new inside: interior material, flat normals
    (vertices split per plane), and UVs from a box projection of world-space
    positions divided by ``uv_scale``.

    Pieces whose region misses the input are logged and left out; the lead's
    runtime uses ``Fragment.piece`` to map fragments to pieces.
    """
    solid, id_to_material, cap_id = _input_solid(surface, options)
    input_volume = float(solid.volume())
    if input_volume <= 0:
        raise StageError("the input encloses no volume; fragments need a solid (closed) mesh", stage=STAGE)
    interior_index = len(surface.materials)
    region_id = manifold3d.Manifold.reserve_ids(1)
    id_to_material = dict(id_to_material)
    id_to_material[region_id] = interior_index
    if cap_id is not None:
        id_to_material[cap_id] = interior_index

    results = []
    empty = []
    for piece, (rv, rf) in enumerate(regions.meshes):
        region = _region_manifold(rv, rf, region_id, piece)
        part = solid ^ region
        volume = part.volume()
        if part.is_empty() or volume <= _SHELL_VOLUME * input_volume:
            empty.append(piece)
            continue
        results.append(_to_fragment(part, piece, id_to_material, interior_index, surface, options,
                                    _SHELL_VOLUME * input_volume))
    if empty:
        log.warning("%s: %d piece(s) do not reach the input and give no fragment: %s", STAGE, len(empty),
                    ", ".join(map(str, empty[:20])) + (" ..." if len(empty) > 20 else ""))
    if not results:
        raise StageError("no piece region intersects the input; the regions do not belong to this mesh", stage=STAGE)

    order = _stable_order(results)
    materials = tuple(surface.materials) + (Material(INTERIOR_MATERIAL_NAME, base_color=(0.55, 0.5, 0.45, 1.0)),)
    total = sum(_mesh_volume(f.vertices, f.faces) for f in results)
    log.info("%s: %d fragments from %d regions, volume %.6g of input %.6g (error %.2g)", STAGE, len(results),
             len(regions.meshes), total, input_volume, abs(total - input_volume) / input_volume)
    return Fragments(
        fragments=tuple(results[i] for i in order),
        materials=materials,
        normalization=surface.normalization,
        input_volume=input_volume,
    )


def _input_solid(surface: SurfaceMesh, options: FragmentOptions):
    """The input as a manifold3d solid with uv/normal properties and one run id per material."""
    V = np.asarray(surface.vertices, dtype=np.float64)
    F = np.asarray(surface.faces, dtype=np.int64)
    n = len(V)
    uvs = surface.uvs if surface.uvs is not None else np.zeros((n, 2))
    normals = surface.normals if surface.normals is not None else _vertex_normals_by_position(V, F)
    props = np.ascontiguousarray(np.hstack([V, uvs, normals]), dtype=np.float64)

    material_ids = np.asarray(surface.material_ids, dtype=np.int64)
    order = np.argsort(material_ids, kind="stable")
    F = F[order]
    material_ids = material_ids[order]
    num_materials = len(surface.materials)
    first_id = manifold3d.Manifold.reserve_ids(num_materials)
    id_to_material = {first_id + i: i for i in range(num_materials)}
    used = np.unique(material_ids)
    run_starts = np.searchsorted(material_ids, used)
    run_index = np.append(run_starts, len(F)) * 3

    # Topological weld of vertices at exactly the same position (UV seams, hard normals).
    _, first, inverse = np.unique(V, axis=0, return_index=True, return_inverse=True)
    target = first[inverse.reshape(-1)]
    from_vert = np.flatnonzero(target != np.arange(n))

    def build(props, faces, run_index, run_ids, from_vert, to_vert):
        mesh = manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(props, dtype=np.float64),
            tri_verts=np.ascontiguousarray(faces, dtype=np.uint64),
            merge_from_vert=np.ascontiguousarray(from_vert, dtype=np.uint64),
            merge_to_vert=np.ascontiguousarray(to_vert, dtype=np.uint64),
            run_index=np.ascontiguousarray(run_index, dtype=np.uint64),
            run_original_id=np.ascontiguousarray(run_ids, dtype=np.uint32),
        )
        mesh.merge()  # welds what remains open within manifold3d's tolerance
        return mesh, manifold3d.Manifold(mesh)

    run_ids = first_id + used
    mesh, solid = build(props, F, run_index, run_ids, from_vert, target[from_vert])
    cap_id = None
    if solid.status() != manifold3d.Error.NoError:
        welded = _weld_map(mesh, n)
        boundary, nonmanifold = _open_edges(welded[F])
        if nonmanifold:
            raise StageError(
                f"the input has {nonmanifold} edges shared by more than two faces (or two faces with the same "
                "orientation) after welding; fragments need a closed, consistently oriented surface. Repair the "
                "mesh (e.g. remove duplicate or flipped faces) and try again",
                stage=STAGE,
            )
        if options.hole_filling == "error":
            raise StageError(
                f"the input is open: {len(boundary)} boundary edges after welding vertices by position; close "
                "the mesh in your modelling tool, or use hole_filling='fan'",
                stage=STAGE,
            )
        loops = _boundary_loops(boundary)
        cap_props, cap_faces = _fan_caps(props, welded, loops)
        log.warning("%s: the input is open; closed %d hole(s) (%d boundary edges) with fans of interior faces",
                    STAGE, len(loops), len(boundary))
        cap_id = manifold3d.Manifold.reserve_ids(1)
        all_props = np.vstack([props, cap_props])
        all_faces = np.vstack([F, cap_faces])
        run_index = np.append(run_index, len(all_faces) * 3)
        run_ids = np.append(run_ids, cap_id)
        m = len(all_props)
        welded_all = np.concatenate([welded, np.arange(n, m)])
        from_vert = np.flatnonzero(welded_all != np.arange(m))
        mesh, solid = build(all_props, all_faces, run_index, run_ids, from_vert, welded_all[from_vert])
        if solid.status() != manifold3d.Error.NoError:
            raise StageError(
                f"the input is open and closing its {len(loops)} hole(s) did not give a closed surface "
                f"({solid.status()}); close the mesh in your modelling tool",
                stage=STAGE,
            )

    components = solid.decompose()
    if len(components) > 1:
        volumes = [c.volume() for c in components]
        if min(volumes) > 0:
            # Separate bodies stored as one mesh may overlap: their union is the solid.
            solid = manifold3d.Manifold.batch_boolean(components, manifold3d.OpType.Add)
            log.info("%s: the input has %d closed parts; using their union", STAGE, len(components))
        else:
            log.info("%s: the input has %d shells (some are cavities); kept as they are", STAGE, len(components))
    return solid, id_to_material, cap_id


def _weld_map(mesh, n: int) -> np.ndarray:
    """Representative vertex (n,) of each vertex under a mesh's merge vectors."""
    target = np.arange(n)
    src = np.asarray(mesh.merge_from_vert, dtype=np.int64)
    dst = np.asarray(mesh.merge_to_vert, dtype=np.int64)
    target[src] = dst
    # Chains a -> b -> c collapse to their end.
    for _ in range(64):
        nxt = target[target]
        if np.array_equal(nxt, target):
            break
        target = nxt
    return target


def _open_edges(F: np.ndarray):
    """Directed boundary edges (b, 2) of a welded triangle list, and the count of non-manifold edges."""
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    directed = directed[directed[:, 0] != directed[:, 1]]
    key = np.sort(directed, axis=1)
    uniq, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    forward = directed[:, 0] < directed[:, 1]
    n_forward = np.bincount(inverse, weights=forward, minlength=len(uniq))
    bad = (counts > 2) | ((counts == 2) & (n_forward != 1))
    single = counts[inverse] == 1
    return directed[single], int(bad.sum())


def _boundary_loops(boundary: np.ndarray) -> list[np.ndarray]:
    """Chain directed boundary edges (b, 2) into closed loops of vertex ids."""
    nxt: dict[int, list[int]] = {}
    for a, b in boundary.tolist():
        nxt.setdefault(a, []).append(b)
    loops = []
    visited_edges = set()
    for a0, b0 in boundary.tolist():
        if (a0, b0) in visited_edges:
            continue
        loop = [a0]
        a, b = a0, b0
        while True:
            visited_edges.add((a, b))
            if b == a0:
                break
            loop.append(b)
            options = [c for c in nxt.get(b, []) if (b, c) not in visited_edges]
            if not options:
                raise StageError("the input's holes are not simple loops (a boundary vertex is pinched); close "
                                 "the mesh in your modelling tool", stage=STAGE)
            a, b = b, options[0]
        loops.append(np.array(loop, dtype=np.int64))
    return loops


def _fan_caps(props: np.ndarray, welded: np.ndarray, loops: list[np.ndarray]):
    """Fans closing each hole: one new vertex at the loop's centroid, faces opposite to the boundary edges.

    Returns the new vertices' properties (h, 8) and the cap faces (c, 3), which
    reference the loops' welded vertices and the new vertices ``len(props) + i``.
    """
    centres = np.zeros((len(loops), _NUM_COLUMNS))
    faces = []
    for i, loop in enumerate(loops):
        centres[i, :3] = props[loop, :3].mean(axis=0)
        following = np.roll(loop, -1)
        # The surface's boundary edges run loop[j] -> loop[j+1]; the cap runs the other way.
        faces.append(np.stack([following, loop, np.full(len(loop), len(props) + i)], axis=1))
    cap_faces = np.concatenate(faces) if faces else np.zeros((0, 3), np.int64)
    return centres, cap_faces


def _region_manifold(vertices: np.ndarray, faces: np.ndarray, region_id: int, piece: int):
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


def _to_fragment(part, piece: int, id_to_material: dict, interior_index: int, surface: SurfaceMesh,
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
            raise StageError(f"a boolean result has faces of unknown origin (id {original})", stage=STAGE)
        material[run_index[r]:run_index[r + 1]] = id_to_material[original]
    tris, material = tris[keep], material[keep]

    inside = material == interior_index
    positions = props[:, :3]
    normals = props[:, _NORMAL].copy()
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > 1e-12, normals / np.maximum(length, 1e-300), 0.0)
    uvs = props[:, _UV].copy()

    # Interior faces: one vertex per (vertex, plane) so normals are flat and
    # UVs follow the face's projection axis.
    ti = tris[inside]
    a, b, c = positions[ti[:, 0]], positions[ti[:, 1]], positions[ti[:, 2]]
    fn = np.cross(b - a, c - a)
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    offset = np.einsum("ij,ij->i", fn, a)
    plane_key = np.column_stack([np.round(fn * 1e6), np.round(offset * 1e9)]).astype(np.int64)
    _, plane = np.unique(plane_key, axis=0, return_inverse=True)
    plane = plane.reshape(-1)
    corner_key = np.column_stack([ti.reshape(-1), np.repeat(plane, 3)])
    uniq, corner_vertex = np.unique(corner_key, axis=0, return_inverse=True)
    corner_vertex = corner_vertex.reshape(-1)
    new_positions = positions[uniq[:, 0]]
    # Each plane's normal: mean of its faces' normals (they agree to 1e-6).
    plane_normal = np.zeros((plane.max() + 1 if len(plane) else 0, 3))
    np.add.at(plane_normal, plane, fn)
    plane_normal /= np.maximum(np.linalg.norm(plane_normal, axis=1, keepdims=True), 1e-300)
    new_normals = plane_normal[uniq[:, 1]]
    new_uvs = _box_uvs(surface.normalization.to_world(new_positions), new_normals, options.uv_scale)

    outer_used = np.unique(tris[~inside])
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


def _box_uvs(world: np.ndarray, normals: np.ndarray, uv_scale: float) -> np.ndarray:
    """Box (tri-planar) projection UVs (n, 2) of world positions along each normal's dominant axis."""
    axis = np.argmax(np.abs(normals), axis=1)
    sign = np.sign(normals[np.arange(len(normals)), axis])
    sign[sign == 0] = 1.0
    # (u, v) axes per dominant axis; u flips with the normal's sign so textures are not mirrored.
    u_axis = np.array([1, 0, 0])[axis]
    v_axis = np.array([2, 2, 1])[axis]
    rows = np.arange(len(world))
    u = world[rows, u_axis] * sign * np.where(axis == 1, -1.0, 1.0)
    v = world[rows, v_axis]
    return np.column_stack([u, v]) / uv_scale


def _vertex_normals_by_position(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted normals (n, 3) averaged over vertices sharing a position."""
    _, pos = np.unique(V, axis=0, return_inverse=True)
    pos = pos.reshape(-1)
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    acc = np.zeros((pos.max() + 1, 3))
    for k in range(3):
        np.add.at(acc, pos[F[:, k]], fn)
    n = acc[pos]
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def _mesh_volume(V: np.ndarray, F: np.ndarray) -> float:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _mesh_centroid(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    total = vol.sum()
    if abs(total) < 1e-300:
        return V.mean(axis=0)
    return ((a + b + c) / 4.0 * vol[:, None]).sum(axis=0) / total


def _stable_order(results: list[Fragment]) -> np.ndarray:
    keys = np.array([_mesh_centroid(f.vertices, f.faces) for f in results])
    keys = np.round(keys, _ORDER_DECIMALS)
    pieces = np.array([f.piece for f in results])
    return np.lexsort((pieces, keys[:, 2], keys[:, 1], keys[:, 0]))
