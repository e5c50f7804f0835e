"""One hit, exactly: first break, first detachment, everything broken, groups at any magnitude.

For a hit (a contact site and a unit direction) a criterion
(:mod:`fracture_cli.atlas.criterion`) gives every bond's breaking impulse
``m[e]``: at impulse magnitude ``M`` bond ``e`` is broken when ``M > m[e]`` and
holds when ``M <= m[e]`` (the runtime's rule: a jump equal to the threshold
holds). With no sampling of magnitudes:

* ``b0 = min_e m[e]``: the first bond breaks just above ``b0``;
* ``d1``, the *first detachment*: the smallest magnitude above which the
  unbroken graph has more components than the whole graph (more than one for a
  connected graph). The components of ``{e : m[e] >= M}`` are those of the
  maximum spanning forest's edges with ``m[e] >= M`` (a property of maximum
  spanning forests), so ``d1`` is the forest's smallest weight. The forest comes
  from Kruskal's algorithm over the edges by decreasing ``m``, ties by edge
  index, with a union-find;
* ``everything = max_e m[e]``: every bond is broken just above it;
* the groups at ``M``: components of the unbroken bonds, labelled by their
  smallest fragment index, as the runtime's ``group`` (docs/FORMAT.md section 4).

Without bonds (one fragment) or when no forest edge can break, ``d1`` is
``+inf``; without bonds ``b0`` and ``everything`` are ``+inf`` too.

*Detached* fragments at ``M``: every fragment outside its main group, the main
group of a component of the whole graph being the group in it with the largest
total volume (ties: the smallest group id); for a connected graph that is "every
fragment not in the heaviest group". Volumes come from
:mod:`fracture_cli.atlas.layout` (equal weights without them). The *hit
fragment* is the fragment whose centroid is nearest the hit point (ties: the
smallest index).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fracture_cli.atlas.criterion import BreakingImpulses, modes_breaking_impulses
from fracture_cli.errors import ImpactArgumentError
from fracture_cli.runtime.format import RuntimeData
from fracture_cli.runtime.impact import components, nearest_site


@dataclass(frozen=True, eq=False)
class HitAnalysis:
    """Everything the atlas needs about one hit.

    Attributes
    ----------
    site : int
        Contact site the hit resolves to (the runtime's nearest site).
    point : (3,) float64
        Hit point, model space.
    direction : (3,) float64
        Unit impulse direction.
    magnitudes : (e,) float64
        Breaking impulse of every bond (``+inf``: never).
    forest : (f,) int64
        Edges of the maximum spanning forest, in Kruskal order (decreasing
        ``magnitudes``, ties by edge index).
    b0, d1, everything : float
        First break, first detachment, every bond broken (module docstring).
    """

    site: int
    point: np.ndarray
    direction: np.ndarray
    magnitudes: np.ndarray
    forest: np.ndarray
    b0: float
    d1: float
    everything: float


def unit_direction(direction) -> np.ndarray:
    """``direction / |direction|`` as (3,) float64; ImpactArgumentError if it is not finite and nonzero."""
    try:
        u = np.asarray(direction, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise ImpactArgumentError(f"direction must be three numbers, got {direction!r}") from None
    length = float(np.sqrt((u[0] * u[0] + u[1] * u[1]) + u[2] * u[2]))
    if not (np.all(np.isfinite(u)) and 0.0 < length < np.inf):
        raise ImpactArgumentError(f"direction must be finite and nonzero, got {direction!r}")
    return u / length


def maximum_spanning_forest(p: int, edges: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Kruskal's maximum spanning forest: edge indices in the order they were taken.

    Parameters
    ----------
    p : int
        Number of vertices.
    edges : (e, 2) int
        Edge endpoints.
    weights : (e,) float
        Edge weights (``+inf`` allowed, no NaN).

    Returns
    -------
    (f,) int64
        Forest edges by decreasing weight, ties by edge index; ``f = p - c``
        for ``c`` components of the graph.
    """
    order = np.lexsort((np.arange(len(weights)), -np.asarray(weights, dtype=np.float64)))
    parent = list(range(p))

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]  # path halving
            x = parent[x]
        return x

    taken = []
    ends = np.asarray(edges, dtype=np.int64).tolist()
    for index in order.tolist():
        a, b = find(ends[index][0]), find(ends[index][1])
        if a != b:
            parent[max(a, b)] = min(a, b)
            taken.append(index)
            if len(taken) == p - 1:
                break
    return np.asarray(taken, dtype=np.int64)


def analyse_hit(data: RuntimeData, hit, direction, criterion: BreakingImpulses = modes_breaking_impulses
                ) -> HitAnalysis:
    """Breaking impulses of one hit and what follows from them (module docstring).

    Parameters
    ----------
    data : RuntimeData
    hit : int or (3,) float
        A contact site index, or a point (model space) that resolves to its
        nearest site as in the runtime.
    direction : (3,) float
        Impulse direction, any nonzero length (normalized here).
    criterion : callable, optional (default the modes criterion)
        ``(data, site, unit direction) -> (e,) breaking impulses``.

    Returns
    -------
    HitAnalysis
    """
    if isinstance(hit, (int, np.integer)):
        site = int(hit)
        if not 0 <= site < data.num_sites:
            raise ImpactArgumentError(f"site {site} is out of range (the file has {data.num_sites} sites)")
        point = np.asarray(data.sites[site], dtype=np.float64)
    else:
        point = np.asarray(hit, dtype=np.float64).reshape(3)
        site = nearest_site(data, point)
    u = unit_direction(direction)
    magnitudes = np.asarray(criterion(data, site, u), dtype=np.float64)
    forest = maximum_spanning_forest(data.p, data.edges, magnitudes)
    bonds = len(magnitudes) > 0
    return HitAnalysis(site=site, point=point, direction=u, magnitudes=magnitudes, forest=forest,
                       b0=float(magnitudes.min()) if bonds else np.inf,
                       d1=float(magnitudes[forest[-1]]) if len(forest) else np.inf,
                       everything=float(magnitudes.max()) if bonds else np.inf)


def groups_at(data: RuntimeData, hit: HitAnalysis, magnitude: float) -> np.ndarray:
    """Groups (p,) int64 after the hit with impulse ``magnitude``: the smallest fragment index of each group."""
    kept = hit.forest[hit.magnitudes[hit.forest] >= magnitude]
    edges = np.asarray(data.edges, dtype=np.int64)
    return components(data.p, edges[kept, 0], edges[kept, 1])


def rest_groups(data: RuntimeData) -> np.ndarray:
    """Groups (p,) int64 with every bond intact (the components of the fragment graph)."""
    edges = np.asarray(data.edges, dtype=np.int64)
    return components(data.p, edges[:, 0], edges[:, 1])


def detached(groups: np.ndarray, rest: np.ndarray, volumes: np.ndarray) -> np.ndarray:
    """Which fragments (n,) bool are outside the main group of their rest component (module docstring).

    Parameters
    ----------
    groups : (n,) int
        Groups after the hit: any integer labels (smallest-index labels for one body; the levels' leaves
        number a split fragment's children's groups after the others, :mod:`fracture_cli.atlas.leaves`).
    rest : (n,) int
        The rest component of every fragment (:func:`rest_groups`); a group lies in one.
    volumes : (n,) float
        Fragment volumes (or equal weights).
    """
    weight: dict[int, float] = {}
    for g, v in zip(groups.tolist(), volumes.tolist()):  # in fragment order, as a running sum
        weight[g] = weight.get(g, 0.0) + v
    main: dict[int, int] = {}
    for g, r in sorted(set(zip(groups.tolist(), rest.tolist()))):  # ascending labels: ties keep the smallest
        if r not in main or weight[g] > weight[main[r]]:
            main[r] = g
    return np.array([g != main[r] for g, r in zip(groups.tolist(), rest.tolist())], dtype=bool)


def nearest_fragment(centroids: np.ndarray, point: np.ndarray) -> int:
    """Index of the fragment whose centroid (p, 3) is nearest ``point`` (3,); ties: the smallest index."""
    delta = centroids - point
    d2 = (delta[:, 0] * delta[:, 0] + delta[:, 1] * delta[:, 1]) + delta[:, 2] * delta[:, 2]
    return int(d2.argmin())
