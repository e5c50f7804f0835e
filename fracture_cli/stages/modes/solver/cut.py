"""Exact solver of the ``d = 1`` fracture-modes subproblem: a partition-refining master LP priced by min cuts.

One ICCM round minimises ``sum_f w_f |u_a - u_b|`` subject to ``1^T M_T u =
0``, ``y_j^T M_T u = 0`` for the earlier modes ``y_j`` and ``c^T M_T u = 1``
(ALGORITHM.md section 2). See :class:`CutSubproblemSolver`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from fracture_cli.geometry import tolerances
from fracture_cli.stages.modes.solver import partition_kernels
from fracture_cli.stages.modes.solver.energy import Constraints, SubproblemResult, scaled_problem
from fracture_cli.stages.modes.solver.master import MasterLP
from fracture_cli.stages.modes.solver.mincut import MinCut

# Above this many cells the master LP costs more than the pricing (dense constraint columns: HiGHS
# time grows ~ cells^2 * constraints); cells on which the master's solution is equal are then merged.
MERGE_CELLS = 150


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
    max_flow : {"auto", "kernel", "ortools", "scipy"}, optional (default "auto")
        Max-flow implementation (:class:`fracture_cli.stages.modes.solver.mincut.MinCut`):
        the compiled push-relabel (about 2x faster than OR-Tools'), OR-Tools'
        push-relabel, or scipy's Dinic (several times slower). All give the
        same minimal minimum cut.
    merge_cells : int, optional (default :data:`MERGE_CELLS`)
        Cell count above which cells with equal master values are merged.

    Notes
    -----
    Dual of the LP: maximise ``lambda_c`` subject to: the supply
    ``s = M_T (sum_j lambda_j y_j + lambda_c c)`` can be routed through the face
    graph with capacities ``w_f``. By max-flow/min-cut this holds iff
    ``s(S) <= w(boundary of S)`` for every tet set ``S``.

    The solver keeps a partition of the tets into cells. The master LP
    (:class:`fracture_cli.stages.modes.solver.master.MasterLP`) restricts ``u`` to be
    constant per cell, plus a multiple of the feasible start vector ``c`` (so it
    is always feasible); HiGHS solves it exactly. Its duals ``lambda`` are
    feasible for every union of cells; pricing checks all other sets with one
    s-t min cut (:class:`fracture_cli.stages.modes.solver.mincut.MinCut`). If a set
    violates its constraint, the partition is split along it and the master
    re-solved; otherwise ``lambda`` certifies that the master's ``u`` is optimal
    (``E(u) <= master objective = lambda_c <= optimum``), and ``u`` is exactly
    piecewise constant.

    What keeps the cost per mode flat (measured in bench/bench_modes.py): the
    master LP has one dense column per constraint, so its cost grows with the
    number of cells times the number of earlier modes. Hence

    * a new mode starts from a single cell (not from the common refinement of
      the earlier modes' pieces, which at mode 20 has hundreds of cells that
      the new mode's solution mostly does not need); the cells found for one
      mode are kept across its ICCM rounds;
    * when the partition grows past ``merge_cells`` and the master's objective
      has strictly decreased since the last merge, neighbouring cells on which
      the master's solution is equal are merged, except across a boundary whose
      flow in the master is at capacity (see :meth:`_coarsen`). The master's
      solution and duals stay optimal for the coarser partition (its feasible set is
      smaller but still contains that solution; its dual constraints are a
      subset), so no LP is re-solved; requiring a strict decrease between
      merges rules out cycling (a partition cannot recur with a lower objective).
      In a call with a ``max_flows`` budget (the middle ICCM rounds of a mode,
      see :func:`fracture_cli.stages.modes._iccm_mode`) the objective of one
      call says nothing about the next, so there a merge needs a lower
      Rayleigh quotient than at the mode's last budgeted merge instead.

    Safeguards: the returned ``u`` must meet the constraints to 1e-7 (relative
    to ``||y_j||_M ||u||_M``) and its energy must not exceed the master's
    objective, else ``RuntimeError``.
    """

    name = "cut"

    def __init__(self, face_tets: np.ndarray, weights: np.ndarray, volumes: np.ndarray, *, tol: float = 1e-9,
                 max_iter: int = 1000,
                 weight_scale: float | None = None, max_flow: str = "auto", merge_cells: int = MERGE_CELLS):
        self.face_tets, self.scale, self.omega, self.vol = scaled_problem(face_tets, weights, volumes, weight_scale)
        self.t = len(self.vol)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.merge_cells = int(merge_cells)
        self._constraints = Constraints(self.vol)
        # Contiguous int64 copies: the compiled partition kernels take them as they are.
        self._fa = np.ascontiguousarray(self.face_tets[:, 0], dtype=np.int64)
        self._fb = np.ascontiguousarray(self.face_tets[:, 1], dtype=np.int64)
        self._max_flow = MinCut(self.face_tets, self.omega, self.t, max_flow)
        self._master_lp = MasterLP(self.vol)
        self.cells = np.zeros(self.t, dtype=np.int64)
        self._partition_version = 0
        self._fixed_count = -1
        self._fixed_cache: list[tuple[np.ndarray, np.ndarray]] = []
        self._cell_cache: tuple[int, np.ndarray, np.ndarray, sp.csr_matrix] | None = None
        self._before_merge: np.ndarray | None = None
        self._budget_merge_rayleigh = np.inf
        # "stalls": pricing found a violated set that is already a union of cells, i.e. the
        # violation is within HiGHS's tolerance; the result stands, min_reduced_cost says by how much.
        self.counters = {"max_flows": 0, "master_lps": 0, "refinements": 0, "stalls": 0, "merges": 0,
                         "unmerges": 0, "lp_retries": 0}

    @property
    def max_flow_backend(self) -> str:
        """'kernel', 'ortools' or 'scipy'."""
        return self._max_flow.backend

    # ------------------------------------------------------------- partition
    def refine(self, members: np.ndarray) -> bool:
        """Split every cell along the tet set ``members``, keeping cells connected; True if any cell split."""
        inside = np.zeros(self.t, dtype=bool)
        inside[members] = True
        fa, fb = self._fa, self._fb
        keep = (self.cells[fa] == self.cells[fb]) & (inside[fa] == inside[fb])
        count, cells = self._components(keep)
        if count == int(self.cells.max()) + 1:
            return False
        self._set_cells(cells)
        return True

    def _coarsen(self, x: np.ndarray) -> np.ndarray:
        """Merge neighbouring cells whose master values ``x`` (n,) are equal and whose common boundary is
        not at capacity in the master's flow; returns ``x`` on the new cells.

        A boundary whose cell-edge flow is nonbasic (at ``+-omega_e``) is a bottleneck of the routing
        that certifies the master's duals, the kind of face set that pricing cuts along: merged away,
        it was found again a few max-flows later (late modes on 12k tets refined back up to 150 cells
        several times in one exact round). Only boundaries with a basic flow are merged. Without a
        HiGHS basis of the current partition (scipy's linprog), every equal-valued boundary is merged.

        With fewer cells than constraint rows the earlier modes' rows can be dependent and HiGHS can
        end without a status: :class:`MasterLP` then solves on a basis of their row space, and if that
        fails too :meth:`_solve_master` undoes the merge. (A floor of half the constraint count used
        to guard against this; it let late modes grow to 300-540 cells, 30-60 ms per master LP.)
        """
        ca, cb = self.cells[self._fa], self.cells[self._fb]
        scale = float(np.abs(x).max()) or 1.0
        join = np.abs(x[ca] - x[cb]) <= 1e-9 * scale
        slack = self._master_lp.slack_edges
        if slack is not None and slack[0] == self._partition_version:
            n, edges = self._cell_graph()[:2]
            between = np.flatnonzero(ca != cb)
            lo, hi = np.minimum(ca[between], cb[between]), np.maximum(ca[between], cb[between])
            edge = np.searchsorted(edges[:, 0] * n + edges[:, 1], lo * n + hi)  # edges are sorted (lo, hi)
            join[between[~slack[1][edge]]] = False
        count, cells = self._components(join)
        if count == len(x):
            return x
        self._before_merge = self.cells
        merged = np.zeros(count)
        merged[cells] = x[self.cells]
        self._set_cells(cells)
        self.counters["merges"] += 1
        return merged

    def _coarsen_budgeted(self, x: np.ndarray, theta: float, v: np.ndarray) -> np.ndarray:
        """:meth:`_coarsen` in a round with a max-flow budget, to any number of cells, but only when the
        Rayleigh quotient ``E(u) / ||u||_M`` of the master's ``u`` has dropped since the last such merge
        of this mode: budgeted rounds that make no progress cannot merge away what they refine."""
        u = x[self.cells] + theta * v
        norm = float(np.sqrt(u @ (self.vol * u)))
        rayleigh = float(self.omega @ np.abs(u[self._fa] - u[self._fb])) / max(norm, tolerances.SMALLEST_DIVISOR)
        if not rayleigh < self._budget_merge_rayleigh * (1.0 - 1e-9):
            return x
        self._budget_merge_rayleigh = rayleigh
        return self._coarsen(x)

    def _components(self, keep: np.ndarray) -> tuple[int, np.ndarray]:
        """Connected components (count, labels (t,)) of the tets joined by the faces in ``keep`` (f,) bool."""
        count, labels = partition_kernels.masked_components(self._fa, self._fb, keep, self.t)
        return int(count), labels

    def _set_cells(self, cells: np.ndarray) -> None:
        self.cells = cells
        self._cell_cache = None
        self._partition_version += 1

    def _cell_graph(self) -> tuple[int, np.ndarray, np.ndarray, sp.csr_matrix]:
        """``(n, edges (E, 2), edge_omega (E,), indicator (n, t))`` of the current partition (cached)."""
        if self._cell_cache is None:
            n = int(self.cells.max()) + 1
            edges, edge_omega = partition_kernels.cell_graph(self.cells, self._fa, self._fb, self.omega, n)
            order, indptr = partition_kernels.cell_order(self.cells, n)
            indicator = sp.csr_matrix((self.vol[order], order, indptr), shape=(n, self.t))
            self._cell_cache = (n, edges, edge_omega, indicator)
        return self._cell_cache

    def _project_fixed(self, k: int, y: np.ndarray) -> np.ndarray:
        """Projected fixed vector ``k``, cached (the same earlier modes recur in every ICCM round)."""
        y = np.asarray(y, dtype=np.float64).reshape(-1)
        if k < len(self._fixed_cache) and (self._fixed_cache[k][0] is y or np.array_equal(self._fixed_cache[k][0], y)):
            return self._fixed_cache[k][1]
        del self._fixed_cache[k:]
        self._fixed_cache.append((y, self._constraints.project(y)))
        return self._fixed_cache[k][1]

    # ----------------------------------------------------------------- solve
    def solve(self, c: np.ndarray, fixed: Sequence[np.ndarray] = (), *, max_flows: int | None = None,
              stall_flows: int | None = None) -> SubproblemResult:
        """Minimise the energy subject to the constraints.

        Parameters
        ----------
        c : (t,) or (t, 1) float
            The ICCM vector; the solution satisfies ``c^T M_T u = 1``.
        fixed : sequence of (t,) or (t, 1) float
            Vectors ``y_j`` with ``y_j^T M_T u = 0`` (the earlier modes).
        max_flows : int, optional (default None: no limit)
            Pricing rounds allowed. When they run out before a certificate, the result is the master's
            solution on the refined partition: feasible, energy at most that of ``c`` scaled to
            ``c^T M_T u = 1``, but not certified (``stats["certified"]`` False, ``lower_bound`` nan).
        stall_flows : int, optional (default None: never)
            Stop the same way (uncertified) once the master's objective, after its first decrease, has
            not decreased by more than 1e-7 (relative) over this many max-flows: the degenerate tail
            of column generation, where the master's solution is already optimal (or nearly) and the
            max-flows only make its duals feasible, which a round that is not the mode's last does
            not need (about 10 max-flows of a late mode's first round).

        Returns
        -------
        SubproblemResult
            ``u`` (t, 1), energy in the units of the weights given, the dual bound.
        """
        start = time.perf_counter()
        before = dict(self.counters, lp_retries=self._master_lp.retries)
        if len(fixed) != self._fixed_count:  # a new mode: start from one cell (see the class notes)
            self._fixed_count = len(fixed)
            self._set_cells(np.zeros(self.t, dtype=np.int64))
            self._before_merge = None
            self._budget_merge_rayleigh = np.inf
        Y, v, v_cost = self._constraint_vectors(c, fixed)
        b = np.zeros(Y.shape[1])
        b[-1] = 1.0
        x, theta, objective, worst_rc, certified = self._cut_loop(Y, b, v, v_cost, max_flows, stall_flows)
        u = x[self.cells]
        if theta > 0.0:
            u = u + theta * v
        u = self._constraints.project(u)
        energy, residual = self._check(u, Y, b, objective)
        self.counters["lp_retries"] = self._master_lp.retries
        stats: dict = {key: self.counters[key] - before[key] for key in self.counters}
        stats.update(cells=int(self.cells.max()) + 1, min_reduced_cost=worst_rc * self.scale,
                     uses_start_vector=bool(theta > 0.0), constraint_residual=residual, certified=certified)
        bound = objective * self.scale if certified else float("nan")
        return SubproblemResult(u=u[:, None], energy=energy * self.scale, lower_bound=bound,
                                iterations=stats["max_flows"], seconds=time.perf_counter() - start, stats=stats)

    def _constraint_vectors(self, c: np.ndarray, fixed: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray, float]:
        """The constraint vectors ``Y`` (t, m) (fixed ones, then ``c``, all projected), the feasible start
        vector ``v`` (t,) (``c`` made M_T-orthogonal to the fixed vectors, ``c^T M v = 1``) and its energy."""
        cp = self._constraints.project(np.asarray(c, dtype=np.float64).reshape(-1))
        projected = [self._project_fixed(k, y) for k, y in enumerate(fixed)]
        if not np.any(cp):
            raise ValueError("c is constant: no displacement with c^T M u = 1 is orthogonal to translations")
        Y = np.column_stack(projected + [cp])
        MY = self.vol[:, None] * Y
        v = cp
        if Y.shape[1] > 1:
            v = cp - Y[:, :-1] @ np.linalg.lstsq(MY[:, :-1].T @ Y[:, :-1], MY[:, :-1].T @ cp, rcond=None)[0]
        norm = float(v @ MY[:, -1])
        if not norm > 1e-12 * float(cp @ MY[:, -1]):
            raise ValueError("c lies in the span of the fixed vectors: the constraints are infeasible")
        v = v / norm
        return Y, v, float(self.omega @ np.abs(v[self._fa] - v[self._fb]))

    def _cut_loop(self, Y: np.ndarray, b: np.ndarray, v: np.ndarray, v_cost: float, max_flows: int | None = None,
                  stall_flows: int | None = None) -> tuple[np.ndarray, float, float, float, bool]:
        """Master LP and pricing until no tet set is violated; returns ``x`` (cells,), ``theta``, the
        objective, the last reduced cost and whether it is certified (False: ``max_flows`` ran out or
        the objective stalled for ``stall_flows``)."""
        MY = self.vol[:, None] * Y
        worst_rc = 0.0
        merged_at = np.inf
        objectives: list[float] = []
        for flows in range(self.max_iter):
            self.counters["master_lps"] += 1
            x, theta, lam, objective = self._solve_master(Y, b, v_cost)
            objectives.append(objective)
            if (stall_flows is not None and len(objectives) > stall_flows and objective < objectives[0]
                    and objective >= objectives[-1 - stall_flows] * (1.0 - 1e-7)):
                return x, theta, objective, worst_rc, False
            if len(x) > self.merge_cells and max_flows is None and objective < merged_at - 1e-9 * abs(objective):
                x = self._coarsen(x)
                merged_at = objective
            elif len(x) > self.merge_cells and max_flows is not None:
                x = self._coarsen_budgeted(x, theta, v)
            if max_flows is not None and flows >= max_flows:
                return x, theta, objective, worst_rc, False
            supply = MY @ lam
            members, rc = self._price(supply)
            worst_rc = min(rc, 0.0)
            if members is None or rc >= -self.tol * max(objective, tolerances.SMALLEST_DIVISOR):
                return x, theta, objective, worst_rc, True
            if not self.refine(members):
                # The set is a union of cells: the violation is within the master LP's tolerance.
                self.counters["stalls"] += 1
                return x, theta, objective, worst_rc, True
            self.counters["refinements"] += 1
        raise RuntimeError(f"no optimality certificate after {self.max_iter} max-flows")

    def _solve_master(self, Y: np.ndarray, b: np.ndarray, v_cost: float) -> tuple[np.ndarray, float, np.ndarray, float]:
        """The master LP on the current partition. If every LP solver fails on it (a merged partition
        can be badly conditioned), once more on its common refinement with the partition before the
        last merge."""
        try:
            return self._master_lp.solve(self.cells, self._partition_version, self._cell_graph(), Y, b, v_cost)
        except RuntimeError:
            if self._before_merge is None:
                raise
        old = self._before_merge
        self._before_merge = None
        self.counters["unmerges"] += 1
        self._set_cells(self._components((self.cells[self._fa] == self.cells[self._fb])
                                         & (old[self._fa] == old[self._fb]))[1])
        return self._master_lp.solve(self.cells, self._partition_version, self._cell_graph(), Y, b, v_cost)

    def _check(self, u: np.ndarray, Y: np.ndarray, b: np.ndarray, objective: float) -> tuple[float, float]:
        """Safeguards on the recovered ``u`` (t,): constraints met, energy not above the master's; returns
        the energy and the relative constraint residual."""
        MY = self.vol[:, None] * Y
        # Relative to ||y_j||_M ||u||_M (the M_T-cosine), the natural scale of y_j^T M_T u.
        norms = np.sqrt(np.einsum("tj,tj->j", MY, Y) * float(u @ (self.vol * u)))
        residual = float(np.max(np.abs(MY.T @ u - b) / np.maximum(norms, tolerances.SMALLEST_DIVISOR)))
        if not residual <= 1e-7:
            raise RuntimeError(f"the master LP's solution violates the constraints by {residual:.2e} (relative)")
        energy = float(self.omega @ np.abs(u[self._fa] - u[self._fb]))
        # Relative to the size of the terms, not absolute: a disconnected tet mesh has
        # zero-energy modes, whose rounding noise an absolute 1e-12 would reject.
        slack = 1e-7 * abs(objective) + 1e-12 * float(self.omega.sum()) * float(np.abs(u).max())
        if energy > objective + slack:
            raise RuntimeError(f"the recovered solution's energy {energy:.9g} exceeds the master's {objective:.9g}")
        return energy, residual

    def _price(self, supply: np.ndarray) -> tuple[np.ndarray | None, float]:
        """Tet set minimising ``w(boundary of S) - supply(S)``, and that value; (None, 0) if none is negative."""
        members = self._max_flow.source_side(supply)
        self.counters["max_flows"] += 1
        if len(members) == 0:
            return None, 0.0
        inside = np.zeros(self.t, dtype=bool)
        inside[members] = True
        rc = float(self.omega[inside[self._fa] != inside[self._fb]].sum()) - float(supply[members].sum())
        return members, rc
