"""The pricing oracle of the cut solver: one minimum s-t cut on a face graph.

``min_S w(boundary of S) - supply(S)`` over all node sets ``S`` is a minimum
s-t cut: capacities ``w_f`` both ways across every face, ``supply^+`` from the
source, ``supply^-`` to the sink.
"""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, maximum_flow

# Max-flow capacities are integers: the supply is scaled so that its positive part
# sums to this many units (int32 for scipy, int64 for OR-Tools); the total flow
# stays well inside the integer range and arcs capped at the maximum never saturate.
_FLOW_UNITS = float(2**29)
_INT32_MAX = 2**31 - 1
_FLOW_UNITS_64 = float(2**52)
# What ``backend="auto"`` means, process-wide: "auto" (OR-Tools if installed), "ortools" or "scipy".
# For benchmarks and tests that compare the two; the pipeline leaves it alone.
MAX_FLOW_BACKEND = "auto"


class MinCut:
    """Minimal source side of ``min_S w(boundary of S) - supply(S)`` on a fixed face graph.

    Uses OR-Tools' push-relabel (int64 capacities) when it is installed, else
    scipy's Dinic (int32 capacities). Both return the unique minimal source side
    of a minimum cut. The graph is built once: every call only sets the
    capacities of the terminal arcs (and the face arcs, rescaled with the supply).

    Parameters
    ----------
    face_tets : (f, 2) int
        The two nodes of every face.
    omega : (f,) float
        Face capacities (> 0).
    t : int
        Number of nodes.
    backend : {"auto", "ortools", "scipy"}
    """

    def __init__(self, face_tets: np.ndarray, omega: np.ndarray, t: int, backend: str = "auto"):
        self.t = t
        self.omega = np.asarray(omega, dtype=np.float64)
        fa, fb = face_tets[:, 0], face_tets[:, 1]
        src, snk = t, t + 1
        arange = np.arange(t)
        tails = np.concatenate([fa, fb, np.full(t, src), arange])
        heads = np.concatenate([fb, fa, arange, np.full(t, snk)])
        if backend == "auto":
            backend = MAX_FLOW_BACKEND
        ortools_max_flow: Any = None
        if backend != "scipy":
            try:
                ortools_max_flow = importlib.import_module("ortools.graph.python.max_flow")
            except ImportError:
                if backend == "ortools":
                    raise
        self.backend = "ortools" if ortools_max_flow is not None else "scipy"
        self._solver = None
        if ortools_max_flow is not None:
            self._solver = ortools_max_flow.SimpleMaxFlow()
            self._arcs = self._solver.add_arcs_with_capacity(tails.astype(np.int32), heads.astype(np.int32),
                                                              np.zeros(len(tails), dtype=np.int64))
            self._status_ok = self._solver.OPTIMAL
        else:
            order = sp.csr_matrix((np.arange(1, len(tails) + 1, dtype=np.float64), (tails, heads)),
                                  shape=(t + 2, t + 2))
            self._perm = order.data.astype(np.int64) - 1  # csr data slot -> arc id
            self._indices = order.indices.astype(np.int32)
            self._indptr = order.indptr.astype(np.int32)

    def source_side(self, supply: np.ndarray) -> np.ndarray:
        """Sorted node ids (k,) of the minimal source side (empty if the minimum is 0 at S = {})."""
        pos = np.maximum(supply, 0.0)
        neg = np.maximum(-supply, 0.0)
        total = float(pos.sum())
        if total <= 0.0:
            return np.zeros(0, dtype=np.int64)
        t = self.t
        caps = np.concatenate([self.omega, self.omega, pos, neg])
        if self._solver is not None:
            # The total flow stays below 2**52; capped arcs can never saturate.
            caps = np.minimum(np.rint(caps * (_FLOW_UNITS_64 / total)), 2.0**62).astype(np.int64)
            self._solver.set_arcs_capacity(self._arcs, caps)
            status = self._solver.solve(t, t + 1)
            if status != self._status_ok:
                raise RuntimeError(f"OR-Tools max-flow returned status {status}")
            side = np.asarray(self._solver.get_source_side_min_cut(), dtype=np.int64)
            return np.sort(side[side < t])
        caps = np.minimum(np.rint(caps * (_FLOW_UNITS / total)), _INT32_MAX).astype(np.int32)
        graph = sp.csr_matrix((caps[self._perm], self._indices, self._indptr), shape=(t + 2, t + 2))
        result = maximum_flow(graph, t, t + 1, method="dinic")
        # Reachable from the source in the residual network.
        remaining = (graph - result.flow).tocsr()
        remaining.data = (remaining.data > 0).astype(np.int8)
        remaining.eliminate_zeros()
        reach = breadth_first_order(remaining, t, directed=True, return_predecessors=False)
        return np.sort(reach[reach < t])
