"""Compiled (numba) manifold tests, for :func:`fracture_cli.trigeom.vertex_manifold` and ``edge_manifold_closed``.

The numpy test builds a sparse graph of the corners glued across edges and
labels its components with scipy; the simplify stage calls it on every
rebuilt fragment (hundreds of small meshes), where the set-up of those calls
was most of the time. This kernel joins the same corners with a union-find
and gives the same verdict (a boolean: no rounding involved).
"""

from __future__ import annotations

import numpy as np

from fracture_cli.jit import njit


@njit()
def _root(parent: np.ndarray, x: int) -> int:  # pragma: no cover (compiled)
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@njit()
def single_fans(F: np.ndarray, n: int) -> bool:  # pragma: no cover (compiled)
    """Whether the corners of every vertex of ``F`` (m, 3) int64 (ids below ``n``) form one fan.

    Corner (f, k) is vertex ``F[f, k]`` in face f; the corner of a in face f is glued to the corner of a in
    the face holding the halfedge b -> a, for every halfedge a -> b of f (as the numpy test does).
    """
    m = F.shape[0]
    key = np.empty(3 * m, dtype=np.int64)
    for f in range(m):
        for k in range(3):
            key[3 * f + k] = F[f, k] * n + F[f, (k + 1) % 3]
    order = np.argsort(key, kind="mergesort")
    sorted_keys = key[order]
    parent = np.arange(3 * m)
    for f in range(m):
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            want = b * n + a
            pos = np.searchsorted(sorted_keys, want)
            if pos >= 3 * m:
                pos = 3 * m - 1
            twin = order[pos]
            if key[twin] != want:
                continue
            # In the twin face the halfedge is b -> a, so a is the corner after b.
            corner = (twin // 3) * 3 + (twin % 3 + 1) % 3
            ra, rb = _root(parent, 3 * f + k), _root(parent, corner)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    fan = np.full(n, -1, dtype=np.int64)
    for c in range(3 * m):
        v = F[c // 3, c % 3]
        r = _root(parent, c)
        if fan[v] == -1:
            fan[v] = r
        elif fan[v] != r:
            return False
    return True


@njit()
def closed_oriented(F: np.ndarray, n: int) -> bool:  # pragma: no cover (compiled)
    """Whether every edge of ``F`` (m, 3) int64 (ids below ``n``) is used once in each direction, by distinct
    vertices (:func:`fracture_cli.trigeom.edge_manifold_closed`, same verdict)."""
    m = F.shape[0]
    key = np.empty(3 * m, dtype=np.int64)
    for f in range(m):
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            if a == b:
                return False
            key[3 * f + k] = a * n + b
    key = np.sort(key)
    for e in range(1, 3 * m):
        if key[e] == key[e - 1]:
            return False  # a directed edge used twice: non-manifold or flipped neighbour
    for e in range(3 * m):
        twin = (key[e] % n) * n + key[e] // n
        pos = np.searchsorted(key, twin)
        if pos >= 3 * m or key[pos] != twin:
            return False
    return True


def warm_kernels() -> None:
    """Compile (or load from the cache) the kernels, on a tetrahedron."""
    closed_oriented(np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], dtype=np.int64), 4)
    single_fans(np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], dtype=np.int64), 4)
