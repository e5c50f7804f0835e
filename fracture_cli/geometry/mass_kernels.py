"""Compiled (numba) :func:`~fracture_cli.geometry.mass.mass_properties`, for the collision stage's small meshes.

The collision stage asks for the mass properties of thousands of small meshes
per bake (every overlap of two parts, every piece it cuts), where numpy's
per-call overhead was most of the time. :func:`mass_properties` here gives the
same :class:`~fracture_cli.geometry.mass.MassProperties`, bit for bit: the
kernel sums in numpy's orders, spelled out (no fastmath: no reassociation,
no fused multiply-adds):

* ``np.einsum("ij,ij->i")`` over rows of three: ``(x0 y0 + x2 y2) + x1 y1``;
* ``v.sum()`` of a contiguous vector: numpy's pairwise summation (eight
  interleaved partial sums per block of at most 128, blocks halved
  recursively, a plain loop below eight);
* ``X.sum(axis=0)`` of rows and ``np.einsum("t,tij->ij")``: in row order.

The few 3 x 3 steps after the sums stay numpy's. tests/test_collision_kernels.py
compares the two on random meshes.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import mass
from fracture_cli.geometry import tolerances as tol
from fracture_cli.system.jit import njit

# numpy's pairwise summation: blocks of at most this many terms are summed with eight partial sums.
_PAIRWISE_BLOCK = 128


@njit(error_model="numpy")
def _block_sum(a: np.ndarray, start: int, count: int) -> float:  # pragma: no cover (compiled)
    """numpy's sum of at most :data:`_PAIRWISE_BLOCK` contiguous terms ``a[start:start + count]``."""
    if count < 8:
        total = 0.0
        for i in range(count):
            total += a[start + i]
        return total
    r = np.empty(8)
    for j in range(8):
        r[j] = a[start + j]
    i = 8
    while i < count - count % 8:
        for j in range(8):
            r[j] += a[start + i + j]
        i += 8
    total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < count:
        total += a[start + i]
        i += 1
    return total


@njit(error_model="numpy")
def _pairwise_sum(a: np.ndarray) -> float:  # pragma: no cover (compiled)
    """``a.sum()`` as numpy sums a contiguous float64 vector: halves (the first a multiple of eight terms)
    summed separately down to blocks of :data:`_PAIRWISE_BLOCK`. The halving walks an explicit stack (numba
    cannot load a cached self-recursive function)."""
    if a.shape[0] <= _PAIRWISE_BLOCK:
        return _block_sum(a, 0, a.shape[0])
    start = np.empty(64, dtype=np.int64)
    count = np.empty(64, dtype=np.int64)
    stage = np.empty(64, dtype=np.int64)  # 0: left half next, 1: right half next, 2: both summed
    value = np.empty(64)
    top, values = 0, 0
    start[0], count[0], stage[0] = 0, a.shape[0], 0
    while top >= 0:
        n = count[top]
        if n <= _PAIRWISE_BLOCK:
            value[values] = _block_sum(a, start[top], n)
            values += 1
            top -= 1
            continue
        half = n // 2
        half -= half % 8
        if stage[top] == 2:
            value[values - 2] = value[values - 2] + value[values - 1]
            values -= 1
            top -= 1
            continue
        first = start[top] + (half if stage[top] == 1 else 0)
        size = n - half if stage[top] == 1 else half
        stage[top] += 1
        top += 1
        start[top], count[top], stage[top] = first, size, 0
    return value[0]


@njit(error_model="numpy")
def _moments(V: np.ndarray, F: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Volume, first moment (3,), second moment (3, 3) about the local origin, and that origin (3,) of a
    closed mesh with at least one face (the sums of :func:`fracture_cli.geometry.mass.mass_properties`)."""
    used = np.zeros(V.shape[0], dtype=np.bool_)
    for f in range(F.shape[0]):
        for k in range(3):
            used[F[f, k]] = True
    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    for i in range(V.shape[0]):
        if used[i]:
            for d in range(3):
                low[d] = min(low[d], V[i, d])
                high[d] = max(high[d], V[i, d])
    origin = np.empty(3)
    for d in range(3):
        origin[d] = (low[d] + high[d]) / 2.0
    t = F.shape[0]
    v = np.empty(t)
    first = np.zeros(3)
    second = np.zeros((3, 3))
    a, b, c, s = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for f in range(t):
        for d in range(3):
            a[d] = V[F[f, 0], d] - origin[d]
            b[d] = V[F[f, 1], d] - origin[d]
            c[d] = V[F[f, 2], d] - origin[d]
            s[d] = (a[d] + b[d]) + c[d]
        x = b[1] * c[2] - b[2] * c[1]
        y = b[2] * c[0] - b[0] * c[2]
        z = b[0] * c[1] - b[1] * c[0]
        v[f] = ((a[0] * x + a[2] * z) + a[1] * y) / 6.0
        w = v[f] / 20.0
        for i in range(3):
            # (v[:, None] * s).sum(axis=0) and einsum("t,tij->ij", v / 20, outer sums): row by row, in order.
            first[i] += v[f] * s[i]
            for j in range(3):
                second[i, j] += w * ((((a[i] * a[j]) + b[i] * b[j]) + c[i] * c[j]) + s[i] * s[j])
    return _pairwise_sum(v), first, second, origin


def mass_properties(vertices: np.ndarray, faces: np.ndarray) -> mass.MassProperties:
    """:func:`fracture_cli.geometry.mass.mass_properties`, compiled: the same values, bit for bit.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
        A closed mesh, counter-clockwise seen from outside.

    Returns
    -------
    MassProperties
    """
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    F = np.ascontiguousarray(np.asarray(faces, dtype=np.int64).reshape(-1, 3))
    if len(F) == 0:
        return mass.mass_properties(V, F)
    volume, first, second, origin = _moments(V, F)
    if not abs(volume) > tol.SMALLEST_DIVISOR:
        return mass.mass_properties(V, F)  # no volume: numpy's (rare) answer
    # The 3 x 3 steps of mass.mass_properties, as they are there.
    centre_local = first / 4.0 / volume
    second -= volume * np.outer(centre_local, centre_local)
    second = (second + second.T) / 2.0
    inertia = np.trace(second) * np.eye(3) - second
    return mass.MassProperties(float(volume), origin + centre_local, inertia)


def warm_kernels() -> float:
    """Compile (and cache) the kernels on a unit tetrahedron; ``make install`` calls it once. Returns its
    volume (1/6)."""
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int64)
    return mass_properties(V, F).volume
