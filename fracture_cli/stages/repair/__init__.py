"""Repair: turn any loaded surface into one closed, outward-oriented solid.

The cage (section 1) and the fragments (section 6) must agree on what the solid
is, so the input is made a solid once, right after loading, and both use the
result. This module holds the stage function and its steps; :mod:`.cleanup`,
:mod:`.orient` and :mod:`.closing` hold the work of each step.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass

import manifold3d
import numpy as np

from fracture_cli import tetgeom, trigeom
from fracture_cli.errors import StageError
from fracture_cli.meshtopo import (
    boundary_edge_faces,
    boundary_edges,
    components,
    nonmanifold_edges,
    propagate_winding,
    unique_faces,
)
from fracture_cli.options import option
from fracture_cli.stages._solids import (
    COLOR,
    NORMAL,
    NUM_COLUMNS,
    POS,
    UV,
    SplitMesh,
    from_manifold,
    to_manifold,
    union_bodies,
    vertex_properties,
    weld_map,
)
from fracture_cli.stages.repair.cleanup import boundary_loops, fan_area, is_flat, split_nonmanifold
from fracture_cli.stages.repair.closing import fill, interior_slot, shell
from fracture_cli.stages.repair.orient import (
    component_orientation,
    fix_shading_normals,
    internal_open_faces,
    sheet_orientation,
)
from fracture_cli.types import Material, SurfaceMesh

__all__ = ["FLAT_HINT", "STAGE", "RepairOptions", "repair"]

log = logging.getLogger(__name__)

STAGE = "repair"

# A solid of a unit-diagonal box enclosing less than this has no inside.
_MIN_VOLUME = 1e-9

FLAT_HINT = ("give it thickness in your modelling tool, or use --set repair.open_surface=shell to thicken it "
             "into a thin solid")
_FLAT_MESSAGE = "flat: all vertices lie in one plane, so it has no inside; " + FLAT_HINT


@dataclass(frozen=True)
class RepairOptions:
    """Options of :func:`repair`."""

    open_surface: str = option(
        "auto",
        "what to do with a surface that is open after welding: 'fill' closes each hole with a fan of interior "
        "faces, 'shell' thickens the sheet into a thin solid, 'auto' fills small holes (total hole area at most "
        "max_fill_ratio of the surface area) and shells otherwise, 'error' stops",
        choices=("auto", "fill", "shell", "error"),
    )
    shell_thickness: float = option(
        0.01,
        "thickness of a shelled sheet, relative to the bounding-box diagonal (thinner where the sheet folds "
        "tighter than that)",
        min=0.0,
        max=0.5,
        min_exclusive=True,
    )
    max_fill_ratio: float = option(
        0.02,
        "open_surface='auto' fills holes whose total area is at most this fraction of the surface area",
        min=0.0,
        max=1.0,
    )


def repair(surface: SurfaceMesh, options: RepairOptions = RepairOptions()) -> SurfaceMesh:
    """Make a surface a closed, edge-manifold, outward-oriented solid.

    Parameters
    ----------
    surface : SurfaceMesh
        The loaded input, normalized coordinates. May have UV seams (vertices
        split at one position), degenerate and duplicated faces, inconsistent
        winding, several overlapping closed bodies, cavities, and holes.
    options : RepairOptions, optional
        ``open_surface`` (default ``'auto'``), ``shell_thickness`` (default
        0.01 of the bounding-box diagonal) and ``max_fill_ratio`` (default 0.02).

    Returns
    -------
    SurfaceMesh
        Closed when its vertices are welded by position, every edge in exactly
        two faces of opposite orientation, positive volume. Vertices stay split
        where their attributes differ (seams keep their UVs and normals);
        positions are the input's (vertices merged within manifold3d's
        tolerance are snapped to one position). Faces added to close the
        surface carry an ``interior`` material slot (appended, or the input's
        own slot of that name). ``normalization`` and ``name`` are unchanged.
        A surface that needs no repair is returned as it is.

    Raises
    ------
    StageError
        If the surface has no inside (flat, or nothing left after removing
        degenerate faces), is open and ``open_surface='error'``, has edges
        shared by more than two faces, or cannot be shelled or filled into a
        valid solid.

    Notes
    -----
    ALGORITHM.md section 8 ("Repair") lists the steps: weld, remove
    degenerate and duplicated faces, orient, close open parts (fill, shell or
    auto), union overlapping bodies. Each step that changes something is logged.
    """
    t0 = time.perf_counter()
    did: list[str] = []
    mesh, num_welded, flat = _weld_and_clean(surface, did)
    mesh, patch = _orient_patches(mesh, did)
    mesh, materials = _close_open(mesh, patch, flat, options, tuple(surface.materials), did)
    mesh = _orient_components(mesh, did, surface.normals is not None)
    mesh, volume = _solid(mesh, len(materials), flat, did)
    welded = f"welded {num_welded} seam vertices by position"
    if not did:
        log.info("%s: %s: %s; a closed solid, nothing to repair (volume %.6g, %.2f s)", STAGE, surface.name,
                 welded, volume, time.perf_counter() - t0)
        return surface
    props, F = trigeom.compact(mesh.props, mesh.faces)
    log.info("%s: %s: %s, %s; %d faces, volume %.6g (%.2f s)", STAGE, surface.name, welded, ", ".join(did), len(F),
             volume, time.perf_counter() - t0)
    normals = props[:, NORMAL]
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > 1e-12, normals / np.maximum(length, 1e-300), 0.0)
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


def _weld_and_clean(surface: SurfaceMesh, did: list[str]) -> tuple[SplitMesh, int, bool]:
    """Steps 1-2: weld by position, drop degenerate and duplicated faces, split many-face edges into bodies.

    Returns the mesh, the number of vertices welded to another, and whether it is flat.
    """
    F = np.asarray(surface.faces, dtype=np.int64)
    material_ids = np.asarray(surface.material_ids, dtype=np.int32)
    props = vertex_properties(surface, NUM_COLUMNS)
    weld = weld_map(props[:, :3], F)
    num_welded = int((weld != np.arange(len(props))).sum())
    snapped = np.any(props[weld, POS] != props[:, POS], axis=1)
    if snapped.any():
        props[:, POS] = props[weld, POS]  # vertices merged within tolerance get one position
        did.append(f"snapped {int(snapped.sum())} nearly coincident vertices together")
    W = weld[F]
    degenerate = (W[:, 0] == W[:, 1]) | (W[:, 1] == W[:, 2]) | (W[:, 2] == W[:, 0])
    if degenerate.any():
        did.append(f"removed {int(degenerate.sum())} degenerate faces")
    F, W, material_ids = F[~degenerate], W[~degenerate], material_ids[~degenerate]
    keep, num_duplicates, num_back_to_back = unique_faces(W)
    if num_duplicates:
        did.append(f"removed {num_duplicates} duplicated faces")
    if num_back_to_back:
        did.append(f"removed {num_back_to_back} back-to-back face pairs")
    mesh = SplitMesh(props, F[keep], material_ids[keep], weld)
    flat = is_flat(props[np.unique(mesh.faces), :3]) if len(mesh.faces) else True
    if len(mesh.faces) == 0:
        raise StageError("no faces are left after removing degenerate and duplicated faces: "
                         + (_FLAT_MESSAGE if flat else "the mesh encloses nothing"), stage=STAGE)
    if nonmanifold_edges(mesh.welded):
        mesh, leftover, note = split_nonmanifold(mesh)
        did.append(note)
        if leftover:
            raise StageError(
                f"{leftover} edges are shared by more than two faces after welding vertices by position, and the "
                "faces around them do not split into closed bodies (two bodies touching along an edge, or cells "
                "sharing an internal wall, are handled), so the mesh has no well-defined inside there; separate the "
                "touching parts in your modelling tool", stage=STAGE)
    return mesh, num_welded, flat


def _orient_patches(mesh: SplitMesh, did: list[str]) -> tuple[SplitMesh, np.ndarray]:
    """Step 3a: consistent winding within each edge-connected patch; returns the mesh and each face's patch (m,)."""
    flip, patch = propagate_winding(mesh.welded)
    if flip.any():
        did.append(f"re-wound {int(flip.sum())} faces")
    mesh.faces[flip] = mesh.faces[flip][:, ::-1]
    return mesh, patch


def _close_open(mesh: SplitMesh, patch: np.ndarray, flat: bool, options: RepairOptions,
                materials: tuple[Material, ...], did: list[str]) -> tuple[SplitMesh, tuple[Material, ...]]:
    """Step 4: close what is open (fill or shell); open sheets entirely inside a closed body go first."""
    boundary = boundary_edges(mesh.welded)
    if len(boundary):
        inside = internal_open_faces(mesh.props[:, POS], mesh.welded, mesh.weld)
        if inside.any():
            did.append(f"removed {int(inside.sum())} internal faces (open sheets inside the solid)")
            mesh = dataclasses.replace(mesh, faces=mesh.faces[~inside], material_ids=mesh.material_ids[~inside])
            _, patch = np.unique(patch[~inside], return_inverse=True)
            patch = patch.reshape(-1)
            boundary = boundary_edges(mesh.welded)
    if not len(boundary):
        return mesh, materials
    loops = boundary_loops(boundary)
    mode = options.open_surface
    hole_area = sum(fan_area(mesh.props[loop, :3]) for loop in loops)
    surface_area = float(tetgeom.triangle_areas(mesh.props[:, :3], mesh.faces).sum())
    ratio = hole_area / surface_area if surface_area > 0 else np.inf
    where = (f"the mesh is open at {len(loops)} boundary loop(s) ({len(boundary)} boundary edges, holes "
             f"{100 * ratio:.3g}% of the surface area) after welding vertices by position")
    if mode == "error":
        raise StageError(f"{where}; close it in your modelling tool, or use --set repair.open_surface=fill "
                         "(close small holes) or --set repair.open_surface=shell (thicken the sheet)", stage=STAGE)
    if mode == "auto":
        if flat:
            raise StageError(_FLAT_MESSAGE, stage=STAGE)
        mode = "fill" if ratio <= options.max_fill_ratio else "shell"
        log.info("%s: %s; auto: %s (fill limit %.3g%%)", STAGE, where, mode, 100 * options.max_fill_ratio)
    interior_material, materials = interior_slot(materials)
    if mode == "fill":
        did.append(f"filled {len(loops)} hole(s)")
        return fill(mesh, loops, interior_material), materials
    patch_open = np.zeros(patch.max() + 1, dtype=bool)
    patch_open[patch[boundary_edge_faces(mesh.welded, boundary)]] = True
    sheet = patch_open[patch]
    sheet_flip = sheet_orientation(mesh.props, mesh.faces, patch, sheet)
    mesh.faces[sheet_flip] = mesh.faces[sheet_flip][:, ::-1]
    mesh, thinned = shell(mesh, sheet, boundary_edges(mesh.welded), options.shell_thickness, interior_material)
    did.append(f"shelled {int(len(np.unique(patch[sheet])))} open sheet(s) (thickness {options.shell_thickness:g}"
               + (f", thinner at {thinned} vertices)" if thinned else ")"))
    return mesh, materials


def _orient_components(mesh: SplitMesh, did: list[str], has_normals: bool) -> SplitMesh:
    """Step 3b: each closed component outward (cavities inward); shading normals agree with their faces."""
    component = components(mesh.welded, len(mesh.props))
    flip_component = component_orientation(mesh.props[:, :3], mesh.faces, component)
    flip = flip_component[component]
    if flip.any():
        did.append(f"flipped {int(flip_component.sum())} inside-out component(s)")
    mesh.faces[flip] = mesh.faces[flip][:, ::-1]
    num_normals = fix_shading_normals(mesh.props, mesh.faces)
    if num_normals and has_normals:
        did.append(f"flipped {num_normals} shading normals")
    return mesh


def _solid(mesh: SplitMesh, num_materials: int, flat: bool, did: list[str]) -> tuple[SplitMesh, float]:
    """Step 5: check the mesh is a valid manifold and union overlapping bodies; returns it and its volume."""
    solid, id_to_material = to_manifold(mesh, num_materials)
    if solid.status() != manifold3d.Error.NoError:
        raise StageError(f"the repaired mesh is not a valid manifold ({solid.status().name}); fix the mesh in "
                         "your modelling tool", stage=STAGE)
    solid, bodies, cavities = union_bodies(solid)
    if bodies > 1:
        did.append(f"unioned {bodies} overlapping bodies" + (f" minus {cavities} cavities" if cavities else ""))
        props, F, material_ids = from_manifold(solid, id_to_material)
        mesh = SplitMesh(props, F, material_ids, np.arange(len(props)))
    volume = float(solid.volume())
    if volume <= _MIN_VOLUME:
        if flat:
            raise StageError(_FLAT_MESSAGE, stage=STAGE)
        raise StageError(f"the repaired mesh encloses no volume ({volume:.3g} of a unit-diagonal box); it needs a "
                         "closed, solid shape", stage=STAGE)
    return mesh, volume
