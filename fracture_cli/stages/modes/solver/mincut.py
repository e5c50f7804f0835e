"""The pricing oracle of the cut solver: one minimum s-t cut on a face graph.

``min_S w(boundary of S) - supply(S)`` over all node sets ``S`` is a minimum
s-t cut: capacities ``w_f`` both ways across every face, ``supply^+`` from the
source, ``supply^-`` to the sink.

The compiled kernel (:mod:`.maxflow_kernel`) solves the face graph as it is.
With OR-Tools it is solved in a form with half the arcs (see :class:`MinCut`):
one arc per face, from its lower node to its higher one, with capacity
``2 w_f`` and ``w_f`` moved to the terminal arcs of its two nodes. Every cut's
value grows by the same ``sum_f w_f``, so the minimum cuts, and the minimal one
returned, are the same sets.
"""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, maximum_flow, reverse_cuthill_mckee

# Max-flow capacities are integers: the supply is scaled so that its positive part
# sums to this many units (int32 for scipy, int64 for OR-Tools); the total flow
# stays well inside the integer range and arcs capped at the maximum never saturate.
_FLOW_UNITS = float(2**29)
_INT32_MAX = 2**31 - 1
_FLOW_UNITS_64 = float(2**52)
# Face capacity cap of the one-arc form: above every minimum cut's value (at most the source's total,
# 2**52 plus rounding), so no capped face is in a minimum cut, as with the cap 2**62 of the two-arc form.
_ONE_ARC_CAP = float(2**53)
# The one-arc form is used while its terminal capacities add up to less than this (OR-Tools reports a
# possible overflow above 2**63 out of the source); else the two-arc form (huge, unbreakable faces).
_ONE_ARC_TOTAL = float(2**61)
# What ``backend="auto"`` means, process-wide: "auto" (the compiled kernel, else OR-Tools if installed,
# else scipy), "kernel", "ortools" or "scipy". For benchmarks and tests that compare them; the pipeline
# leaves it alone.
MAX_FLOW_BACKEND = "auto"


class MinCut:
    """Minimal source side of ``min_S w(boundary of S) - supply(S)`` on a fixed face graph.

    Three backends, which all return the unique minimal source side of a
    minimum cut of integer capacities: the supply scaled so that its positive
    part is 2**52 units (int64) for the first two, which give the same sets,
    2**29 units for scipy (int32):

    * "kernel" (the default): the compiled push-relabel of
      :mod:`.maxflow_kernel` on both arcs of every face, its arcs grouped by
      node once; about 1.9x faster than OR-Tools on the pricing max-flows of
      the pillar's glass bake (5.3 ms against 10.0 ms, median);
    * "ortools": OR-Tools' push-relabel (int64 capacities). Each call builds
      the one-arc form (module notes) with the non-zero terminal arcs only,
      about 40% fewer arcs than both arcs of every face plus two terminal arcs
      per node, and ~25% less time per max-flow on the sample assets; when its
      shifted terminal capacities could overflow int64 (faces weighted ~1e9
      times the mean), the two-arc form instead;
    * "scipy": scipy's Dinic (int32 capacities); the graph is built once and
      every call sets its capacities.

    Parameters
    ----------
    face_tets : (f, 2) int
        The two nodes of every face.
    omega : (f,) float
        Face capacities (> 0).
    t : int
        Number of nodes.
    backend : {"auto", "kernel", "ortools", "scipy"}
        "auto": :data:`MAX_FLOW_BACKEND`, which by default is the first of "kernel", "ortools" and
        "scipy" that can be imported.
    """

    def __init__(self, face_tets: np.ndarray, omega: np.ndarray, t: int, backend: str = "auto"):
        self.t = t
        self.omega = np.asarray(omega, dtype=np.float64)
        self._face_tets = np.asarray(face_tets, dtype=np.int64)
        if backend == "auto":
            backend = MAX_FLOW_BACKEND
        self._kernel: Any = None
        if backend in ("auto", "kernel"):
            try:
                self._kernel = importlib.import_module("fracture_cli.stages.modes.solver.maxflow_kernel")
            except ImportError:  # numba missing or broken
                if backend == "kernel":
                    raise
        ortools_max_flow: Any = None
        if self._kernel is None and backend != "scipy":
            try:
                ortools_max_flow = importlib.import_module("ortools.graph.python.max_flow")
            except ImportError:
                if backend == "ortools":
                    raise
        self.backend = "kernel" if self._kernel is not None else "ortools" if ortools_max_flow is not None else "scipy"
        self._module = ortools_max_flow
        self._two_arc: tuple | None = None
        if self._kernel is not None:
            lo, hi, order, _ = self._one_arc_graph(incidence=False)
            self._order = order
            self._arcs = self._kernel.arc_structure(lo, hi, t)
        elif ortools_max_flow is not None:
            self._one_arc = self._one_arc_graph()
        else:
            tails, heads = self._two_arc_lists()
            order = sp.csr_matrix((np.arange(1, len(tails) + 1, dtype=np.float64), (tails, heads)),
                                  shape=(t + 2, t + 2))
            self._perm = order.data.astype(np.int64) - 1  # csr data slot -> arc id
            self._indices = order.indices.astype(np.int32)
            self._indptr = order.indptr.astype(np.int32)

    def _two_arc_lists(self) -> tuple[np.ndarray, np.ndarray]:
        """Tails and heads (2f + 2t,) of the two-arc form: faces both ways, then source arcs, then sink arcs."""
        t, fa, fb = self.t, self._face_tets[:, 0], self._face_tets[:, 1]
        arange = np.arange(t)
        return (np.concatenate([fa, fb, np.full(t, t), arange]), np.concatenate([fb, fa, arange, np.full(t, t + 1)]))

    def _one_arc_graph(self, incidence: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, sp.csr_matrix | None]:
        """Face arcs (lower, higher) (f,) int32, node order (t,) (solver node -> node) and face-node
        incidence (t, f) of the one-arc form (None if not ``incidence``: the kernel needs none).

        The nodes are numbered in reverse Cuthill-McKee order (neighbours close in memory: about 8%
        faster max-flows on the sample assets' tet meshes); the cut is mapped back.
        """
        t, f = self.t, len(self._face_tets)
        fa, fb = self._face_tets[:, 0], self._face_tets[:, 1]
        adjacency = sp.csr_matrix((np.ones(f), (fa, fb)), shape=(t, t))
        order = np.asarray(reverse_cuthill_mckee((adjacency + adjacency.T).tocsr(), symmetric_mode=True),
                           dtype=np.int64)
        rank = np.empty(t, dtype=np.int64)
        rank[order] = np.arange(t)
        lo, hi = np.minimum(rank[fa], rank[fb]), np.maximum(rank[fa], rank[fb])
        if not incidence:
            return lo.astype(np.int32), hi.astype(np.int32), order, None
        # +1 at a face's lower node, -1 at its higher one, in int64: the terminal shifts are exact.
        incidence = sp.csr_matrix((np.concatenate([np.ones(f, dtype=np.int64), -np.ones(f, dtype=np.int64)]),
                                   (np.concatenate([lo, hi]), np.tile(np.arange(f), 2))), shape=(t, f))
        return lo.astype(np.int32), hi.astype(np.int32), order, incidence

    def source_side(self, supply: np.ndarray) -> np.ndarray:
        """Sorted node ids (k,) of the minimal source side (empty if the minimum is 0 at S = {})."""
        pos = np.maximum(supply, 0.0)
        neg = np.maximum(-supply, 0.0)
        total = float(pos.sum())
        if total <= 0.0:
            return np.zeros(0, dtype=np.int64)
        if self._kernel is None and self._module is None:
            return self._scipy_side(pos, neg, total)
        # The total flow stays below 2**52 + t units (the source's total); capped arcs can never saturate.
        units = _FLOW_UNITS_64 / total
        faces = np.rint(self.omega * units)
        terminal = np.rint(pos * units) - np.rint(neg * units)
        if self._kernel is not None:
            # Both arcs of every face, capped as in the one-arc form (no minimum cut holds a capped face):
            # every capacity and flow stays below 2**54, with no terminal shifts to overflow.
            return self._kernel_side(np.minimum(faces, _ONE_ARC_CAP).astype(np.int64), terminal.astype(np.int64))
        side = self._one_arc_side(np.minimum(faces, _ONE_ARC_CAP).astype(np.int64), terminal.astype(np.int64))
        if side is None:
            side = self._two_arc_side(np.minimum(faces, float(2**62)).astype(np.int64), terminal.astype(np.int64))
        return side

    def _kernel_side(self, faces: np.ndarray, terminal: np.ndarray) -> np.ndarray:
        """The cut by the compiled kernel: ``faces`` (f,) and ``terminal`` (t,) are the integer capacities."""
        first, head, sister, face = self._arcs
        side, certified = self._kernel.source_side(first, head, sister, face, faces, terminal[self._order])
        if not certified:
            raise RuntimeError("the compiled max-flow ended with an excess that could still reach the sink")
        return np.sort(self._order[side])

    def _one_arc_side(self, faces: np.ndarray, terminal: np.ndarray) -> np.ndarray | None:
        """The cut in the one-arc form (module notes); None if its terminal capacities could overflow.

        ``faces`` (f,) are the integer face capacities, ``terminal`` (t,) the integer supplies.
        """
        lo, hi, order, incidence = self._one_arc
        t = self.t
        # Node i of the solver is node order[i]; face capacity w_f becomes 2 w_f from the lower node to the
        # higher one, plus w_f from the source to the lower node and w_f to the sink from the higher one.
        net = terminal[order] + incidence @ faces
        if float(np.abs(net).sum()) >= _ONE_ARC_TOTAL:
            return None
        # A new solver with the non-zero terminal arcs only (about one per node, not two): building it
        # costs less than the push-relabel saves on the zero-capacity arcs.
        sources, sinks = np.flatnonzero(net > 0), np.flatnonzero(net < 0)
        solver = self._module.SimpleMaxFlow()
        solver.add_arc_with_capacity(t, t + 1, 0)  # both terminals exist even without arcs of their own
        solver.add_arcs_with_capacity(np.concatenate([lo, np.full(len(sources), t, dtype=np.int32),
                                                      sinks.astype(np.int32)]),
                                      np.concatenate([hi, sources.astype(np.int32),
                                                      np.full(len(sinks), t + 1, dtype=np.int32)]),
                                      np.concatenate([2 * faces, net[sources], -net[sinks]]))
        status = solver.solve(t, t + 1)
        if status != solver.OPTIMAL:
            raise RuntimeError(f"OR-Tools max-flow returned status {status}")
        side = np.array(solver.get_source_side_min_cut(), dtype=np.int64)
        return np.sort(order[side[side < t]])

    def _two_arc_side(self, faces: np.ndarray, terminal: np.ndarray) -> np.ndarray:
        """The cut with both arcs of every face (no shifted terminal capacities: no overflow)."""
        if self._two_arc is None:
            tails, heads = self._two_arc_lists()
            solver = self._module.SimpleMaxFlow()
            arcs = solver.add_arcs_with_capacity(tails.astype(np.int32), heads.astype(np.int32),
                                                 np.zeros(len(tails), dtype=np.int64))
            self._two_arc = (solver, arcs)
        solver, arcs = self._two_arc
        solver.set_arcs_capacity(arcs, np.concatenate([faces, faces, np.maximum(terminal, 0),
                                                       np.maximum(-terminal, 0)]))
        status = solver.solve(self.t, self.t + 1)
        if status != solver.OPTIMAL:
            raise RuntimeError(f"OR-Tools max-flow returned status {status}")
        side = np.array(solver.get_source_side_min_cut(), dtype=np.int64)
        return np.sort(side[side < self.t])

    def _scipy_side(self, pos: np.ndarray, neg: np.ndarray, total: float) -> np.ndarray:
        """The cut by scipy's Dinic (int32 capacities, both arcs of every face)."""
        t = self.t
        caps = np.concatenate([self.omega, self.omega, pos, neg])
        caps = np.minimum(np.rint(caps * (_FLOW_UNITS / total)), _INT32_MAX).astype(np.int32)
        graph = sp.csr_matrix((caps[self._perm], self._indices, self._indptr), shape=(t + 2, t + 2))
        result = maximum_flow(graph, t, t + 1, method="dinic")
        # Reachable from the source in the residual network.
        remaining = (graph - result.flow).tocsr()
        remaining.data = (remaining.data > 0).astype(np.int8)
        remaining.eliminate_zeros()
        reach = breadth_first_order(remaining, t, directed=True, return_predecessors=False)
        return np.sort(reach[reach < t])
