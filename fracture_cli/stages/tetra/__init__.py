"""The ``tetra`` stage: a quality tet mesh of the cage that keeps its surface exactly."""

from __future__ import annotations

from typing import TYPE_CHECKING

from fracture_cli.stages.tetra.options import STAGE, TetraOptions

if TYPE_CHECKING:
    from fracture_cli.types import Cage, TetMesh


def tetra(cage: Cage, options: TetraOptions = TetraOptions()) -> TetMesh:
    """Tetrahedralize the inside of a cage, keeping the cage surface as the boundary.

    Parameters
    ----------
    cage : Cage
        A closed, manifold, outward-oriented surface (from :func:`fracture_cli.stages.cage.cage`).
    options : TetraOptions, optional
        ``radius_edge_ratio`` (default 1.5), ``min_dihedral`` (default 10
        degrees), ``max_volume`` (default 0 = no limit; fraction of the cage
        volume), ``optimization`` (default 1), ``timeout`` (default 300 s).

    Returns
    -------
    TetMesh
        ``vertices (n, 3) float64`` (the cage's vertices first, then interior
        Steiner points) and ``tets (t, 4) int64`` with positive volumes. Its
        boundary faces are exactly the cage's faces.

    Raises
    ------
    StageError
        If TetGen fails, crashes or times out, or its result is not a valid
        tet mesh of the cage.

    Notes
    -----
    ALGORITHM.md section 1, step 4 (TetGen ``p`` with quality ``q``); ``Y``
    forbids Steiner points on the boundary so fragments later cut along the
    exact cage. Quality points are added only inside; because the boundary
    cannot be split, tets touching it may stay above the quality and volume
    bounds. TetGen runs in a child
    process (see :mod:`fracture_cli.stages.tetra.tetgen`) and is deterministic.
    """
    # on first use: a recipe reads TetraOptions from here without loading the stage's libraries
    from fracture_cli.stages.tetra.mesh import build_tet_mesh

    return build_tet_mesh(cage, options)


__all__ = ["STAGE", "TetraOptions", "tetra"]
