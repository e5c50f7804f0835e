"""Laplacian fault smoothing: closed piece regions that partition the cage (ALGORITHM.md section 5).

The stage function and its options. The two methods live in :mod:`.geometric`
(move tet vertices) and :mod:`.field` (smooth the piece field on a refined
mesh); both build their regions with :mod:`.marching` (multi-label marching
tets), which falls back to :mod:`.cells` (unions of convex cells).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.options import option
from fracture_cli.stages.smooth.cells import union_regions
from fracture_cli.stages.smooth.field import forced_field, refined, winning_field
from fracture_cli.stages.smooth.geometric import smoothed_vertices
from fracture_cli.stages.smooth.marching import region_defects, repaired_regions
from fracture_cli.stages.smooth.topology import STAGE, Topology
from fracture_cli.types import Pieces, Regions, SurfaceMesh, TetMesh

__all__ = ["STAGE", "SmoothOptions", "smooth"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SmoothOptions:
    """Options of :func:`smooth`."""

    smoothing: float = option(
        1e-3,
        "fault smoothing lambda in units of (bbox diagonal)^2, about the square of the radius over which faults "
        "are rounded; 0 = faults follow tet faces",
        min=0.0,
    )
    method: str = option(
        "geometric",
        "geometric: move the tet vertices so the tet-aligned faults become smooth surfaces (pieces keep their "
        "tets); field: smooth the piece membership field and cut tets along its level sets",
        choices=("geometric", "field"),
    )
    refine: int = option(
        2,
        "field method: levels of regular 1:8 tet refinement before smoothing, so faults are cut along a finer "
        "mesh than the cage tets (fewer levels when the refined mesh would exceed max_refined_tets); it pays off "
        "when sqrt(smoothing) is at least about the refined tet edge, else the faults zigzag at the fine scale",
        min=0,
        max=3,
    )
    max_refined_tets: int = option(
        400_000,
        "field method: the most tets refinement may create (memory and time grow with it)",
        min=1,
    )
    vanish_fraction: float = option(
        0.01,
        "field method: a piece whose smoothed region is below this fraction of its own volume gets its field "
        "raised to keep about its volume, and if that fails keeps its own tets",
        min=0.0,
        max=1.0,
    )


def smooth(tet_mesh: TetMesh, pieces: Pieces, options: SmoothOptions = SmoothOptions(),
           surface: SurfaceMesh | None = None) -> Regions:
    """Closed regions of space, one per atomic piece, with smoothed faults.

    Parameters
    ----------
    tet_mesh : TetMesh
        The tet mesh of the cage (``n`` vertices, ``t`` tets).
    pieces : Pieces
        Atomic pieces; ``pieces.tet_piece`` (t,) assigns every tet to a piece.
    options : SmoothOptions, optional
        ``smoothing`` (lambda, default 1e-3), ``method`` (default
        ``"geometric"``); field method only: ``refine`` (default 2),
        ``max_refined_tets`` (default 400000) and ``vanish_fraction``
        (default 0.01).
    surface : SurfaceMesh, optional (default None)
        The (repaired) input the cage contains, in the same normalized
        coordinates. Geometric method only: when given, fault vertices on the
        cage boundary may slide along the cage wherever the moved cage still
        strictly contains it; without it cage-boundary vertices never move.

    Returns
    -------
    Regions
        For each piece a closed, edge-manifold, outward-oriented triangle mesh
        (vertices (n_i, 3) float64, faces (m_i, 3) int64) of its region; the
        regions partition the cage. ``vanished`` lists the pieces that kept
        their own tets.

    Raises
    ------
    StageError
        If ``pieces`` does not match ``tet_mesh`` or a region cannot be built.

    Notes
    -----
    ALGORITHM.md section 5 describes both methods, the direct construction of
    the regions and what happens where a region touches itself or a piece
    would vanish. ``lambda`` has units of length^2 in normalized coordinates
    for both methods (``sqrt(lambda)`` is roughly the radius over which faults
    are rounded); ``lambda = 0`` gives tet-aligned faults with either method.
    Smoothing never creates or removes a piece.
    """
    t = tet_mesh.num_tets
    tet_piece = np.asarray(pieces.tet_piece, dtype=np.int64)
    if tet_piece.shape != (t,):
        raise StageError(f"pieces cover {tet_piece.shape[0]} tets but the tet mesh has {t}", stage=STAGE)
    p = pieces.num_pieces
    lam = float(options.smoothing)
    if lam > 0.0 and options.method == "field":
        tet_mesh, tet_piece = refined(tet_mesh, tet_piece, options.refine, options.max_refined_tets)
        t = tet_mesh.num_tets
    V, T = tet_mesh.vertices, tet_mesh.tets
    topo = Topology(T, tet_mesh.num_vertices)

    vanished: list[int] = []
    Z: np.ndarray | None = None
    if lam == 0.0 or options.method == "geometric":
        if lam > 0.0:
            V, moves = smoothed_vertices(tet_mesh, topo, tet_piece, p, lam, surface)
            log.info("%s: geometric smoothing moved %d fault vertices (%d on junction curves, %d slid along the cage, "
                     "%d sent back to keep the cage around the input), %d held back in %d round(s) to keep tets from "
                     "flattening, displacement scale %g", STAGE, moves["moved"], moves["curve"], moves["slid"],
                     moves["reverted"], moves["frozen"], moves["rounds"], moves["alpha"])
        meshes, pinches, repaired = repaired_regions(V, T, topo, None, np.ones(t, dtype=bool), tet_piece, p)
    else:
        Z, vanished, built = winning_field(tet_mesh, topo, tet_piece, pieces, lam, options.vanish_fraction)
        forced, Zv = forced_field(Z, tet_piece, vanished)
        meshes, pinches, repaired = repaired_regions(V, T, topo, Zv, forced, tet_piece, p, first=built)

    broken = [P for P in range(p) if region_defects(*meshes[P])]
    if broken:
        log.warning("%s: %d region(s) were not closed and edge-manifold when built directly (e.g. piece %d); "
                    "rebuilding them as unions of cells", STAGE, len(broken), broken[0])
        rebuilt = union_regions(V, T, Z, tet_piece, p, vanished, broken)
        for P, mesh in zip(broken, rebuilt):
            meshes[P] = mesh
    log.info("%s: %d regions, lambda=%g, %d triangles, %d vanished, %d tet(s) made tet-aligned, %d pinched edge(s) "
             "given a spindle", STAGE, p, lam, sum(len(f) for _, f in meshes), len(vanished), repaired, pinches)
    return Regions(meshes=tuple(meshes), smoothing=lam, vanished=tuple(sorted(vanished)))
