"""The work of the ``modes`` stage: start vectors, the ICCM loop and its subproblem solvers (ALGORITHM.md section 2).

Per-tet displacements, an interior-face discontinuity energy, and the adapted
ICCM loop (paper Algorithm 1) started from the tet mesh's generalized Laplacian
eigenvectors. The convex subproblem of each ICCM round is solved exactly by
:class:`fracture_cli.stages.modes.solver.CutSubproblemSolver` (default, ``solver =
"fast"``) or by the interior-point baseline
:class:`fracture_cli.stages.modes.solver.ConicSubproblemSolver` (``solver = "clarabel"``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from fracture_cli.errors import StageError
from fracture_cli.geometry import tolerances
from fracture_cli.stages.modes.options import STAGE, ModesOptions
from fracture_cli.stages.modes.solver import (
    ConicSubproblemSolver,
    CutSubproblemSolver,
    SubproblemResult,
    discontinuity_energy,
    face_weights,
    jump_norms,
    lp_backend,
)
from fracture_cli.stages.modes.start import scalar_start_vectors
from fracture_cli.system import parallel, progress
from fracture_cli.types import Modes, TetMesh

log = logging.getLogger(__name__)


# ICCM rounds of a mode with a max-flow budget at most, and that budget (see _iccm_mode). Measured at
# k = 24 on 6k tets (one run each, CPU s on a loaded machine, before budgeted rounds could merge cells):
# budgets 1, 2, 3, 4 gave 12.7, 10.0, 10.2, 12.2 s and worst/median 4.8, 6.4, 3.6, 5.2, with sums of
# the 24 energies 35.9, 36.9, 37.1, 37.4 (37.1 with exact rounds only, 17-18 s, worst/median 9).
_BUDGET_ROUNDS = 60
_ROUND_FLOWS = 3
# The first round of a mode stops (uncertified) when the master's objective has not decreased for this
# many max-flows (CutSubproblemSolver.solve's stall_flows). k = 24 and 32 on the 3k/6k/12k bench meshes:
# max-flows 476/520/695 -> 470/495/597 (k = 24), 878/1021/1295 -> 873/1051/1175 (k = 32), sums of
# energies within +-2% either way (other local minima, as with any change of the ICCM path).
_FIRST_ROUND_STALL = 3
# solve(c, earlier_modes, max_flows, first_round) of an ICCM chain (see _iccm).
_Solve = Callable[[np.ndarray, list[np.ndarray], int | None, bool], SubproblemResult]
# One chain of _axis_chain: face_tets, weights, weight_scale, volumes, scalar_init, count, opts, axis, d.
_ChainTask = tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray, int, "ModesOptions", int, int]

def compute_modes(tet_mesh: TetMesh, options: ModesOptions, eta: np.ndarray | None,
                  cells: np.ndarray | None) -> Modes:
    """The body of :func:`fracture_cli.stages.modes.modes` (parameters, results and notes there)."""
    opts = options
    t = tet_mesh.num_tets
    k = int(opts.num_modes)
    d = int(opts.dim)
    face_tets = tet_mesh.interior_face_tets
    f = len(face_tets)
    if t < 2 or f == 0:
        raise StageError(f"the tet mesh has {t} tets and {f} interior faces; fracture modes need at least two "
                         "tets sharing a face", stage=STAGE)
    scalar_count = k if d == 1 else math.ceil(k / 3)
    if scalar_count + 2 > tet_mesh.num_vertices or k > d * (t - 1):
        raise StageError(f"{k} modes of dimension {d} need a larger tet mesh (it has {t} tets, "
                         f"{tet_mesh.num_vertices} vertices); lower num_modes or refine the mesh", stage=STAGE)
    eta2 = _check_eta(eta, f, d)
    areas = face_weights(tet_mesh)
    volumes = np.asarray(tet_mesh.tet_volumes, dtype=np.float64)
    if np.any(volumes <= 0):
        raise StageError("the tet mesh has tets with non-positive volume; re-run the tetrahedralization",
                         stage=STAGE)

    start = time.perf_counter()
    scalar_init = scalar_start_vectors(tet_mesh, scalar_count, opts.seed)
    eig_seconds = time.perf_counter() - start
    log.info("%s: %d start vectors from the Laplacian eigenproblem in %.2f s", STAGE, scalar_count, eig_seconds)

    if cells is not None:
        U, info = _modes_on_cells(cells, face_tets, areas, eta2, volumes, scalar_init, k, d, opts)
        k = U.shape[0]
    elif opts.solver == "fast":
        U, info = _modes_fast(face_tets, areas, eta2, volumes, scalar_init, k, d, opts)
    else:
        U, info = _modes_clarabel(face_tets, areas, eta2, volumes, scalar_init, k, d, opts)

    labels = np.zeros((k, t), dtype=np.int32)
    cut = np.zeros((k, f), dtype=bool)
    piece_counts = np.zeros(k, dtype=np.int32)
    energies = np.zeros(k)
    for i in range(k):
        cut[i], labels[i], piece_counts[i] = mode_pieces(U[i], face_tets, t, opts.sigma)
        energies[i] = discontinuity_energy(U[i], face_tets, areas, eta2)
        if piece_counts[i] < 2:
            log.warning("%s: mode %d has a single piece (degenerate)", STAGE, i)
    stats = {
        "solver": opts.solver,
        "dim": d,
        "eigensolver_seconds": eig_seconds,
        "seconds": time.perf_counter() - start,
        **info,
    }
    log.info("%s: %d modes in %.2f s (%.3f s per mode), pieces per mode %s", STAGE, k, stats["seconds"],
             stats["seconds"] / k, piece_counts.tolist())
    return Modes(U=U, labels=labels, cut=cut, piece_counts=piece_counts, energies=energies,
                 iterations=np.asarray(info["iterations"], dtype=np.int32), stats=stats)


def mode_pieces(u: np.ndarray, face_tets: np.ndarray, num_tets: int,
                sigma: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Cut faces and pieces of one mode.

    Parameters
    ----------
    u : (t, d) or (t,) float
        One mode.
    face_tets : (f, 2) int
        Interior faces' tets.
    num_tets : int
        ``t``.
    sigma : float
        Relative threshold: a face is cut when its jump exceeds ``sigma`` times the largest jump.

    Returns
    -------
    cut : (f,) bool
    labels : (t,) int32
        Connected components of the face-adjacency graph without cut faces.
    count : int
        Number of pieces.
    """
    jumps = jump_norms(u, face_tets)
    largest = float(jumps.max()) if len(jumps) else 0.0
    cut = jumps > sigma * largest if largest > 0 else np.zeros(len(jumps), dtype=bool)
    keep = ~cut
    a, b = face_tets[keep, 0], face_tets[keep, 1]
    graph = sp.csr_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(num_tets, num_tets))
    count, labels = connected_components(graph, directed=False)
    return cut, labels.astype(np.int32), int(count)


def _check_eta(eta: np.ndarray | None, f: int, d: int) -> np.ndarray:
    if eta is None:
        return np.ones((f, d))
    eta = np.asarray(eta, dtype=np.float64)
    if eta.ndim == 1:
        eta = eta[:, None] * np.ones((1, d))
    if eta.shape != (f, d):
        raise StageError(f"eta has shape {eta.shape}; expected ({f},) or ({f}, {d}) (one weight per interior face "
                         "and axis)", stage=STAGE)
    if not np.all(np.isfinite(eta)) or np.any(eta <= 0):
        raise StageError("eta must be positive and finite; use a large value (e.g. 1e6) for unbreakable faces",
                         stage=STAGE)
    return eta


class _MInner:
    """M_T inner products of (t, d) fields."""

    def __init__(self, volumes: np.ndarray, d: int):
        self.vol = volumes
        self.d = d
        self.translations = []
        for a in range(d):
            e = np.zeros((len(volumes), d))
            e[:, a] = 1.0 / math.sqrt(volumes.sum())
            self.translations.append(e)

    def dot(self, x: np.ndarray, y: np.ndarray) -> float:
        return float(np.einsum("t,td,td->", self.vol, x, y))

    def orthonormalize(self, c: np.ndarray, basis: Sequence[np.ndarray]) -> np.ndarray | None:
        """``c`` minus its M_T-projection on ``basis`` (M_T-orthonormal), normalized; None if nothing is left."""
        norm0 = math.sqrt(self.dot(c, c))
        for _ in range(2):  # twice is enough (Gram-Schmidt reorthogonalization)
            for b in basis:
                c = c - self.dot(c, b) * b
        norm = math.sqrt(self.dot(c, c))
        if not norm > 1e-8 * norm0:
            return None
        return c / norm


def _iccm(solve: _Solve, starts: np.ndarray | Sequence[np.ndarray], count: int, inner: _MInner, opts: ModesOptions,
          label: str, random_start: Callable[[int], np.ndarray],
          restricted: bool = False) -> tuple[list[np.ndarray], list[dict]]:
    """Adapted ICCM (paper Algorithm 1): ``count`` modes (t, d) from start vectors ``starts``.

    ``solve(c, earlier_modes, max_flows, first_round) -> SubproblemResult`` (``max_flows`` None: exact,
    except that a first round may stop on a stalled objective);
    ``restricted``: the solver takes a max-flow budget (see :func:`_iccm_mode`).
    """
    found: list[np.ndarray] = []
    per_mode: list[dict] = []
    progress.items(count, f"mode{label}")
    for i in range(count):
        mode_start = time.perf_counter()
        mode_cpu = time.process_time()
        c = inner.orthonormalize(starts[i], inner.translations + found)
        attempts = 0
        while c is None:  # the start vector lies in the span of the earlier modes
            attempts += 1
            c = inner.orthonormalize(random_start(attempts), inner.translations + found)
        c, stats = _iccm_mode(solve, c, found, inner, opts, f"mode {i}{label}", restricted)
        rounds, inner_iterations = stats["rounds"], stats["inner_iterations"]
        found.append(c)
        seconds = time.perf_counter() - mode_start
        per_mode.append(dict(stats, seconds=seconds, cpu_seconds=time.process_time() - mode_cpu))
        log.info("%s: mode %d%s: %d ICCM rounds, %d inner iterations, %.3f s", STAGE, i, label, rounds,
                 inner_iterations, seconds)
        progress.advance()
    return found, per_mode


def _iccm_mode(solve: _Solve, c: np.ndarray, found: list[np.ndarray], inner: _MInner, opts: ModesOptions, name: str,
               restricted: bool) -> tuple[np.ndarray, dict[str, int | float | bool]]:
    """ICCM rounds of one mode from the start vector ``c`` (t, d); returns the mode and its stats.

    The first round has no max-flow budget: from the smooth start vector it picks the basin
    (budgeting it too lands later modes in other local minima, about 5% more energy in total);
    with ``restricted`` it stops once the master's objective stalls (:data:`_FIRST_ROUND_STALL`
    max-flows without a decrease: only the duals were still moving). With ``restricted``,
    the rounds after it get a budget of :data:`_ROUND_FLOWS` max-flows each: a round that runs out
    returns the master's solution on the refined partition, uncertified. It is feasible and its
    energy is at most ``E(c)`` (``c`` itself, rescaled, is in the master), so the Rayleigh quotient
    ``E(u) / ||u||_M`` never increases, and the partition keeps growing where the next rounds need
    it instead of being refined to the end for vectors ``c`` that ICCM is about to leave (late
    modes took 8-10 exact rounds of ~8 max-flows each). The mode returned is always the output of
    a certified round that moved ``c`` by at most ``tol``: a fixed point of the exact ICCM map, as
    with exact rounds only. After :data:`_BUDGET_ROUNDS` budgeted rounds every round is exact;
    ``opts.max_iter`` caps the exact ones.
    """
    rounds = budgeted = inner_iterations = 0
    gaps: list[float] = []
    converged = False
    while rounds < opts.max_iter:
        budget = _ROUND_FLOWS if restricted and rounds > 0 and budgeted < _BUDGET_ROUNDS else None
        try:
            result = solve(c, found, budget, rounds + budgeted == 0)
        except (RuntimeError, ValueError) as error:
            raise StageError(f"{name}: subproblem failed in ICCM round {rounds + budgeted + 1}: {error}",
                             stage=STAGE) from error
        inner_iterations += result.iterations
        certified = result.stats.get("certified", True)
        if budget is None:
            rounds += 1
        else:
            budgeted += 1
        if certified:
            gaps.append(result.energy - result.lower_bound)
        u = result.u / math.sqrt(inner.dot(result.u, result.u))
        change = float(np.abs(u - c).max()) / max(float(np.abs(c).max()), tolerances.SMALLEST_DIVISOR)
        c = u
        if change <= opts.tol and certified:
            converged = True
            break
    if not converged:
        log.warning("%s: %s did not converge in %d ICCM rounds (last change above tol=%g)", STAGE, name,
                    opts.max_iter, opts.tol)
    return c, {"rounds": rounds + budgeted, "budgeted_rounds": budgeted, "converged": converged,
               "inner_iterations": inner_iterations, "max_gap": float(max(gaps, default=float("nan"))),
               "last_gap": float(gaps[-1]) if gaps else float("nan")}


def _modes_on_cells(cells: np.ndarray, face_tets: np.ndarray, areas: np.ndarray, eta2: np.ndarray,
                    volumes: np.ndarray, scalar_init: np.ndarray, k: int, d: int,
                    opts: ModesOptions) -> tuple[np.ndarray, dict[str, Any]]:
    """The modes with one value per pattern cell: the same solvers on the cell graph, prolongated to the tets."""
    # pattern code loads only when a recipe uses a pattern
    from fracture_cli.stages.pattern.restrict import cell_problem

    problem = cell_problem(cells, face_tets, areas, eta2, volumes, scalar_init, k, stage=STAGE)
    if problem.num_modes < k:
        log.info("%s: %d cells hold %d modes (of %d asked for)", STAGE, len(problem.volumes), problem.num_modes, k)
    solve = _modes_fast if opts.solver == "fast" else _modes_clarabel
    W, info = solve(problem.edges, problem.areas, problem.eta, problem.volumes, problem.starts, problem.num_modes,
                    d, opts)
    return problem.prolong(W), {**info, "cells": len(problem.volumes), "cell_edges": len(problem.edges)}


def _modes_fast(face_tets: np.ndarray, areas: np.ndarray, eta2: np.ndarray, volumes: np.ndarray,
                scalar_init: np.ndarray, k: int, d: int, opts: ModesOptions) -> tuple[np.ndarray, dict[str, Any]]:
    """Scalar modes per distinct axis weight (see the Notes of :func:`modes`).

    Axes with equal weights share one ICCM chain; distinct chains are independent and run in the
    worker processes of :func:`fracture_cli.system.parallel.ordered_map` (the global ``--jobs``). Each
    chain has its own random generator and BLAS runs single-threaded in every chain, so the
    result does not depend on the number of workers.
    """
    axis_count = [len(range(a, k, d)) for a in range(d)]
    chains = []  # (axis that runs the chain, axes it serves, modes to compute)
    served: set[int] = set()
    for a in range(d):
        if a not in served:
            same = [b for b in range(a, d) if np.array_equal(eta2[:, b], eta2[:, a])]
            served.update(same)
            chains.append((a, same, max(axis_count[b] for b in same)))
    scale = float(areas.mean())
    tasks = [(face_tets, areas * eta2[:, a], scale, volumes, scalar_init, count, opts, a, d) for a, _, count in chains]
    results = parallel.ordered_map(_axis_chain, tasks)
    per_axis_modes: list = [None] * d
    per_axis_stats: list = [None] * d
    backend = results[0][2]
    for (a, same, _), (found, stats, _backend) in zip(chains, results):
        for b in same:
            per_axis_modes[b] = found
            per_axis_stats[b] = stats if b == a else [dict(m, seconds=0.0, replicated=True) for m in stats]
    t = len(volumes)
    U = np.zeros((k, t, d))
    per_mode = []
    for i in range(k):
        a, j = i % d, i // d
        U[i, :, a] = per_axis_modes[a][j][:, 0]
        per_mode.append(dict(per_axis_stats[a][j]))
    return U, {**_summary(per_mode), "max_flow_backend": backend, "lp_backend": lp_backend(),
               # an upper bound: a bake's map forks only where the work left pays for a pool (system.parallel)
               "chains": len(chains), "max_workers": min(len(chains), parallel.current_jobs())}


def _axis_chain(_shared: None, task: _ChainTask) -> tuple[list[np.ndarray], list[dict], str]:
    """One ICCM chain of scalar modes with face weights ``weights`` (in units of ``weight_scale``).

    Returns the modes, their stats and the max-flow backend. Runs in the caller or in a worker
    process (BLAS single-threaded either way). ``task`` is ``(face_tets, weights, weight_scale,
    volumes, scalar_init, count, opts, axis, d)``; :func:`parallel.ordered_map` passes no shared data.
    """
    from threadpoolctl import threadpool_limits

    face_tets, weights, weight_scale, volumes, scalar_init, count, opts, axis, d = task
    t = len(volumes)
    inner = _MInner(volumes, 1)
    # Axis 0 keeps the generator of the scalar case; other axes get their own stream.
    rng = np.random.default_rng(opts.seed + 1 if axis == 0 else (opts.seed + 1, axis))
    solver = CutSubproblemSolver(face_tets, weights, volumes, tol=opts.inner_tol, max_iter=opts.inner_max_iter,
                                 weight_scale=weight_scale)
    label = "" if d == 1 else f" (axis {'xyz'[axis]})"
    with threadpool_limits(limits=1, user_api="blas"):
        found, stats = _iccm(lambda c, fixed, budget, first: solver.solve(
            c, fixed, max_flows=budget, stall_flows=_FIRST_ROUND_STALL if first else None), scalar_init[:, :, None],
                             count, inner, opts, label, lambda n: rng.uniform(-1.0, 1.0, (t, 1)), restricted=True)
    return found, stats, solver.max_flow_backend


def _modes_clarabel(face_tets: np.ndarray, areas: np.ndarray, eta2: np.ndarray, volumes: np.ndarray,
                    scalar_init: np.ndarray, k: int, d: int, opts: ModesOptions) -> tuple[np.ndarray, dict[str, Any]]:
    t = len(volumes)
    inner = _MInner(volumes, d)
    solver = ConicSubproblemSolver(face_tets, areas, eta2, volumes, tol=opts.inner_tol, max_iter=opts.inner_max_iter,
                                   weight_scale=float(areas.mean()))
    starts = []
    for i in range(k):
        s = np.zeros((t, d))
        s[:, i % d] = scalar_init[i // d]
        starts.append(s)
    rng = np.random.default_rng(opts.seed + 1)
    found, per_mode = _iccm(lambda c, fixed, budget, first: solver.solve(c, fixed), starts, k, inner, opts, "",
                            lambda n: rng.uniform(-1.0, 1.0, (t, d)))
    return np.stack(found), _summary(per_mode)


def _summary(per_mode: list[dict]) -> dict[str, Any]:
    return {
        "iterations": [m["rounds"] for m in per_mode],
        "converged": [m["converged"] for m in per_mode],
        "inner_iterations": [m["inner_iterations"] for m in per_mode],
        "mode_seconds": [m["seconds"] for m in per_mode],
        "max_gap": max(m["max_gap"] for m in per_mode),
        "per_mode": per_mode,
    }
