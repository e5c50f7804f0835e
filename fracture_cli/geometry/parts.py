"""Which fragment a point lands on, from the fragments' convex collision parts (what a game's collider reports).

A part's hull gives face planes ``(n, c)`` (unit ``n``, inside ``n . x + c <= 0``); a point's value for a
part is the largest ``n . x + c`` over its planes (0 on the part's surface, negative inside, outside a
lower bound of the distance), and the point lands on the fragment with the smallest value over its
parts (ties: the smallest index). The break atlas and the stress criterion's blocks model use it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def part_planes(parts: Sequence[Sequence[np.ndarray]]) -> tuple[tuple[np.ndarray, ...], ...] | None:
    """Per fragment, each convex part's face planes ``(m, 4)``: rows ``(n, c)``; None when a fragment has no part.

    Parameters
    ----------
    parts : sequence of sequence of (k, 3) float
        Every fragment's parts' corners (any one space; points are compared in it). Flat parts are skipped:
        they hold no volume, so no hit lands inside them.
    """
    # on first use: qhull loads only where a point is placed on the parts
    from scipy.spatial import ConvexHull, QhullError

    out = []
    for fragment_parts in parts:
        planes = []
        for corners in fragment_parts:
            try:
                planes.append(ConvexHull(np.asarray(corners, dtype=np.float64)).equations)
            except (QhullError, ValueError):
                continue
        if not planes:
            return None
        out.append(tuple(planes))
    return tuple(out)


def gameready_parts(gameready: dict[str, np.ndarray], p: int) -> list[list[np.ndarray]]:
    """The corners of every fragment's parts from the runtime file's game-ready arrays (docs/FORMAT.md 9)."""
    vertices = np.asarray(gameready["collision_vertices"], dtype=np.float64)
    part_ptr = np.asarray(gameready["collision_part_offsets"], dtype=np.int64)
    fragment_ptr = np.asarray(gameready["collision_fragment_offsets"], dtype=np.int64)
    return [[vertices[part_ptr[i]:part_ptr[i + 1]] for i in range(int(fragment_ptr[j]), int(fragment_ptr[j + 1]))]
            for j in range(p)]


def nearest_part(planes: tuple[tuple[np.ndarray, ...], ...], point: np.ndarray) -> int:
    """The fragment (index) whose parts ``point`` (3,) lands on (module docstring)."""
    x = np.append(np.asarray(point, dtype=np.float64).reshape(3), 1.0)
    values = [min((float((part @ x).max()) for part in fragment), default=np.inf) for fragment in planes]
    return int(np.argmin(values))


def nearest_parts(planes: tuple[tuple[np.ndarray, ...], ...], points: np.ndarray) -> np.ndarray:
    """:func:`nearest_part` of every point (s, 3): (s,) int64."""
    return np.array([nearest_part(planes, x) for x in np.asarray(points, dtype=np.float64).reshape(-1, 3)],
                    dtype=np.int64)
