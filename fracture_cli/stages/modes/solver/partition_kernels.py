"""Compiled (numba) partition bookkeeping of the cut solver (:class:`~.cut.CutSubproblemSolver`).

After every pricing round the solver relabels the connected cells of its
partition and rebuilds the cell graph (the boundary between every two cells
and its total weight). Done with scipy's ``connected_components`` and
``np.unique``/``np.bincount`` that took about 1 ms per round on 8k tets, a
tenth of a late mode's time; these loops do the same in a few microseconds
of set-up and one pass over the faces. Their results are the same arrays,
bit for bit: the labels are numbered in the order of each cell's smallest tet
(as scipy's labelling is), and each boundary's weight is summed over its faces
in ascending face order (as ``np.bincount`` sums).
"""

from __future__ import annotations

import numpy as np

from fracture_cli.system.jit import njit


# The same four lines as trigeom_topology._root, on purpose: numba keys a kernel's cache to its own file only,
# so a kernel here calling a compiled function of another module would go on running that function's old code
# after it changed.
@njit()
def _root(parent: np.ndarray, x: int) -> int:  # pragma: no cover (compiled)
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@njit()
def masked_components(fa: np.ndarray, fb: np.ndarray, keep: np.ndarray,  # pragma: no cover (compiled)
                      t: int) -> tuple[int, np.ndarray]:
    """Connected components of ``t`` nodes joined by the edges ``(fa[i], fb[i])`` (f,) where ``keep[i]``.

    Returns ``(count, labels (t,) int64)``, labels numbered in the order of each component's smallest node
    (the numbering of ``scipy.sparse.csgraph.connected_components`` on an undirected graph).
    """
    parent = np.arange(t)
    for i in range(fa.shape[0]):
        if keep[i]:
            ra, rb = _root(parent, fa[i]), _root(parent, fb[i])
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    labels = np.empty(t, dtype=np.int64)
    count = 0
    for x in range(t):
        r = _root(parent, x)
        if r == x:  # every root is its component's smallest node (the larger root always joins the smaller)
            labels[x] = count
            count += 1
        else:
            labels[x] = labels[r]
    return count, labels


@njit()
def cell_graph(cells: np.ndarray, fa: np.ndarray, fb: np.ndarray, omega: np.ndarray,  # pragma: no cover
               n: int) -> tuple[np.ndarray, np.ndarray]:
    """Boundaries between the ``n`` cells of a partition ``cells`` (t,) of the face graph ``(fa, fb)`` (f,).

    Returns ``edges (E, 2)`` int64, the distinct cell pairs ``(lo, hi)`` that share a face in ascending order of
    ``lo * n + hi``, and ``edge_omega (E,)``, the sum of ``omega`` over each pair's faces in ascending face order.
    """
    f = fa.shape[0]
    key = np.empty(f, dtype=np.int64)
    face = np.empty(f, dtype=np.int64)
    k = 0
    for i in range(f):
        a, b = cells[fa[i]], cells[fb[i]]
        if a != b:
            key[k] = min(a, b) * n + max(a, b)
            face[k] = i
            k += 1
    order = np.argsort(key[:k], kind="mergesort")  # stable: a pair's faces stay in ascending order
    edges = np.empty((k, 2), dtype=np.int64)
    edge_omega = np.empty(k, dtype=np.float64)
    count = -1
    last = -1
    for j in range(k):
        i = order[j]
        if count < 0 or key[i] != last:
            count += 1
            last = key[i]
            edges[count, 0] = last // n
            edges[count, 1] = last % n
            edge_omega[count] = 0.0
        edge_omega[count] += omega[face[i]]
    return edges[:count + 1], edge_omega[:count + 1]


@njit()
def cell_order(cells: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """``(order (t,), indptr (n + 1,))``: the tets sorted by cell, ascending within a cell (a stable counting
    sort, as ``np.argsort(cells, kind="stable")``), and where each cell's run starts."""
    t = cells.shape[0]
    indptr = np.zeros(n + 1, dtype=np.int32)
    for x in range(t):
        indptr[cells[x] + 1] += 1
    for c in range(n):
        indptr[c + 1] += indptr[c]
    fill = indptr[:-1].copy()
    order = np.empty(t, dtype=np.int32)
    for x in range(t):
        c = cells[x]
        order[fill[c]] = x
        fill[c] += 1
    return order, indptr


def warm_kernels() -> None:
    """Compile (or load from the cache) every kernel of this module on a tiny problem."""
    fa = np.array([0, 1, 2], dtype=np.int64)
    fb = np.array([1, 2, 3], dtype=np.int64)
    masked_components(fa, fb, np.array([True, False, True]), 4)
    cells = np.array([0, 0, 1, 1], dtype=np.int64)
    cell_graph(cells, fa, fb, np.ones(3), 2)
    cell_order(cells, 2)
