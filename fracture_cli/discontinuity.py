"""The discontinuity energy of per-tet displacements and its constrained minimisation.

ALGORITHM.md section 2. A displacement field gives one vector ``u_t`` in R^d per
tet; its discontinuity energy is a weighted group lasso over the interior faces,

    E_D(u) = sum_f w_f * || eta_f o (u_a - u_b) ||_2 ,

and one ICCM round of the fracture-modes solver minimises it subject to a few
dense linear constraints (M_T-orthogonality to the rigid translations and to the
modes found so far, and ``c^T M_T u = 1``). This module holds that convex
subproblem and two solvers for it:

* :class:`CutSubproblemSolver` (``d = 1``, the default, exact): a master LP
  over a partition of the tets into cells (``u`` constant per cell) is solved
  exactly by HiGHS; its duals ``lambda`` define a supply ``s = M_T Y lambda``
  per tet, and the most violated dual constraint ``min_S w(boundary of S) -
  s(S)`` over all tet sets is one minimum s-t cut (max-flow). A violated set
  refines the partition; when none is left, ``lambda`` certifies that the
  master's solution is optimal, and it is exactly piecewise constant.
* :class:`ConicSubproblemSolver` (any ``d``, baseline): the whole problem handed
  to the interior-point solver Clarabel.

Face weights are ``w_f = A_f`` (:func:`face_weights`: the one place where this
choice is made). Both solvers divide the weights by their mean internally: with
raw areas (~1e-5 in normalized units) interior-point solvers stop well above the
optimum.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linprog
from scipy.sparse.csgraph import breadth_first_order, connected_components, maximum_flow

log = logging.getLogger(__name__)

# Max-flow capacities are integers: the supply is scaled so that its positive part
# sums to this many units (int32 for scipy, int64 for OR-Tools); the total flow
# stays well inside the integer range and arcs capped at the maximum never saturate.
_FLOW_UNITS = float(2**29)
_INT32_MAX = 2**31 - 1
_FLOW_UNITS_64 = float(2**52)
# What ``max_flow="auto"`` means, process-wide: "auto" (OR-Tools if installed), "ortools" or "scipy".
# For benchmarks and tests that compare the two; the pipeline leaves it alone.
MAX_FLOW_BACKEND = "auto"

try:  # HiGHS's own bindings allow warm starts; scipy's linprog (same HiGHS) is the fallback
    import highspy as _highspy
except ImportError:
    _highspy = None
# The master LP's duals are the pricing's supply: keep HiGHS's tolerances tight.
# Serial dual simplex: deterministic.
_HIGHS_SETTINGS = {"solver": "simplex", "simplex_strategy": 1, "primal_feasibility_tolerance": 1e-9,
                   "dual_feasibility_tolerance": 1e-9, "threads": 1, "output_flag": False}
_HIGHS_OPTIONS = (("highs-ds", {"primal_feasibility_tolerance": 1e-9, "dual_feasibility_tolerance": 1e-9}),
                  ("highs-ds", {"primal_feasibility_tolerance": 1e-9, "dual_feasibility_tolerance": 1e-9,
                                "presolve": False}),
                  ("highs-ipm", {"primal_feasibility_tolerance": 1e-9, "dual_feasibility_tolerance": 1e-9}))


def face_weights(tet_mesh) -> np.ndarray:
    """Face weights ``w_f = A_f`` (f,) of the discontinuity energy.

    The paper writes ``sqrt(A_f)``; ``A_f`` makes the cost of a crack
    proportional to its area and independent of how finely it is triangulated
    (ALGORITHM.md section 2). This is the only place that makes the choice.
    """
    return np.asarray(tet_mesh.interior_face_areas, dtype=np.float64)


def jump_norms(u: np.ndarray, face_tets: np.ndarray, eta: np.ndarray | None = None) -> np.ndarray:
    """Norms ``|| eta_f o (u_a - u_b) ||`` (f,) of the jumps of ``u`` (t, d) across interior faces."""
    u = np.asarray(u, dtype=np.float64)
    if u.ndim == 1:
        u = u[:, None]
    jump = u[face_tets[:, 0]] - u[face_tets[:, 1]]
    if eta is not None:
        jump = jump * _as_2d(eta, u.shape[1])
    return np.sqrt(np.einsum("fd,fd->f", jump, jump))


def discontinuity_energy(u, face_tets, weights, eta=None) -> float:
    """``E_D(u) = sum_f weights_f || eta_f o (u_a - u_b) ||`` for ``u`` (t,) or (t, d)."""
    return float(np.dot(weights, jump_norms(u, face_tets, eta)))


def _as_2d(eta: np.ndarray, d: int) -> np.ndarray:
    eta = np.asarray(eta, dtype=np.float64)
    return np.repeat(eta[:, None], d, axis=1) if eta.ndim == 1 else eta


@dataclass
class SubproblemResult:
    """The minimiser of one ICCM subproblem.

    Attributes
    ----------
    u : (t, d) float64
        The minimiser: feasible, ``c^T M_T u = 1``.
    energy : float
        Its discontinuity energy, in the units of the weights given.
    lower_bound : float
        A lower bound on the optimum from the dual (``nan`` if the solver gives none).
    iterations : int
        Solver iterations (max-flows for the cut solver, interior-point steps for Clarabel).
    seconds : float
        Wall time of the solve.
    stats : dict
        Solver-specific counters.
    """

    u: np.ndarray
    energy: float
    lower_bound: float
    iterations: int
    seconds: float
    stats: dict = field(default_factory=dict)


_HIGHS_BANNER_SHOWN = False


def lp_backend() -> str:
    """'highspy' (warm-started HiGHS) or 'scipy' (HiGHS through scipy.optimize.linprog)."""
    return "highspy" if _highspy is not None else "scipy"


def _new_highs():
    """A ``highspy.Highs`` whose one-time copyright banner does not reach our stdout.

    HiGHS prints it from C++ on the first construction in a process, before any
    option can be set; a library must not write to stdout (the CLI may stream data there).
    """
    global _HIGHS_BANNER_SHOWN
    if _HIGHS_BANNER_SHOWN:
        return _highspy.Highs()
    import os
    import sys

    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 1)
            highs = _highspy.Highs()
    finally:
        os.dup2(saved, 1)
        os.close(saved)
    _HIGHS_BANNER_SHOWN = True
    return highs


class _Constraints:
    """The dense constraint rows ``Y^T M_T u = b``, projected M_T-orthogonally to translations."""

    def __init__(self, volumes: np.ndarray):
        self.vol = volumes
        self.total = float(volumes.sum())

    def project(self, y: np.ndarray) -> np.ndarray:
        """Remove the M_T-mean of each column (the translation component), per axis."""
        y = np.asarray(y, dtype=np.float64)
        # A plain reduction, not BLAS: tiny products are slow when BLAS threads wait on a busy machine.
        mean = np.einsum("t,t...->...", self.vol, y) / self.total
        return y - mean


def _scaled_problem(face_tets, weights, volumes, weight_scale):
    """Arrays of a subproblem with the face weights divided by their mean (or ``weight_scale``).

    Raw weights (face areas, ~1e-5 on a unit-diagonal asset) leave solvers far
    from the optimum; scaled to mean 1 they do not (the energy just scales).
    """
    weights = np.asarray(weights, dtype=np.float64)
    scale = float(weight_scale) if weight_scale else float(weights.mean()) if len(weights) else 1.0
    return np.asarray(face_tets, dtype=np.int64), scale, weights / scale, np.asarray(volumes, dtype=np.float64)


class CutSubproblemSolver:
    """Exact solver of the ``d = 1`` subproblem: a partition-refining master LP priced by min cuts.

    Solves ``min_u sum_f w_f |u_a - u_b|`` subject to ``1^T M_T u = 0``,
    ``y_j^T M_T u = 0`` for the fixed vectors ``y_j`` and ``c^T M_T u = 1``.

    Parameters
    ----------
    face_tets : (f, 2) int
        The two tets of every interior face.
    weights : (f,) float
        Face weights ``w_f eta_f`` (> 0; a huge weight makes a face unbreakable).
    volumes : (t,) float
        Tet volumes (the diagonal of ``M_T``).
    tol : float, optional (default 1e-9)
        Stop when no tet set violates its dual constraint by more than ``tol``
        times the objective.
    max_iter : int, optional (default 1000)
        Pricing rounds (max-flows) per solve before giving up.
    weight_scale : float, optional (default mean of weights)
        Internal unit of the weights.
    max_flow : {"auto", "ortools", "scipy"}, optional (default "auto")
        Max-flow implementation: OR-Tools' push-relabel if installed (several
        times faster), else scipy's Dinic. Both give the same minimal minimum cut.

    Notes
    -----
    Dual of the LP: maximise ``lambda_c`` subject to: the supply
    ``s = M_T (sum_j lambda_j y_j + lambda_c c)`` can be routed through the face
    graph with capacities ``w_f``. By max-flow/min-cut this holds iff
    ``s(S) <= w(boundary of S)`` for every tet set ``S``.

    The solver keeps a partition of the tets into cells. The master LP restricts ``u`` to be constant per cell, plus a multiple of the
    feasible start vector ``c`` (so it is always feasible); it is tiny and HiGHS
    solves it exactly. Its duals ``lambda`` are feasible for every union of cells;
    pricing checks all other sets with one s-t min cut (terminal capacities
    ``s^+``, ``s^-``). If a set violates its constraint, the partition is split
    along it and the master re-solved; otherwise ``lambda`` certifies that the
    master's ``u`` is optimal (``E(u) <= master objective = lambda_c <= optimum``),
    and ``u`` is exactly piecewise constant.

    Cells found while solving for one mode are kept across its ICCM rounds;
    when the number of fixed vectors changes (a new mode), the partition
    restarts from the pieces of the fixed vectors (cuts found with intermediate
    duals would otherwise accumulate and slow the master down). HiGHS is
    warm-started: a new ``c`` on the same partition only edits one column of
    the (dual) master; after a refinement the previous optimal basis is carried
    over to the split cells.

    Safeguards: the returned ``u`` must meet the constraints to 1e-7 (relative
    to ``||y_j||_M ||u||_M``) and its energy must not exceed the master's
    objective, else ``RuntimeError``.
    """

    name = "cut"

    def __init__(self, face_tets, weights, volumes, *, tol: float = 1e-9, max_iter: int = 1000,
                 weight_scale: float | None = None, max_flow: str = "auto"):
        self.face_tets, self.scale, self.omega, self.vol = _scaled_problem(face_tets, weights, volumes, weight_scale)
        self.t = len(self.vol)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self._constraints = _Constraints(self.vol)
        self._fa, self._fb = self.face_tets[:, 0], self.face_tets[:, 1]
        t = self.t
        self._max_flow = _MinCut(self.face_tets, self.omega, t, max_flow)
        self.cells = np.zeros(t, dtype=np.int64)
        self._partition_version = 0
        self._fixed_count = -1
        self._fixed_cache = []
        self._lp = None
        self._lp_key = None
        self._lp_G = None
        self._lp_basis = None
        self._cell_cache = None
        # "stalls": pricing found a violated set that is already a union of cells, i.e. the
        # violation is within HiGHS's tolerance; the result stands, min_reduced_cost says by how much.
        self.counters = {"max_flows": 0, "master_lps": 0, "refinements": 0, "stalls": 0}

    # ------------------------------------------------------------- partition
    def refine(self, members: np.ndarray) -> bool:
        """Split every cell along the tet set ``members``, keeping cells connected; True if any cell split."""
        inside = np.zeros(self.t, dtype=bool)
        inside[members] = True
        fa, fb = self._fa, self._fb
        return self._refine_by((self.cells[fa] == self.cells[fb]) & (inside[fa] == inside[fb]))

    @property
    def max_flow_backend(self) -> str:
        """'ortools' or 'scipy'."""
        return self._max_flow.backend

    def _project_fixed(self, k: int, y) -> np.ndarray:
        """Projected fixed vector ``k``, cached (the same earlier modes recur in every ICCM round)."""
        y = np.asarray(y, dtype=np.float64).reshape(-1)
        if k < len(self._fixed_cache) and (self._fixed_cache[k][0] is y or np.array_equal(self._fixed_cache[k][0], y)):
            return self._fixed_cache[k][1]
        del self._fixed_cache[k:]
        self._fixed_cache.append((y, self._constraints.project(y)))
        return self._fixed_cache[k][1]

    def _restart_partition(self, fixed) -> None:
        """Partition into the pieces of the fixed vectors (connected sets of equal values)."""
        self.cells = np.zeros(self.t, dtype=np.int64)
        self._cell_cache = None
        self._partition_version += 1
        if len(fixed):
            keep = np.ones(len(self._fa), dtype=bool)
            for y in fixed:
                y = np.asarray(y).reshape(-1)
                keep &= y[self._fa] == y[self._fb]
            self._refine_by(keep)

    def _refine_by(self, keep: np.ndarray) -> bool:
        """Cells = connected components of the faces in ``keep`` (f,) bool; True if the partition changed."""
        graph = sp.csr_matrix((np.ones(int(keep.sum()), dtype=np.int8), (self._fa[keep], self._fb[keep])),
                              shape=(self.t, self.t))
        count, cells = connected_components(graph, directed=False)
        if count == int(self.cells.max()) + 1:
            return False
        self.cells = cells.astype(np.int64)
        self._cell_cache = None
        self._partition_version += 1
        return True

    def _cell_graph(self):
        if self._cell_cache is None:
            n = int(self.cells.max()) + 1
            ca, cb = self.cells[self._fa], self.cells[self._fb]
            between = ca != cb
            lo = np.minimum(ca[between], cb[between])
            hi = np.maximum(ca[between], cb[between])
            key, inverse = np.unique(lo * n + hi, return_inverse=True)
            edge_omega = np.bincount(inverse.reshape(-1), weights=self.omega[between], minlength=len(key))
            edges = np.column_stack([key // n, key % n])
            indicator = sp.csr_matrix((self.vol, (self.cells, np.arange(self.t))), shape=(n, self.t))
            self._cell_cache = (n, edges, edge_omega, indicator)
        return self._cell_cache

    # ----------------------------------------------------------------- solve
    def solve(self, c: np.ndarray, fixed=()) -> SubproblemResult:
        """Minimise the energy subject to the constraints.

        Parameters
        ----------
        c : (t,) or (t, 1) float
            The ICCM vector; the solution satisfies ``c^T M_T u = 1``.
        fixed : sequence of (t,) or (t, 1) float
            Vectors ``y_j`` with ``y_j^T M_T u = 0`` (the earlier modes).

        Returns
        -------
        SubproblemResult
            ``u`` (t, 1), energy in the units of the weights given, the dual bound.
        """
        start = time.perf_counter()
        before = dict(self.counters)
        if len(fixed) != self._fixed_count:
            self._fixed_count = len(fixed)
            self._restart_partition(fixed)
        cp = self._constraints.project(np.asarray(c, dtype=np.float64).reshape(-1))
        fixed = [self._project_fixed(k, y) for k, y in enumerate(fixed)]
        if not np.any(cp):
            raise ValueError("c is constant: no displacement with c^T M u = 1 is orthogonal to translations")
        Y = np.column_stack(fixed + [cp])
        MY = self.vol[:, None] * Y
        m = Y.shape[1]
        b = np.zeros(m)
        b[-1] = 1.0
        # The feasible start vector: c made M_T-orthogonal to the fixed vectors, c^T M v = 1.
        v = cp
        if m > 1:
            v = cp - Y[:, :-1] @ np.linalg.lstsq(MY[:, :-1].T @ Y[:, :-1], MY[:, :-1].T @ cp, rcond=None)[0]
        norm = float(v @ MY[:, -1])
        if not norm > 1e-12 * float(cp @ MY[:, -1]):
            raise ValueError("c lies in the span of the fixed vectors: the constraints are infeasible")
        v = v / norm
        v_cost = float(self.omega @ np.abs(v[self._fa] - v[self._fb]))
        worst_rc = 0.0
        for _ in range(self.max_iter):
            x, theta, lam, objective = self._master(Y, b, v_cost)
            supply = MY @ lam
            members, rc = self._price(supply)
            eps = self.tol * max(objective, 1e-300)
            worst_rc = min(rc, 0.0)
            if members is None or rc >= -eps:
                break
            if not self.refine(members):
                # The set is a union of cells: the violation is within the master LP's tolerance.
                self.counters["stalls"] += 1
                break
            self.counters["refinements"] += 1
        else:
            raise RuntimeError(f"no optimality certificate after {self.max_iter} max-flows")
        u = x[self.cells]
        if theta > 0.0:
            u = u + theta * v
        u = self._constraints.project(u)
        # Safeguard: the master's solution must meet the constraints it was built from.
        # Relative to ||y_j||_M ||u||_M (the M_T-cosine), the natural scale of y_j^T M_T u.
        norms = np.sqrt(np.einsum("tj,tj->j", MY, Y) * float(u @ (self.vol * u)))
        residual = float(np.max(np.abs(MY.T @ u - b) / np.maximum(norms, 1e-300)))
        if not residual <= 1e-7:
            raise RuntimeError(f"the master LP's solution violates the constraints by {residual:.2e} (relative)")
        energy = float(self.omega @ np.abs(u[self._fa] - u[self._fb]))
        # Relative to the size of the terms, not absolute: a disconnected tet mesh has
        # zero-energy modes, whose rounding noise an absolute 1e-12 would reject.
        slack = 1e-7 * abs(objective) + 1e-12 * float(self.omega.sum()) * float(np.abs(u).max())
        if energy > objective + slack:
            raise RuntimeError(f"the recovered solution's energy {energy:.9g} exceeds the master's {objective:.9g}")
        stats = {key: self.counters[key] - before[key] for key in self.counters}
        stats.update(cells=int(self.cells.max()) + 1, min_reduced_cost=worst_rc * self.scale,
                     uses_start_vector=bool(theta > 0.0), constraint_residual=residual)
        return SubproblemResult(u=u[:, None], energy=energy * self.scale, lower_bound=objective * self.scale,
                                iterations=stats["max_flows"],
                                seconds=time.perf_counter() - start, stats=stats)

    def _master(self, Y, b, v_cost):
        """The LP restricted to cell-constant ``u`` plus ``theta`` times the start vector.

        Primal: ``min sum_e omega_e |x_P - x_Q| + cost(v) theta`` subject to
        ``G x + g theta = b`` (the constraint rows, scaled) and ``vol^T x = 0``,
        ``theta >= 0``. HiGHS solves its dual, which is smaller: edge flows
        ``|z_e| <= omega_e``, ``lambda`` and ``mu`` free, one conservation row per
        cell ``B^T z - G^T lambda - mu vol = 0`` and ``g^T lambda <= cost(v)``;
        ``x`` and ``theta`` are that LP's row duals. Returns ``x``, ``theta``,
        the (unscaled) ``lambda`` and the objective.
        """
        n, edges, edge_omega, indicator = self._cell_graph()
        G = np.asarray((indicator @ Y).T)  # (m, n): y_j^T M_T 1_P
        # Row scaling for HiGHS (tet volumes are tiny in normalized units); lambda is scaled back.
        row_scale = 1.0 / np.maximum(np.einsum("t,tj->j", self.vol, np.abs(Y)), 1e-300)
        G = G * row_scale[:, None]
        G[np.abs(G) < 1e-12] = 0.0  # round-off of sums that cancel; keeps HiGHS's matrix clean
        b = b * row_scale
        self.counters["master_lps"] += 1
        x, theta, lam, objective = self._solve_master(n, edges, edge_omega, indicator, G, b, row_scale[-1], v_cost)
        return x, theta, lam * row_scale, objective

    def _master_dual_lp(self, n, edges, edge_omega, indicator, G, b, g_c, v_cost):
        """Matrix (n + 1, E + m + 1), costs, column bounds and row bounds of the dual master LP."""
        E, m = len(edges), G.shape[0]
        eidx = np.arange(E)
        cell_vol = np.asarray(indicator.sum(axis=1)).reshape(-1)
        Gs = sp.coo_matrix(G)
        rows = np.concatenate([edges[:, 0], edges[:, 1], Gs.col, np.arange(n), [n]])
        cols = np.concatenate([eidx, eidx, E + Gs.row, np.full(n, E + m), [E + m - 1]])
        vals = np.concatenate([np.ones(E), -np.ones(E), -Gs.data, -cell_vol / cell_vol.sum(), [g_c]])
        A = sp.csc_matrix((vals, (rows, cols)), shape=(n + 1, E + m + 1))
        cost = np.concatenate([np.zeros(E), -b, [0.0]])
        col_lower = np.concatenate([-edge_omega, np.full(m + 1, -np.inf)])
        col_upper = np.concatenate([edge_omega, np.full(m + 1, np.inf)])
        row_lower = np.concatenate([np.zeros(n), [-np.inf]])
        row_upper = np.concatenate([np.zeros(n), [v_cost]])
        return A, cost, col_lower, col_upper, row_lower, row_upper

    def _solve_master(self, n, edges, edge_omega, indicator, G, b, g_c, v_cost):
        E, m = len(edges), G.shape[0]
        if _highspy is None:
            return self._solve_master_linprog(n, edges, edge_omega, indicator, G, b, g_c, v_cost)
        key = (self._partition_version, m)
        h = self._lp
        if h is not None and self._lp_key == key and np.array_equal(self._lp_G[:-1], G[:-1]):
            # Same partition and fixed rows: only c changed; HiGHS keeps its basis (warm start).
            col = E + m - 1
            for P in np.flatnonzero(self._lp_G[-1] != G[-1]):
                h.changeCoeff(int(P), col, float(-G[-1, P]))
            h.changeCoeff(n, col, float(g_c))
            h.changeColCost(col, float(-b[-1]))
            h.changeRowBounds(n, -_highspy.kHighsInf, float(v_cost))
        else:
            A, cost, col_lower, col_upper, row_lower, row_upper = self._master_dual_lp(
                n, edges, edge_omega, indicator, G, b, g_c, v_cost)
            h = _new_highs()
            for name, value in _HIGHS_SETTINGS.items():
                h.setOptionValue(name, value)
            lp = _highspy.HighsLp()
            lp.num_col_, lp.num_row_ = A.shape[1], A.shape[0]
            lp.col_cost_, lp.col_lower_, lp.col_upper_ = cost, col_lower, col_upper
            lp.row_lower_, lp.row_upper_ = row_lower, row_upper
            lp.a_matrix_.format_ = _highspy.MatrixFormat.kColwise
            lp.a_matrix_.start_, lp.a_matrix_.index_, lp.a_matrix_.value_ = A.indptr, A.indices, A.data
            h.passModel(lp)
            basis = self._inherited_basis(n, edges, m)
            if basis is not None:
                h.setBasis(basis)
        self._lp, self._lp_key, self._lp_G = h, key, G
        h.run()
        if h.getModelStatus() != _highspy.HighsModelStatus.kOptimal:
            self._lp = self._lp_basis = None  # rare numerical trouble: scipy's HiGHS chain (no presolve, IPM)
            return self._solve_master_linprog(n, edges, edge_omega, indicator, G, b, g_c, v_cost)
        basis = h.getBasis()
        self._lp_basis = (self.cells, edges, m, np.array([int(v) for v in basis.col_status]),
                          np.array([int(v) for v in basis.row_status]))
        solution = h.getSolution()
        lam = np.asarray(solution.col_value)[E:E + m]
        row_dual = np.asarray(solution.row_dual)
        return row_dual[:n], max(-float(row_dual[n]), 0.0), lam, -float(h.getInfo().objective_function_value)

    def _inherited_basis(self, n, edges, m):
        """A starting basis for the master after a refinement, from the previous optimal basis.

        Every new cell is part of an old one: its row inherits the old row's status
        (the first child) or is basic (the others: one new basic per new row); an
        edge between new cells inherits the status of the old edge between their
        parents (its reduced cost is unchanged while children share the parent's
        ``x``), a new edge inside an old cell starts at its lower bound. The
        ``lambda``, ``mu`` columns and the ``theta`` row keep theirs. None if the
        partition is not a refinement of the previous one.
        """
        if self._lp_basis is None:
            return None
        old_cells, old_edges, old_m, col_status, row_status = self._lp_basis
        if old_m != m:
            return None
        first = np.unique(self.cells, return_index=True)[1]
        parent = old_cells[first]  # new cell -> old cell
        if not np.array_equal(parent[self.cells], old_cells):
            return None
        n_old = int(old_cells.max()) + 1
        E_old = len(old_edges)
        new_rows = np.full(n, int(_highspy.HighsBasisStatus.kBasic))
        child_first = np.zeros(n, dtype=bool)
        child_first[np.unique(parent, return_index=True)[1]] = True
        new_rows[child_first] = row_status[parent[child_first]]
        rows = np.concatenate([new_rows, row_status[n_old:]])
        pa, pb = parent[edges[:, 0]], parent[edges[:, 1]]
        lo, hi = np.minimum(pa, pb), np.maximum(pa, pb)
        old_key = old_edges[:, 0] * n_old + old_edges[:, 1]
        position = np.searchsorted(old_key, lo * n_old + hi)
        position = np.minimum(position, E_old - 1) if E_old else position
        found = (pa != pb) & (E_old > 0)
        if E_old:
            found &= old_key[position] == lo * n_old + hi
        edge_status = np.full(len(edges), int(_highspy.HighsBasisStatus.kLower))
        basic = int(_highspy.HighsBasisStatus.kBasic)
        inherited = col_status[position[found]]
        # Only one child edge may stay basic per old edge; the others start at a bound.
        inherited = np.where(inherited == basic, int(_highspy.HighsBasisStatus.kLower), inherited)
        edge_status[found] = inherited
        idx = np.flatnonzero(found)
        first_child = idx[np.unique(position[found], return_index=True)[1]]
        edge_status[first_child] = col_status[position[first_child]]
        cols = np.concatenate([edge_status, col_status[E_old:]])
        if np.count_nonzero(cols == basic) + np.count_nonzero(rows == basic) != n + 1:
            return None
        status = list(_highspy.HighsBasisStatus.__members__.values())
        by_code = {int(v): v for v in status}
        result = _highspy.HighsBasis()
        result.col_status = [by_code[int(v)] for v in cols]
        result.row_status = [by_code[int(v)] for v in rows]
        result.valid = True
        return result

    def _solve_master_linprog(self, n, edges, edge_omega, indicator, G, b, g_c, v_cost):
        E, m = len(edges), G.shape[0]
        A, cost, col_lower, col_upper, _, row_upper = self._master_dual_lp(n, edges, edge_omega, indicator, G, b,
                                                                             g_c, v_cost)
        A = A.tocsr()
        for method, options in _HIGHS_OPTIONS:  # dual simplex; without presolve or IPM + crossover if it fails
            res = linprog(cost, A_ub=A[n:], b_ub=row_upper[n:], A_eq=A[:n], b_eq=np.zeros(n),
                          bounds=np.column_stack([col_lower, col_upper]), method=method, options=options)
            if res.status == 0:
                break
        else:
            raise RuntimeError(f"master LP failed: {res.message}")
        return res.eqlin.marginals, max(-float(res.ineqlin.marginals[0]), 0.0), res.x[E:E + m], -float(res.fun)

    def _price(self, supply: np.ndarray):
        """Tet set minimising ``w(boundary of S) - supply(S)``, and that value; (None, 0) if none is negative."""
        members = self._max_flow.source_side(supply)
        self.counters["max_flows"] += 1
        if len(members) == 0:
            return None, 0.0
        inside = np.zeros(self.t, dtype=bool)
        inside[members] = True
        rc = float(self.omega[inside[self._fa] != inside[self._fb]].sum()) - float(supply[members].sum())
        return members, rc


class _MinCut:
    """Minimal source side of ``min_S w(boundary of S) - supply(S)`` on the tet face graph.

    Capacities: ``w_f`` both ways across every face, ``supply^+`` from the
    source, ``supply^-`` to the sink. Uses OR-Tools' push-relabel (int64
    capacities) when it is installed, else scipy's Dinic (int32 capacities).
    Both return the unique minimal source side of a minimum cut.
    """

    def __init__(self, face_tets: np.ndarray, omega: np.ndarray, t: int, backend: str = "auto"):
        self.t = t
        self.omega = omega
        fa, fb = face_tets[:, 0], face_tets[:, 1]
        src, snk = t, t + 1
        arange = np.arange(t)
        self.tails = np.concatenate([fa, fb, np.full(t, src), arange])
        self.heads = np.concatenate([fb, fa, arange, np.full(t, snk)])
        if backend == "auto":
            backend = MAX_FLOW_BACKEND
        ortools_max_flow = None
        if backend != "scipy":
            try:
                from ortools.graph.python import max_flow as ortools_max_flow
            except ImportError:
                if backend == "ortools":
                    raise
        self._ortools = ortools_max_flow
        self.backend = "ortools" if ortools_max_flow is not None else "scipy"
        if self._ortools is None:
            order = sp.csr_matrix((np.arange(1, len(self.tails) + 1, dtype=np.float64), (self.tails, self.heads)),
                                  shape=(t + 2, t + 2))
            self._perm = order.data.astype(np.int64) - 1  # csr data slot -> arc id
            self._indices = order.indices.astype(np.int32)
            self._indptr = order.indptr.astype(np.int32)
        else:
            self._tails32 = self.tails.astype(np.int32)
            self._heads32 = self.heads.astype(np.int32)

    def source_side(self, supply: np.ndarray) -> np.ndarray:
        """Sorted tet ids (k,) of the minimal source side (empty if the minimum is 0 at S = {})."""
        pos = np.maximum(supply, 0.0)
        neg = np.maximum(-supply, 0.0)
        total = float(pos.sum())
        if total <= 0.0:
            return np.zeros(0, dtype=np.int64)
        t = self.t
        caps = np.concatenate([self.omega, self.omega, pos, neg])
        if self._ortools is not None:
            # The total flow stays below 2**52; capped arcs can never saturate.
            caps = np.minimum(np.rint(caps * (_FLOW_UNITS_64 / total)), 2.0**62).astype(np.int64)
            solver = self._ortools.SimpleMaxFlow()
            solver.add_arcs_with_capacity(self._tails32, self._heads32, caps)
            status = solver.solve(t, t + 1)
            if status != solver.OPTIMAL:
                raise RuntimeError(f"OR-Tools max-flow returned status {status}")
            side = np.asarray(solver.get_source_side_min_cut(), dtype=np.int64)
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


class ConicSubproblemSolver:
    """Baseline solver of the subproblem for any ``d``: the whole SOCP (LP for ``d = 1``) in Clarabel.

    Parameters
    ----------
    face_tets : (f, 2) int
        The two tets of every interior face.
    weights : (f,) float
        Face weights ``w_f``.
    eta : (f, d) float
        Material weight per face and axis.
    volumes : (t,) float
        Tet volumes.
    tol : float, optional (default 1e-9)
        Clarabel's gap and feasibility tolerances.
    max_iter : int, optional (default 200)
        Interior-point iterations.
    weight_scale : float, optional (default mean of weights)
        Internal unit of the weights.

    Notes
    -----
    Variables ``x = [u (t*d, row-major), tau (f)]``; minimise ``sum omega_f tau_f``
    with ``(tau_f, eta_f o (u_a - u_b))`` in a second-order cone (two linear
    inequalities for ``d = 1``) and the equality rows in a zero cone.
    """

    name = "clarabel"

    def __init__(self, face_tets, weights, eta, volumes, *, tol: float = 1e-9, max_iter: int = 200,
                 weight_scale: float | None = None):
        import clarabel  # the baseline only; the default solver does not need it

        self._clarabel = clarabel
        self.face_tets, self.scale, self.omega, self.vol = _scaled_problem(face_tets, weights, volumes, weight_scale)
        self.t = len(self.vol)
        self.eta = np.asarray(eta, dtype=np.float64)
        self.d = self.eta.shape[1]
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self._constraints = _Constraints(self.vol)
        self._cone_rows = self._build_cone_rows()

    def _build_cone_rows(self) -> sp.csc_matrix:
        t, d = self.t, self.d
        f = len(self.face_tets)
        nu = t * d
        fa, fb = self.face_tets[:, 0], self.face_tets[:, 1]
        fid = np.arange(f)
        if d == 1:
            e = self.eta[:, 0]
            # tau - eta*(u_a - u_b) >= 0 and tau + eta*(u_a - u_b) >= 0, as s = -A x >= 0.
            rows = np.concatenate([fid, fid, fid, f + fid, f + fid, f + fid])
            cols = np.concatenate([fa, fb, nu + fid, fa, fb, nu + fid])
            vals = np.concatenate([e, -e, -np.ones(f), -e, e, -np.ones(f)])
            return sp.csc_matrix((vals, (rows, cols)), shape=(2 * f, nu + f))
        block = d + 1
        rows = [block * fid]
        cols = [nu + fid]
        vals = [-np.ones(f)]
        for a in range(d):
            r = block * fid + 1 + a
            rows += [r, r]
            cols += [fa * d + a, fb * d + a]
            vals += [-self.eta[:, a], self.eta[:, a]]
        return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(block * f, nu + f))

    def solve(self, c: np.ndarray, fixed=()) -> SubproblemResult:
        """Minimise the energy subject to the constraints (see :meth:`CutSubproblemSolver.solve`).

        ``c`` and every fixed vector are (t, d) (or (t,) when ``d = 1``).
        """
        clarabel = self._clarabel
        start = time.perf_counter()
        t, d = self.t, self.d
        f = len(self.face_tets)
        nu = t * d
        rows = []
        for a in range(d):  # translations
            r = np.zeros((t, d))
            r[:, a] = self.vol
            rows.append(r.reshape(-1))
        for y in fixed:
            rows.append((self.vol[:, None] * np.asarray(y, dtype=np.float64).reshape(t, d)).reshape(-1))
        rows.append((self.vol[:, None] * np.asarray(c, dtype=np.float64).reshape(t, d)).reshape(-1))
        E = np.vstack(rows)
        b_eq = np.zeros(len(rows))
        b_eq[-1] = 1.0
        A_eq = sp.csc_matrix(np.hstack([E, np.zeros((len(rows), f))]))
        A = sp.vstack([A_eq, self._cone_rows], format="csc")
        b = np.concatenate([b_eq, np.zeros(self._cone_rows.shape[0])])
        q = np.concatenate([np.zeros(nu), self.omega])
        P = sp.csc_matrix((nu + f, nu + f))
        if d == 1:
            cones = [clarabel.ZeroConeT(len(rows)), clarabel.NonnegativeConeT(2 * f)]
        else:
            cones = [clarabel.ZeroConeT(len(rows))] + [clarabel.SecondOrderConeT(d + 1)] * f
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        settings.max_iter = self.max_iter
        settings.tol_gap_abs = self.tol
        settings.tol_gap_rel = self.tol
        settings.tol_feas = self.tol
        solver = clarabel.DefaultSolver(P, q, A, b, cones, settings)
        sol = solver.solve()
        status = str(sol.status)
        if "Solved" not in status:
            raise RuntimeError(f"Clarabel stopped with status {status}")
        x = np.asarray(sol.x)
        u = x[:nu].reshape(t, d)
        energy = discontinuity_energy(u, self.face_tets, self.omega, self.eta)
        z = np.asarray(sol.z)
        # Clarabel's dual of the equality rows; b has a single 1, so the dual objective is -z_c.
        lower = -float(z[len(rows) - 1])
        seconds = time.perf_counter() - start
        return SubproblemResult(u=u, energy=energy * self.scale, lower_bound=lower * self.scale,
                                iterations=int(sol.iterations), seconds=seconds, stats={"status": status})
