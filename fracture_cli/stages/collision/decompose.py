"""Approximate convex decomposition of one fragment by best-first plane cuts (the collision parts' first step).

The part whose hull wastes the most volume is cut by the plane (principal and
coordinate axes, seven offsets each) that minimises the hull volume of the two
halves, until every part is nearly convex or ``max_parts`` is reached. Parts
of one fragment lie in disjoint cells of the partition, so their hulls cannot
overlap. Deterministic: fixed candidate order, stable tie-breaks.
"""

from __future__ import annotations

from collections.abc import Callable

import manifold3d
import numpy as np
from scipy.spatial import ConvexHull, QhullError

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.hulls import MIN_PART_VOLUME, hull_of, mesh_of
from fracture_cli.geometry.mass_kernels import mass_properties
from fracture_cli.geometry.meshtopo import unique_edges
from fracture_cli.stages.collision import kernels

# A coordinate axis is not tried as a cut normal when a principal axis is this close (cosine, ~15 degrees).
_SAME_AXIS = 0.966
# Offsets tried along each candidate normal, as fractions of the part's extent.
_CUT_FRACTIONS = np.arange(1, 8) / 8.0
# Parts with more vertices get a lower bound of each candidate cut's cost first, from a thinned point set ...
_BOUND_VERTICES = 2000
# ... of one point per cell of this fraction of the part's diagonal (the cut's points: per half cell).
_BOUND_CELLS = 24
# A bound is trusted up to this relative error: a hull of fewer points has no more volume, but the costs are
# manifold3d's hull volumes, which differ from qhull's by up to ~2e-4 (its hull merges near-flat corners).
_BOUND_SLACK = 1e-3


def convex_decomposition(solid: manifold3d.Manifold, max_parts: int, concavity: float,
                         intrusion: Callable[[manifold3d.Manifold], float] | None = None,
                         max_intrusion: float = 0.05) -> list[manifold3d.Manifold]:
    """Approximate convex decomposition of a closed solid by best-first plane cuts.

    Parameters
    ----------
    solid : manifold3d.Manifold
        One closed body.
    max_parts : int
        At most this many parts.
    concavity : float
        A part is final when its hull volume is at most ``(1 + concavity)``
        times its volume and its hull reaches into the neighbours' material
        by at most ``max_intrusion`` of its volume.
    intrusion : callable, optional
        ``intrusion(hull) -> float``: the volume of a part's hull inside other
        fragments (neighbours are ignored without it).
    max_intrusion : float, optional (default 0.05)
        See ``concavity``.

    Returns
    -------
    list of manifold3d.Manifold
        The (concave) pieces of material, in a deterministic order; each
        collision part is the hull of one. One piece, the solid itself, when it
        is nearly convex.
    """
    return decomposition_cells(solid, max_parts, concavity, intrusion, max_intrusion)[0]


def decomposition_cells(solid: manifold3d.Manifold, max_parts: int, concavity: float,
                        intrusion: Callable[[manifold3d.Manifold], float] | None = None,
                        max_intrusion: float = 0.05) -> tuple[list[manifold3d.Manifold], list[int]]:
    """:func:`convex_decomposition` and the cell of the partition each piece lies in (a list of ints).

    Pieces in different cells cannot overlap, nor can their hulls (a cell is
    convex); pieces of one cell (the components of one side of a cut, or of
    the solid) may interlock. A piece that shares its cell is cut within that
    cell: its halves keep the cell's number, since the other pieces there may
    reach into either half-space of the cut.
    """
    leaves, cells, _ = decomposition_hulls(solid, max_parts, concavity, intrusion, max_intrusion)
    return leaves, cells


def decomposition_hulls(solid: manifold3d.Manifold, max_parts: int, concavity: float,
                        intrusion: Callable[[manifold3d.Manifold], float] | None = None,
                        max_intrusion: float = 0.05) -> tuple[list[manifold3d.Manifold], list[int],
                                                              list[manifold3d.Manifold]]:
    """:func:`decomposition_cells` and the convex hull of each piece (computed once: a dense piece's hull is
    a large share of the decomposition's time)."""
    def excess(part: manifold3d.Manifold, hull: manifold3d.Manifold) -> float:
        # How far a part is from acceptable, as a volume (> 0: cut it); the worst part is cut first.
        volume = part.volume()
        own = hull.volume() - (1.0 + concavity) * volume
        if intrusion is None:
            return own
        return max(own, intrusion(hull) - max_intrusion * volume)

    leaves = components(solid)
    hulls = [p.hull() for p in leaves]
    cells = [0] * len(leaves)
    waste = [excess(p, h) for p, h in zip(leaves, hulls)]
    next_cell = 1
    while len(leaves) < max_parts:
        worst = int(np.argmax(waste))
        if waste[worst] <= 0:
            break
        sides = _best_cut(leaves[worst], hulls[worst])
        count = sum(len(side) for side in sides) if sides else 0
        if count < 2 or len(leaves) - 1 + count > max_parts:
            waste[worst] = -np.inf  # final: no cut helps, or no room for its pieces
            continue
        assert sides is not None  # count >= 2
        pieces = [p for side in sides for p in side]
        leaves[worst:worst + 1] = pieces
        hulls[worst:worst + 1] = [p.hull() for p in pieces]
        if cells.count(cells[worst]) == 1:
            # Alone in its cell: the cut splits the cell into two cells, one per side, that no other piece is in.
            cells[worst:worst + 1] = [next_cell + k for k, side in enumerate(sides) for _ in side]
            next_cell += len(sides)
        else:
            # Its cell also holds other pieces (components of one side of an earlier cut, which may interlock):
            # they can reach into either side of this cut, so the halves stay in that cell, with them.
            cells[worst:worst + 1] = [cells[worst]] * len(pieces)
        waste[worst:worst + 1] = [excess(p, h) for p, h in zip(pieces, hulls[worst:worst + len(pieces)])]
    return leaves, cells, hulls


def components(solid: manifold3d.Manifold) -> list[manifold3d.Manifold]:
    """Connected components of a solid with volume, largest first (ties by centre), deterministic."""
    parts = [p for p in solid.decompose() if p.volume() > MIN_PART_VOLUME]
    return sorted(parts, key=lambda p: (-round(p.volume(), 15), tuple(np.round(p.bounding_box()[:3], 12))))


def _best_cut(part: manifold3d.Manifold,
              hull: manifold3d.Manifold) -> tuple[list[manifold3d.Manifold], list[manifold3d.Manifold]] | None:
    """The pieces above and below the candidate plane with the smallest total hull volume; None if no cut helps.

    A part with many vertices first gets a lower bound of every candidate's cost (:func:`_cost_bounds`); the
    costs are then computed in the order of the bounds until a bound exceeds the best cost found. The others
    cannot win, so the choice is that of computing every cost (the smallest, the first candidate on a tie).
    """
    V, F = mesh_of(part)
    # (a row-wise np.unique took 8 s of the 1M bench bake)
    edges = np.ascontiguousarray(unique_edges(F), dtype=np.int64)
    props = mass_properties(V, F)
    _, axes = props.principal()
    # (normal, offset, heights of the vertices along the normal, points where the edges cross the plane), in
    # the fixed order; the crossings once, for the bound and the cost alike, all offsets of a normal at once
    # (compiled: numpy's overhead per offset over a part's few hundred edges was most of their time).
    candidates = []
    for normal in _cut_normals(axes):
        s = V @ normal
        lo, hi = float(s.min()), float(s.max())
        offsets = lo + (hi - lo) * _CUT_FRACTIONS
        cut, start = kernels.cut_points(V, edges, s, offsets)
        candidates += [(normal, offset, s, cut[start[k]:start[k + 1]]) for k, offset in enumerate(offsets)]
    bounds = _cost_bounds(V, candidates) if len(V) > _BOUND_VERTICES else np.zeros(len(candidates))
    best, best_cost = None, hull.volume() * (1.0 - tol.TIE)
    for index in np.argsort(bounds, kind="stable").tolist():
        if bounds[index] * (1.0 - _BOUND_SLACK) > best_cost:
            break  # this bound and every later one exceed the best cost
        normal, offset, s, cut = candidates[index]
        cost = _halves_hull_volume(V, s, offset, cut)
        if cost < best_cost or (cost == best_cost and best is not None and index < best[0]):
            best, best_cost = (index, normal, offset), cost
    if best is None:
        return None
    above, below = part.split_by_plane(best[1], best[2])
    return components(above), components(below)


def _cost_bounds(V: np.ndarray, candidates: list) -> np.ndarray:
    """Lower bounds (c,) of the candidates' costs (:func:`_halves_hull_volume`): hull volumes of thinned halves.

    A half's hull holds the hull of any subset of its points: here the part's vertices thinned to one per grid
    cell (1 / :data:`_BOUND_CELLS` of the part's diagonal; the one farthest from the centroid, the likeliest
    hull corner) on that side, and the cut's crossing points thinned to one per half cell. A bound then costs
    a hull of a few hundred points, not of half the (dense) surface: the cheap bounds are within ~0.1 % of the
    costs, so the exact cost is computed for one or two candidates per cut.
    """
    diagonal = float(np.linalg.norm(np.ptp(V, axis=0)))
    thinned = _thin(V, diagonal / _BOUND_CELLS)
    bounds = np.empty(len(candidates))
    for index, (normal, offset, _, cut) in enumerate(candidates):
        s = thinned @ normal
        ring = _thin(cut, 0.5 * diagonal / _BOUND_CELLS)
        bounds[index] = (_hull_volume(np.vstack([thinned[s > offset], ring]))
                         + _hull_volume(np.vstack([thinned[s <= offset], ring])))
    return bounds


def _hull_volume(points: np.ndarray) -> float:
    """Volume of the convex hull of points (k, 3) by qhull; 0 for a flat set.

    qhull, not manifold3d, for the bounds: manifold3d's hull of a few hundred points with many coplanar ones
    (the cut's ring, a planar fault) came out 5 % too large, which would make a bound exceed the cost. Joggled
    input (QJ, a fixed seed): the cut's coplanar ring made qhull's exact merging 7x slower, and the joggle
    changes the volume by ~1e-10 of it, far inside :data:`_BOUND_SLACK`.
    """
    if len(points) < 4:
        return 0.0
    try:
        return float(ConvexHull(points, qhull_options="QJ").volume)
    except QhullError:
        return 0.0


def _cut_normals(axes: np.ndarray) -> np.ndarray:
    """Candidate cut normals: the principal axes (columns of ``axes``), then each coordinate axis not within
    :data:`_SAME_AXIS` of one of them (an asset's own axes often follow its structure: legs, seat, walls)."""
    principal = axes.T
    extra = [e for e in np.eye(3) if np.abs(principal @ e).max() < _SAME_AXIS]
    return np.vstack([principal] + extra) if extra else principal


def _thin(points: np.ndarray, cell: float) -> np.ndarray:
    """In each grid cell of size ``cell``, the point (k, 3) farthest from the points' centroid (the lowest
    index on ties), in their order: a subset spread like the set, biased to its hull corners."""
    if len(points) == 0:
        return points
    key = np.floor((points - points.min(axis=0)) / cell).astype(np.int64)
    key = (key[:, 0] * (1 << 21) + key[:, 1]) * (1 << 21) + key[:, 2]
    offset = points - points.mean(axis=0)
    order = np.lexsort((-np.einsum("ij,ij->i", offset, offset), key))
    first = order[np.r_[True, key[order][1:] != key[order][:-1]]]
    return points[np.sort(first)]


def _halves_hull_volume(V: np.ndarray, s: np.ndarray, offset: float, cut: np.ndarray) -> float:
    """Total hull volume of the two halves of a closed mesh cut at ``s == offset``.

    The corners of a half are the mesh vertices on its side plus the points
    ``cut`` (c, 3) where edges cross the plane (:func:`.kernels.cut_points`), so each
    half's hull comes from points alone, without a boolean.
    """
    total = 0.0
    for points in kernels.split_points(V, s, float(offset), cut):
        if len(points) >= 4:
            total += hull_of(points).volume()
    return total
