"""Simplify: lean fragment meshes, the faults simplified to a tolerance (issue 20, "lean meshes").

Runs on the fragments stage's output; the algorithm is
:func:`fracture_cli.stages.simplify.faults.simplify_faults`. The outer surface
stays the input's (its vertices, UVs and normals); the faults and the curves
where they cut the outer surface lose the triangles they do not need, both
sides of every fault alike, so every fragment stays closed and the volumes
still sum to the input's. The pipeline checks the result again, as it will
be written (:mod:`fracture_cli.checks`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

from fracture_cli.options import option
from fracture_cli.stages.simplify.budget import BUDGET_PER_FRAGMENT, triangle_budget

if TYPE_CHECKING:
    from fracture_cli.stages.simplify.faults import FaultReport
    from fracture_cli.types import Fragments, SurfaceMesh

log = logging.getLogger(__name__)

STAGE = "simplify"

__all__ = ["BUDGET_PER_FRAGMENT", "SimplifyOptions", "simplify", "skipped", "triangle_budget"]


@dataclass(frozen=True)
class SimplifyOptions:
    """Options of the ``simplify`` stage (a recipe's ``[simplify]`` section)."""

    tolerance: float = option(
        0.002,
        "largest distance of a simplified fault from the cut one, as a fraction of the asset's bounding-box "
        "diagonal; 0 keeps the faults as cut",
        min=0.0,
        max=0.1,
    )
    max_triangles: int = option(
        0,
        "triangles per fragment to aim for: fragments above it are simplified further, up to 64 times the "
        "tolerance; 0 = no budget",
        min=0,
    )
    fit_budget: bool = option(
        True,
        "keep the asset within twice the input's triangles plus 64 per fragment (the report's triangle_budget): "
        "fragments above their share of it are simplified further, up to 64 times the tolerance",
    )
    max_input_triangles: int = option(
        200_000,
        "inputs with more triangles keep their faults as cut (a safety net: on a 1M-triangle input the "
        "collapses take about 20 s, but checking the rebuilt fragments for self-intersections does not scale "
        "yet); 0 = no limit",
        min=0,
    )


def simplify(fragments: Fragments, surface: SurfaceMesh,
             options: SimplifyOptions = SimplifyOptions()) -> tuple[Fragments, FaultReport]:
    """Simplify the fragments' faults (callers check :func:`skipped` first).

    Parameters
    ----------
    fragments : Fragments
        The fragments stage's output.
    surface : SurfaceMesh
        The (repaired) input they were cut from.
    options : SimplifyOptions, optional

    Returns
    -------
    fragments : Fragments
        Same fragments, order, pieces and materials, fewer triangles.
    report : FaultReport
    """
    # on first use: a recipe reads SimplifyOptions from here without loading the collapse kernels
    from fracture_cli.stages.simplify.faults import simplify_faults

    result, report = simplify_faults(fragments, surface, options.tolerance, options.max_triangles, options.fit_budget)
    if report.over_budget:
        log.warning("%s: %d fragment(s) stay above max_triangles = %d (their faults cannot go further within "
                    "64 times the tolerance)", STAGE, report.over_budget, options.max_triangles)
    budget = triangle_budget(len(surface.faces), len(result.fragments))
    if options.fit_budget and report.triangles_after > budget:
        log.warning("%s: %d triangles, above the budget of %d (twice the input's plus %d per fragment): some "
                    "faults cannot go further within 64 times the tolerance", STAGE, report.triangles_after, budget,
                    BUDGET_PER_FRAGMENT)
    return result, report


def skipped(surface: SurfaceMesh, options: SimplifyOptions) -> bool:
    """Whether the stage leaves the faults as cut: tolerance 0, or an input above ``max_input_triangles`` (warned)."""
    if options.tolerance <= 0:
        return True
    if options.max_input_triangles and len(surface.faces) > options.max_input_triangles:
        log.warning("%s: the faults are kept as cut: the input has %d triangles, above simplify.max_input_triangles "
                    "= %d (set it to 0 to simplify anyway, slowly)", STAGE, len(surface.faces),
                    options.max_input_triangles)
        return True
    return False
