"""Compiled (numba) manifold tests, for :func:`fracture_cli.geometry.trigeom.vertex_manifold`, ``edge_manifold_closed``
and ``face_components``.

The numpy tests built a sparse graph of the corners glued across edges and
labelled its components with scipy; the simplify stage calls them on every
rebuilt fragment (hundreds of small meshes), where the set-up of those calls
was most of the time, and repair's fast path on million-triangle inputs.

Every test here looks at one vertex at a time. A corner of vertex v (v in
some face) has a next vertex b and a previous vertex p: it holds the halfedges
v -> b and p -> v. So the halfedges into v are read off v's own corners, and
the twin b -> v of v -> b is the corner of v whose previous vertex is b: no
search through other vertices' halfedges, which on a million faces was mostly
cache misses. The corners are grouped by vertex by counting (linear, no global
sort). The verdicts are the numpy tests' (booleans and counts: no rounding).
"""

from __future__ import annotations

import numpy as np

from fracture_cli.system.jit import njit

# A vertex's corners are ordered by insertion sort up to this many (a vertex's valence is a handful); longer
# runs (fan centres of CAD caps) by a stable argsort, so that no input takes quadratic time.
_INSERTION_MAX = 32


@njit()
def _root(parent: np.ndarray, x: int) -> int:  # pragma: no cover (compiled)
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@njit()
def _corners(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """Corners ``c = 3 f + k`` of ``F`` (m, 3) int64 (ids below ``n``) grouped by vertex ``F[f, k]``.

    Returns ``order`` (3m,) and ``start`` (n + 1,): ``order[start[v]:start[v + 1]]`` are v's corners, in
    increasing order.
    """
    m = F.shape[0]
    start = np.zeros(n + 1, dtype=np.int64)
    for f in range(m):
        for k in range(3):
            start[F[f, k] + 1] += 1
    for v in range(n):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    order = np.empty(3 * m, dtype=np.int64)
    for f in range(m):
        for k in range(3):
            v = F[f, k]
            order[fill[v]] = 3 * f + k
            fill[v] += 1
    return order, start


@njit()
def _sort_by_key(key: np.ndarray, value: np.ndarray, s: int) -> None:  # pragma: no cover (compiled)
    """Sort ``key[:s]`` in place, stably, moving ``value[:s]`` along."""
    if s <= _INSERTION_MAX:
        for i in range(1, s):
            k, x = key[i], value[i]
            j = i - 1
            while j >= 0 and key[j] > k:
                key[j + 1], value[j + 1] = key[j], value[j]
                j -= 1
            key[j + 1], value[j + 1] = k, x
    else:
        by_key = np.argsort(key[:s], kind="mergesort")
        key[:s] = key[:s][by_key]
        value[:s] = value[:s][by_key]


@njit()
def _first(key: np.ndarray, s: int, k: int) -> int:  # pragma: no cover (compiled)
    """Position of the first ``k`` in the sorted ``key[:s]``, or -1."""
    lo, hi = 0, s
    while lo < hi:
        mid = (lo + hi) // 2
        if key[mid] < k:
            lo = mid + 1
        else:
            hi = mid
    return lo if lo < s and key[lo] == k else -1


@njit()
def single_fans(F: np.ndarray, n: int) -> bool:  # pragma: no cover (compiled)
    """Whether the corners of every vertex of ``F`` (m, 3) int64 (ids below ``n``) form one fan.

    Corner (f, k) is vertex ``F[f, k]`` in face f; the corner of a in face f is glued to the corner of a in
    the face holding the halfedge b -> a (the smallest such halfedge id), for every halfedge a -> b of f (as
    the numpy test does). That halfedge's corner of a is the first corner of a whose previous vertex is b
    (two halfedges b -> a cannot share a face, so the smallest halfedge has the smallest corner).
    """
    order, start = _corners(F, n)
    size = 0
    for v in range(n):
        size = max(size, start[v + 1] - start[v])
    prev = np.empty(size, dtype=np.int64)  # previous vertex of v's corners, sorted (stably: first corner first)
    at = np.empty(size, dtype=np.int64)  # where each of them is among v's corners
    parent = np.empty(size, dtype=np.int64)
    for v in range(n):
        lo, s = start[v], start[v + 1] - start[v]
        for i in range(s):
            c = order[lo + i]
            prev[i] = F[c // 3, (c % 3 + 2) % 3]
            at[i] = i
            parent[i] = i
        _sort_by_key(prev, at, s)
        for i in range(s):
            c = order[lo + i]
            pos = _first(prev, s, F[c // 3, (c % 3 + 1) % 3])
            if pos < 0:
                continue
            ra, rb = _root(parent, i), _root(parent, at[pos])
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
        for i in range(1, s):
            if _root(parent, i) != 0:
                return False
    return True


@njit()
def closed_oriented(F: np.ndarray, n: int) -> bool:  # pragma: no cover (compiled)
    """Whether every edge of ``F`` (m, 3) int64 (ids below ``n``) is used once in each direction, by distinct
    vertices (:func:`fracture_cli.geometry.trigeom.edge_manifold_closed`, same verdict).

    At every vertex, the next vertices of its corners (its outgoing halfedges) must be distinct and the same
    set as their previous vertices (its incoming ones): then every halfedge is used once and has its twin.
    """
    m = F.shape[0]
    for f in range(m):
        for k in range(3):
            if F[f, k] == F[f, (k + 1) % 3]:
                return False
    order, start = _corners(F, n)
    size = 0
    for v in range(n):
        size = max(size, start[v + 1] - start[v])
    out = np.empty(size, dtype=np.int64)
    into = np.empty(size, dtype=np.int64)
    unused = np.empty(size, dtype=np.int64)
    for v in range(n):
        lo, s = start[v], start[v + 1] - start[v]
        for i in range(s):
            c = order[lo + i]
            out[i] = F[c // 3, (c % 3 + 1) % 3]
            into[i] = F[c // 3, (c % 3 + 2) % 3]
        _sort_by_key(out, unused, s)
        _sort_by_key(into, unused, s)
        for i in range(s):
            if i > 0 and out[i] == out[i - 1]:
                return False  # a directed edge used twice: non-manifold or flipped neighbour
            if out[i] != into[i]:
                return False  # an edge with no way back: open, or a flipped neighbour
    return True


@njit()
def edge_components(F: np.ndarray, n: int) -> int:  # pragma: no cover (compiled)
    """How many groups the faces of ``F`` (m, 3) int64 (ids below ``n``) form, joined where they share an
    edge (the same two vertex ids, in either direction; any number of faces per edge).

    The faces on edge {v, x} (v <= x) are v's corners whose next or previous vertex is x.
    """
    m = F.shape[0]
    order, start = _corners(F, n)
    size = 0
    for v in range(n):
        size = max(size, start[v + 1] - start[v])
    other = np.empty(2 * size, dtype=np.int64)
    face = np.empty(2 * size, dtype=np.int64)
    parent = np.arange(m)
    for v in range(n):
        s = 0
        for i in range(start[v], start[v + 1]):
            c = order[i]
            for x in (F[c // 3, (c % 3 + 1) % 3], F[c // 3, (c % 3 + 2) % 3]):
                if x >= v:
                    other[s], face[s] = x, c // 3
                    s += 1
        _sort_by_key(other, face, s)
        for i in range(1, s):
            if other[i] == other[i - 1]:
                ra, rb = _root(parent, face[i]), _root(parent, face[i - 1])
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
    count = 0
    for f in range(m):
        if parent[f] == f:
            count += 1
    return count


def warm_kernels() -> None:
    """Compile (or load from the cache) the kernels, on a tetrahedron."""
    tetrahedron = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], dtype=np.int64)
    closed_oriented(tetrahedron, 4)
    single_fans(tetrahedron, 4)
    edge_components(tetrahedron, 4)
