"""The discontinuity energy of per-tet displacements and its constrained minimisation.

ALGORITHM.md section 2. A displacement field gives one vector ``u_t`` in R^d per
tet; its discontinuity energy is a weighted group lasso over the interior faces,

    E_D(u) = sum_f w_f * || eta_f o (u_a - u_b) ||_2 ,

and one ICCM round of the fracture-modes solver minimises it subject to a few
dense linear constraints (M_T-orthogonality to the rigid translations and to the
modes found so far, and ``c^T M_T u = 1``). The package holds that convex
subproblem and two solvers for it:

* :mod:`.energy`: the energy, the face weights ``w_f = A_f`` (:func:`face_weights`:
  the one place where this choice is made) and what the solvers share;
* :mod:`.cut`: :class:`CutSubproblemSolver` (``d = 1``, the default, exact): a
  master LP over a partition of the tets into cells (:mod:`.master`, HiGHS),
  priced by minimum s-t cuts (:mod:`.mincut`: :mod:`.maxflow_kernel`, OR-Tools or scipy);
* :mod:`.conic`: :class:`ConicSubproblemSolver` (any ``d``, baseline): the whole
  problem handed to the interior-point solver Clarabel.

Both solvers divide the weights by their mean internally: with raw areas (~1e-5
in normalized units) interior-point solvers stop well above the optimum.
"""

from fracture_cli.stages.modes.solver.conic import ConicSubproblemSolver
from fracture_cli.stages.modes.solver.cut import CutSubproblemSolver
from fracture_cli.stages.modes.solver.energy import SubproblemResult, discontinuity_energy, face_weights, jump_norms
from fracture_cli.stages.modes.solver.master import lp_backend

__all__ = ["ConicSubproblemSolver", "CutSubproblemSolver", "SubproblemResult", "discontinuity_energy",
           "face_weights", "jump_norms", "lp_backend"]
