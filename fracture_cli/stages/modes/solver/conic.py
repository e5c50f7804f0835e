"""Interior-point baseline for the fracture-modes subproblem (any ``d``): the whole SOCP in Clarabel.

The slow reference that the exact cut solver (:mod:`.cut`) is checked against
(tests/test_modes*.py): energies within 1e-4, the same pieces up to ties.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from fracture_cli.stages.modes.solver.energy import (
    Constraints,
    SubproblemResult,
    discontinuity_energy,
    scaled_problem,
)


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

    def __init__(self, face_tets: np.ndarray, weights: np.ndarray, eta: np.ndarray, volumes: np.ndarray, *,
                 tol: float = 1e-9, max_iter: int = 200,
                 weight_scale: float | None = None):
        import clarabel  # the baseline only; the default solver does not need it

        self._clarabel = clarabel
        self.face_tets, self.scale, self.omega, self.vol = scaled_problem(face_tets, weights, volumes, weight_scale)
        self.t = len(self.vol)
        self.eta = np.asarray(eta, dtype=np.float64)
        self.d = self.eta.shape[1]
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self._constraints = Constraints(self.vol)
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
        row_parts = [block * fid]
        col_parts = [nu + fid]
        val_parts = [-np.ones(f)]
        for a in range(d):
            r = block * fid + 1 + a
            row_parts += [r, r]
            col_parts += [fa * d + a, fb * d + a]
            val_parts += [-self.eta[:, a], self.eta[:, a]]
        return sp.csc_matrix((np.concatenate(val_parts), (np.concatenate(row_parts), np.concatenate(col_parts))),
                             shape=(block * f, nu + f))

    def solve(self, c: np.ndarray, fixed: Sequence[np.ndarray] = ()) -> SubproblemResult:
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
