"""Options of the ``modes`` stage (what a recipe's ``[modes]`` section may say).

Apart from the solver so that resolving a recipe loads neither scipy nor the compiled kernels.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.options import option

STAGE = "modes"


@dataclass(frozen=True)
class ModesOptions:
    """Options of :func:`modes`."""

    num_modes: int = option(12, "number of non-trivial fracture modes k (translations are not counted)", min=1,
                            max=200)
    dim: int = option(1, "displacement dimension: 1 = scalar modes (fast default), 3 = vector modes", choices=(1, 3))
    solver: str = option("fast", "subproblem solver: 'fast' (exact: partition LP + min-cut pricing, scalar per "
                         "axis) or 'clarabel' (interior-point baseline, slow)", choices=("fast", "clarabel"))
    sigma: float = option(1e-3, "a face is cut when its jump exceeds sigma times the mode's largest jump", min=0.0,
                          max=1.0, min_exclusive=True)
    tol: float = option(1e-6, "ICCM stops when max|U_i - c| <= tol * max|c|", min=0.0, max=1.0, min_exclusive=True)
    max_iter: int = option(30, "ICCM rounds per mode at most", min=1, max=10000)
    inner_tol: float = option(1e-9, "subproblem tolerance (relative dual violation / interior-point gap)", min=0.0,
                              max=1e-2, min_exclusive=True)
    inner_max_iter: int = option(1000, "subproblem iterations at most (max-flows or interior-point steps)", min=1,
                                 max=1000000)
    seed: int = option(0, "seed of the eigensolver's start vector (fixed: results are reproducible)", min=0)
