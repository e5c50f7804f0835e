"""Compiled (numba) step of :func:`fracture_cli.geometry.hulls.simplify_hull`: how far points lie outside a
convex mesh.

The vertex cap's greedy insertion asks this once per inserted corner (up to
60 times per part, for thousands of parts per bake), of a hull of at most
:data:`~fracture_cli.stages.collision.options.ENGINE_MAX_VERTICES` corners;
numpy's per-call overhead over those small arrays was most of its time.

The kernel computes the numpy expressions of :func:`~fracture_cli.geometry.hulls.face_planes`
and :func:`~fracture_cli.geometry.hulls.max_beyond` with the same IEEE
operations in the same order (no fastmath: no reassociation, no fused
multiply-adds), so the values are the same bits. Two orders are numpy's and
are spelled out here: ``np.einsum("ij,ij->i")`` over rows of three sums
``(x0 y0 + x2 y2) + x1 y1`` (its SIMD loop pairs the first and last), and the
matrix product of three-vectors (OpenBLAS, pinned to one kernel set by
:mod:`fracture_cli.system.numeric_env`) sums ``(x0 y0 + x1 y1) + x2 y2``;
tests/test_collision_kernels.py checks both bit for bit.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.system.jit import njit


@njit(error_model="numpy")
def outside_distances(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, int]:  # pragma: no cover
    """For each point, the largest signed distance beyond the face planes of a convex mesh.

    Parameters
    ----------
    points : (k, 3) float64
        The points.
    V : (n, 3) float64
        The mesh's vertices.
    F : (m, 3) int64
        Its outward faces.

    Returns
    -------
    outside : (k,) float64
        ``max over faces with area of (normal . p - offset)`` (unit outward normals; > 0: outside), as
        ``max_beyond(points, *face_planes(V, F))``; -inf where no face has area.
    planes : int
        The number of faces with area (0: ``max_beyond`` has no plane to take a maximum over).
    """
    m = F.shape[0]
    normal = np.empty((m, 3))
    offset = np.empty(m)
    planes = 0
    for f in range(m):
        c0, c1, c2 = V[F[f, 0], 0], V[F[f, 0], 1], V[F[f, 0], 2]
        u0, u1, u2 = V[F[f, 1], 0] - c0, V[F[f, 1], 1] - c1, V[F[f, 1], 2] - c2
        v0, v1, v2 = V[F[f, 2], 0] - c0, V[F[f, 2], 1] - c1, V[F[f, 2], 2] - c2
        # cross3, then the length (einsum's order) and the division by max(length, SMALLEST_DIVISOR).
        x = u1 * v2 - u2 * v1
        y = u2 * v0 - u0 * v2
        z = u0 * v1 - u1 * v0
        length = np.sqrt((x * x + z * z) + y * y)
        if not 0.5 * length > 0:
            continue  # no area: face_planes leaves it out
        divisor = max(length, tol.SMALLEST_DIVISOR)
        x, y, z = x / divisor, y / divisor, z / divisor
        normal[planes, 0], normal[planes, 1], normal[planes, 2] = x, y, z
        offset[planes] = (x * c0 + z * c2) + y * c1
        planes += 1
    outside = np.full(points.shape[0], -np.inf)
    for i in range(points.shape[0]):
        p0, p1, p2 = points[i, 0], points[i, 1], points[i, 2]
        best = -np.inf
        for f in range(planes):
            h = (p0 * normal[f, 0] + p1 * normal[f, 1] + p2 * normal[f, 2]) - offset[f]
            if f == 0 or h > best or h != h:
                if best == best:  # numpy's maximum keeps a nan
                    best = h
        outside[i] = best
    return outside, planes


@njit(error_model="numpy")
def plane_separates(corners_a: np.ndarray, normal: np.ndarray, offset: np.ndarray, corners_b: np.ndarray,
                    slack: float) -> bool:  # pragma: no cover (compiled)
    """Whether a plane ``normal . x = offset`` of a's has a's corners below it and b's beyond it, up to ``slack``.

    Parameters
    ----------
    corners_a, corners_b : (k_a, 3), (k_b, 3) float64
        Corners of two convex parts.
    normal : (m, 3) float64
        Unit outward normals of a's face planes.
    offset : (m,) float64
        Their offsets.
    slack : float
        Allowance on either side.

    Returns
    -------
    bool
        As ``((corners_a @ normal.T).max(axis=0) - offset <= slack) & ((corners_b @ normal.T).min(axis=0) -
        offset >= -slack)`` has a True entry (a nan height fails the plane, as numpy's maximum and minimum keep
        it); the planes in order, stopping at the first that separates.
    """
    for f in range(normal.shape[0]):
        n0, n1, n2 = normal[f, 0], normal[f, 1], normal[f, 2]
        top = -np.inf
        for i in range(corners_a.shape[0]):
            h = corners_a[i, 0] * n0 + corners_a[i, 1] * n1 + corners_a[i, 2] * n2
            if not h <= top:  # a larger height, or a nan (then the test below fails)
                top = h
                if h != h:
                    break
        if not top - offset[f] <= slack:
            continue
        bottom = np.inf
        for i in range(corners_b.shape[0]):
            h = corners_b[i, 0] * n0 + corners_b[i, 1] * n1 + corners_b[i, 2] * n2
            if not h >= bottom:
                bottom = h
                if h != h:
                    break
        if bottom - offset[f] >= -slack:
            return True
    return False


@njit(error_model="numpy")
def max_beyond(points: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:  # pragma: no cover
    """For each point (k, 3), the largest ``normal . x - offset`` (k,) over planes (normals (m, 3), offsets (m,),
    m >= 1), as :func:`fracture_cli.geometry.hulls.max_beyond` (a nan height gives nan)."""
    outside = np.empty(points.shape[0])
    for i in range(points.shape[0]):
        p0, p1, p2 = points[i, 0], points[i, 1], points[i, 2]
        best = -np.inf
        for f in range(normal.shape[0]):
            h = (p0 * normal[f, 0] + p1 * normal[f, 1] + p2 * normal[f, 2]) - offset[f]
            if f == 0 or h > best or h != h:
                if best == best:  # numpy's maximum keeps a nan
                    best = h
        outside[i] = best
    return outside


def warm_kernels() -> int:
    """Compile (and cache) the kernel on a unit tetrahedron; ``make install`` calls it once. Returns the number
    of points outside it (1)."""
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int64)
    points = np.array([[0.1, 0.1, 0.1], [1.0, 1.0, 1.0]])
    outside, _ = outside_distances(points, V, F)
    normal = np.array([[0.0, 0.0, 1.0]])
    plane_separates(V, normal, np.array([1.0]), points, 0.0)
    max_beyond(points, normal, np.array([1.0]))
    return int((outside > 0).sum())
