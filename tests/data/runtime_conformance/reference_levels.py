"""Exact reference of docs/FORMAT.md section 14 (levels), in plain Python, for the conformance vectors.

Independent of ``fracture_cli.runtime.levels`` and ``levelstate``: a body's view is cut out of the
file's arrays as lists (section 14.3) and answered by :mod:`reference` / :mod:`reference_damage`;
the object state, its pieces and a hit on a piece follow sections 14.4 and 14.5 to the letter.
Margins to ties are carried along so the generator keeps only hits every reader must answer alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import reference
import reference_damage


@dataclass(frozen=True)
class LevelFile:
    """A runtime file with levels as Python lists (float32 values widened exactly)."""

    body0: reference.Runtime
    p: int
    parent: list
    body_fragment: list
    child_ptr: list
    site_ptr: list
    edge_ptr: list
    sites: list
    B: list
    W: list  # K lists of C d-tuples
    edges: list
    thresholds: list
    stress: tuple | None  # (ptr, bonds, gains, strength) over all body sites / bonds
    sharing: tuple | None = None  # (body_site_fragment, body_edge_areas): feature "sharing" (section 11.1)

    @classmethod
    def from_data(cls, data) -> LevelFile:
        lv = data.levels
        stress = None
        if "body_site_bonds_ptr" in lv:
            stress = (lv["body_site_bonds_ptr"].tolist(), lv["body_site_bonds"].tolist(),
                      [tuple(g) for g in lv["body_site_bond_gain"].tolist()], lv["body_bond_strength"].tolist())
        return cls(body0=reference.Runtime.from_data(data), p=data.p, parent=lv["parent"].tolist(),
                   body_fragment=lv["body_fragment"].tolist(), child_ptr=lv["body_child_ptr"].tolist(),
                   site_ptr=lv["body_site_ptr"].tolist(), edge_ptr=lv["body_edge_ptr"].tolist(),
                   sites=[tuple(s) for s in lv["body_sites"].tolist()],
                   B=[[tuple(m) for m in site] for site in lv["body_B"].tolist()],
                   W=[[tuple(f) for f in mode] for mode in lv["body_W"].tolist()],
                   edges=[tuple(e) for e in lv["body_edges"].tolist()],
                   thresholds=[float(t) for t in data.levels_info["thresholds"]], stress=stress,
                   sharing=(lv["body_site_fragment"].tolist(), [float(a) for a in lv["body_edge_areas"].tolist()])
                   if "body_site_fragment" in lv else None)

    @property
    def bodies(self) -> int:
        return len(self.body_fragment)

    @property
    def e0(self) -> int:
        return len(self.body0.edges)

    def level(self, g: int) -> int:
        return 1 if self.parent[g] < 0 else self.level(self.parent[g]) + 1

    def body_level(self, b: int) -> int:
        return 1 if b == 0 else self.level(self.body_fragment[b]) + 1

    def children(self, b: int) -> range:
        return range(self.child_ptr[b], self.child_ptr[b + 1])

    def body_of(self, g: int) -> int:
        return self.body_fragment.index(g) if g in self.body_fragment else -1

    def holder(self, g: int) -> int:
        return next(b for b in range(self.bodies) if self.child_ptr[b] <= g < self.child_ptr[b + 1])

    def state_range(self, b: int) -> range:
        if b == 0:
            return range(0, self.e0)
        return range(self.e0 + self.edge_ptr[b], self.e0 + self.edge_ptr[b + 1])

    def view(self, b: int) -> reference.Runtime:
        """Body ``b``'s view (section 14.3) as a :class:`reference.Runtime`."""
        if b == 0:
            return self.body0
        s0, s1 = self.site_ptr[b], self.site_ptr[b + 1]
        g0, g1 = self.child_ptr[b] - self.p, self.child_ptr[b + 1] - self.p
        e0, e1 = self.edge_ptr[b], self.edge_ptr[b + 1]
        stress = None
        if self.stress is not None:
            ptr, bonds, gains, strength = self.stress
            n0, n1 = ptr[s0], ptr[s1]
            stress = ([x - n0 for x in ptr[s0: s1 + 1]], bonds[n0:n1], gains[n0:n1], strength[e0:e1])
        sharing = None
        if self.sharing is not None and self.body0.sharing is not None:
            sharing = (self.sharing[0][s0:s1], self.sharing[1][e0:e1], self.body0.sharing[2])
        return reference.Runtime(sites=self.sites[s0:s1], B=self.B[s0:s1], W=[mode[g0:g1] for mode in self.W],
                                 edges=self.edges[e0:e1], default_threshold=self.thresholds[self.body_level(b) - 1],
                                 criterion=self.body0.criterion, stress=stress, anchored=None,
                                 damage=self.body0.damage, sharing=sharing)


def typical_load(rt: reference.Runtime, point, direction) -> float:
    """Largest bond measure of a unit hit per unit threshold (to scale random impulses); 1 when nothing loads."""
    if rt.criterion == "stress":
        v = reference.nearest(rt, point)[0]
        m = max(abs(c) for c in direction)
        n = [c / m for c in direction]
        strength = rt.stress[3]
        ratios = [g / m / strength[e] for e, g in reference.stress_gains(rt, v, n) if g > 0 and strength[e] > 0]
        return max(ratios, default=0.0) or 1.0
    result = reference.project(rt, point, direction, math.inf)
    jumps = [abs(result.displacement[P][c] - result.displacement[Q][c]) for P, Q in rt.edges for c in range(rt.d)]
    return max(jumps, default=0.0) or 1.0


def safe_stateless(rt: reference.Runtime, point, impulse, threshold) -> bool:
    """Whether a stateless hit on ``rt`` is decided far from every tie."""
    try:
        return reference_damage.safe(reference_damage.solve(rt, point, impulse, threshold))
    except reference.InvalidImpact:
        return True


def components(n: int, pairs) -> list:
    """Smallest member of each vertex's component over ``pairs``."""
    return reference.components(n, list(pairs), [False] * len(pairs))


def _holds(lf: LevelFile, health: list, b: int) -> list:
    return [health[i] > 0 for i in lf.state_range(b)]


def split(lf: LevelFile, health: list, g: int) -> bool:
    """Section 14.4: ``g`` has a body whose children form two or more groups over its holding bonds."""
    b = lf.body_of(g)
    if b < 0:
        return False
    view = lf.view(b)
    pairs = [e for e, ok in zip(view.edges, _holds(lf, health, b)) if ok]
    groups = components(view.p, pairs)
    return sum(1 for j, x in enumerate(groups) if x == j) >= 2


def shown(lf: LevelFile, health: list, g: int) -> bool:
    if split(lf, health, g):
        return False
    a = lf.parent[g]
    while a >= 0:
        if not split(lf, health, a):
            return False
        a = lf.parent[a]
    return True


def pieces_of(lf: LevelFile, health: list, b: int, members: set | None = None) -> list:
    """Body ``b``'s pieces (lists of global fragments) among its shown children (and ``members``)."""
    first = lf.child_ptr[b]
    view = lf.view(b)
    keep = [shown(lf, health, first + j) and (members is None or first + j in members) for j in range(view.p)]
    pairs = [(P, Q) for (P, Q), ok in zip(view.edges, _holds(lf, health, b)) if ok and keep[P] and keep[Q]]
    groups = components(view.p, pairs)
    return [[first + j for j in range(view.p) if keep[j] and groups[j] == root]
            for root in range(view.p) if keep[root] and groups[root] == root]


def all_pieces(lf: LevelFile, health: list) -> list:
    return [piece for b in range(lf.bodies) for piece in pieces_of(lf, health, b)]


def anchored_piece(lf: LevelFile, piece: list) -> bool:
    anchored = lf.body0.anchored
    return anchored is not None and any(g < lf.p and anchored[g] == 1 for g in piece)


def hit_piece(lf: LevelFile, health: list, struck: int, point, impulse, threshold) -> dict:
    """Section 14.5 on a copy of ``health``: the answer, the new state and the margins to ties.

    Raises :class:`reference.InvalidImpact` (``what``: ``point``, ``impulse``, ``threshold`` or ``struck``).
    """
    reference.check_inputs(point, impulse, threshold)
    if not (0 <= struck < len(lf.parent)) or not shown(lf, health, struck):
        raise reference.InvalidImpact("struck")
    b = lf.holder(struck)
    piece = next(pc for pc in pieces_of(lf, health, b) if struck in pc)
    view = lf.view(b)
    rng = lf.state_range(b)
    old = [health[i] for i in rng]
    first = lf.child_ptr[b]
    result = reference_damage.hit(view, old, point, impulse, threshold)
    new = list(health)
    inside = [first + P in piece and first + Q in piece for P, Q in view.edges]
    for k, i in enumerate(rng):
        if inside[k]:
            new[i] = result.health[k]
    margins = [result]
    child_body, child_result, is_split = lf.body_of(struck), None, False
    if child_body >= 0:
        crng = lf.state_range(child_body)
        child_result = reference_damage.hit(lf.view(child_body), [new[i] for i in crng], point, impulse, threshold)
        for k, i in enumerate(crng):
            new[i] = child_result.health[k]
        margins.append(child_result)
        is_split = split(lf, new, struck)
    body_health = [new[i] for i in rng]
    pieces = all_pieces(lf, new)
    return {
        "body": b, "site": result.site,
        "broken": [k for k, h in enumerate(body_health) if h <= 0],
        "child_body": child_body, "child_site": -1 if child_result is None else child_result.site,
        "child_broken": [] if child_result is None else [k for k, h in enumerate(child_result.health) if h <= 0],
        "split": is_split, "pieces": pieces, "anchored": [anchored_piece(lf, pc) for pc in pieces],
        "_health": new, "_safe": all(reference_damage.safe(m) for m in margins),
        "_tied": any(len(m.tied_sites) > 1 for m in margins),
    }
