"""Options of the ``tetra`` stage (what a recipe's ``[tetra]`` section may say).

Apart from the stage's work so that resolving a recipe loads none of its libraries.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.options import option

STAGE = "tetra"


@dataclass(frozen=True)
class TetraOptions:
    """Options of the ``tetra`` stage."""

    radius_edge_ratio: float = option(1.5, "quality bound: largest tet circumradius / shortest edge (TetGen -q)",
                                      min=1.0, max=10.0, min_exclusive=True)
    min_dihedral: float = option(10.0, "quality bound: smallest dihedral angle in degrees (TetGen -q/)",
                                 min=0.0, max=30.0)
    max_volume: float = option(0.0, "target largest tet volume as a fraction of the cage volume; 0 = no limit "
                               "(tets at the kept boundary may exceed it)", min=0.0, max=1.0)
    optimization: int = option(1, "TetGen mesh optimization level (-O): 0 = off; higher is slower "
                               "(level 2 took minutes on some 5,000-face cages)", min=0, max=10)
    timeout: float = option(300.0, "seconds before TetGen is abandoned", min=1.0, max=36000.0)
