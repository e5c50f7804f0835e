"""Fracture modes of a tet mesh: the stage ``modes`` (ALGORITHM.md section 2).

Per-tet displacements, an interior-face discontinuity energy, and the adapted
ICCM loop (paper Algorithm 1) started from the tet mesh's generalized Laplacian
eigenvectors. The convex subproblem of each ICCM round is solved exactly by
:class:`fracture_cli.stages.modes.solver.CutSubproblemSolver` (default, ``solver =
"fast"``) or by the interior-point baseline
:class:`fracture_cli.stages.modes.solver.ConicSubproblemSolver` (``solver = "clarabel"``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fracture_cli.stages.modes.options import STAGE, ModesOptions

if TYPE_CHECKING:
    import numpy as np

    from fracture_cli.types import Modes, TetMesh


def modes(tet_mesh: TetMesh, options: ModesOptions = ModesOptions(), eta: np.ndarray | None = None,
          cells: np.ndarray | None = None) -> Modes:
    """Compute the ``k`` lowest fracture modes of a tet mesh.

    Parameters
    ----------
    tet_mesh : TetMesh
        The (cage) tet mesh; ``t`` tets, ``f`` interior faces.
    options : ModesOptions, optional
        See :class:`ModesOptions` (default: 12 scalar modes, fast solver).
    eta : (f,) or (f, d) float, optional (default all ones)
        Material weight of every interior face (and axis, for ``d = 3``):
        anisotropy and strength maps. A large value makes a face effectively
        unbreakable. Must be positive and finite.
    cells : (t,) int, optional
        An authored pattern's cell of every tet (the ``pattern`` stage): the
        modes are then solved with one value per cell, on the cells' adjacency
        graph (:mod:`fracture_cli.stages.pattern.restrict`), and are piecewise
        constant on the cells; ``k`` is at most ``d (cells - 1)``.

    Returns
    -------
    Modes
        ``U (k, t, d)`` M_T-orthonormal and M_T-orthogonal to translations,
        ``labels (k, t)``, ``cut (k, f)``, ``piece_counts``, ``energies``
        (``sum_f A_f ||eta_f o jump_f||``), ICCM ``iterations`` and ``stats``
        (solver name, seconds and subproblem counters per mode, duality gaps).

    Raises
    ------
    StageError
        If the mesh is too small for ``k`` modes, ``eta`` has the wrong shape or
        values, or a subproblem solver fails.

    Notes
    -----
    ALGORITHM.md section 2 and the paper's Algorithm 1 (adapted ICCM). Each ICCM
    round solves ``min E_D(u)`` subject to ``U_j^T M_T u = 0`` (earlier modes and
    translations) and ``c^T M_T u = 1``, then sets ``c = u / ||u||_M``.

    For ``d = 3`` the start vectors are the scalar eigenvectors times the axes,
    ``s_j (x) e_a`` (mode ``i`` uses ``s_{i // 3} (x) e_{i % 3}``). With such a
    ``c`` and axis-aligned earlier modes, the vector subproblem has an
    axis-aligned minimiser: ``sum_f w_f ||eta_f o jump_f|| >= sum_f w_f eta_fa
    |jump_fa|``, the right side is the scalar problem on axis ``a`` with weights
    ``w_f eta_fa``, and that scalar minimiser times ``e_a`` attains it. So the
    fast solver computes ``d = 3`` modes exactly as scalar modes per axis (once
    per distinct column of ``eta``); the Clarabel baseline solves the vector
    problem itself and reaches the same energies.

    The fast solver (:class:`fracture_cli.stages.modes.solver.CutSubproblemSolver`)
    is exact: a mode is the output of a subproblem that ends with a dual
    certificate (no tet set violates its max-flow/min-cut condition), its
    solution is piecewise constant, so the pieces do not depend on ``sigma``.
    The ICCM rounds between a mode's first and last may stop early, on a
    max-flow budget (:func:`_iccm_mode`: descent is kept, the fixed point is
    certified). ``stats["max_gap"]`` is the largest
    primal-dual gap over all subproblems.

    Parallelism (the global ``--jobs``, :func:`fracture_cli.system.parallel.current_jobs`):
    mode ``i`` is constrained by modes ``< i``, so one ICCM chain is sequential;
    only chains that share nothing (``d = 3`` with per-axis weights) run in worker
    processes. BLAS is single-threaded in every chain (threadpoolctl), so results
    are the same bytes for any job count and a pool of bakes does not
    oversubscribe the cores.
    """
    # on first use: a recipe reads ModesOptions from this package without loading scipy and the kernels
    from fracture_cli.stages.modes.iccm import compute_modes

    return compute_modes(tet_mesh, options, eta, cells)


__all__ = ["STAGE", "ModesOptions", "modes"]
