"""The discontinuity energy of per-tet displacements, and what its subproblem solvers share.

ALGORITHM.md section 2: a displacement field gives one vector ``u_t`` in R^d per
tet; its discontinuity energy is a weighted group lasso over the interior faces,

    E_D(u) = sum_f w_f * || eta_f o (u_a - u_b) ||_2 .
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from fracture_cli.types import TetMesh


def face_weights(tet_mesh: TetMesh) -> np.ndarray:
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
        jump = jump * as_2d(eta, u.shape[1])
    return np.sqrt(np.einsum("fd,fd->f", jump, jump))


def discontinuity_energy(u: np.ndarray, face_tets: np.ndarray, weights: np.ndarray,
                         eta: np.ndarray | None = None) -> float:
    """``E_D(u) = sum_f weights_f || eta_f o (u_a - u_b) ||`` for ``u`` (t,) or (t, d)."""
    return float(np.dot(weights, jump_norms(u, face_tets, eta)))


def as_2d(eta: np.ndarray, d: int) -> np.ndarray:
    """``eta`` (f,) or (f, d) as (f, d)."""
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


class Constraints:
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


def scaled_problem(face_tets: np.ndarray, weights: np.ndarray, volumes: np.ndarray,
                   weight_scale: float | None) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Arrays of a subproblem with the face weights divided by their mean (or ``weight_scale``).

    Raw weights (face areas, ~1e-5 on a unit-diagonal asset) leave solvers far
    from the optimum; scaled to mean 1 they do not (the energy just scales).
    Returns ``face_tets`` (f, 2) int64, the scale, the scaled weights (f,) and the volumes (t,).
    """
    weights = np.asarray(weights, dtype=np.float64)
    scale = float(weight_scale) if weight_scale else float(weights.mean()) if len(weights) else 1.0
    return np.asarray(face_tets, dtype=np.int64), scale, weights / scale, np.asarray(volumes, dtype=np.float64)
