"""Convex hulls for the collision parts: manifold3d solids, canonical corners, the vertex cap.

Shared by the decomposition (:mod:`~fracture_cli.stages.collision.decompose`), the
separation (:mod:`~fracture_cli.stages.collision.separate`) and the stage
(:mod:`~fracture_cli.stages.collision.convex`). Everything is deterministic: the
same points give the same corners in the same (lexicographic) order.
"""

from __future__ import annotations

import manifold3d
import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.trigeom import cross3

# Pieces and parts with less volume are dropped.
MIN_PART_VOLUME = 1e-12


def mesh_of(solid: manifold3d.Manifold) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and faces (m, 3) of a manifold3d solid."""
    mesh = solid.to_mesh64()
    # Copies: manifold3d hands out read-only buffers, and its constructors refuse read-only input.
    return (np.array(mesh.vert_properties, dtype=np.float64)[:, :3].copy(),
            np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3))


def solid_of(vertices: np.ndarray, faces: np.ndarray) -> manifold3d.Manifold:
    """A manifold3d solid of a closed mesh whose vertices may be split (welded by position)."""
    V, weld = np.unique(np.asarray(vertices, dtype=np.float64), axis=0, return_inverse=True)
    F = weld.reshape(-1)[np.asarray(faces, dtype=np.int64)]
    return manifold3d.Manifold(manifold3d.Mesh64(vert_properties=V, tri_verts=F.astype(np.uint64)))


def hull_of(points: np.ndarray) -> manifold3d.Manifold:
    """The convex hull of points (k, 3) as a manifold3d solid."""
    return manifold3d.Manifold.hull_points(np.ascontiguousarray(points, dtype=np.float64))


def hull_mesh(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The convex hull of points (k, 3) as a triangle mesh: vertices (n, 3), outward faces (m, 3)."""
    return mesh_of(hull_of(points))


def canonical(V: np.ndarray) -> np.ndarray:
    """Points (k, 3) sorted lexicographically (the canonical order of a part's corners)."""
    return V[np.lexsort(V.T[::-1])]


def hull_corners(solid: manifold3d.Manifold) -> np.ndarray:
    """Corners (k, 3) of a solid's convex hull, sorted lexicographically (a canonical order)."""
    return canonical(mesh_of(solid.hull())[0])


def face_planes(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit outward normals (m', 3) and offsets (m',) of a convex mesh's faces (``normal . x <= offset`` inside);
    faces without area (no normal) are left out."""
    normal, offset, area = _planes(V, F)
    keep = area > 0
    return normal[keep], offset[keep]


def surface_area(V: np.ndarray, F: np.ndarray) -> float:
    """Total area of a triangle mesh's faces."""
    return float(_planes(V, F)[2].sum())


def _planes(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normals (m, 3), offsets (m,) and areas (m,) of a mesh's faces."""
    corner = V[F[:, 0]]
    normal = cross3(V[F[:, 1]] - corner, V[F[:, 2]] - corner)
    length = np.sqrt(np.einsum("ij,ij->i", normal, normal))
    normal /= np.maximum(length, tol.SMALLEST_DIVISOR)[:, None]
    return normal, np.einsum("ij,ij->i", normal, corner), 0.5 * length


def simplify_hull(points: np.ndarray, max_vertices: int) -> np.ndarray:
    """At most ``max_vertices`` corners of a convex part, as a subset of its corners (so it only shrinks).

    Parameters
    ----------
    points : (k, 3) float
        Corners of a convex part (or any points: their hull is the part).
    max_vertices : int
        Cap on the number of corners (>= 4).

    Returns
    -------
    (k', 3) float64
        Hull corners of the simplified part, ``k' <= max_vertices``, sorted
        lexicographically; a subset of the input's hull corners.

    Notes
    -----
    Greedy farthest-point insertion: start from a large tetrahedron of
    corners, then repeatedly add the corner farthest outside the current hull
    (largest distance to a face plane) until the cap is reached or every corner
    is inside. Each step adds the point that removes the largest error of the
    current approximation, so the result covers the part well; ties go to the
    first corner in lexicographic order, so it is deterministic.
    """
    corners = hull_corners(hull_of(points))
    if len(corners) <= max_vertices:
        return corners
    chosen = _initial_tetrahedron(corners)
    scale = float(np.linalg.norm(np.ptp(corners, axis=0)))
    # The corners still outside the current hull, in order. One inside it stays inside the larger hulls that
    # follow (up to rounding, far below the tol.ROUNDOFF that stops the loop), so it is never the farthest again and
    # is not looked at again: most of a dense hull's corners drop out after a few insertions.
    outside_ids = np.setdiff1d(np.arange(len(corners)), chosen)
    # on first use: numba loads when a part needs the cap, not with this module (io.physics imports it)
    from fracture_cli.geometry.hull_kernels import outside_distances

    while len(chosen) < max_vertices and len(outside_ids):
        V, F = hull_mesh(corners[chosen])
        # max_beyond(corners[outside_ids], *face_planes(V, F)), compiled: the same bits, without numpy's
        # per-call overhead, which was most of a step's time.
        outside, planes = outside_distances(corners[outside_ids], V, F)
        if planes == 0:
            outside = max_beyond(corners[outside_ids], *face_planes(V, F))  # no plane: numpy's error
        farthest = int(np.argmax(outside))  # the first of equals: the ids are in order
        if outside[farthest] <= tol.ROUNDOFF * scale:
            break
        chosen.append(int(outside_ids[farthest]))
        keep = outside > 0
        keep[farthest] = False
        outside_ids = outside_ids[keep]
    return hull_corners(hull_of(corners[chosen]))


def max_beyond(points: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """For points (k, 3), the largest ``normal . x - offset`` (k,) over planes (normals (m, 3), offsets (m,)).

    The same values as ``(points @ normal.T - offset).max(axis=1)``, compiled
    (:func:`.hull_kernels.max_beyond`: the same bits, without numpy's overhead over a part's few dozen planes);
    numpy's product where there is no plane (its error) or a point.
    """
    if len(normal) and len(points):
        # on first use: numba loads with the collision stage, not with this module (io.physics imports it)
        from fracture_cli.geometry import hull_kernels

        return hull_kernels.max_beyond(np.ascontiguousarray(points, dtype=np.float64),
                                       np.ascontiguousarray(normal, dtype=np.float64),
                                       np.ascontiguousarray(offset, dtype=np.float64))
    heights = points @ normal.T
    heights -= offset
    # Reduced along the transposed view: numpy reduces a short contiguous row at a time, ~8x slower.
    return np.maximum.reduce(heights.T, axis=0)


def _initial_tetrahedron(points: np.ndarray) -> list[int]:
    """Indices of four points spanning a large tetrahedron (the classic quickhull start)."""
    centre = points.mean(axis=0)
    a = int(np.argmax(np.linalg.norm(points - centre, axis=1)))
    b = int(np.argmax(np.linalg.norm(points - points[a], axis=1)))
    ab = points[b] - points[a]
    c = int(np.argmax(np.linalg.norm(cross3(points - points[a], ab[None, :]), axis=1)))
    normal = cross3(ab, points[c] - points[a])
    d = int(np.argmax(np.abs((points - points[a]) @ normal)))
    return list(dict.fromkeys([a, b, c, d]))


def overlap_bound_separated(corners_a: np.ndarray, planes_a: tuple[np.ndarray, np.ndarray], corners_b: np.ndarray,
                            slack: float) -> bool:
    """Whether a face plane of convex part a has a's corners on its inside and b's beyond it, up to ``slack``.

    Then the two parts overlap at most in a slab ``2 slack`` thick along that
    plane: a volume below ``2 slack`` times a's largest cross-section. A
    plane is used only if it supports a (a degenerate face's normal may point
    anywhere).
    """
    normal, offset = planes_a
    if len(corners_b) == 0 or len(normal) == 0:
        return True
    if len(corners_a):
        # Compiled (the same products and comparisons, stopping at the first separating plane): thousands of
        # pairs per bake ask, and numpy's overhead over a part's few dozen corners was most of the time.
        from fracture_cli.geometry import hull_kernels

        return bool(hull_kernels.plane_separates(np.ascontiguousarray(corners_a, dtype=np.float64),
                                                 np.ascontiguousarray(normal, dtype=np.float64),
                                                 np.ascontiguousarray(offset, dtype=np.float64),
                                                 np.ascontiguousarray(corners_b, dtype=np.float64), float(slack)))
    supports = (corners_a @ normal.T).max(axis=0) - offset <= slack  # no corner: numpy's error
    beyond = (corners_b @ normal.T).min(axis=0) - offset >= -slack
    return bool((supports & beyond).any())
