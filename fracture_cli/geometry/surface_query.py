"""Compiled (numba) queries on a fixed triangle mesh: closest distances and ray casts, float64, deterministic.

The cage stage measures distances from grid points and cage triangles to the
input and votes inside/outside by ray parity; the pieces stage tests sample
points for inside; the report measures fragment vertices against the input;
thickening casts rays behind an open sheet. These used open3d's Embree scene,
which works in float32 and picks SIMD code paths by CPU (so last bits, and the
decisions they feed, could differ between machines), and whose import costs
0.4-1.4 s of every bake.

:func:`build` makes a bounding-volume hierarchy by a fixed rule: top down,
each node's triangles split by the binned surface-area heuristic along the
longest axis of their box centres (ties to the first bin, partitions in place
by one fixed loop), leaves of at most :data:`LEAF_SIZE` triangles (on the
sample assets 10-25% faster queries than a Morton-order hierarchy, on a
million-triangle sphere about the same). Node boxes are widened by
:data:`~fracture_cli.geometry.tolerances.SAME_POINT` of the mesh's scale, far more than any rounding of the
triangle tests, so pruning a node never drops a triangle the test would keep:
every query returns what a brute-force loop over all triangles with the same
per-triangle arithmetic returns, whatever the traversal order.

* :func:`distances`: unsigned distance from points to the mesh, exact (the
  projection onto the triangle's plane when it falls strictly inside its edges,
  else the nearest of the three edges as segments; degenerate triangles are
  their edges), optionally only below an upper bound (farther points get inf,
  and the search stops early).
* :func:`first_hits`, :func:`hit_counts`: rays are sheared so that they run
  along an axis (the watertight ray-triangle test of Woop, Benthin and Wald
  2013); each triangle's 2D edge functions are products of the corners' sheared
  coordinates, so an edge shared by two triangles gets exactly opposite values
  in both. An edge function that is exactly zero (the ray through an edge or a
  corner) takes the sign it would have for the ray moved by an infinitesimal
  ``(e1, e2)``, ``e1 >> e2 > 0``, in the sheared plane: a ray through an edge
  inside a closed surface crosses exactly one of its two triangles, through a
  silhouette edge none or both. A hit needs ``t > 0``.
  Many rays along one direction are counted through a uniform grid across
  it instead, with the same triangle test (the same counts).
* :func:`inside`: a majority vote of the ray parities along
  :data:`VOTE_DIRECTIONS`.

The kernels (:mod:`fracture_cli.geometry.surface_kernels`) use only ``+ - * /``,
comparisons and ``sqrt`` (correctly rounded): no transcendental functions, no
fastmath, one point or ray per loop iteration with no shared reduction, no
threads. They give the same bits with numba compiled for this CPU or for a
generic x86-64 one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.surface_kernels import cast_rays, closest_d2, count_parallel, node_boxes, sah_tree

# Triangles per leaf.
LEAF_SIZE = 4
# Ray directions of the inside vote; irrational-looking on purpose so rays do not run along grid-aligned edges.
VOTE_DIRECTIONS = np.array(
    [[0.5773, 0.6123, 0.5402], [-0.7071, 0.3162, 0.6325], [0.2673, -0.8018, 0.5345]], dtype=np.float64
)
# Bins of the surface-area split, and the level from which nodes are split in the middle of their range
# (so that no input makes the hierarchy, and the traversal stacks, deeper than 48 + log2(m) levels).
_BINS = 16
# The grid of many parallel rays (hit_counts): at least this many cells per triangle, and at most this many rays
# per cell, in all at most _GRID_CELLS.
_GRID_CELLS_PER_TRIANGLE = 2
_GRID_RAYS_PER_CELL = 8
_GRID_CELLS = 1 << 22
_SAH_LEVELS = 48


@dataclass(frozen=True)
class SurfaceQuery:
    """A bounding-volume hierarchy over a triangle mesh (see :func:`build`).

    Attributes
    ----------
    corners : (m, 3, 3) float64
        The triangles' corners, in leaf order.
    box : (n, 2, 3) float64
        Each node's widened box (min, max); node 0 is the root, nodes in preorder (a node's left child follows it).
    right : (n,) int64
        Each inner node's right child; -1 for a leaf.
    start, count : (n,) int64
        Each leaf's first triangle (in ``corners``) and how many.
    depth : int
        The number of levels (the traversal stack's size).
    scale : float
        The larger of the mesh's extent and its largest coordinate (what the margins are fractions of).
    """

    corners: np.ndarray
    box: np.ndarray
    right: np.ndarray
    start: np.ndarray
    count: np.ndarray
    depth: int
    scale: float


def build(vertices: np.ndarray, faces: np.ndarray) -> SurfaceQuery:
    """The hierarchy of triangles ``faces`` (m, 3) int over ``vertices`` (n, 3) float (used as float64).

    Unreferenced vertices do not matter; the same arrays give the same hierarchy on any machine.
    """
    corners = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)])
    corners = corners.reshape(-1, 3, 3)
    if len(corners) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return SurfaceQuery(corners, np.zeros((0, 2, 3)), empty, empty, empty, 0, 0.0)
    order, right, start, count, depth = sah_tree(corners, LEAF_SIZE, _BINS, _SAH_LEVELS)
    corners = np.ascontiguousarray(corners[order])
    # The mesh's scale: its extent or its largest coordinate, whichever is larger (float64 rounding of the
    # triangle tests is ~1e-16 of it).
    scale = max(float(np.abs(corners).max()), float((corners.max(axis=(0, 1)) - corners.min(axis=(0, 1))).max()))
    box = node_boxes(corners, right, start, count, tol.SAME_POINT * scale)
    return SurfaceQuery(corners, box, right, start, count, int(depth), scale)


def distances(query: SurfaceQuery, points: np.ndarray, upper: float | np.ndarray | None = None) -> np.ndarray:
    """Unsigned distance (k,) float64 from each of ``points`` (k, 3) to the mesh.

    Parameters
    ----------
    query : SurfaceQuery
    points : (k, 3) float
    upper : float or (k,) float, optional (default none)
        Only distances up to this matter: a point farther than ``upper`` may get inf instead (its search
        ends as soon as nothing nearer is left); every point within it gets its distance.

    Returns
    -------
    (k,) float64
        The exact distance (inf for an empty mesh, or beyond ``upper``).
    """
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if upper is None:
        bound2 = np.full(len(points), np.inf)
    else:
        bound = np.broadcast_to(np.asarray(upper, dtype=np.float64), (len(points),))
        # Widened by far more than the rounding of squares, so that no distance <= upper is cut off.
        bound2 = np.ascontiguousarray((bound * bound) * (1.0 + tol.TIE))
    if len(query.corners) == 0 or len(points) == 0:
        return np.full(len(points), np.inf)
    d2 = closest_d2(query.corners, query.box, query.right, query.start, query.count, query.depth, points, bound2)
    return np.sqrt(d2)


def _rays(query: SurfaceQuery, origins: np.ndarray, directions: np.ndarray, first: bool) -> np.ndarray:
    origins = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.ascontiguousarray(np.broadcast_to(np.asarray(directions, dtype=np.float64), origins.shape))
    if not np.all(np.any(directions != 0.0, axis=1)):
        raise ValueError("a ray direction is zero")
    if len(query.corners) == 0 or len(origins) == 0:
        return np.full(len(origins), np.inf if first else 0.0)
    return cast_rays(query.corners, query.box, query.right, query.start, query.count, query.depth, origins,
                     directions, first)


def first_hits(query: SurfaceQuery, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance (k,) float64 along each ray to the first triangle it crosses at ``t > 0``; inf if none.

    ``origins`` (k, 3); ``directions`` (k, 3) or (3,), nonzero; ``t`` is in units of each direction's length
    (the distance for unit directions).
    """
    return _rays(query, origins, directions, True)


def hit_counts(query: SurfaceQuery, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """How many triangles (k,) int64 each ray crosses at ``t > 0`` (``origins`` (k, 3), ``directions`` (k, 3) or
    (3,)); a ray through a shared edge or corner counts by the rule of the module docstring.

    Many rays along one direction (at least as many as triangles) go through a grid across the direction
    instead of the hierarchy (:func:`~fracture_cli.geometry.surface_kernels.count_parallel`; the same
    triangle test, so the same counts, several times faster).
    """
    direction = np.asarray(directions, dtype=np.float64)
    origins = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    if direction.shape != (3,) or len(origins) < len(query.corners) or len(query.corners) == 0:
        return _rays(query, origins, directions, False).astype(np.int64)
    if not np.any(direction != 0.0):
        raise ValueError("a ray direction is zero")
    # As the node boxes' margin: far above the rounding of the shear, here of origins too.
    scale = max(query.scale, float(np.abs(origins).max()))
    cells = min(max(_GRID_CELLS_PER_TRIANGLE * len(query.corners), len(origins) // _GRID_RAYS_PER_CELL), _GRID_CELLS)
    return count_parallel(query.corners, origins, direction, tol.SAME_POINT * scale, cells)


def inside(query: SurfaceQuery, points: np.ndarray) -> np.ndarray:
    """Whether each of ``points`` (k, 3) is inside the closed mesh (k,) bool: odd ray parity along at least two
    of the three :data:`VOTE_DIRECTIONS`.

    The third ray is cast only from the points on which the first two disagree: the others' vote is decided.
    """
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    first = hit_counts(query, points, VOTE_DIRECTIONS[0]) % 2 == 1
    second = hit_counts(query, points, VOTE_DIRECTIONS[1]) % 2 == 1
    result = first & second
    undecided = np.flatnonzero(first != second)
    if len(undecided):
        result[undecided] = hit_counts(query, points[undecided], VOTE_DIRECTIONS[2]) % 2 == 1
    return result


def warm_kernels() -> None:
    """Compile (or load from the cache) the kernels, on a tetrahedron."""
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    query = build(vertices, np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]))
    points = np.array([[0.1, 0.1, 0.1], [2.0, 2.0, 2.0]])
    distances(query, points)
    distances(query, points, 0.5)
    first_hits(query, points, np.array([1.0, 0.0, 0.0]))
    hit_counts(query, points, np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    inside(query, points)  # many rays along one direction: the grid
