"""Laplacian fault smoothing: closed piece regions that partition the cage (ALGORITHM.md section 5).

The stage function and its options (:mod:`.options`); the work is in :mod:`.regions`.
The two methods live in :mod:`.geometric` (move tet vertices) and :mod:`.field` (smooth the piece field on a refined
mesh); both build their regions with :mod:`.marching` (multi-label marching
tets), which falls back to :mod:`.cells` (unions of convex cells).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fracture_cli.stages.smooth.options import STAGE, SmoothOptions

if TYPE_CHECKING:
    from fracture_cli.types import Pieces, Regions, SurfaceMesh, TetMesh


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
    # on first use: a recipe reads SmoothOptions from here without loading the stage's libraries
    from fracture_cli.stages.smooth.regions import smoothed_regions

    return smoothed_regions(tet_mesh, pieces, options, surface)


__all__ = ["STAGE", "SmoothOptions", "smooth"]
