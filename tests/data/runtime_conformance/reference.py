"""Exact reference of docs/FORMAT.md section 4, in plain Python doubles, for the conformance vectors.

It follows the spec's order of operations literally (the scale-invariant rule,
sums in index order, the Euclidean norm of a jump) and also measures how close
each decision is to a tie, so the generator can keep only impacts whose answer
every reader computing in double must reproduce. It does not replace
``fracture_cli.runtime.impact`` (the numpy reference); the tests check that both
agree on every vector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# A decision (nearest site, edge broken) is "safe" when the two sides differ by more
# than this fraction of the magnitudes that went into them: far above the rounding
# of any evaluation order in double (about k * 1e-16), far below real differences.
SAFE_MARGIN = 1e-9


class InvalidImpact(ValueError):
    """The impact's point, impulse or threshold is not allowed (section 4, "Inputs")."""

    def __init__(self, what: str):
        super().__init__(what)
        self.what = what


@dataclass(frozen=True)
class Runtime:
    """The arrays of one runtime file as Python floats / ints (float32 values widened exactly).

    Attributes
    ----------
    sites : list of (x, y, z)
    B : list over sites of list over modes of d-tuples
    W : list over modes of list over fragments of d-tuples
    edges : list of (P, Q)
    default_threshold : float
    criterion : str
        ``"modes"`` or ``"stress"`` (docs/FORMAT.md section 11).
    stress : tuple or None
        With the stress criterion: ``(ptr, bonds, gains, strength)`` as lists (gains of 3-tuples).
    anchored : list or None
        Feature ``"anchors"`` (docs/FORMAT.md section 12): 0/1 per fragment.
    sharing : tuple or None
        Feature ``"sharing"`` (section 11.1): ``(site_fragment, edge_areas, concentration)``.
    damage : tuple or None
        Feature ``"damage"``: ``(c, r)``, the crack level and the damage rate.
    """

    sites: list
    B: list
    W: list
    edges: list
    default_threshold: float
    criterion: str = "modes"
    stress: tuple | None = None
    anchored: list | None = None
    damage: tuple | None = None
    sharing: tuple | None = None

    @property
    def features(self) -> list:
        """The file's version-2 features, sorted."""
        present = {"anchors": self.anchored is not None, "damage": self.damage is not None,
                   "stress": self.criterion == "stress", "sharing": self.sharing is not None}
        return [name for name in sorted(present) if present[name]]

    @property
    def d(self) -> int:
        return len(self.W[0][0])

    @property
    def k(self) -> int:
        return len(self.W)

    @property
    def p(self) -> int:
        return len(self.W[0])

    @classmethod
    def from_data(cls, data) -> Runtime:
        """From a :class:`fracture_cli.runtime.format.RuntimeData`."""
        stress = None
        if getattr(data, "criterion", "modes") == "stress":
            arrays = data.stress
            stress = (arrays["site_bonds_ptr"].tolist(), arrays["site_bonds"].tolist(),
                      [tuple(g) for g in arrays["site_bond_gain"].tolist()], arrays["bond_strength"].tolist())
        anchored = None if data.anchored is None else [int(x) for x in data.anchored.tolist()]
        damage = (float(data.damage["crack_level"]), float(data.damage["damage_rate"])) if data.damage else None
        sharing = None
        if getattr(data, "sharing", None):
            sharing = (data.stress["site_fragment"].tolist(), [float(a) for a in data.edge_areas.tolist()],
                       float(data.sharing["concentration"]))
        return cls(sites=[tuple(float(c) for c in s) for s in data.sites.tolist()],
                   B=[[tuple(m) for m in site] for site in data.B.tolist()],
                   W=[[tuple(f) for f in mode] for mode in data.W.tolist()],
                   edges=[tuple(e) for e in data.edges.tolist()],
                   default_threshold=float(data.default_threshold),
                   criterion=getattr(data, "criterion", "modes"), stress=stress, anchored=anchored, damage=damage,
                   sharing=sharing)


@dataclass(frozen=True)
class Expected:
    """The answer to one impact, and how far each decision was from a tie."""

    site: int
    tied_sites: tuple
    alpha: list
    displacement: list
    broken: list
    groups: list
    site_margin: float  # relative gap to the runner-up site (inf: one site, 0: exact tie)
    edge_margin: float  # smallest relative gap between |jump'| and T/m over the edges (stress: g and t * S)
    loads: list | None = None  # stress criterion: L_e = g / (t * S_e) for listed bonds with g > 0, else 0
    cracked: list | None = None  # section 12: cracked bonds (bool per bond)
    anchored: list | None = None  # section 12: 0/1 per fragment (its group holds an anchored fragment)
    health: list | None = None  # section 12: the state after the hit
    crack_margin: float = math.inf  # smallest relative gap between a and c * b over the bonds
    health_margin: float = math.inf  # smallest health left above 0 (a health within rounding of 0 is a tie)


def squared_distance(site, x, y, z) -> float:
    """``((sx-x)^2 + (sy-y)^2) + (sz-z)^2`` in double, in this order (section 4, step 1)."""
    dx = site[0] - x
    dy = site[1] - y
    dz = site[2] - z
    return dx * dx + dy * dy + dz * dz


def check_inputs(point, impulse, threshold) -> None:
    """Raise :class:`InvalidImpact` for a non-finite point/impulse or a NaN/negative threshold."""
    if not all(math.isfinite(c) for c in point):
        raise InvalidImpact("point")
    if not all(math.isfinite(c) for c in impulse):
        raise InvalidImpact("impulse")
    if threshold is not None and (math.isnan(threshold) or threshold < 0):
        raise InvalidImpact("threshold")


def nearest(rt: Runtime, point) -> tuple[int, tuple, float]:
    """Nearest site (smallest index on exact ties), all exactly tied sites, relative margin."""
    x, y, z = point
    d2 = [squared_distance(s, x, y, z) for s in rt.sites]
    best = min(d2)
    tied = tuple(i for i, v in enumerate(d2) if v == best)
    others = [v for v in d2 if v != best]
    if len(tied) > 1:
        margin = 0.0
    elif not others:
        margin = math.inf
    else:
        # Each squared distance is computed with a relative error of a few ulps (one
        # rounding per subtraction, square and sum), so the gap is measured relative to it.
        runner_up = min(others)
        margin = (runner_up - best) / runner_up if math.isfinite(runner_up) else math.inf
    return tied[0], tied, margin


def components(p: int, edges, broken) -> list:
    """Group of every fragment: the smallest index in its component over unbroken edges."""
    parent = list(range(p))

    def find(a: int) -> int:
        while parent[a] != a:
            a = parent[a]
        return a

    for (P, Q), cut in zip(edges, broken):
        if not cut:
            a, b = find(P), find(Q)
            if a != b:
                parent[max(a, b)] = min(a, b)
    return [find(j) for j in range(p)]


@dataclass(frozen=True)
class Response:
    """Steps 1-5 of section 4 before any decision: the site, the scale and the unscaled response."""

    v: int
    tied: tuple
    site_margin: float
    m: float
    n: list  # n' = n / m
    t: float  # T / m
    alpha: list  # of n' (unscaled)
    alpha_scale: list  # magnitudes behind alpha (for tie margins)
    disp: list  # of n' (unscaled), p rows of d


def response(rt: Runtime, point, impulse, threshold) -> Response:
    """:class:`Response` of one valid impact (``m == 0``: everything zero, ``t`` = inf)."""
    check_inputs(point, impulse, threshold)
    T = rt.default_threshold if threshold is None else threshold
    v, tied, site_margin = nearest(rt, point)
    k, p, d = rt.k, rt.p, rt.d
    m = max(abs(c) for c in impulse)
    if m == 0:
        return Response(v, tied, site_margin, 0.0, [0.0] * 3, math.inf, [0.0] * k, [0.0] * k,
                        [[0.0] * d for _ in range(p)])
    n = [c / m for c in impulse]
    B = rt.B[v]
    if d == 1:
        length = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        alpha = [B[i][0] * length for i in range(k)]
        alpha_scale = [abs(B[i][0]) * length for i in range(k)]
    else:
        alpha = [B[i][0] * n[0] + B[i][1] * n[1] + B[i][2] * n[2] for i in range(k)]
        alpha_scale = [sum(abs(B[i][c] * n[c]) for c in range(3)) for i in range(k)]
    disp = []
    for j in range(p):
        row = []
        for c in range(d):
            acc = 0.0
            for i in range(k):
                acc += alpha[i] * rt.W[i][j][c]
            row.append(acc)
        disp.append(row)
    t = T / m  # overflow -> inf (nothing breaks), underflow -> 0 (any nonzero jump breaks)
    return Response(v, tied, site_margin, m, n, t, alpha, alpha_scale, disp)


def project(rt: Runtime, point, impulse, threshold) -> Expected:
    """The answer docs/FORMAT.md section 4 prescribes, with the scale-invariant rule (stateless, no damage).

    Parameters
    ----------
    rt : Runtime
    point, impulse : 3 floats
    threshold : float or None (the file's default threshold)
    """
    r = response(rt, point, impulse, threshold)
    v, tied, site_margin, m, n, t = r.v, r.tied, r.site_margin, r.m, r.n, r.t
    alpha, alpha_scale, disp = r.alpha, r.alpha_scale, r.disp
    p, k, d = rt.p, rt.k, rt.d
    if m == 0:
        zero = [[0.0] * d for _ in range(p)]
        broken = [False] * len(rt.edges)
        return Expected(v, tied, [0.0] * k, zero, broken, components(p, rt.edges, broken),
                        site_margin, math.inf)
    if rt.criterion == "stress":
        broken, loads, edge_margin = stress_test(rt, v, n, t)
        return Expected(site=v, tied_sites=tied, alpha=[m * a for a in alpha],
                        displacement=[[m * x for x in row] for row in disp], broken=broken,
                        groups=components(p, rt.edges, broken), site_margin=site_margin, edge_margin=edge_margin,
                        loads=loads)
    broken, edge_margin = [], math.inf
    for (norm, limit, scale) in modes_measures(rt, disp, alpha_scale, t):
        broken.append(norm > limit)
        if math.isfinite(t) and scale > 0:
            edge_margin = min(edge_margin, abs(norm - t) / scale)
    return Expected(site=v, tied_sites=tied, alpha=[m * a for a in alpha],
                    displacement=[[m * x for x in row] for row in disp], broken=broken,
                    groups=components(p, rt.edges, broken), site_margin=site_margin, edge_margin=edge_margin)


def modes_measures(rt: Runtime, disp, alpha_scale, t: float) -> list:
    """``(a, b, scale)`` per bond, criterion ``"modes"``: ``|jump'|``, ``t`` and the magnitudes behind ``a``."""
    out = []
    for P, Q in rt.edges:
        jump = [disp[P][c] - disp[Q][c] for c in range(rt.d)]
        norm = abs(jump[0]) if rt.d == 1 else math.sqrt(jump[0] * jump[0] + jump[1] * jump[1] + jump[2] * jump[2])
        scale = sum(alpha_scale[i] * (max(map(abs, rt.W[i][P])) + max(map(abs, rt.W[i][Q]))) for i in range(rt.k))
        out.append((norm, t, scale))
    return out


def stress_gains(rt: Runtime, v: int, n) -> list:
    """``(bond, g)`` for site ``v``'s list: ``g = (G0 * n0 + G1 * n1) + G2 * n2`` (docs/FORMAT.md section 11)."""
    ptr, bonds, gains, _ = rt.stress
    out = []
    for j in range(ptr[v], ptr[v + 1]):
        G = gains[j]
        out.append((bonds[j], G[0] * n[0] + G[1] * n[1] + G[2] * n[2]))
    return out


def stress_measures(rt: Runtime, v: int, n, t: float, before: list | None = None) -> tuple[list, list, list]:
    """``(a, b, scale)`` lists over the bonds, stress criterion (sections 11 and 11.1).

    ``a``: ``g`` for site ``v``'s list, 0 for the others, then (feature ``"sharing"``) the passes of section
    11.1 with ``before`` (bool per bond: broken by an earlier hit) in the starting set; ``b = t * S``;
    ``scale``: the magnitudes behind ``a`` (``sum |G_c n_c|`` plus the shared load ``q * area``).
    """
    ptr, _, gains, strength = rt.stress
    e = len(rt.edges)
    a, scale = [0.0] * e, [0.0] * e
    for j, (bond, g) in zip(range(ptr[v], ptr[v + 1]), stress_gains(rt, v, n)):
        a[bond] = g
        scale[bond] = sum(abs(gains[j][c] * n[c]) for c in range(3))
    b = [t * strength[i] for i in range(e)]
    if rt.sharing is not None:
        a, scale = share(rt, v, a, b, scale, before)
    return a, b, scale


def share(rt: Runtime, v: int, a0: list, b: list, scale: list, before: list | None) -> tuple[list, list]:
    """Section 11.1's passes, literally: the struck fragment's bonds share the load of its broken ones."""
    site_fragment, areas, kappa = rt.sharing
    f = site_fragment[v]
    F = [i for i, (P, Q) in enumerate(rt.edges) if P == f or Q == f]  # increasing bond index
    out = {i for i in F if a0[i] > b[i] or (before is not None and before[i])}
    a, sc = list(a0), list(scale)
    while True:
        L = 0.0
        for i in F:
            if i in out:
                L = L + max(a0[i], 0.0)
        A = 0.0
        for i in F:
            if i not in out:
                A = A + areas[i]
        if L == 0 or A == 0:
            break
        q = (kappa * L) / A
        new = []
        for i in F:
            if i not in out:
                a[i] = a0[i] + q * areas[i]
                sc[i] = scale[i] + abs(q * areas[i])
                if a[i] > b[i]:
                    new.append(i)
        if not new:
            break
        out.update(new)
    return a, sc


def stress_test(rt: Runtime, v: int, n, t: float) -> tuple[list, list, float]:
    """Broken bonds, loads and the smallest relative gap to a tie, stress criterion (sections 11, 11.1).

    Bond ``e`` breaks when its measure ``a > t * S_e``; the gap is ``|a - t S_e|`` over
    ``scale + t S_e`` (the magnitudes that went into the comparison).
    """
    a, b, scale = stress_measures(rt, v, n, t)
    broken = [a[e] > b[e] for e in range(len(a))]
    loads = [0.0] * len(a)
    margin = math.inf
    for e in range(len(a)):
        if a[e] > 0:
            loads[e] = a[e] / b[e] if b[e] > 0 else (math.inf if b[e] == 0 else 0.0)
        total = scale[e] + (b[e] if math.isfinite(b[e]) else 0.0)
        if math.isfinite(b[e]) and total > 0 and (scale[e] > 0 or a[e] != 0):
            margin = min(margin, abs(a[e] - b[e]) / total)
    return broken, loads, margin
