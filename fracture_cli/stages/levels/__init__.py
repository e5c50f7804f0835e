"""Levels of fracture: fragments that break again, each by its own impact data (issue 34; ALGORITHM.md section 13).

With ``count = 2`` the stage picks level-1 fragments by a rule (the largest first, at most
``ratio`` of them, none below ``min_volume``, none anchored) and breaks each into children
computed on the bake's own tet mesh: the modes of its piece's tets, their pieces, regions
grown over the tets around it and smoothed, cut from the fragment's mesh
(:mod:`.refine`). The total number of leaves stays within ``max_leaves``: fragments are
accepted in the rule's order while their children fit. Every refined fragment becomes a
*body* of the runtime file (docs/FORMAT.md section 14, :mod:`.bodies`). ``count = 1`` does
nothing: the bake writes the same bytes as without the stage.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.stages.levels.options import STAGE, LevelsOptions

if TYPE_CHECKING:  # resolving a recipe imports this package for its options: refine (numba) loads only in a bake
    from fracture_cli.stages.levels.refine import Context, Refinement

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Levels:
    """What the stage made.

    Attributes
    ----------
    refinements : tuple of Refinement
        The fragments broken again, by increasing fragment index (body ``b`` is ``refinements[b - 1]``).
    candidates : tuple of int
        The fragments the rule chose, in its order (largest first).
    skipped : dict of int -> str
        Candidates that stay whole, and why (the leaf cap, too few tets, one child, ...).
    leaves : int
        Fragments without children, over both levels.
    options : LevelsOptions
    """

    refinements: tuple[Refinement, ...] = ()
    candidates: tuple[int, ...] = ()
    skipped: dict[int, str] = field(default_factory=dict)
    leaves: int = 0
    options: LevelsOptions = LevelsOptions()


def candidates(volumes: np.ndarray, anchored: np.ndarray | None, options: LevelsOptions) -> list[int]:
    """The fragments the rule may refine, in its order: the ``ceil(ratio * p)`` largest, of them those above
    ``min_volume`` (fraction of the total) and not anchored; largest first, ties by index.

    Parameters
    ----------
    volumes : (p,) float
        The level-1 fragments' volumes.
    anchored : (p,) int or None
        1 where a fragment is bonded to the world (never refined).
    options : LevelsOptions
    """
    volumes = np.asarray(volumes, dtype=np.float64)
    p = len(volumes)
    order = np.lexsort((np.arange(p), -volumes))[: math.ceil(options.ratio * p - 1e-9)]
    total = float(volumes.sum())
    keep = volumes[order] >= options.min_volume * total
    if anchored is not None:
        keep &= np.asarray(anchored)[order] != 1
    return [int(j) for j in order[keep]]


def levels(ctx: Context, anchored: np.ndarray | None = None) -> Levels:
    """Break the rule's fragments again, within the leaf cap (see the module notes).

    Parameters
    ----------
    ctx : Context
        The bake's tet mesh, pieces, material weights, level-1 fragments, options and level-1 stage options.
    anchored : (p,) int, optional
        Anchored fragments (never refined).

    Returns
    -------
    Levels
    """
    options, frags = ctx.options, ctx.fragments
    p = len(frags.fragments)
    if options.count < 2:
        return Levels(leaves=p, options=options)
    # only a bake with levels loads the geometry, the worker pool, the refinement and its compiled kernels (start-up,
    # issue 33: a recipe reads LevelsOptions from this package)
    from fracture_cli.geometry import trigeom
    from fracture_cli.stages.levels.refine import plan_refinement, refine_fragment
    from fracture_cli.system import parallel

    volumes = np.array([trigeom.signed_volume(f.vertices, f.faces) for f in frags.fragments])
    chosen = candidates(volumes, anchored, options)
    skipped: dict[int, str] = {}
    # Step 1 (cheap): how many children each would get; the cap is applied to those counts first.
    plans = parallel.ordered_map(plan_refinement, chosen, ctx)
    accepted, leaves = [], p
    for index, plan in zip(chosen, plans):
        if isinstance(plan, str):
            skipped[index] = plan
        elif leaves + plan.children - 1 > options.max_leaves:
            skipped[index] = f"its {plan.children} children would exceed max_leaves = {options.max_leaves}"
        else:
            accepted.append(plan)
            leaves += plan.children - 1
    # Step 2: the children; a cut may give more bodies than pieces, so the cap is applied again, in the same order.
    done = parallel.ordered_map(refine_fragment, accepted, ctx)
    kept, leaves = [], p
    for plan, result in zip(accepted, done):
        if isinstance(result, str):
            skipped[plan.fragment] = result
        elif leaves + len(result.children.fragments) - 1 > options.max_leaves:
            skipped[plan.fragment] = (f"its {len(result.children.fragments)} children would exceed max_leaves = "
                                      f"{options.max_leaves}")
        else:
            kept.append(result)
            leaves += len(result.children.fragments) - 1
    kept.sort(key=lambda r: r.fragment)
    log.info("%s: %d of %d fragments broken again (%d candidates), %d leaves (cap %d)", STAGE, len(kept), p,
             len(chosen), leaves, options.max_leaves)
    for index in sorted(skipped):
        log.debug("%s: fragment %d stays whole: %s", STAGE, index, skipped[index])
    return Levels(refinements=tuple(kept), candidates=tuple(chosen), skipped=skipped, leaves=leaves,
                  options=options)


__all__ = ["STAGE", "Levels", "LevelsOptions", "candidates", "levels"]
