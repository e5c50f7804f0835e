"""Options of the ``levels`` stage (what a recipe's ``[levels]`` section may say).

Apart from the stage's work so that resolving a recipe loads none of its libraries.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.options import option

STAGE = "levels"


@dataclass(frozen=True)
class LevelsOptions:
    """Options of :func:`fracture_cli.stages.levels.levels` (fragments that break again)."""

    count: int = option(1, "levels of fracture: 1 = the fragments only (as before, the same bytes); 2 = fragments "
                           "that break again into their own children, each by its own impact data", min=1, max=2)
    max_leaves: int = option(256, "at most this many leaves (fragments without children, over every level): "
                                  "fragments are refined in the rule's order while the total stays within it",
                             min=1, max=100000)
    ratio: float = option(1.0, "share of the level-1 fragments that may break again, the largest first (Houdini's "
                               "ratio): the ceil(ratio * fragments) largest", min=0.0, max=1.0)
    min_volume: float = option(0.02, "fragments holding less than this fraction of the asset's volume do not break "
                                     "again", min=0.0, max=1.0)
    num_modes: int = option(6, "fracture modes of each refined fragment (its own solve on its tets)", min=1, max=64)
    min_fragment_fraction: float = option(0.1, "children holding less than this fraction of their parent's volume "
                                               "are merged into a neighbour (the children's size)", min=0.0, max=0.5)
    threshold_factor: float = option(1.0, "default toughness of the children's bonds: the runtime threshold times "
                                          "this (bigger = the children hold on harder)", min=0.0,
                                     min_exclusive=True)
    radius_factor: float = option(1.0, "impact radius of a refined fragment's data: the runtime radius times this",
                                  min=0.0, max=1.0, min_exclusive=True)
    max_parts: int = option(4, "convex collision parts per child at most (the collision stage's max_parts caps it)",
                            min=1, max=64)
    smoothing_factor: float = option(0.25, "fault smoothing of the children's faults: smooth.smoothing times this "
                                           "(smaller pieces, rounder over a smaller radius)", min=0.0, max=1.0)
