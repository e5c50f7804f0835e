"""The master LP of the cut solver: the subproblem restricted to cell-constant displacements.

Primal: ``min sum_e omega_e |x_P - x_Q| + cost(v) theta`` subject to ``G x + g
theta = b`` (the constraint rows, scaled) and ``vol^T x = 0``, ``theta >= 0``.
HiGHS solves its dual, which is smaller: edge flows ``|z_e| <= omega_e``,
``lambda`` and ``mu`` free, one conservation row per cell ``B^T z - G^T lambda
- mu vol = 0`` and ``g^T lambda <= cost(v)``; ``x`` and ``theta`` are that LP's
row duals.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from fracture_cli.geometry import tolerances

_highspy: Any
try:  # HiGHS's own bindings allow warm starts; scipy's linprog (same HiGHS) is the fallback
    import highspy as _highspy
except ImportError:
    _highspy = None

if TYPE_CHECKING:
    import highspy

# The dual master LP: matrix, costs, column lower / upper bounds, row lower / upper bounds.
_DualLP = tuple[sp.csc_matrix, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
# The master's arguments: cells (t,), partition version, n, edges (E, 2), edge_omega (E,), indicator (n, t),
# G (m, n), b (m,), g_c, v_cost.
_MasterArgs = tuple[np.ndarray, int, int, np.ndarray, np.ndarray, sp.csr_matrix, np.ndarray, np.ndarray, float, float]
# x (n,), theta, lambda (m,), objective
_MasterSolution = tuple[np.ndarray, float, np.ndarray, float]

log = logging.getLogger(__name__)

# The master LP's duals are the pricing's supply: keep HiGHS's tolerances tight.
# Serial dual simplex: deterministic.
_HIGHS_SETTINGS: dict[str, bool | float | str] = {
    "solver": "simplex", "simplex_strategy": 1, "primal_feasibility_tolerance": 1e-9,
    "dual_feasibility_tolerance": 1e-9, "threads": 1, "output_flag": False}
# Cold retries when the warm-started solve does not end optimal (small masters with nearly dependent
# constraint rows can leave HiGHS without a status): a fresh dual simplex, primal simplex, both
# without presolve, then IPM.
# Without presolve too: a 28-row master (mode 18 at k = 24, 6k tets) ended in kSolveError with
# presolve and solved at once without it.
_HIGHS_RETRIES: tuple[dict, ...] = ({}, {"simplex_strategy": 4}, {"presolve": "off"},
                                    {"simplex_strategy": 4, "presolve": "off"}, {"solver": "ipm"})
_LINPROG_OPTIONS = (("highs-ds", {"primal_feasibility_tolerance": 1e-9, "dual_feasibility_tolerance": 1e-9}),
                    ("highs-ds", {"primal_feasibility_tolerance": 1e-9, "dual_feasibility_tolerance": 1e-9,
                                  "presolve": False}),
                    ("highs-ipm", {"primal_feasibility_tolerance": 1e-9, "dual_feasibility_tolerance": 1e-9}))
_HIGHS_BANNER_SHOWN = False


def lp_backend() -> str:
    """'highspy' (warm-started HiGHS) or 'scipy' (HiGHS through scipy.optimize.linprog)."""
    return "highspy" if _highspy is not None else "scipy"


def _new_highs() -> highspy.Highs:
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


def _highs_model(A: sp.csc_matrix, cost: np.ndarray, col_lower: np.ndarray, col_upper: np.ndarray,
                 row_lower: np.ndarray, row_upper: np.ndarray, *, reuse: highspy.Highs | None = None,
                 **extra: bool | float | str) -> highspy.Highs:
    """A ``highspy.Highs`` holding the LP, with the project's settings (and ``extra`` ones).

    ``reuse``: a ``Highs`` made here before with the project's settings only; passing a new model
    to it drops its old model, basis and solution, and saves building a solver object (a third of
    the Python cost of a master LP).
    """
    if reuse is not None and not extra:
        h = reuse
    else:
        h = _new_highs()
        for name, value in dict(_HIGHS_SETTINGS, **extra).items():
            h.setOptionValue(name, value)
    lp = _highspy.HighsLp()
    lp.num_col_, lp.num_row_ = A.shape[1], A.shape[0]
    lp.col_cost_, lp.col_lower_, lp.col_upper_ = cost, col_lower, col_upper
    lp.row_lower_, lp.row_upper_ = row_lower, row_upper
    lp.a_matrix_.format_ = _highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_, lp.a_matrix_.index_, lp.a_matrix_.value_ = A.indptr, A.indices, A.data
    h.passModel(lp)
    return h


def _basis_statuses() -> np.ndarray:
    """``highspy.HighsBasisStatus`` members (object array) indexed by their integer codes."""
    members = list(_highspy.HighsBasisStatus.__members__.values())
    lookup = np.empty(max(int(v) for v in members) + 1, dtype=object)
    for v in members:
        lookup[int(v)] = v
    return lookup


def _independent_fixed_rows(G: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(W (r, n), back (m - 1, r))``: an orthonormal basis of the row space of the fixed rows ``G[:-1]``
    and the map of its multipliers to theirs; None if those rows are independent (nothing to reduce)."""
    fixed = G[:-1]
    if len(fixed) == 0:
        return None
    U, S, Vt = np.linalg.svd(fixed, full_matrices=False)
    keep = S > 1e-9 * S[0] if len(S) and S[0] > 0 else np.zeros(len(S), dtype=bool)
    if keep.all():
        return None
    # W^T mu = fixed^T (U_r S_r^-1 mu): the same dual constraint, so lambda = U_r S_r^-1 mu.
    return Vt[keep], U[:, keep] / S[keep]


class MasterLP:
    """The master LP over a partition of the tets into cells, warm-started across calls.

    A new ``c`` on the same partition only edits one column of the (dual)
    master, and HiGHS keeps its basis; after a refinement the previous optimal
    basis is carried over to the split cells (:meth:`_inherited_basis`).
    """

    def __init__(self, volumes: np.ndarray):
        self.vol = volumes
        self._lp: Any = None  # the HiGHS object of the last master (highspy has no type stubs)
        self._lp_key: Any = None
        self._lp_G: Any = None
        # (cells, edges, m, column statuses, row statuses) of the last optimal basis
        self._lp_basis: tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray] | None = None
        # the Highs object of the master with default settings (see _highs_model)
        self._highs: highspy.Highs | None = None
        self.retries = 0
        # (partition version, (E,) bool): cell edges whose flow was basic (strictly inside its bounds)
        # in the last optimal HiGHS basis; None after a solve without a basis (scipy's linprog).
        self.slack_edges: tuple[int, np.ndarray] | None = None

    def solve(self, cells: np.ndarray, version: int, cell_graph: tuple[int, np.ndarray, np.ndarray, sp.csr_matrix],
              Y: np.ndarray, b: np.ndarray, v_cost: float) -> _MasterSolution:
        """Solve the master on the partition ``cells`` (t,) (``version`` changes with it).

        ``cell_graph`` is ``(n, edges (E, 2), edge_omega (E,), indicator (n, t))``; ``Y`` (t, m)
        the constraint vectors. Returns ``x`` (n,), ``theta``, the (unscaled) ``lambda`` (m,)
        and the objective.
        """
        n, edges, edge_omega, indicator = cell_graph
        G = np.asarray((indicator @ Y).T)  # (m, n): y_j^T M_T 1_P
        # Row scaling for HiGHS (tet volumes are tiny in normalized units); lambda is scaled back.
        row_scale = 1.0 / np.maximum(np.einsum("t,tj->j", self.vol, np.abs(Y)), tolerances.SMALLEST_DIVISOR)
        G = G * row_scale[:, None]
        G[np.abs(G) < 1e-12] = 0.0  # round-off of sums that cancel; keeps HiGHS's matrix clean
        b = b * row_scale
        args = (cells, version, n, edges, edge_omega, indicator, G, b, row_scale[-1], v_cost)
        try:
            x, theta, lam, objective = self._solve_any(args)
        except RuntimeError:
            reduced = _independent_fixed_rows(G)
            if reduced is None:
                raise
            x, theta, lam, objective = self._solve_reduced(args, *reduced)
        return x, theta, lam * row_scale, objective

    def _solve_any(self, args: _MasterArgs) -> _MasterSolution:
        if _highspy is None:
            return self._solve_linprog(*args[2:])
        return self._solve_highs(*args)

    def _solve_reduced(self, args: _MasterArgs, W: np.ndarray, back: np.ndarray) -> _MasterSolution:
        """The master with the fixed rows replaced by an orthonormal basis ``W`` (r, n) of their row space.

        On a coarse partition the earlier modes' rows can be dependent up to round-off (singular values
        1e-12 to 1e-19 next to 5e-5 and up, seen at mode 18 of 24 on 27 cells): HiGHS then ends
        without a status or reports a spurious unbounded ray. Their right-hand sides are 0, so the
        basis gives the same feasible set; ``lambda`` of the original rows is ``back @ lambda_W``.
        """
        cells, version, n, edges, edge_omega, indicator, G, b, g_c, v_cost = args
        self.retries += 1
        self._lp = self._lp_basis = None  # another row set: no warm start from or into it
        G_reduced = np.vstack([W, G[-1:]])
        b_reduced = np.concatenate([np.zeros(len(W)), b[-1:]])
        x, theta, lam, objective = self._solve_any((cells, version, n, edges, edge_omega, indicator, G_reduced,
                                                    b_reduced, g_c, v_cost))
        self._lp = self._lp_basis = None
        return x, theta, np.concatenate([back @ lam[:-1], lam[-1:]]), objective

    @staticmethod
    def _dual_lp(n: int, edges: np.ndarray, edge_omega: np.ndarray, indicator: sp.csr_matrix, G: np.ndarray,
                 b: np.ndarray, g_c: float, v_cost: float) -> _DualLP:
        """Matrix (n + 1, E + m + 1), costs, column bounds and row bounds of the dual master LP."""
        E, m = len(edges), G.shape[0]
        cell_vol = np.asarray(indicator.sum(axis=1)).reshape(-1)
        # CSC in canonical order, built directly (the master is rebuilt after every refinement): edge
        # column e holds +1 at its lower cell and -1 at its higher one (edges are (lo, hi)); lambda
        # column j holds -G[j] at its non-zeros (and g_c in the theta row for c's column); the mu
        # column holds the cells' volume shares.
        lam_rows, lam_cells = np.nonzero(G)
        lam_counts = np.bincount(lam_rows, minlength=m)
        lam_counts[m - 1] += 1
        lam_index = np.empty(len(lam_rows) + 1, dtype=np.int32)
        lam_value = np.empty(len(lam_rows) + 1)
        lam_index[:-1], lam_value[:-1] = lam_cells, -G[lam_rows, lam_cells]
        lam_index[-1], lam_value[-1] = n, g_c  # last: the theta row of c's column, below every cell row
        indptr = np.concatenate([np.arange(0, 2 * E + 1, 2), 2 * E + np.cumsum(lam_counts),
                                 [2 * E + len(lam_index) + n]]).astype(np.int32)
        indices = np.concatenate([edges.reshape(-1), lam_index, np.arange(n)]).astype(np.int32)
        values = np.concatenate([np.tile([1.0, -1.0], E), lam_value, -cell_vol / cell_vol.sum()])
        A = sp.csc_matrix((values, indices, indptr), shape=(n + 1, E + m + 1))
        cost = np.concatenate([np.zeros(E), -b, [0.0]])
        col_lower = np.concatenate([-edge_omega, np.full(m + 1, -np.inf)])
        col_upper = np.concatenate([edge_omega, np.full(m + 1, np.inf)])
        row_lower = np.concatenate([np.zeros(n), [-np.inf]])
        row_upper = np.concatenate([np.zeros(n), [v_cost]])
        return A, cost, col_lower, col_upper, row_lower, row_upper

    def _solve_highs(self, cells: np.ndarray, version: int, n: int, edges: np.ndarray, edge_omega: np.ndarray,
                     indicator: sp.csr_matrix, G: np.ndarray, b: np.ndarray, g_c: float,
                     v_cost: float) -> _MasterSolution:
        E, m = len(edges), G.shape[0]
        key = (version, m)
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
            h = _highs_model(*self._dual_lp(n, edges, edge_omega, indicator, G, b, g_c, v_cost), reuse=self._highs)
            self._highs = h
            basis = self._inherited_basis(cells, n, edges, m)
            if basis is not None:
                h.setBasis(basis)
        self._lp, self._lp_key, self._lp_G = h, key, G
        h.run()
        if h.getModelStatus() != _highspy.HighsModelStatus.kOptimal:
            h = self._retry(n, edges, edge_omega, indicator, G, b, g_c, v_cost)
        if h is None:  # rare numerical trouble: scipy's HiGHS chain (no presolve, IPM)
            self._lp = self._lp_basis = None
            return self._solve_linprog(n, edges, edge_omega, indicator, G, b, g_c, v_cost)
        basis = h.getBasis()
        self._lp_basis = (cells, edges, m, np.array(basis.col_status, dtype=np.int64),
                          np.array(basis.row_status, dtype=np.int64))
        self.slack_edges = (version, self._lp_basis[3][:E] == int(_highspy.HighsBasisStatus.kBasic))
        solution = h.getSolution()
        lam = np.asarray(solution.col_value)[E:E + m]
        row_dual = np.asarray(solution.row_dual)
        return row_dual[:n], max(-float(row_dual[n]), 0.0), lam, -float(h.getInfo().objective_function_value)

    def _retry(self, n: int, edges: np.ndarray, edge_omega: np.ndarray, indicator: sp.csr_matrix, G: np.ndarray,
               b: np.ndarray, g_c: float, v_cost: float) -> highspy.Highs | None:
        """Cold solves with other HiGHS settings after a warm-started one did not end optimal; None if all fail."""
        self.retries += 1
        lp = self._dual_lp(n, edges, edge_omega, indicator, G, b, g_c, v_cost)
        for extra in _HIGHS_RETRIES:
            h = _highs_model(*lp, **extra)
            h.run()
            if h.getModelStatus() == _highspy.HighsModelStatus.kOptimal:
                self._lp = h
                return h
        log.debug("master LP: HiGHS ended without an optimal status %d times; trying scipy's chain",
                  len(_HIGHS_RETRIES))
        return None

    def _inherited_basis(self, cells: np.ndarray, n: int, edges: np.ndarray, m: int) -> highspy.HighsBasis | None:
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
        parent = np.empty(n, dtype=old_cells.dtype)
        parent[cells] = old_cells  # new cell -> old cell (if the partition refines the old one)
        if not np.array_equal(parent[cells], old_cells):
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
        by_code = _basis_statuses()
        result = _highspy.HighsBasis()
        result.col_status = by_code[cols].tolist()
        result.row_status = by_code[rows].tolist()
        result.valid = True
        return result

    def _solve_linprog(self, n: int, edges: np.ndarray, edge_omega: np.ndarray, indicator: sp.csr_matrix,
                       G: np.ndarray, b: np.ndarray, g_c: float, v_cost: float) -> _MasterSolution:
        # Imported here: scipy.optimize costs ~0.1 s to import, and with highspy this fallback rarely runs.
        from scipy.optimize import linprog

        self.slack_edges = None
        E, m = len(edges), G.shape[0]
        A, cost, col_lower, col_upper, _, row_upper = self._dual_lp(n, edges, edge_omega, indicator, G, b, g_c, v_cost)
        A = A.tocsr()
        for method, options in _LINPROG_OPTIONS:  # dual simplex; without presolve or IPM + crossover if it fails
            res = linprog(cost, A_ub=A[n:], b_ub=row_upper[n:], A_eq=A[:n], b_eq=np.zeros(n),
                          bounds=np.column_stack([col_lower, col_upper]), method=method, options=options)
            if res.status == 0:
                break
        else:
            raise RuntimeError(f"master LP failed: {res.message}")
        return res.eqlin.marginals, max(-float(res.ineqlin.marginals[0]), 0.0), res.x[E:E + m], -float(res.fun)
