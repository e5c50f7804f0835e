"""The ``cage`` stage: a coarse closed surface that strictly contains the input.

A binary search on an offset ``d`` (paper Algorithm 2): offset surface of the
input at distance ``d`` -> decimate -> reject if broken -> check containment
-> TetGen. The tightest ``d`` that passes every check wins.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fracture_cli.stages.cage.options import DECIMATORS, STAGE, CageOptions

if TYPE_CHECKING:
    from fracture_cli.types import Cage, SurfaceMesh

__all__ = ["DECIMATORS", "STAGE", "CageOptions", "cage"]


def cage(surface: SurfaceMesh, options: CageOptions = CageOptions()) -> Cage:
    """Build a nested cage: a closed manifold surface of about ``target_faces`` triangles strictly containing the input.

    Parameters
    ----------
    surface : SurfaceMesh
        The input, in normalized coordinates; may be open, non-manifold or
        made of several parts (only its triangles matter).
    options : CageOptions, optional
        ``target_faces`` (default 2000), ``grid_resolution`` (default 0 =
        automatic), ``initial_offset`` (default 0.01), ``tolerance`` (default
        0.002), ``max_iterations`` (default 12), ``max_offset`` (default 0.5),
        ``tetgen_timeout`` (default 60 s), ``decimator`` (default
        "fast-simplification").

    Returns
    -------
    Cage
        ``vertices (n, 3) float64``, outward ``faces (m, 3) int64``, the offset
        used and one log entry per tried offset.

    Raises
    ------
    StageError
        If no offset up to ``max_offset`` gave a valid cage within
        ``max_iterations`` tries.

    Notes
    -----
    ALGORITHM.md section 1 (paper Algorithm 2). Each try: unsigned distance on
    a grid, outer sheet of its level set ``d`` by marching cubes, quadric
    decimation, rejection of non-manifold or self-intersecting results (the
    paper's "self-union" step; decimation sometimes folds the surface and
    manifold3d does not repair a single self-intersecting mesh), a strict
    containment check independent of the construction, and a boundary-preserving
    TetGen run (``pYO0Q``) in a crash-safe child process. Distances and the
    inside vote are :mod:`fracture_cli.geometry.surface_query`'s (exact float64, the same
    bits on every machine; open3d is loaded only for ``decimator = "open3d"``),
    on one hierarchy of the input that the pieces stage and the report's checks
    reuse (:func:`fracture_cli.geometry.scenes.surface_scene`). Containment is not
    monotone in ``d``, so the search brackets upward from ``initial_offset``
    (doubling), then bisects, keeping the tightest success seen.
    """
    # on first use: a recipe reads CageOptions from this package without loading the distance field and TetGen
    from fracture_cli.stages.cage.build import nested_cage

    return nested_cage(surface, options)
