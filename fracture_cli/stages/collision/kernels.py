"""Compiled (numba) element-wise loops of the collision stage: a plane's cut of a mesh and the positive parts of
linear functions over triangles.

Both loops were numpy expressions over small arrays (a part's few hundred
edges, an overlap's few dozen triangles) evaluated tens of thousands of times
per bake, where numpy's per-call overhead and temporaries were most of the
time. Each kernel computes the same IEEE operations, in the same order, as
the numpy expression it replaces (no fastmath, so no reassociation and no
fused multiply-adds): the values are the same bits on every CPU. Reductions
(sums, dot products) stay with the numpy callers, whose summation order is
numpy's and OpenBLAS's.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.system.jit import njit


@njit(error_model="numpy")
def cut_points(V: np.ndarray, edges: np.ndarray, sa: np.ndarray, sb: np.ndarray,
               offset: float) -> np.ndarray:  # pragma: no cover (compiled)
    """The points where mesh edges cross the plane ``s == offset``, in edge order.

    Parameters
    ----------
    V : (n, 3) float64
        Mesh vertices.
    edges : (e, 2) int64
        Vertex indices of each edge.
    sa, sb : (e,) float64
        Heights ``s`` of each edge's first and second vertex.
    offset : float
        The plane's height.

    Returns
    -------
    (c, 3) float64
        ``a + t (b - a)``, ``t = da / (da - db)``, ``da = sa - offset``, ``db = sb - offset``, for each edge
        with exactly one end above the plane (``s > offset``), as
        :func:`fracture_cli.stages.collision.decompose._cut_points` computes them in numpy.
    """
    count = 0
    for e in range(edges.shape[0]):
        if (sa[e] > offset) != (sb[e] > offset):
            count += 1
    out = np.empty((count, 3))
    k = 0
    for e in range(edges.shape[0]):
        if (sa[e] > offset) != (sb[e] > offset):
            da = sa[e] - offset
            db = sb[e] - offset
            t = da / (da - db)
            a, b = edges[e, 0], edges[e, 1]
            for d in range(3):
                out[k, d] = V[a, d] + t * (V[b, d] - V[a, d])
            k += 1
    return out


@njit(error_model="numpy")
def split_points(V: np.ndarray, s: np.ndarray, offset: float,
                 cut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """The corners of the two halves of a mesh cut at ``s == offset``: the vertices on each side, then the cut.

    Parameters
    ----------
    V : (n, 3) float64
        Mesh vertices.
    s : (n,) float64
        Their heights along the cut's normal.
    offset : float
        The plane's height.
    cut : (c, 3) float64
        The points where edges cross the plane (:func:`cut_points`).

    Returns
    -------
    above, below : (n_a + c, 3), (n_b + c, 3) float64
        ``vstack([V[s - offset > 0], cut])`` and ``vstack([V[s - offset <= 0], cut])``, in order.
    """
    n_above = 0
    for i in range(s.shape[0]):
        if s[i] - offset > 0:
            n_above += 1
    c = cut.shape[0]
    above = np.empty((n_above + c, 3))
    below = np.empty((s.shape[0] - n_above + c, 3))
    ka, kb = 0, 0
    for i in range(s.shape[0]):
        if s[i] - offset > 0:
            above[ka] = V[i]
            ka += 1
        else:
            below[kb] = V[i]
            kb += 1
    for i in range(c):
        above[ka + i] = cut[i]
        below[kb + i] = cut[i]
    return above, below


@njit(error_model="numpy")
def positive_means(h: np.ndarray, offsets: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    """Mean over each triangle of the positive part of a linear function, for every offset.

    Parameters
    ----------
    h : (t, 3) float64
        The function's values at each triangle's corners, sorted ascending per triangle.
    offsets : (k,) float64
        Offsets subtracted from the values.

    Returns
    -------
    (k, t) float64
        With ``x = h - offset`` (``x0 <= x1 <= x2``): the mean ``(x0 + x1 + x2) / 3`` where ``x0 > 0``, the
        mean plus ``max(-x0, 0)^3 / (3 (x1 - x0)(x2 - x0))`` where only ``x1, x2 > 0``,
        ``x2^3 / (3 (x2 - x0)(x2 - x1))`` where only ``x2 > 0``, else 0: the operations of
        :func:`fracture_cli.stages.collision.separate._volume_beyond`'s numpy form, in its order.
    """
    out = np.zeros((offsets.shape[0], h.shape[0]))
    for i in range(offsets.shape[0]):
        o = offsets[i]
        for t in range(h.shape[0]):
            x0 = h[t, 0] - o
            x1 = h[t, 1] - o
            x2 = h[t, 2] - o
            if x0 > 0:
                out[i, t] = (x0 + x1 + x2) / 3.0
            elif x1 > 0:
                m = -x0
                if m < 0.0:  # np.maximum(-x0, 0.0); a nan stays nan, as there
                    m = 0.0
                out[i, t] = (x0 + x1 + x2) / 3.0 + m * m * m / (3.0 * (x1 - x0) * (x2 - x0))
            elif x2 > 0:
                out[i, t] = x2 * x2 * x2 / (3.0 * (x2 - x0) * (x2 - x1))
    return out


def warm_kernels() -> int:
    """Compile (and cache) the kernels on a unit tetrahedron cut at half height; ``make install`` calls it once.
    Returns the number of cut points (3)."""
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    edges = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)
    s = V[:, 2].copy()
    cut = cut_points(V, edges, s[edges[:, 0]], s[edges[:, 1]], 0.5)
    split_points(V, s, 0.5, cut)
    positive_means(np.array([[0.0, 0.5, 1.0]]), np.array([0.25, 0.75]))
    return len(cut)
