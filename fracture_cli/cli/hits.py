"""What ``fracture impact`` prints: one hit or a sequence of hits on one damage state.

A sequence (``--hit``, ``--repeat``) is applied with :func:`fracture_cli.runtime.damage.hit`
to one state from :func:`~fracture_cli.runtime.damage.new_state`, as a game does
between saves (docs/FORMAT.md section 12.4): on a file with feature ``"damage"``
light hits crack bonds and wear them down until one breaks; on any other file the
state only remembers what broke. One hit answers as the stateless projection.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fracture_cli.io.regroup import group_name
from fracture_cli.runtime.damage import hit, new_state
from fracture_cli.runtime.format import RuntimeData
from fracture_cli.runtime.impact import ImpactResult

Vector = tuple[float, float, float]


@dataclass(frozen=True)
class HitOutcome:
    """One hit of a sequence and the state after it.

    Attributes
    ----------
    point, impulse : (3,) float
        The hit as given.
    result : ImpactResult
        What it did (``broken``: every broken bond so far; ``cracked``: bonds that hold but are cracked).
    health : (e,) float64
        Every bond's health after the hit.
    """

    point: Vector
    impulse: Vector
    result: ImpactResult
    health: np.ndarray


def apply_hits(data: RuntimeData, hits: Sequence[tuple[Vector, Vector]], threshold: float | None) -> list[HitOutcome]:
    """Apply ``hits`` (point, impulse) in order to one fresh damage state; one outcome per hit."""
    state = new_state(data)
    out = []
    for point, impulse in hits:
        result = hit(data, state, point, impulse, threshold)
        out.append(HitOutcome(point, impulse, result, state.copy()))
    return out


def groups_of(data: RuntimeData, result: ImpactResult) -> dict[str, list[str]]:
    """Fragment names per group, the groups named ``group_###`` after their smallest fragment (as ``-o`` writes)."""
    groups: dict[str, list[str]] = {}
    for j, g in enumerate(result.groups.tolist()):
        groups.setdefault(group_name(int(g)), []).append(data.fragment_names[j])
    return groups


def anchored_groups(data: RuntimeData, result: ImpactResult) -> list[str]:
    """Names of the groups held by the world (they stay static in a game)."""
    return [group_name(int(g)) for g in np.unique(result.groups[result.anchored]).tolist()]


def _bond(data: RuntimeData, index: int) -> str:
    p, q = (int(x) for x in data.edges[index])
    return f"{data.fragment_names[p]} - {data.fragment_names[q]}"


def _summary(data: RuntimeData, outcome: HitOutcome) -> str:
    result = outcome.result
    text = f"{result.num_groups} group(s), {int(result.broken.sum())} of {len(result.broken)} bonds broken"
    if data.damage:
        text += f", {int(result.cracked.sum())} cracked"
        if result.cracked.any():
            text += f" (lowest health {float(outcome.health[result.cracked].min()):.3g})"
    return text


def text_lines(data: RuntimeData, outcomes: Sequence[HitOutcome]) -> list[str]:
    """What ``impact`` prints: a line per hit of a sequence, then the groups and cracked bonds after the last.

    One hit prints its summary line and the groups only (as before sequences), a sequence a numbered line per
    hit first. Anchored groups end with ``(anchored)``; each cracked bond gets a line with its health.
    """
    lines = []
    if len(outcomes) > 1:
        lines += [f"hit {i + 1}: {_summary(data, o)}" for i, o in enumerate(outcomes)]
    last = outcomes[-1]
    if len(outcomes) == 1:
        lines.append(_summary(data, last))
    held = set(anchored_groups(data, last.result))
    for name, members in groups_of(data, last.result).items():
        lines.append(f"{name}: {' '.join(members)}" + (" (anchored)" if name in held else ""))
    for index in np.flatnonzero(last.result.cracked).tolist():
        lines.append(f"cracked: {_bond(data, index)} (health {float(last.health[index]):.3g})")
    return lines


def json_body(data: RuntimeData, outcomes: Sequence[HitOutcome], site_distances: Sequence[float]) -> dict[str, Any]:
    """``impact --json``: the state after the last hit (the keys of one hit, as before) and ``hits``, one per hit.

    Per hit: ``site``, ``site_distance``, ``groups`` (count), ``broken_bonds`` (every broken bond so far),
    ``now_broken`` (bonds this hit broke), ``cracked_bonds``, ``anchored_groups``.
    """
    last = outcomes[-1]
    groups = groups_of(data, last.result)
    ptr = data.cracks.get("crack_ptr")
    cracked = [{"bond": int(i), "fragments": [data.fragment_names[int(x)] for x in data.edges[i]],
                "health": float(last.health[i]),
                "crack_segments": 0 if ptr is None else int(ptr[i + 1] - ptr[i])}
               for i in np.flatnonzero(last.result.cracked).tolist()]
    per_hit = []
    before = np.zeros(data.num_edges, dtype=bool)
    for outcome, distance in zip(outcomes, site_distances):
        result = outcome.result
        per_hit.append({"point": list(outcome.point), "impulse": list(outcome.impulse), "site": int(result.site),
                        "site_distance": float(distance), "groups": result.num_groups,
                        "broken_bonds": int(result.broken.sum()),
                        "now_broken": np.flatnonzero(result.broken & ~before).tolist(),
                        "cracked_bonds": np.flatnonzero(result.cracked).tolist(),
                        "anchored_groups": anchored_groups(data, result)})
        before = result.broken
    return {"site": int(last.result.site), "site_distance": float(site_distances[-1]),
            "broken_bonds": int(last.result.broken.sum()), "group_names": list(groups),
            "groups": list(groups.values()), "anchored_groups": anchored_groups(data, last.result),
            "cracked_bonds": cracked, "health": [float(h) for h in last.health], "hits": per_hit}
