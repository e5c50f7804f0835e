"""Compiled (numba) box-overlap search of one mesh's triangles, for :mod:`.trigeom`'s self-intersections.

:class:`fracture_cli.geometry.trigeom.BoxGrid` expands every box into the cells it
covers in numpy arrays of (entries,) and (candidates, 3); the simplify stage's
fault checks query it thousands of times on small meshes, where those
temporaries and the calls around them were most of the time. These kernels
walk the same uniform grid (the same cells, from the same floor arithmetic,
done by the caller) and return the same pairs in the same order:
:func:`self_pairs` those of ``BoxGrid(boxes, cell).query(boxes)`` with
``i < j``; :func:`among_pairs` the sorted, unique pairs of the queried faces.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.rows import unique_rows
from fracture_cli.system.jit import njit

# Offset and stride of the cell keys (as BoxGrid's: cells may be negative, keys must not collide).
_STRIDE = 1 << 20


@njit(error_model="numpy")
def _index(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """Cell keys (e,) of every (box, cell) entry, sorted, with their box ids (e,), ascending per key.

    ``lo``, ``hi`` (m, 3) int64: the boxes' first and last cells. Entries are made box by box, cells x
    fastest, and sorted stably by key: BoxGrid's lexsort by (key, id).
    """
    m = lo.shape[0]
    total = 0
    for b in range(m):
        total += (hi[b, 0] - lo[b, 0] + 1) * (hi[b, 1] - lo[b, 1] + 1) * (hi[b, 2] - lo[b, 2] + 1)
    keys = np.empty(total, dtype=np.int64)
    ids = np.empty(total, dtype=np.int64)
    half = _STRIDE // 2
    e = 0
    for b in range(m):
        for iz in range(lo[b, 2], hi[b, 2] + 1):
            for iy in range(lo[b, 1], hi[b, 1] + 1):
                for ix in range(lo[b, 0], hi[b, 0] + 1):
                    keys[e] = ((ix + half) * _STRIDE + (iy + half)) * _STRIDE + (iz + half)
                    ids[e] = b
                    e += 1
    order = np.argsort(keys, kind="mergesort")
    return keys[order], ids[order]


@njit(error_model="numpy")
def _overlap(boxes: np.ndarray, a: int, b: int) -> bool:  # pragma: no cover (compiled)
    """Whether closed boxes ``a`` and ``b`` of ``boxes`` (m, 2, 3) overlap."""
    for k in range(3):
        if not (boxes[a, 0, k] <= boxes[b, 1, k] and boxes[b, 0, k] <= boxes[a, 1, k]):
            return False
    return True


@njit(error_model="numpy")
def _query(boxes: np.ndarray, lo: np.ndarray, hi: np.ndarray, queries: np.ndarray,
           keys: np.ndarray, ids: np.ndarray, ordered: bool) -> np.ndarray:  # pragma: no cover (compiled)
    """Overlapping pairs (p, 2) ``(q, j)`` of query faces ``queries`` (c,) and all faces, in BoxGrid's order.

    Each pair is taken once, in the cell holding the corner max(lo_q, lo_j); ``ordered`` keeps only
    ``q < j``, else only ``q != j``.
    """
    half = _STRIDE // 2
    out = np.empty((max(16, 4 * len(queries)), 2), dtype=np.int64)
    n = 0
    for q in queries:
        for iz in range(lo[q, 2], hi[q, 2] + 1):
            for iy in range(lo[q, 1], hi[q, 1] + 1):
                for ix in range(lo[q, 0], hi[q, 0] + 1):
                    key = ((ix + half) * _STRIDE + (iy + half)) * _STRIDE + (iz + half)
                    s = np.searchsorted(keys, key, side="left")
                    t = np.searchsorted(keys, key, side="right")
                    for e in range(s, t):
                        j = ids[e]
                        if (ordered and j <= q) or j == q:
                            continue
                        if (ix != max(lo[q, 0], lo[j, 0]) or iy != max(lo[q, 1], lo[j, 1])
                                or iz != max(lo[q, 2], lo[j, 2])):
                            continue
                        if not _overlap(boxes, q, j):
                            continue
                        if n == len(out):
                            grown = np.empty((2 * n, 2), dtype=np.int64)
                            grown[:n] = out
                            out = grown
                        out[n, 0] = q
                        out[n, 1] = j
                        n += 1
    return out[:n].copy()


@njit()
def shared_corners(F: np.ndarray, i: np.ndarray,
                   j: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """For face pairs ``(i, j)`` (p,) of ``F`` (m, 3): how many corners of ``F[i]`` are corners of ``F[j]`` (p,),
    the first such corner of ``F[i]`` (p,) and the first of ``F[j]`` that is a corner of ``F[i]`` (p,), 0 if none.
    """
    p = len(i)
    count = np.zeros(p, dtype=np.int64)
    first_i = np.zeros(p, dtype=np.int64)
    first_j = np.zeros(p, dtype=np.int64)
    for r in range(p):
        f, g = F[i[r]], F[j[r]]
        found_i = found_j = False
        for k in range(3):
            if f[k] == g[0] or f[k] == g[1] or f[k] == g[2]:
                count[r] += 1
                if not found_i:
                    first_i[r], found_i = k, True
            if not found_j and (g[k] == f[0] or g[k] == f[1] or g[k] == f[2]):
                first_j[r], found_j = k, True
    return count, first_i, first_j


def self_pairs(boxes: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The pairs (p, 2) ``(i, j)``, ``i < j``, of ``BoxGrid(boxes, cell).query(boxes)``, in its order.

    Parameters
    ----------
    boxes : (m, 2, 3) float64
        Triangle boxes.
    lo, hi : (m, 3) int64
        Their first and last grid cells (``BoxGrid._cells``).
    """
    keys, ids = _index(lo, hi)
    return _query(boxes, lo, hi, np.arange(len(boxes), dtype=np.int64), keys, ids, True)


def among_pairs(boxes: np.ndarray, lo: np.ndarray, hi: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The overlapping pairs (p, 2) ``(f, g)``, ``f < g``, with ``f`` or ``g`` in ``faces`` (c,); sorted, unique.

    ``boxes``, ``lo``, ``hi`` as in :func:`self_pairs`.
    """
    keys, ids = _index(lo, hi)
    pairs = _query(boxes, lo, hi, np.asarray(faces, dtype=np.int64), keys, ids, False)
    pairs = np.stack([np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])], axis=1)
    return unique_rows(pairs) if len(pairs) else pairs.reshape(0, 2)


def warm_kernels() -> None:
    """Compile (or load from the cache) the kernels, on two boxes."""
    boxes = np.array([[[0.0, 0, 0], [1, 1, 1]], [[0.5, 0.5, 0.5], [2, 2, 2]]])
    lo = np.zeros((2, 3), dtype=np.int64)
    hi = np.ones((2, 3), dtype=np.int64)
    self_pairs(boxes, lo, hi)
    among_pairs(boxes, lo, hi, np.array([0]))
    shared_corners(np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64), np.array([0]), np.array([1]))
