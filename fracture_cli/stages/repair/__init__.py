"""Repair: turn any loaded surface into one closed, outward-oriented solid, and say what was done.

The cage (section 1) and the fragments (section 6) must agree on what the solid
is, so the input is made a solid once, right after loading, and both use the
result. This package holds the stage function and its options (:mod:`.options`); the
steps are in :mod:`.solid` (duplicates, winding, non-manifold edges, holes, sheets),
:mod:`.carry` keeps UVs, normals and colours through them, and :mod:`.cleanup`,
:mod:`.orient` and :mod:`.closing` hold the rest.

The policy (README, "Accepted inputs"): solid or shell is decided from the mesh.
Holes are filled when they close into a solid; anything else open is a sheet,
thickened behind its visible side inside the input's bounding box; edges and
vertices shared by several bodies are split; only what has no inside is
refused. Every repair is a :class:`~fracture_cli.stages.repair.records.RepairRecord`
(report.json ``repairs``), and the ones that change the shape are logged as
warnings with the per-asset override.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fracture_cli.stages.repair.options import FLAT_HINT, SNAP_TOLERANCE, STAGE, RepairOptions, RepairResult

if TYPE_CHECKING:
    from fracture_cli.types import SurfaceMesh

__all__ = ["FLAT_HINT", "SNAP_TOLERANCE", "STAGE", "RepairOptions", "RepairResult", "repair", "repair_surface"]


def repair(surface: SurfaceMesh, options: RepairOptions = RepairOptions()) -> SurfaceMesh:
    """Make a surface a closed, edge-manifold, outward-oriented solid (see :func:`repair_surface`)."""
    return repair_surface(surface, options).surface


def repair_surface(surface: SurfaceMesh, options: RepairOptions = RepairOptions()) -> RepairResult:
    """Make a surface a closed, edge-manifold, outward-oriented solid, recording every repair.

    Parameters
    ----------
    surface : SurfaceMesh
        The loaded input, normalized coordinates. May have UV seams (vertices
        split at one position), degenerate and duplicated faces, inconsistent
        winding, several overlapping or touching bodies, cavities, holes and
        open sheets.
    options : RepairOptions, optional

    Returns
    -------
    RepairResult
        ``surface`` is closed when its vertices are welded by position, every
        edge in exactly two faces of opposite orientation, positive volume.
        Vertices stay split where their attributes differ; the input's
        positions are kept (vertices of touching bodies within
        :data:`SNAP_TOLERANCE` are snapped to one). Faces added to close the
        surface carry an ``interior`` material slot. A surface that needs no
        repair is returned as it is.

    Raises
    ------
    StageError
        If the surface has no inside (flat, nothing left after removing
        degenerate faces, edges whose faces do not bound alternating solid and
        empty wedges), is open and ``open_surface='error'``, has holes that
        cannot be filled with ``open_surface='fill'``, or a sheet that cannot
        be thickened.

    Notes
    -----
    ALGORITHM.md section 8 ("Input repair") lists the steps: weld and snap,
    remove degenerate and repeated faces, orient, split non-manifold edges and
    vertices, fill or thicken what is open, orient bodies (cavities inward),
    union overlapping bodies.
    """
    # on first use: a recipe reads RepairOptions from this package without loading manifold3d and the steps
    from fracture_cli.stages.repair.solid import repair_surface as repair_solid

    return repair_solid(surface, options)
