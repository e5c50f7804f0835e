"""Compiled (numba) separating-axis test of triangle pairs, for :func:`.trigeom.triangles_intersect`.

The numpy test builds all 17 candidate axes of every pair that its two
normals do not separate, in arrays of (p, 15, 3); the cage's and the smoothing's
self-intersection checks and the simplify stage's fault checks call it on tens
of thousands of pairs, and numpy's temporaries were most of their time. This
kernel walks the pairs one by one and stops at the first separating axis.

It is the same test: the same axes (in the same order), the same relative
frame (corner 0 of the first triangle), the same scale per chunk of
:data:`PAIR_CHUNK` pairs for the threshold below which an axis counts as
degenerate, and the same ``gap > eps`` verdict. Only the projections' last
bits may differ: numpy projects with a BLAS matrix product, whose summation
order (and use of fused multiply-adds) is the library's; a verdict can change
only for a gap within a few units in the last place of ``eps``, which
:func:`~fracture_cli.geometry.trigeom.triangles_intersect` already treats as touching.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.system.jit import njit

#: Pairs per chunk; the degenerate-axis threshold scales with the largest coordinate of a chunk.
PAIR_CHUNK = 20_000


@njit(error_model="numpy")
def _separates(x: float, y: float, z: float, a: np.ndarray, b: np.ndarray, threshold: float,
               eps: float) -> bool:  # pragma: no cover (compiled)
    """Whether axis (x, y, z) separates triangles ``a`` and ``b`` (3, 3) by more than ``eps``.

    An axis no longer than ``threshold`` is degenerate and separates nothing.
    """
    length = np.sqrt((x * x + y * y) + z * z)
    if not length > threshold:
        return False
    x, y, z = x / length, y / length, z / length
    a0 = x * a[0, 0] + y * a[0, 1] + z * a[0, 2]
    a1 = x * a[1, 0] + y * a[1, 1] + z * a[1, 2]
    a2 = x * a[2, 0] + y * a[2, 1] + z * a[2, 2]
    b0 = x * b[0, 0] + y * b[0, 1] + z * b[0, 2]
    b1 = x * b[1, 0] + y * b[1, 1] + z * b[1, 2]
    b2 = x * b[2, 0] + y * b[2, 1] + z * b[2, 2]
    gap_ab = min(min(a0, a1), a2) - max(max(b0, b1), b2)
    gap_ba = min(min(b0, b1), b2) - max(max(a0, a1), a2)
    return gap_ab > eps or gap_ba > eps


@njit(error_model="numpy")
def _cross_separates(u: np.ndarray, v: np.ndarray, a: np.ndarray, b: np.ndarray, threshold: float,
                     eps: float) -> bool:  # pragma: no cover (compiled)
    """Whether the cross product of 3-vectors ``u`` and ``v`` separates ``a`` and ``b`` (see :func:`_separates`)."""
    return _separates(u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0],
                      a, b, threshold, eps)


@njit(error_model="numpy")
def _pair_hits(a: np.ndarray, b: np.ndarray, threshold: float, eps: float) -> bool:  # pragma: no cover
    """Whether triangles ``a`` and ``b`` (3, 3; relative to a's corner 0) intersect or touch: no axis separates."""
    ea = np.empty((3, 3))
    eb = np.empty((3, 3))
    for k in range(3):
        for d in range(3):
            ea[k, d] = a[(k + 1) % 3, d] - a[k, d]
            eb[k, d] = b[(k + 1) % 3, d] - b[k, d]
    na = np.empty(3)
    nb = np.empty(3)
    na[0] = ea[0, 1] * ea[1, 2] - ea[0, 2] * ea[1, 1]
    na[1] = ea[0, 2] * ea[1, 0] - ea[0, 0] * ea[1, 2]
    na[2] = ea[0, 0] * ea[1, 1] - ea[0, 1] * ea[1, 0]
    nb[0] = eb[0, 1] * eb[1, 2] - eb[0, 2] * eb[1, 1]
    nb[1] = eb[0, 2] * eb[1, 0] - eb[0, 0] * eb[1, 2]
    nb[2] = eb[0, 0] * eb[1, 1] - eb[0, 1] * eb[1, 0]
    # The two normals separate most pairs; then edge x edge, normal x own edges, normal x other's edges.
    if _separates(na[0], na[1], na[2], a, b, threshold, eps) or _separates(nb[0], nb[1], nb[2], a, b,
                                                                           threshold, eps):
        return False
    for i in range(3):
        for j in range(3):
            if _cross_separates(ea[i], eb[j], a, b, threshold, eps):
                return False
    for k in range(3):
        if (_cross_separates(na, ea[k], a, b, threshold, eps) or _cross_separates(nb, eb[k], a, b, threshold, eps)
                or _cross_separates(na, eb[k], a, b, threshold, eps)
                or _cross_separates(nb, ea[k], a, b, threshold, eps)):
            return False
    return True


@njit(error_model="numpy")
def intersect_pairs(A: np.ndarray, B: np.ndarray, eps: float) -> np.ndarray:  # pragma: no cover (compiled)
    """Separating-axis verdicts of triangle pairs, as :func:`fracture_cli.geometry.trigeom.triangles_intersect`.

    Parameters
    ----------
    A, B : (p, 3, 3) float64
        Corners of the two triangles of each pair.
    eps : float
        A gap no larger than this counts as touching.

    Returns
    -------
    hit : (p,) bool
        True where no axis separates the pair by more than ``eps``.
    """
    p = A.shape[0]
    hit = np.zeros(p, dtype=np.bool_)
    a = np.empty((3, 3))
    b = np.empty((3, 3))
    for start in range(0, p, PAIR_CHUNK):
        stop = min(start + PAIR_CHUNK, p)
        # The chunk's largest coordinate relative to each pair's origin (numpy's max propagates a nan).
        scale = 0.0
        for i in range(start, stop):
            for c in range(3):
                for d in range(3):
                    x = abs(A[i, c, d] - A[i, 0, d])
                    y = abs(B[i, c, d] - A[i, 0, d])
                    if x != x or y != y:
                        scale = np.nan
                    elif scale == scale:
                        scale = max(scale, x, y)
        if scale == scale:
            scale = max(scale, tol.SMALLEST_DIVISOR)
        threshold = tol.ROUNDOFF * scale * scale
        for i in range(start, stop):
            for c in range(3):
                for d in range(3):
                    a[c, d] = A[i, c, d] - A[i, 0, d]
                    b[c, d] = B[i, c, d] - A[i, 0, d]
            hit[i] = _pair_hits(a, b, threshold, eps)
    return hit


def warm_kernels() -> int:
    """Compile (and cache) the kernel on two touching triangles; ``make install`` calls it once. Returns hits."""
    A = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    B = np.array([[[0.5, 0.0, 0.0], [1.5, 0.0, 0.0], [0.5, 1.0, 0.0]]])
    return int(intersect_pairs(A, B, tol.ZERO_LENGTH).sum())
