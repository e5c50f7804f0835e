"""Compiled (numba) loops of the collision stage: a plane's cut of a mesh, the corners of its halves, and the
triangle terms of :func:`~fracture_cli.stages.collision.separate.volume_beyond`.

These were numpy expressions over small arrays (a part's few hundred edges,
an overlap's few dozen triangles) evaluated tens of thousands of times per
bake, where numpy's per-call overhead and temporaries were most of the time.
Each kernel computes the same IEEE operations, in the same order, as the
numpy expressions it replaced (no fastmath, so no reassociation and no fused
multiply-adds): the values are the same bits. The three-term dot products
are summed in the order of numpy's (pinned) matrix products, spelled out;
longer sums (dot products over triangles, totals) stay with the numpy
callers. tests/test_collision_kernels.py compares each kernel with its numpy
form, bit for bit.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.system.jit import njit


@njit(error_model="numpy")
def cut_points(V: np.ndarray, edges: np.ndarray, s: np.ndarray,
               offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """The points where mesh edges cross each of parallel planes ``s == offset``, in edge order.

    Parameters
    ----------
    V : (n, 3) float64
        Mesh vertices.
    edges : (e, 2) int64
        Vertex indices of each edge.
    s : (n,) float64
        Height of each vertex along the planes' normal.
    offsets : (k,) float64
        The planes' heights.

    Returns
    -------
    points : (c, 3) float64
        For each plane in turn, ``a + t (b - a)``, ``t = da / (da - db)``, ``da = s_a - offset``,
        ``db = s_b - offset``, for each edge ``(a, b)`` with exactly one end above the plane (``s > offset``;
        ``s - offset > 0`` exactly when ``s > offset``, as a difference of two floats is 0 only if they are
        equal).
    start : (k + 1,) int64
        Plane ``i``'s points are ``points[start[i]:start[i + 1]]``.
    """
    start = np.zeros(offsets.shape[0] + 1, dtype=np.int64)
    for i in range(offsets.shape[0]):
        count = 0
        for e in range(edges.shape[0]):
            if (s[edges[e, 0]] > offsets[i]) != (s[edges[e, 1]] > offsets[i]):
                count += 1
        start[i + 1] = start[i] + count
    out = np.empty((start[-1], 3))
    for i in range(offsets.shape[0]):
        offset = offsets[i]
        k = start[i]
        for e in range(edges.shape[0]):
            a, b = edges[e, 0], edges[e, 1]
            if (s[a] > offset) != (s[b] > offset):
                da = s[a] - offset
                db = s[b] - offset
                t = da / (da - db)
                for d in range(3):
                    out[k, d] = V[a, d] + t * (V[b, d] - V[a, d])
                k += 1
    return out, start


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
        ``x2^3 / (3 (x2 - x0)(x2 - x1))`` where only ``x2 > 0``, else 0 (see
        :func:`fracture_cli.stages.collision.separate.volume_beyond`); the operations and order of the numpy
        expressions it replaced.
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


@njit(error_model="numpy")
def beyond_terms(triangles: np.ndarray, area: np.ndarray, centroid: np.ndarray, radius: np.ndarray,
                 normal: np.ndarray, low: float,
                 high: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """The triangles of a closed mesh that reach beyond the lowest of parallel planes, split by how they do.

    Parameters
    ----------
    triangles : (t, 3, 3) float64
        Corners of each triangle.
    area : (t, 3) float64
        Area vector of each triangle.
    centroid : (t, 3) float64
        Centroid of each triangle.
    radius : (t,) float64
        A bound on each corner's distance from its centroid.
    normal : (3,) float64
        Unit normal of the planes.
    low, high : float
        The lowest and highest plane offset.

    Returns
    -------
    full_weight, full_mean : (f,) float64
        Of each triangle wholly beyond every plane (lowest corner height above ``high``): ``area . normal``
        and the mean of its corner heights.
    reach_heights : (r, 3) float64
        Of each other triangle whose highest corner is above ``low``: its corner heights, ascending.
    reach_weight : (r,) float64
        Their ``area . normal``.

    Notes
    -----
    The steps of the numpy expressions it replaced in
    :func:`fracture_cli.stages.collision.separate.volume_beyond`, with their operations: triangles whose
    centroid height plus radius is not above ``low`` are skipped, and a height is ``(x n0 + y n1) + z n2``,
    the order in which numpy's (pinned, SSE3) matrix-vector products sum three terms (tests/
    test_collision_kernels.py checks it bit for bit); the mean is ``((h0 + h1) + h2) / 3``, as numpy's.
    Triangles keep their order.
    """
    n0, n1, n2 = normal[0], normal[1], normal[2]
    t = triangles.shape[0]
    heights = np.empty((t, 3))
    weight = np.empty(t)
    kind = np.zeros(t, dtype=np.int8)  # 0: skipped, 1: wholly beyond, 2: reaching beyond the lowest plane
    n_full, n_reach = 0, 0
    for i in range(t):
        if not centroid[i, 0] * n0 + centroid[i, 1] * n1 + centroid[i, 2] * n2 + radius[i] > low:
            continue
        a = triangles[i, 0, 0] * n0 + triangles[i, 0, 1] * n1 + triangles[i, 0, 2] * n2
        b = triangles[i, 1, 0] * n0 + triangles[i, 1, 1] * n1 + triangles[i, 1, 2] * n2
        c = triangles[i, 2, 0] * n0 + triangles[i, 2, 1] * n1 + triangles[i, 2, 2] * n2
        if a > b:
            a, b = b, a
        if b > c:
            b, c = c, b
        if a > b:
            a, b = b, a
        heights[i, 0], heights[i, 1], heights[i, 2] = a, b, c
        weight[i] = area[i, 0] * n0 + area[i, 1] * n1 + area[i, 2] * n2
        if a > high:
            kind[i] = 1
            n_full += 1
        elif c > low:
            kind[i] = 2
            n_reach += 1
    full_weight = np.empty(n_full)
    full_mean = np.empty(n_full)
    reach_heights = np.empty((n_reach, 3))
    reach_weight = np.empty(n_reach)
    f, r = 0, 0
    for i in range(t):
        if kind[i] == 1:
            full_weight[f] = weight[i]
            full_mean[f] = (heights[i, 0] + heights[i, 1] + heights[i, 2]) / 3.0
            f += 1
        elif kind[i] == 2:
            reach_weight[r] = weight[i]
            for d in range(3):
                reach_heights[r, d] = heights[i, d]
            r += 1
    return full_weight, full_mean, reach_heights, reach_weight


def warm_kernels() -> int:
    """Compile (and cache) the kernels on a unit tetrahedron cut at half height; ``make install`` calls it once.
    Returns the number of cut points (3)."""
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    edges = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)
    s = V[:, 2].copy()
    cut, _ = cut_points(V, edges, s, np.array([0.5]))
    split_points(V, s, 0.5, cut)
    positive_means(np.array([[0.0, 0.5, 1.0]]), np.array([0.25, 0.75]))
    triangles = V[np.array([[0, 2, 1], [0, 1, 3]])]
    beyond_terms(triangles, np.zeros((2, 3)), triangles.mean(axis=1), np.ones(2), np.array([0.0, 0.0, 1.0]), 0.25,
                 0.75)
    return len(cut)
