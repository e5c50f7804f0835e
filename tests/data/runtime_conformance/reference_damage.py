"""Exact reference of docs/FORMAT.md section 12 (anchors, the damage state, cracks), in plain Python doubles.

:func:`hit` applies one hit to a list of bond healths in the order of section
12.4 and measures how close every decision is to a tie (the crack test
``a > c * b`` and a health left within rounding of 0), so the generator keeps
only hits every reader computing in double must answer alike. :func:`solve`
is the stateless answer (a hit on a fresh state) and falls back to
:func:`reference.project` for files without those features.
"""

from __future__ import annotations

import dataclasses
import math

import reference

# A health within this of 0 after a crack (absolute) is a tie: whether the bond breaks depends on rounding.
HEALTH_MARGIN = 1e-7


def measures(rt: reference.Runtime, r: reference.Response, health: list | None = None) -> list:
    """``(a, b, scale)`` per bond (section 12.4 step 2): the measure, the limit, the magnitudes behind ``a``.

    ``health``: the state before the hit (feature ``"sharing"`` starts its passes with the broken bonds).
    """
    if rt.criterion != "stress":
        return reference.modes_measures(rt, r.disp, r.alpha_scale, r.t)
    before = None if health is None else [h <= 0 for h in health]
    a, b, scale = reference.stress_measures(rt, r.v, r.n, r.t, before)
    return list(zip(a, b, scale))


def damage_factor(rt: reference.Runtime) -> tuple[float, float]:
    """``(c, q)`` with ``q = r / (1 - c)`` (0 when ``c == 1``); a file without ``"damage"``: ``(1, 0)``."""
    if rt.damage is None:
        return 1.0, 0.0
    c, rate = rt.damage
    return c, (0.0 if c == 1.0 else rate / (1.0 - c))


def hit(rt: reference.Runtime, health: list, point, impulse, threshold) -> reference.Expected:
    """One hit on ``health`` (not modified; the new state is ``Expected.health``), section 12.4 to the letter.

    Raises :class:`reference.InvalidImpact` for an invalid input (the state is then unchanged).
    """
    r = reference.response(rt, point, impulse, threshold)
    base = reference.project(rt, point, impulse, threshold)
    c, q = damage_factor(rt)
    e = len(rt.edges)
    now_broken, now_cracked = [False] * e, [False] * e
    rows = measures(rt, r, health) if r.m != 0 else [(0.0, math.inf, 0.0)] * e
    crack_margin = math.inf
    for i, (a, b, scale) in enumerate(rows):
        if r.m == 0:
            continue
        now_broken[i] = a > b
        cb = c * b  # one product
        now_cracked[i] = a > cb
        if math.isfinite(cb) and scale + cb > 0 and c < 1:
            crack_margin = min(crack_margin, abs(a - cb) / (scale + cb))
    new, health_margin = [], math.inf
    for i, h in enumerate(health):
        if h > 0:
            if now_broken[i]:
                h = 0.0
            elif now_cracked[i]:
                a, b, _ = rows[i]
                h = h - q * (a / b - c)  # a / b: one division
                health_margin = min(health_margin, abs(h))
            if h < 0:
                h = 0.0
        new.append(h)
    broken = [h <= 0 for h in new]
    cracked = [not broken[i] and (now_cracked[i] or new[i] < 1) for i in range(e)]
    groups = reference.components(rt.p, rt.edges, broken)
    return dataclasses.replace(base, broken=broken, groups=groups, cracked=cracked, anchored=anchored_of(rt, groups),
                               health=new, crack_margin=crack_margin, health_margin=health_margin)


def anchored_of(rt: reference.Runtime, groups: list) -> list:
    """Per fragment: 1 when its group holds a fragment with ``anchored = 1`` (all 0 without the feature)."""
    if rt.anchored is None:
        return [0] * rt.p
    held = {groups[j] for j in range(rt.p) if rt.anchored[j] == 1}
    return [1 if groups[j] in held else 0 for j in range(rt.p)]


def solve(rt: reference.Runtime, point, impulse, threshold) -> reference.Expected:
    """The stateless answer: section 4 (and 11), or with section 12's features a hit on a fresh state."""
    if rt.damage is None and rt.anchored is None:
        return reference.project(rt, point, impulse, threshold)
    return hit(rt, [1.0] * len(rt.edges), point, impulse, threshold)


def safe(result: reference.Expected) -> bool:
    """Every decision of ``result`` is far enough from a tie for any evaluation order in double."""
    return (result.site_margin > reference.SAFE_MARGIN and result.edge_margin > reference.SAFE_MARGIN
            and result.crack_margin > reference.SAFE_MARGIN and result.health_margin > HEALTH_MARGIN)


def peak_load(rt: reference.Runtime, point, impulse, threshold) -> float:
    """The largest ``a / b`` over the bonds for this hit (1 = the most loaded bond at its strength)."""
    r = reference.response(rt, point, impulse, threshold)
    if r.m == 0:
        return 0.0
    loads = [a / b for a, b, _ in measures(rt, r) if 0 < b < math.inf and a > 0]
    return max(loads, default=0.0)
