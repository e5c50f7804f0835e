"""The ``levels`` row of the pipeline: fragments broken again, checked as level 1 is, and the report's block.

The stage (:mod:`fracture_cli.stages.levels`) makes the children of the chosen fragments the way
the level-1 stages made the fragments (their options, from the state's ``stage_options``), and
checks them with :func:`fracture_cli.checks.checked_fragments` against their parent; here that
function is handed to it (a stage does not import the checks) and the runtime file gets the bodies.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from fracture_cli.checks import checked_fragments
from fracture_cli.stages.levels import levels
from fracture_cli.stages.levels.bodies import with_levels
from fracture_cli.stages.levels.refine import Context

if TYPE_CHECKING:  # pipeline/__init__.py imports this module on first use
    from fracture_cli.pipeline import PipelineState
    from fracture_cli.stages.levels import Levels
    from fracture_cli.stages.levels.options import LevelsOptions

# The level-1 stages whose options the children are made with (their defaults when a chain skipped one).
LEVEL_ONE = ("modes", "pieces", "smooth", "fragments", "simplify", "collision", "runtime")


def run_levels(state: PipelineState, options: LevelsOptions, stages: dict[str, Any]) -> PipelineState:
    """The state with ``levels`` (the refinements) and the runtime data with their bodies (docs/FORMAT.md 14).

    ``stages``: the options of the level-1 stages :data:`LEVEL_ONE` (the children are made as the fragments were).
    """
    data = state.need("runtime", "levels")
    ctx = Context(tet_mesh=state.need("tet_mesh", "levels"), tet_piece=state.need("pieces", "levels").tet_piece,
                  eta=state.eta, fragments=state.need("fragments", "levels"), options=options, stages=stages,
                  radius=float(data.radius), threshold=float(data.default_threshold), check=checked_fragments)
    anchored = None if state.anchors is None else state.anchors.anchored
    result = levels(ctx, anchored=anchored)
    return dataclasses.replace(state, levels=result, runtime=with_levels(data, result))


# The written-mesh checks counted over every child (each 0 when the children pass, as level 1's).
BROKEN_FACES = ("open_edges", "pinched_edges", "misoriented_edges", "degenerate_faces", "separated_vertices")


def levels_summary(result: Levels | None, names: list[str]) -> dict[str, Any] | None:
    """The report's ``levels`` block: what was broken again, the leaves, and the children's checks (worst over all).

    Parameters
    ----------
    result : Levels or None
        The stage's result (None or no refinement with ``count = 1``: no block).
    names : list of str
        The level-1 fragments' names (as the GLB's nodes).
    """
    if result is None or result.options.count < 2:
        return None
    checks = [r.checks for r in result.refinements]

    def worst(key: str, pick: Callable[[list], Any] = max) -> Any:
        values = [c[key] for c in checks if key in c]
        return pick(values) if values else None

    return {
        "count": result.options.count,
        "refined": [names[r.fragment] for r in result.refinements],
        "children": [len(r.children.fragments) for r in result.refinements],
        "leaves": int(result.leaves),
        "max_leaves": int(result.options.max_leaves),
        "candidates": len(result.candidates),
        "stay_whole": {names[j]: why for j, why in sorted(result.skipped.items())},
        "checks": {
            "watertight": all(c.get("watertight", True) for c in checks),
            "connected": all(c.get("connected", True) for c in checks),
            **{key: int(sum(c.get(key, 0) for c in checks)) for key in BROKEN_FACES},
            "fragment_bodies_max": worst("fragment_bodies_max"),
            "max_outer_distance": worst("max_outer_distance"),
            "volume_error_max": worst("volume_error"),
            "parent_area_error_max": worst("parent_area_error"),
            "parent_distance_max": worst("parent_distance"),
            "max_overlap": worst("max_overlap"),
            "collision_max_overlap": worst("collision_max_overlap"),
            "collision_min_coverage": worst("collision_min_coverage", min),
            "fragment_volume_min": worst("fragment_volume_min", min),
            "triangles": int(sum(c.get("triangles", 0) for c in checks)),
        },
    }
