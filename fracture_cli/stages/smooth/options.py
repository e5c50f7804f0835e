"""Options of the ``smooth`` stage (what a recipe's ``[smooth]`` section may say).

Apart from the stage's work so that resolving a recipe loads none of its libraries.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.options import option

STAGE = "smooth"


@dataclass(frozen=True)
class SmoothOptions:
    """Options of :func:`smooth`."""

    smoothing: float = option(
        1e-3,
        "fault smoothing lambda in units of (bbox diagonal)^2, about the square of the radius over which faults "
        "are rounded; 0 = faults follow tet faces",
        min=0.0,
    )
    method: str = option(
        "geometric",
        "geometric: move the tet vertices so the tet-aligned faults become smooth surfaces (pieces keep their "
        "tets); field: smooth the piece membership field and cut tets along its level sets",
        choices=("geometric", "field"),
    )
    refine: int = option(
        2,
        "field method: levels of regular 1:8 tet refinement before smoothing, so faults are cut along a finer "
        "mesh than the cage tets (fewer levels when the refined mesh would exceed max_refined_tets); it pays off "
        "when sqrt(smoothing) is at least about the refined tet edge, else the faults zigzag at the fine scale",
        min=0,
        max=3,
    )
    max_refined_tets: int = option(
        400_000,
        "field method: the most tets refinement may create (memory and time grow with it)",
        min=1,
    )
    vanish_fraction: float = option(
        0.01,
        "field method: a piece whose smoothed region is below this fraction of its own volume gets its field "
        "raised to keep about its volume, and if that fails keeps its own tets",
        min=0.0,
        max=1.0,
    )
