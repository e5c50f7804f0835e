"""A non-planar hole patch: the triangulation of a boundary loop of least total area (no new vertices).

A hole whose outline folds over itself in every plane (it wraps around a thin
stem, an ear's rim, a nostril) has no fan and no flat ear-clipped patch. The
least-area triangulation of the loop's own vertices still closes it with a
surface that follows the outline in 3-d, the way a soap film would; the
caller checks it against the surface (and itself) before using it.
"""

from __future__ import annotations

import numpy as np

# Loops with more vertices than this get no least-area patch: the search is cubic in the loop's length
# (0.1 s at 150 vertices), and a hole that large is not small (see holes.FillOptions.small_hole).
MAX_LOOP = 200


def least_area_patch(loop: np.ndarray, P: np.ndarray) -> np.ndarray | None:
    """Triangulate a closed loop with its own vertices so that the total area is least.

    Parameters
    ----------
    loop : (k,) int64
        Vertex ids of the loop, in the direction of the surface's boundary edges.
    P : (k, 3) float64
        Their positions.

    Returns
    -------
    (k - 2, 3) int64 or None
        Triangles over the ids in ``loop``, oriented as a cap of the surface
        (each boundary edge ``a -> b`` run ``b -> a``); None when the loop is
        longer than :data:`MAX_LOOP` or shorter than 3.

    Notes
    -----
    The classic dynamic programme over sub-polygons (Barequet and Sharir 1995;
    Liepa 2003, "Filling holes in meshes", without the dihedral term):
    ``cost[i, j] = min_k cost[i, k] + cost[k, j] + area(i, k, j)``, ``i < k < j``.
    Ties go to the smallest ``k``, so the patch is the same on every machine.
    """
    k = len(loop)
    if k < 3 or k > MAX_LOOP:
        return None
    P = np.asarray(P, dtype=np.float64)
    cost = np.zeros((k, k))
    split = np.zeros((k, k), dtype=np.int64)
    for gap in range(2, k):
        i = np.arange(k - gap)
        j = i + gap
        mid = i[:, None] + np.arange(1, gap)[None, :]  # (k - gap, gap - 1): every k between i and j
        a, b, c = P[i][:, None, :], P[mid], P[j][:, None, :]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=2)
        total = cost[i[:, None], mid] + cost[mid, j[:, None]] + area
        best = np.argmin(total, axis=1)
        cost[i, j] = total[np.arange(len(i)), best]
        split[i, j] = mid[np.arange(len(i)), best]
    triangles: list[tuple[int, int, int]] = []
    stack = [(0, k - 1)]
    while stack:
        lo, hi = stack.pop()
        if hi - lo < 2:
            continue
        m = int(split[lo, hi])
        # The loop runs lo -> m -> hi; the cap runs it backwards.
        triangles.append((int(loop[hi]), int(loop[m]), int(loop[lo])))
        stack += [(lo, m), (m, hi)]
    return np.array(sorted(triangles), dtype=np.int64)
