"""Fitting the fault simplification to the asset's triangle budget (step 3 of :mod:`.faults`).

:func:`within_budget` goes on from a valid simplification at the recipe's tolerance: the fragments above
their share of the budget (:mod:`.budget`) get their tolerance doubled and are simplified further
(:func:`rounds`), and the rebuilt fragments are checked again. Where a fragment comes out invalid (a face
turned over or through another, mostly where a thin wall's two sides come close), the vertices whose budget
collapses made its bad faces are pinned where the valid simplification had them and the rest is fitted again;
only a fragment that stays invalid is held whole as it was. Holding a whole fragment also holds every fault
it shares, so pinning the few vertices at fault first keeps most of the budget's collapses.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.stages.simplify.budget import Limits
from fracture_cli.stages.simplify.decimate import SurfaceComplex
from fracture_cli.stages.simplify.rebuild import Classified

if TYPE_CHECKING:
    from fracture_cli.stages.simplify.faults import _Checker, _Tried
    from fracture_cli.types import Fragment

__all__ = ["BUDGET_ROUNDS", "rounds", "within_budget"]

log = logging.getLogger(__name__)

# Times a fragment above its triangle budget gets its tolerance doubled.
BUDGET_ROUNDS = 6
# Fits in which a fragment that came out invalid gets the vertices behind its bad faces pinned; after these it
# is held whole.
_PIN_TRIES = 4


def within_budget(checker: _Checker, tried: _Tried, tolerance: float, limits: Limits,
                  results: list[Fragment]) -> list[Fragment]:
    """Simplify the fragments above their share of ``limits.budget`` further, every fragment still valid.

    Goes on from (a copy of) the valid simplification ``tried`` (``results``), the last fit's budget
    collapses redone first where still allowed. A fragment that turns invalid gets the vertices whose budget
    collapses made its bad faces pinned (kept as in ``tried``); after :data:`_PIN_TRIES` fits, or when no
    such vertex is left, it is held as it was in ``tried`` (every vertex of its faces kept, its shared faults
    included). When every fragment is held, that is ``results``.
    """
    count = len(results)
    held = set(tried.as_cut)
    pinned: set[int] = set()
    tries = dict.fromkeys(range(count), 0)
    owners = checker.classified.owners
    later: _Fitted | None = None
    while len(held) < count:
        hold = pinned | {x for t, f in tried.complex_.faces.items() if held.intersection(owners[t]) for x in f}
        later = _fit(checker, tried, tolerance, limits, hold, frozenset(held), later)
        fitted, face_ids, bad = checker.check(later.complex_, tried.as_cut)
        if not bad:
            return fitted
        log.debug("faults: %d fragment(s) invalid within the budget; pinning the vertices behind", len(bad))
        before = frozenset(pinned)  # a vertex behind two fragments' bad faces is new to both
        for k, b in sorted(bad.items()):
            behind = _budget_vertices(later.complex_, tried.complex_, face_ids[k][b].tolist()) - before
            tries[k] += 1
            if behind and tries[k] <= _PIN_TRIES:
                pinned |= behind
            else:
                held.add(k)
    return results


def _budget_vertices(fitted: SurfaceComplex, tried: SurfaceComplex, faces: list[int]) -> set[int]:
    """The vertices whose collapses made ``faces`` of ``fitted`` and that are still in ``tried``: the budget's
    collapses behind them (pinning those undoes them; the tolerance's collapses are ``tried``'s own)."""
    return {u for u in fitted.behind(faces) if u in tried.vertex_faces}


@dataclass(frozen=True)
class _Fitted:
    """A complex simplified for the budget (:func:`_fit`)."""

    complex_: SurfaceComplex
    bound: dict  # the tolerance each fragment ended with
    start: int  # collapses of ``complex_.done`` that made the valid try (the budget's follow)


def _fit(checker: _Checker, tried: _Tried, tolerance: float, limits: Limits, hold: set, held: frozenset[int],
         later: _Fitted | None) -> _Fitted:
    """The valid try's complex (a copy), the vertices ``hold`` (of fragments ``held``) locked, simplified to
    the budget; ``later``: an earlier fit whose budget collapses are redone first, at its tolerances."""
    count = len(checker.fragments.fragments)
    complex_ = tried.complex_.copy()
    complex_.locked |= hold
    bound = {k: tolerance for k in range(count)}
    start = len(complex_.done)
    if later is not None:
        bound = {k: tolerance if k in held else b for k, b in later.bound.items()}
        complex_.replay(later.complex_.done[later.start:], bound, later.complex_.final_refusals())
        complex_.decimate(bound)
    rounds(complex_, checker.classified, limits, bound, tolerance, held)
    complex_.flip_needles(set(tried.as_cut) | held)
    return _Fitted(complex_, bound, start)


def rounds(complex_: SurfaceComplex, classified: Classified, limits: Limits, bound: dict, tolerance: float,
            held: frozenset[int] = frozenset()) -> np.ndarray:
    """Double the tolerance (``bound``, per fragment, updated) of the fragments over ``limits`` and simplify
    them further, until none is; the fragments' triangles (count,) at the end.

    A fragment goes no further once its tolerance is :data:`BUDGET_ROUNDS` doublings up, when all its
    vertices are locked, or when it is ``held``.
    """
    count = len(bound)
    sizes = _sizes(complex_, classified, count)
    if not limits.active:
        return sizes
    limit = tolerance * 2**BUDGET_ROUNDS
    # Fragments with every vertex locked (kept as cut) cannot give anything: the others share what they leave.
    stuck = np.ones(count, dtype=bool)
    for t, f in complex_.faces.items():
        if not complex_.locked.issuperset(f):
            stuck[list(classified.owners[t])] = False
    stuck[sorted(held)] = True
    for _ in range(BUDGET_ROUNDS):
        stuck |= np.array([bound[k] >= limit for k in range(count)])
        todo = limits.over(sizes, stuck)
        if not len(todo):
            break
        for k in todo.tolist():
            bound[k] *= 2.0
        chosen = set(todo.tolist())
        vertices = {x for t, f in complex_.faces.items() if chosen.intersection(classified.owners[t]) for x in f}
        complex_.decimate(bound, sorted(vertices))
        sizes = _sizes(complex_, classified, count)
    return sizes


def _sizes(complex_: SurfaceComplex, classified: Classified, count: int) -> np.ndarray:
    """Triangles (count,) of each fragment in the complex as it is (a fault face counts for both sides)."""
    sizes = np.zeros(count, dtype=np.int64)
    for t in complex_.faces:
        for k in classified.owners[t]:
            sizes[k] += 1
    return sizes
