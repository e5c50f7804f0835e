"""Realtime impact projection: which fragments move together after a hit.

Depends on numpy only (plus :mod:`fracture_cli.errors`, which has no
dependencies), so a game server can import it cheaply.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import ImpactArgumentError
from fracture_cli.runtime.format import RuntimeData
from fracture_cli.runtime.levels import body_view
from fracture_cli.runtime.stress import PreparedStress
from fracture_cli.runtime.structure import damage_factor


@dataclass(frozen=True, eq=False)
class ImpactResult:
    """What one impact does to an object.

    Attributes
    ----------
    groups : (p,) int32
        Group of every fragment; fragments with the same value move together.
        The value is the smallest fragment index in the group, so ids are
        deterministic (but not contiguous).
    displacement : (p, d) float64
        Projected displacement of every fragment (dimensionless, see docs/FORMAT.md).
    broken : (e,) bool
        Which piece-graph edges are broken (with a damage state: this hit's and earlier ones').
    site : int
        Index of the contact site nearest to the hit point.
    alpha : (k,) float64
        Mode coefficients of the impact.
    cracked : (e,) bool
        Bonds that are cracked but hold: loaded above the crack level by this hit, or weakened by an
        earlier one (docs/FORMAT.md section 12.4; all False without feature ``"damage"``).
    anchored : (p,) bool
        Fragments whose group holds a fragment bonded to the world (all False without ``"anchors"``):
        a game keeps those groups static.
    """

    groups: np.ndarray
    displacement: np.ndarray
    broken: np.ndarray
    site: int
    alpha: np.ndarray
    cracked: np.ndarray
    anchored: np.ndarray

    @property
    def num_groups(self) -> int:
        return int(np.count_nonzero(self.groups == np.arange(len(self.groups))))


class _Prepared:
    """Per-file precomputation done once: float64 copies and per-edge mode differences."""

    def __init__(self, data: RuntimeData):
        k, p, d = data.k, data.p, data.dim
        self.k, self.p, self.d, self.e = k, p, d, data.num_edges
        sites = np.asarray(data.sites, dtype=np.float64)
        # Columns stored separately and contiguous: three 1-D passes beat a (s, 3) reduction.
        self.sx, self.sy, self.sz = (np.ascontiguousarray(sites[:, c]) for c in range(3))
        self.B = np.ascontiguousarray(data.B, dtype=np.float64)  # (s, k, d)
        self.B1 = np.ascontiguousarray(self.B[:, :, 0])  # (s, k): the d = 1 coefficients (unused for d = 3)
        W = np.asarray(data.W, dtype=np.float64)
        edges = np.asarray(data.edges, dtype=np.int64)
        self.edge_p = np.ascontiguousarray(edges[:, 0])
        self.edge_q = np.ascontiguousarray(edges[:, 1])
        dW = W[:, self.edge_p, :] - W[:, self.edge_q, :]  # (k, e, d)
        # One matrix so displacement and edge jumps come out of a single product.
        self.WdW = np.ascontiguousarray(np.concatenate([W.reshape(k, p * d), dW.reshape(k, self.e * d)], axis=1))
        self.split = p * d
        self.forest = _SpanningForest(p, self.edge_p, self.edge_q)
        self.stress = (PreparedStress(data.stress, self.e, edges, data.edge_areas, data.sharing)
                       if data.criterion == "stress" else None)
        self.anchored = None if data.anchored is None else np.flatnonzero(np.asarray(data.anchored) == 1)
        # (c, q) of docs/FORMAT.md section 12.4; a file without "damage" acts as c = 1, r = 0 (a state
        # then only remembers broken bonds).
        self.damage = damage_factor(data.damage) if data.damage else None
        self.crack_level, self.rate = self.damage if self.damage is not None else (1.0, 0.0)


_PREPARED: weakref.WeakKeyDictionary[RuntimeData, _Prepared] = weakref.WeakKeyDictionary()


def prepare(data: RuntimeData) -> _Prepared:
    """The (cached) precomputation for ``data``; called implicitly by :func:`project_impact`."""
    prepared = _PREPARED.get(data)
    if prepared is None:
        prepared = _PREPARED[data] = _Prepared(data)
    return prepared


def components(p: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected components of a graph, labelled by their smallest vertex.

    Parameters
    ----------
    p : int
        Number of vertices.
    a, b : (e,) int64
        Edge endpoints.

    Returns
    -------
    labels : (p,) int64
        ``labels[j]`` = smallest vertex index in ``j``'s component.

    Notes
    -----
    Vectorized hook-and-compress union-find (Shiloach-Vishkin style): every
    round, each component root with an edge to a smaller root is hooked onto
    the smallest such root, then pointers are jumped until nothing changes (at
    most ``ceil(log2 p)`` times, which flattens any tree of depth < p). Labels only ever decrease and a root
    points at itself, so the final root is the component's minimum.
    """
    labels = np.arange(p, dtype=np.int64)
    jumps = max(1, int(p - 1).bit_length())
    while len(a):
        la, lb = labels[a], labels[b]
        differ = la != lb
        if not differ.any():
            break
        la, lb = la[differ], lb[differ]
        a, b = a[differ], b[differ]  # edges inside one component stay inside it
        np.minimum.at(labels, np.maximum(la, lb), np.minimum(la, lb))
        # Jump pointers until every vertex points at a root; hooking keeps trees shallow, so this
        # usually takes one or two jumps (at most ceil(log2 p), the depth bound).
        for _ in range(jumps):
            jumped = labels[labels]
            if np.array_equal(jumped, labels):
                break
            labels = jumped
    return labels


class _SpanningForest:
    """Connected components of the piece graph minus a few edges, fast.

    At load time a depth-first spanning forest of the whole graph is built and
    its vertices are numbered in preorder, so every subtree is one contiguous
    range of positions. Per call, removing the broken *tree* edges splits the
    forest into subtrees that are labelled with one slice assignment each;
    unbroken non-tree edges then glue subtrees back together (a union-find on
    the few subtree labels). Broken non-tree edges alone never split anything.
    When many tree edges break, the generic :func:`components` is used instead.
    """

    MAX_CUTS = 24  # beyond this the Python loops cost more than the vectorized fallback

    def __init__(self, p: int, edge_p: np.ndarray, edge_q: np.ndarray):
        self.p = p
        self.edge_p, self.edge_q = edge_p, edge_q
        adjacency: list[list[tuple[int, int]]] = [[] for _ in range(p)]
        for index, (u, v) in enumerate(zip(edge_p.tolist(), edge_q.tolist())):
            adjacency[u].append((v, index))
            adjacency[v].append((u, index))
        position = [-1] * p
        subtree_end = [0] * p  # by position: one past the last position of the subtree
        root_position = [0] * p  # by position: position of the tree's root
        tree_child = {}  # edge index -> position of the child it leads to
        counter = 0
        for root in range(p):
            if position[root] >= 0:
                continue
            root_pos = counter
            position[root] = counter
            root_position[counter] = root_pos
            counter += 1
            stack = [(root, iter(adjacency[root]))]
            while stack:
                node, neighbours = stack[-1]
                for other, index in neighbours:
                    if position[other] < 0:
                        position[other] = counter
                        root_position[counter] = root_pos
                        tree_child[index] = counter
                        counter += 1
                        stack.append((other, iter(adjacency[other])))
                        break
                else:
                    stack.pop()
                    subtree_end[position[node]] = counter
        self.position = np.asarray(position, dtype=np.int64)
        self.subtree_end = subtree_end
        self.root_position = np.asarray(root_position, dtype=np.int64)
        tree = np.zeros(len(edge_p), dtype=bool)
        tree[list(tree_child)] = True
        self.tree_edges = np.flatnonzero(tree)
        self.tree_child_position = np.asarray([tree_child[i] for i in self.tree_edges.tolist()], dtype=np.int64)
        self.other_edges = np.flatnonzero(~tree)
        self.other_pos_p = self.position[edge_p[self.other_edges]]
        self.other_pos_q = self.position[edge_q[self.other_edges]]
        self.node_ids = np.arange(p, dtype=np.int64)
        self.whole = components(p, edge_p, edge_q)

    def labels(self, broken: np.ndarray) -> np.ndarray:
        """Component labels (smallest vertex per component) without the ``broken`` edges."""
        cuts = self.tree_child_position[broken[self.tree_edges]]
        if len(cuts) == 0:
            return self.whole
        if len(cuts) > self.MAX_CUTS:
            keep = ~broken
            return components(self.p, self.edge_p[keep], self.edge_q[keep])
        subtree = self.root_position.copy()  # by position: label = position of the subtree's top
        end = self.subtree_end
        # Preorder: a nested cut comes after its ancestor, so it overwrites it.
        for start in np.sort(cuts).tolist():
            subtree[start:end[start]] = start
        lp = subtree[self.other_pos_p]
        lq = subtree[self.other_pos_q]
        glue = (lp != lq) > broken[self.other_edges]  # joins two subtrees and is not broken
        component = subtree[self.position]
        if glue.any():
            parent: dict[int, int] = {}
            for u, v in zip(lp[glue].tolist(), lq[glue].tolist()):
                while u in parent:
                    u = parent[u]
                while v in parent:
                    v = parent[v]
                if u != v:
                    if u < v:
                        u, v = v, u
                    parent[u] = v
            remap = np.arange(self.p, dtype=np.int64)
            for u in parent:
                root = u
                while root in parent:
                    root = parent[root]
                remap[u] = root
            component = remap[component]
        smallest = np.full(self.p, self.p, dtype=np.int64)
        np.minimum.at(smallest, component, self.node_ids)
        return smallest[component]


def nearest_site(data: RuntimeData, point) -> int:
    """Index of the contact site nearest to ``point`` (ties: the smallest index)."""
    prep = prepare(data)
    x, y, z = (float(c) for c in point)
    return _nearest(prep, x, y, z)


def _nearest(prep: _Prepared, x: float, y: float, z: float) -> int:
    dx = prep.sx - x
    d2 = dx * dx
    dy = prep.sy - y
    dy *= dy
    d2 += dy
    dz = prep.sz - z
    dz *= dz
    d2 += dz
    return int(d2.argmin())  # argmin returns the first minimum: smallest index on ties


def _vector3(value, name: str) -> tuple[float, float, float]:
    try:
        x, y, z = (float(c) for c in value)
    except (TypeError, ValueError):
        raise ImpactArgumentError(f"{name} must be three numbers, got {value!r}") from None
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise ImpactArgumentError(f"{name} must be finite, got {value!r}")
    return x, y, z


def _threshold(value) -> float:
    try:
        threshold = float(value)
    except (TypeError, ValueError):
        raise ImpactArgumentError(f"threshold must be a number >= 0, got {value!r}") from None
    if not threshold >= 0:  # also catches NaN
        raise ImpactArgumentError(f"threshold must be a number >= 0 (inf: unbreakable), got {value!r}")
    return threshold


def project_impact(data: RuntimeData, point, impulse, threshold: float | None = None, body: int = 0) -> ImpactResult:
    """Project an impact onto the fracture modes and group the fragments.

    Parameters
    ----------
    data : RuntimeData
        A loaded runtime file (:func:`fracture_cli.runtime.format.load_runtime`).
    point : (3,) float
        Contact point in the asset's model space and units (the same space as
        ``data.sites``); finite.
    impulse : (3,) float
        Impulse vector in model-space axes; any unit, the same as ``threshold``;
        finite. Only ``impulse / threshold`` matters.
    threshold : float, optional (default ``data.default_threshold``; the body's level's with ``body``)
        Toughness, >= 0 (``inf``: nothing breaks): an edge breaks when the
        displacement jump across it exceeds this.
    body : int, optional (default 0: the whole asset)
        With feature ``"levels"`` (docs/FORMAT.md section 14): the body that answers, one that breaks a
        fragment into its children (:func:`fracture_cli.runtime.levels.body_of`); the answer is then in
        that body's local indices (child ``j`` is fragment ``children_range(data, body)[j]``).

    Returns
    -------
    ImpactResult

    Raises
    ------
    ImpactArgumentError
        (a :class:`ValueError`) if ``point`` or ``impulse`` is not three finite
        numbers, or ``threshold`` is NaN or negative.

    Notes
    -----
    ALGORITHM.md section 4; the exact steps are in docs/FORMAT.md ("Runtime
    algorithm"). Scale-invariant: with ``m = max |n_i|`` the impulse is
    normalised first (``n' = n / m``), the jumps computed from ``n'`` are
    compared with ``T / m`` (in double: overflow to inf breaks nothing,
    underflow to 0 breaks every nonzero jump), and the reported
    displacements and coefficients are ``m`` times those of ``n'``. So
    impulses of 1e-170 or 1e200 give the same groups as any other impulse
    with the same ``impulse / threshold``; a zero impulse breaks nothing.
    """
    return apply_hit(body_view(data, body), None, point, impulse, threshold)


def apply_hit(data: RuntimeData, state: np.ndarray | None, point, impulse, threshold: float | None) -> ImpactResult:
    """One hit on ``data`` with the damage ``state`` (updated in place; None: a fresh state thrown away).

    Inputs are validated before ``state`` changes (an invalid hit leaves it as it was). Public entry points:
    :func:`project_impact` (stateless) and :func:`fracture_cli.runtime.damage.hit`.
    """
    prep = prepare(data)
    x, y, z = _vector3(point, "point")
    nx, ny, nz = _vector3(impulse, "impulse")
    threshold = _threshold(data.default_threshold if threshold is None else threshold)

    site = _nearest(prep, x, y, z)
    m = max(abs(nx), abs(ny), abs(nz))
    if m == 0.0:
        no = np.zeros(prep.e, dtype=bool)
        return _answer(prep, state, no, no, site, np.zeros((prep.p, prep.d)), np.zeros(prep.k))
    nx, ny, nz = nx / m, ny / m, nz / m
    if prep.d == 1:
        alpha = prep.B1[site] * math.sqrt(nx * nx + ny * ny + nz * nz)
    else:
        alpha = prep.B[site] @ np.array((nx, ny, nz))
    out = alpha @ prep.WdW
    displacement = out[: prep.split].reshape(prep.p, prep.d)
    limit = threshold / m  # Python floats: overflow gives inf (nothing breaks), underflow 0.0
    measure, bound = _measure(prep, out[prep.split:], site, nx, ny, nz, limit)
    if prep.stress is not None and prep.stress.sharing is not None:  # section 11.1: the struck fragment's bonds
        measure = prep.stress.sharing.share(site, measure, np.asarray(bound), None if state is None else state <= 0.0)
    now_broken = measure > bound
    if prep.damage is None and state is None:  # version 1 and "stress" alone: nothing can crack
        now_cracked = np.zeros(prep.e, dtype=bool)
    else:
        now_cracked = measure > prep.crack_level * bound  # one product (docs/FORMAT.md section 12.4)
        if state is None:
            state = np.ones(prep.e)
        _damage(prep, state, measure, bound, now_broken, now_cracked)
    return _answer(prep, state, now_broken, now_cracked, site, m * displacement, m * alpha)


def _measure(prep: _Prepared, jumps: np.ndarray, site: int, nx: float, ny: float, nz: float,
             limit: float) -> tuple[np.ndarray, np.ndarray | float]:
    """Every bond's measure ``a`` (e,) and limit ``b`` (scalar or (e,)) of docs/FORMAT.md section 12.4, step 2."""
    if prep.stress is not None:  # criterion "stress" (section 11): tension g against t * S, 0 off the site's list
        bonds, g = prep.stress.gains(site, nx, ny, nz)
        measure = np.zeros(prep.e)
        measure[bonds] = g
        return measure, limit * prep.stress.strength
    if prep.d == 1:
        return np.abs(jumps), limit
    j = jumps.reshape(prep.e, 3)
    # The same order of operations as docs/FORMAT.md (and the engine readers): sqrt(j0^2 + j1^2 + j2^2).
    return np.sqrt(j[:, 0] * j[:, 0] + j[:, 1] * j[:, 1] + j[:, 2] * j[:, 2]), limit


def _damage(prep: _Prepared, health: np.ndarray, measure: np.ndarray, bound: np.ndarray | float,
            now_broken: np.ndarray, now_cracked: np.ndarray) -> None:
    """Step 3 of docs/FORMAT.md section 12.4 on ``health`` (e,) float64, in place and in the spec's order."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # a / b, minus c, times q, subtracted: evaluated everywhere, used only where a bond cracked
        # (where 0 < b < inf, so the quotient is finite there).
        weakened = health - prep.rate * (measure / bound - prep.crack_level)
    updated = np.where(now_broken, 0.0, np.where(now_cracked, weakened, health))
    updated = np.where(updated < 0.0, 0.0, updated)
    alive = health > 0.0
    health[alive] = updated[alive]


def _answer(prep: _Prepared, health: np.ndarray | None, now_broken: np.ndarray, now_cracked: np.ndarray, site: int,
            displacement: np.ndarray, alpha: np.ndarray) -> ImpactResult:
    """Step 4 of docs/FORMAT.md section 12.4: broken, cracked, groups and anchored after the update."""
    if health is None:
        broken, cracked = now_broken, np.zeros(prep.e, dtype=bool)
    else:
        broken = health <= 0.0
        cracked = ~broken & (now_cracked | (health < 1.0))
    labels = prep.forest.labels(broken) if broken.any() else prep.forest.whole
    anchored = np.zeros(prep.p, dtype=bool)
    if prep.anchored is not None and len(prep.anchored):
        held = np.zeros(prep.p, dtype=bool)
        held[labels[prep.anchored]] = True
        anchored = held[labels]
    return ImpactResult(groups=labels.astype(np.int32), displacement=displacement, broken=broken, site=site,
                        alpha=alpha, cracked=cracked, anchored=anchored)
