"""Fracture modes restricted to a pattern's cells (ALGORITHM.md section 9).

With one value per cell, ``u = P w`` where ``P`` (t, c) is the aggregation
matrix (``P[t, C] = 1`` when tet ``t`` is in cell ``C``). Then

* the mass is ``P^T M_T P = diag(vol_C)``, the cells' volumes;
* the discontinuity energy ``sum_f A_f ||eta_f o (u_a - u_b)||`` is zero on
  faces inside a cell, and on the faces between cells ``C < D`` it is
  ``||(sum_f A_f eta_f) o (w_C - w_D)||`` per axis, so it is the same energy on
  the cell adjacency graph with edge weights ``A_CD eta_CD = sum_f A_f eta_f``
  (the fault areas, times the material);
* the constraints (orthogonality to translations and earlier modes,
  ``c^T M u = 1``) keep their form with ``M = diag(vol_C)``.

So the restricted problem is the tet problem on a smaller graph, and the
modes stage's own ICCM and subproblem solvers solve it unchanged
(:func:`fracture_cli.stages.modes.modes`); its start vectors are the tets'
Laplacian eigenvectors averaged over the cells, ``(P^T M_T P)^{-1} P^T M_T s``.
The modes found are prolongated back, ``U = P W``: piecewise constant on the
cells, so the cells are exactly the atomic pieces and the runtime file's
per-bond jumps are the jumps between the pattern's cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry.rows import unique_rows


@dataclass(frozen=True)
class CellProblem:
    """The fracture-mode problem on a pattern's cells.

    Attributes
    ----------
    cells : (t,) int64
        Cell of every tet.
    edges : (e, 2) int64
        Adjacent cells ``C < D``, sorted.
    areas : (e,) float
        Shared face area of every edge.
    eta : (e, d) float
        Area-weighted mean material weight of the shared faces (``areas * eta`` is ``sum_f A_f eta_f``).
    volumes : (c,) float
        Cell volumes (the restricted mass).
    starts : (s, c) float
        Start vectors averaged onto the cells.
    num_modes : int
        Modes the cells can hold: at most ``d (c - 1)`` (the constants are not modes).
    """

    cells: np.ndarray
    edges: np.ndarray
    areas: np.ndarray
    eta: np.ndarray
    volumes: np.ndarray
    starts: np.ndarray
    num_modes: int

    def prolong(self, W: np.ndarray) -> np.ndarray:
        """Per-tet modes ``U = P W`` (k, t, d) from per-cell modes ``W`` (k, c, d)."""
        return np.ascontiguousarray(np.asarray(W)[:, self.cells, :])


def cell_problem(cells: np.ndarray, face_tets: np.ndarray, areas: np.ndarray, eta: np.ndarray,
                 volumes: np.ndarray, starts: np.ndarray, num_modes: int, stage: str = "modes") -> CellProblem:
    """Aggregate the tet problem onto ``cells`` (t,): ``P^T M_T P``, the cell graph and its weights.

    Parameters
    ----------
    cells : (t,) int
        Cell ids 0..c-1 of every tet (each cell one connected set of tets).
    face_tets : (f, 2) int
        Interior faces' tets.
    areas : (f,) float
        Face weights ``A_f``.
    eta : (f, d) float
        Material weights.
    volumes : (t,) float
        Tet volumes.
    starts : (s, t) float
        Start vectors on the tets.
    num_modes : int
        Modes asked for; fewer when the cells cannot hold them.

    Raises
    ------
    StageError
        If ``cells`` does not match the tet mesh or no two cells touch.
    """
    cells = np.asarray(cells, dtype=np.int64).reshape(-1)
    if len(cells) != len(volumes) or (len(cells) and cells.min() < 0):
        raise StageError(f"the pattern has {len(cells)} cell ids for {len(volumes)} tets", stage=stage)
    c = int(cells.max()) + 1
    d = eta.shape[1]
    a, b = cells[face_tets[:, 0]], cells[face_tets[:, 1]]
    between = np.flatnonzero(a != b)
    if len(between) == 0:
        raise StageError("the pattern's cells share no face: nothing to break", stage=stage)
    pairs = np.stack([np.minimum(a[between], b[between]), np.maximum(a[between], b[between])], axis=1)
    edges, inverse = unique_rows(pairs, return_inverse=True)
    inverse = inverse.reshape(-1)
    e = len(edges)
    # bincount sums in face order: the same bits for any BLAS.
    edge_areas = np.bincount(inverse, weights=areas[between], minlength=e)
    weighted = np.stack([np.bincount(inverse, weights=areas[between] * eta[between, j], minlength=e)
                         for j in range(d)], axis=1)
    cell_volumes = np.bincount(cells, weights=volumes, minlength=c)
    averaged = np.stack([np.bincount(cells, weights=volumes * s, minlength=c) for s in starts]) / cell_volumes
    return CellProblem(cells=cells, edges=np.asarray(edges, dtype=np.int64), areas=edge_areas,
                       eta=weighted / edge_areas[:, None], volumes=cell_volumes,
                       starts=averaged, num_modes=min(int(num_modes), d * (c - 1)))
