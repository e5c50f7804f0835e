"""The ``repair`` stage's work: weld, orient, split, close and unite the input into one solid.

:func:`fracture_cli.stages.repair.repair_surface` is the stage's entry point (its docstring says what
is done); this module holds the steps, so that the package itself loads nothing heavy.
"""

from __future__ import annotations

import logging
import time

import manifold3d
import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.edges import edge_table
from fracture_cli.geometry.meshtopo import components
from fracture_cli.geometry.rows import used_vertices
from fracture_cli.geometry.solids import (
    COLOR,
    NORMAL,
    NUM_COLUMNS,
    POS,
    UV,
    SplitMesh,
    body_groups,
    from_manifold,
    to_manifold,
    union_bodies,
    vertex_properties,
    weld_map,
)
from fracture_cli.geometry.weld_check import collapsed
from fracture_cli.stages.repair.carry import after_split
from fracture_cli.stages.repair.clean import closed_as_given
from fracture_cli.stages.repair.cleanup import is_flat, snap_between_bodies
from fracture_cli.stages.repair.closing import fill_where_planned, interior_slot, open_bodies, thicken_sheets
from fracture_cli.stages.repair.faces import orient_consistently, unique_faces
from fracture_cli.stages.repair.fins import detach, empty_bodies, empty_record, fin_record, hinged_sheets, without
from fracture_cli.stages.repair.holes import FillOptions, boundary_loops
from fracture_cli.stages.repair.nonmanifold import NonManifoldSplit, split_nonmanifold
from fracture_cli.stages.repair.options import FLAT_HINT, SNAP_TOLERANCE, STAGE, RepairOptions, RepairResult
from fracture_cli.stages.repair.orient import (
    closed_patches_outward,
    component_orientation,
    fix_shading_normals,
    internal_open_faces,
)
from fracture_cli.stages.repair.records import RepairRecord
from fracture_cli.stages.repair.report import describe, warn_significant
from fracture_cli.types import Material, Normalization, SurfaceMesh

log = logging.getLogger(__name__)

_FLAT_MESSAGE = "flat: all vertices lie in one plane, so it has no inside; " + FLAT_HINT


def repair_surface(surface: SurfaceMesh, options: RepairOptions) -> RepairResult:
    """The stage's work (:func:`fracture_cli.stages.repair.repair_surface`)."""
    t0 = time.perf_counter()
    clean, clean_volume = closed_as_given(surface)
    if clean:
        # Every step below would find nothing to do (see .clean): the same result, without the work.
        decision = describe([], False)
        log.info("%s: %s: %s; volume %.6g (%.2f s)", STAGE, surface.name, decision.detail, clean_volume,
                 time.perf_counter() - t0)
        return RepairResult(surface, (decision,))
    records: list[RepairRecord] = []
    mesh, flat = _weld_and_clean(surface, records)
    mesh = _orient_and_split(mesh, surface.normalization, records, options.fins)
    box = np.stack([surface.vertices.min(axis=0), surface.vertices.max(axis=0)])
    materials = tuple(surface.materials)
    mesh, materials, shell = _close_open(mesh, flat, options, materials, box, surface.normals is not None, records)
    mesh = _orient_components(mesh, records, surface.normals is not None)
    mesh, volume = _solid(mesh, len(materials), flat, records, options.touching)
    changed = any(r.what not in _NO_CHANGE for r in records)
    records.insert(0, describe(records, shell))
    warn_significant(surface.name, records)
    log.info("%s: %s: %s; volume %.6g (%.2f s)", STAGE, surface.name, records[0].detail, volume,
             time.perf_counter() - t0)
    if not changed:
        return RepairResult(surface, tuple(records))
    return RepairResult(_as_surface(mesh, surface, materials), tuple(records))


# Records that describe the input without changing the geometry the later stages see.
_NO_CHANGE = {"welded_vertices"}


def _as_surface(mesh: SplitMesh, surface: SurfaceMesh, materials: tuple[Material, ...]) -> SurfaceMesh:
    """The repaired split mesh as a compact SurfaceMesh (attributes the input had, unit normals)."""
    props, F = trigeom.compact(mesh.props, mesh.faces)
    normals = props[:, NORMAL]
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > tol.ROUNDOFF, normals / np.maximum(length, tol.SMALLEST_DIVISOR), 0.0)
    return SurfaceMesh(
        vertices=np.ascontiguousarray(props[:, POS]),
        faces=np.ascontiguousarray(F, dtype=np.int64),
        uvs=np.ascontiguousarray(props[:, UV]) if surface.uvs is not None else None,
        normals=np.ascontiguousarray(normals) if surface.normals is not None else None,
        colors=np.ascontiguousarray(props[:, COLOR]) if surface.colors is not None else None,
        material_ids=np.ascontiguousarray(mesh.material_ids, dtype=np.int32),
        materials=materials,
        normalization=surface.normalization,
        name=surface.name,
    )


def _weld_and_clean(surface: SurfaceMesh, records: list[RepairRecord]) -> tuple[SplitMesh, bool]:
    """Weld by position, snap touching bodies together, drop degenerate and repeated faces.

    Returns the mesh and whether its vertices all lie in one plane.
    """
    F = np.asarray(surface.faces, dtype=np.int64)
    material_ids = np.asarray(surface.material_ids, dtype=np.int32)
    props = vertex_properties(surface, NUM_COLUMNS)
    weld = weld_map(props[:, :3], F)
    num_welded = int((weld != np.arange(len(props))).sum())
    if num_welded:
        records.append(RepairRecord("welded_vertices", f"welded {num_welded} vertices at one position (UV seams, "
                                    "split normals)", count=num_welded))
    snapped = np.any(props[weld, POS] != props[:, POS], axis=1)
    props[:, POS] = props[weld, POS]  # vertices merged within manifold3d's tolerance get one position
    num_snapped = snap_between_bodies(props, F, weld, SNAP_TOLERANCE)
    if snapped.any() or num_snapped:
        count = int(snapped.sum()) + num_snapped
        records.append(RepairRecord("snapped_vertices", f"snapped {count} nearly coincident vertices together "
                                    "(bodies touching, or open edges, a rounding step apart)", count=count))
    W = weld[F]
    degenerate = collapsed(W)
    if degenerate.any():
        records.append(RepairRecord("removed_degenerate_faces", f"removed {int(degenerate.sum())} degenerate faces "
                                    "(two corners at one position)", count=int(degenerate.sum())))
    F, W, material_ids = F[~degenerate], W[~degenerate], material_ids[~degenerate]
    unique = unique_faces(W)
    records += unique.records
    mesh = SplitMesh(props, F[unique.keep], material_ids[unique.keep], weld)
    flat = is_flat(props[used_vertices(mesh.faces, len(props)), :3]) if len(mesh.faces) else True
    if len(mesh.faces) == 0:
        raise StageError("no faces are left after removing degenerate and duplicated faces: "
                         + (_FLAT_MESSAGE if flat else "the mesh encloses nothing"), stage=STAGE)
    return mesh, flat


def _flipped(mesh: SplitMesh, flip: np.ndarray) -> SplitMesh:
    faces = mesh.faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    return SplitMesh(mesh.props, faces, mesh.material_ids, mesh.weld)


def _orient_and_split(mesh: SplitMesh, normalization: Normalization, records: list[RepairRecord],
                      fins: str = "thicken") -> SplitMesh:
    """Consistent winding across two-face edges; then edges of more than two faces and pinched vertices split.

    Where the faces around an edge do not bound alternating solid and empty
    wedges, open sheets hinged there (fins) are cut off (``fins``:
    ``thicken``: kept as sheets of their own, ``drop``: left out) and closed
    bodies enclosing nothing are left out (:mod:`.fins`).

    Raises
    ------
    StageError
        Where that does not give closed bodies (or ``fins`` is ``error``): no
        inside there.
    """
    table = edge_table(mesh.welded)
    flip, flipped = orient_consistently(mesh.welded, table)
    records += flipped
    turned = bool(flip.any())
    if turned:
        mesh = _flipped(mesh, flip)
    V = mesh.props[:, POS]
    if (table.count > 2).any():  # turning faces keeps the edges and their counts
        outward = closed_patches_outward(V, mesh.welded)
        if outward.any():
            records.append(RepairRecord("flipped_winding", f"turned {int(outward.sum())} faces of inside-out bodies "
                                        "that touch others outward", count=int(outward.sum())))
            mesh = _flipped(mesh, outward)
            turned = True
    # The table's sides are still the faces' when none was turned.
    split = split_nonmanifold(V, mesh.welded, None if turned else table)
    if fins != "error" and _lacks_inside(split):
        mesh, split = _cut_fins(mesh, split, fins, records)
    _refuse_without_inside(split, normalization)
    changes = [r for r in split.records if r.what != "unclosed_body"]
    if changes:
        records += changes
        mesh = after_split(mesh, split)
    return mesh


def _lacks_inside(split: NonManifoldSplit) -> bool:
    """Whether :func:`_refuse_without_inside` would refuse the split."""
    table = split.edges if split.edges is not None else edge_table(split.faces)
    flat = split.body_closed & (np.abs(split.body_volume) <= tol.SLIVER_VOLUME)
    return bool(len(split.unresolved_edges)) or bool((table.count > 2).any()) or bool(flat.any())


def _cut_fins(mesh: SplitMesh, split: NonManifoldSplit, policy: str,
              records: list[RepairRecord]) -> tuple[SplitMesh, NonManifoldSplit]:
    """Cut open sheets hinged on an edge of more than two faces off (or drop them), drop closed bodies enclosing
    nothing, and split again (see :mod:`.fins`)."""
    hinged = hinged_sheets(mesh.welded)
    if hinged.any():
        where = tuple(float(x) for x in mesh.props[np.unique(mesh.faces[hinged]), :3].mean(axis=0))
        mesh = without(mesh, hinged) if policy == "drop" else detach(mesh, hinged)
        records.append(fin_record(int(hinged.sum()), policy == "drop", where))
        split = split_nonmanifold(mesh.props[:, POS], mesh.welded)
    empty = empty_bodies(split, tol.SLIVER_VOLUME)
    if empty.any() and not len(split.unresolved_edges) and not empty.all():
        where = tuple(float(x) for x in mesh.props[np.unique(mesh.faces[empty]), :3].mean(axis=0))
        mesh = without(mesh, empty)
        records.append(empty_record(int(empty.sum()), where))
        split = split_nonmanifold(mesh.props[:, POS], mesh.welded)
    return mesh, split


def _refuse_without_inside(split: NonManifoldSplit, normalization: Normalization) -> None:
    """Refuse edges of more than two faces that the split could not pair into bodies with an inside.

    Left unpaired: faces that do not bound alternating solid and empty wedges
    (sheets hinged on a solid, a book's pages), edges still shared by more than
    two faces after the split, or bodies that close only onto themselves with
    no volume (a fin doubled into a wall of nothing).
    """
    table = split.edges if split.edges is not None else edge_table(split.faces)
    many = table.ends[table.count > 2]
    flat = split.body_closed & (np.abs(split.body_volume) <= tol.SLIVER_VOLUME)
    if len(split.unresolved_edges):
        ends = split.unresolved_edges
    elif len(many):
        ends = split.source_vertex[many]
    elif flat.any():
        ends = split.source_vertex[split.faces[np.isin(split.body, np.flatnonzero(flat))][:, :2]]
    else:
        return
    P = normalization.to_world(split.vertices[ends].mean(axis=1))
    where = ", ".join(f"({x:.4g}, {y:.4g}, {z:.4g})" for x, y, z in P[:3])
    raise StageError(
        f"{len(ends)} edges are shared by more than two faces that do not pair into closed bodies (fins or sheets "
        f"hinged on a solid, or identical faces of two overlapping parts; at {where}), so the mesh has no clear "
        "inside there; remove those faces, give them thickness or separate the parts in your modelling tool",
        stage=STAGE)


def _close_open(mesh: SplitMesh, flat: bool, options: RepairOptions, materials: tuple[Material, ...],
                box: np.ndarray, shading: bool,
                records: list[RepairRecord]) -> tuple[SplitMesh, tuple[Material, ...], bool]:
    """Close what is open: open sheets inside a closed body go; holes that close into a solid are filled
    ('auto', 'fill'); other open bodies are thickened inward ('auto', 'shell'). Returns whether any was."""
    if not open_bodies(mesh):
        return mesh, materials, False
    inside = internal_open_faces(mesh.props[:, POS], mesh.welded, mesh.weld)
    if inside.any():
        records.append(RepairRecord("removed_internal_faces", f"removed {int(inside.sum())} faces of open sheets "
                                    "lying inside the solid (internal faces)", count=int(inside.sum())))
        mesh = SplitMesh(mesh.props, mesh.faces[~inside], mesh.material_ids[~inside], mesh.weld)
        if not open_bodies(mesh):
            return mesh, materials, False
    mode = options.open_surface
    if mode == "error":
        loops = boundary_loops(mesh.welded)
        raise StageError(f"the mesh is open at {len(loops)} boundary loop(s) after welding vertices by position; "
                         "close it in your modelling tool, or use --set repair.open_surface=fill (close holes) or "
                         "--set repair.open_surface=shell (thicken the sheet)", stage=STAGE)
    if flat and mode != "shell":
        raise StageError(_FLAT_MESSAGE, stage=STAGE)
    interior_material, materials = interior_slot(materials)
    if mode != "shell":
        everything = float("inf")
        fill_options = (FillOptions(everything, everything, everything, container_opening=everything)
                        if mode == "fill" else
                        FillOptions(options.hole_planarity, options.small_hole, options.max_fill_share,
                                    container_opening=options.container_opening))
        mesh, plan, done = fill_where_planned(mesh, fill_options, interior_material)
        records += done
        refused = [b for b in plan.bodies if b.action != "fill"]
        if mode == "fill" and refused:
            raise StageError(f"cannot fill the holes of an open body: {refused[0].reason}; use --set "
                             "repair.open_surface=shell to thicken it, or close it in your modelling tool",
                             stage=STAGE)
    if not open_bodies(mesh):
        return mesh, materials, False
    mesh, done = thicken_sheets(mesh, options.shell_thickness, box, shading, interior_material)
    records += done
    return mesh, materials, True


def _orient_components(mesh: SplitMesh, records: list[RepairRecord], has_normals: bool) -> SplitMesh:
    """Each closed component outward (cavities inward); shading normals agree with their faces."""
    component = components(mesh.welded, len(mesh.props))
    flip_component = component_orientation(mesh.props[:, :3], mesh.faces, component)
    flip = flip_component[component]
    if flip.any():
        records.append(RepairRecord("flipped_winding", f"turned {int(flip_component.sum())} inside-out bodies "
                                    "outward", count=int(flip.sum())))
        mesh = _flipped(mesh, flip)
    num_normals = fix_shading_normals(mesh.props, mesh.faces)
    if num_normals and has_normals:
        records.append(RepairRecord("flipped_shading_normals", f"flipped {num_normals} shading normals that pointed "
                                    "into the solid", count=num_normals))
    return mesh


def _solid(mesh: SplitMesh, num_materials: int, flat: bool, records: list[RepairRecord],
           touching: str = "separate") -> tuple[SplitMesh, float]:
    """Check the mesh is a valid manifold and union overlapping bodies (``touching='unite'``: also those that only
    touch); returns it and its volume."""
    solid, id_to_material = to_manifold(mesh, num_materials)
    if solid.status() != manifold3d.Error.NoError:
        raise StageError(f"the repaired mesh is not a valid manifold ({solid.status().name}); fix the mesh in "
                         "your modelling tool", stage=STAGE)
    if touching == "unite":
        solid, bodies, cavities = union_bodies(solid)
        groups = [solid]
    else:
        groups, bodies, cavities = body_groups(solid)
    if bodies > 1:
        minus = f" minus {cavities} cavities" if cavities else ""
        if len(groups) == 1:
            records.append(RepairRecord("unioned_bodies", f"united {bodies} overlapping or touching bodies{minus}",
                                        count=bodies, extra={"cavities": cavities}))
        else:
            if len(groups) < bodies:
                records.append(RepairRecord("unioned_bodies", f"united the overlapping ones of {bodies} bodies into "
                                            f"{len(groups)}{minus}", count=bodies, extra={"cavities": cavities}))
            records.append(RepairRecord("kept_bodies_apart", f"kept {len(groups)} bodies that only touch (along a "
                                        "face, an edge or at a point) apart: each breaks on its own (to unite them: "
                                        "--set repair.touching=unite)", count=len(groups)))
        parts = [from_manifold(g, id_to_material) for g in groups]
        offsets = np.cumsum([0] + [len(p[0]) for p in parts])
        mesh = SplitMesh(np.vstack([p[0] for p in parts]), np.vstack([p[1] + o for p, o in zip(parts, offsets)]),
                         np.concatenate([p[2] for p in parts]), np.arange(int(offsets[-1])))
    volume = float(sum(g.volume() for g in groups))
    if volume <= tol.SLIVER_VOLUME:
        if flat:
            raise StageError(_FLAT_MESSAGE, stage=STAGE)
        raise StageError(f"the repaired mesh encloses no volume ({volume:.3g} of a unit-diagonal box); it needs a "
                         "closed, solid shape", stage=STAGE)
    return mesh, volume
