"""Approximate convex decomposition of one fragment by best-first plane cuts (the collision parts' first step).

The part whose hull wastes the most volume is cut by the plane (principal and
coordinate axes, seven offsets each) that minimises the hull volume of the two
halves, until every part is nearly convex or ``max_parts`` is reached. Parts
of one fragment lie in disjoint cells of the partition, so their hulls cannot
overlap. Deterministic: fixed candidate order, stable tie-breaks.
"""

from __future__ import annotations

import manifold3d
import numpy as np

from fracture_cli.gameready.hulls import MIN_PART_VOLUME, hull_of, mesh_of
from fracture_cli.gameready.mass import mass_properties
from fracture_cli.meshtopo import unique_edges

# A coordinate axis is not tried as a cut normal when a principal axis is this close (cosine, ~15 degrees).
_SAME_AXIS = 0.966
# Offsets tried along each candidate normal, as fractions of the part's extent.
_CUT_FRACTIONS = np.arange(1, 8) / 8.0


def convex_decomposition(solid: manifold3d.Manifold, max_parts: int, concavity: float,
                         intrusion=None, max_intrusion: float = 0.05) -> list[manifold3d.Manifold]:
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


def decomposition_cells(solid: manifold3d.Manifold, max_parts: int, concavity: float, intrusion=None,
                        max_intrusion: float = 0.05) -> tuple[list[manifold3d.Manifold], list[int]]:
    """:func:`convex_decomposition` and the cell of the partition each piece lies in (a list of ints).

    Pieces in different cells cannot overlap, nor can their hulls (a cell is
    convex); pieces of one cell (the components of one side of a cut, or of
    the solid) may interlock.
    """
    def excess(part: manifold3d.Manifold) -> float:
        # How far a part is from acceptable, as a volume (> 0: cut it); the worst part is cut first.
        hull, volume = part.hull(), part.volume()
        own = hull.volume() - (1.0 + concavity) * volume
        if intrusion is None:
            return own
        return max(own, intrusion(hull) - max_intrusion * volume)

    leaves = components(solid)
    cells = [0] * len(leaves)
    waste = [excess(p) for p in leaves]
    next_cell = 1
    while len(leaves) < max_parts:
        worst = int(np.argmax(waste))
        if waste[worst] <= 0:
            break
        sides = _best_cut(leaves[worst])
        count = sum(len(side) for side in sides) if sides else 0
        if count < 2 or len(leaves) - 1 + count > max_parts:
            waste[worst] = -np.inf  # final: no cut helps, or no room for its pieces
            continue
        leaves[worst:worst + 1] = [p for side in sides for p in side]
        cells[worst:worst + 1] = [next_cell + k for k, side in enumerate(sides) for _ in side]
        next_cell += len(sides)
        waste[worst:worst + 1] = [excess(p) for side in sides for p in side]
    return leaves, cells


def components(solid: manifold3d.Manifold) -> list[manifold3d.Manifold]:
    """Connected components of a solid with volume, largest first (ties by centre), deterministic."""
    parts = [p for p in solid.decompose() if p.volume() > MIN_PART_VOLUME]
    return sorted(parts, key=lambda p: (-round(p.volume(), 15), tuple(np.round(p.bounding_box()[:3], 12))))


def _best_cut(part: manifold3d.Manifold):
    """The pieces above and below the candidate plane with the smallest total hull volume; None if no cut helps."""
    V, F = mesh_of(part)
    edges = unique_edges(F)  # (a row-wise np.unique took 8 s of the 1M bench bake)
    props = mass_properties(V, F)
    _, axes = props.principal()
    best, best_cost = None, part.hull().volume() * (1.0 - 1e-9)
    for normal in _cut_normals(axes):
        s = V @ normal
        lo, hi = float(s.min()), float(s.max())
        for offset in lo + (hi - lo) * _CUT_FRACTIONS:
            cost = _halves_hull_volume(V, edges, s, offset)
            if cost < best_cost:
                best, best_cost = (normal, offset), cost
    if best is None:
        return None
    above, below = part.split_by_plane(best[0], best[1])
    return components(above), components(below)


def _cut_normals(axes: np.ndarray) -> np.ndarray:
    """Candidate cut normals: the principal axes (columns of ``axes``), then each coordinate axis not within
    :data:`_SAME_AXIS` of one of them (an asset's own axes often follow its structure: legs, seat, walls)."""
    principal = axes.T
    extra = [e for e in np.eye(3) if np.abs(principal @ e).max() < _SAME_AXIS]
    return np.vstack([principal] + extra) if extra else principal


def _halves_hull_volume(V: np.ndarray, edges: np.ndarray, s: np.ndarray, offset: float) -> float:
    """Total hull volume of the two halves of a closed mesh cut at ``s == offset``.

    The corners of a half are the mesh vertices on its side plus the points
    where edges cross the plane, so each half's hull comes from points alone,
    without a boolean.
    """
    d = s - offset
    da, db = d[edges[:, 0]], d[edges[:, 1]]
    crossing = (da > 0) != (db > 0)
    t = da[crossing] / (da[crossing] - db[crossing])
    cut = V[edges[crossing, 0]] + t[:, None] * (V[edges[crossing, 1]] - V[edges[crossing, 0]])
    total = 0.0
    for side in (d > 0, d <= 0):
        points = np.vstack([V[side], cut])
        if len(points) >= 4:
            total += hull_of(points).volume()
    return total
