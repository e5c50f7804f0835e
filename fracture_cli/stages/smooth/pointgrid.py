"""A uniform grid over points, queried with boxes: the broad phase of the sliding containment check.

:class:`fracture_cli.geometry.trigeom.BoxGrid` indexes boxes and reports each pair once
through per-cell bookkeeping; points need none of it. Here the points are
sorted by cell, the cells of one (x, y) column are one run of that order, so
a query box costs one pair of binary searches per column it covers (not per
cell), and the candidates are tested against the box directly.
"""

from __future__ import annotations

import numpy as np


class PointGrid:
    """Points ``P`` (n, 3) indexed in cubic cells of size ``cell``.

    :meth:`query` returns the same pairs as ``BoxGrid(np.stack([P, P], axis=1), cell).query`` (in another
    order): a point is in a box when every coordinate is within the box's closed interval.
    """

    def __init__(self, points: np.ndarray, cell: float):
        self.points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        self.cell = float(cell)
        self.origin = self.points.min(axis=0) - self.cell if len(self.points) else np.zeros(3)
        ijk = self._cells(self.points)
        self.dims = ijk.max(axis=0) + 1 if len(ijk) else np.ones(3, dtype=np.int64)
        keys = (ijk[:, 0] * self.dims[1] + ijk[:, 1]) * self.dims[2] + ijk[:, 2]
        self.order = np.argsort(keys, kind="stable")
        self.keys = keys[self.order]
        self.sorted_points = self.points[self.order]

    def _cells(self, x: np.ndarray) -> np.ndarray:
        # Monotone in x (a subtraction, a division by a positive constant, floor): a point inside a box lies
        # in a cell between the cells of the box's corners.
        return np.floor((x - self.origin) / self.cell).astype(np.int64)

    def query(self, boxes: np.ndarray, pad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Pairs ``(i, j)`` (p,) of query box ``i`` (of ``boxes`` (q, 2, 3), grown by ``pad``) holding point ``j``."""
        boxes = np.asarray(boxes, dtype=np.float64).copy()
        boxes[:, 0] -= pad
        boxes[:, 1] += pad
        empty = np.zeros(0, dtype=np.int64)
        if len(boxes) == 0 or len(self.points) == 0:
            return empty, empty.copy()
        lo = np.maximum(self._cells(boxes[:, 0]), 0)
        hi = np.minimum(self._cells(boxes[:, 1]), self.dims - 1)
        span = np.maximum(hi - lo + 1, 0)
        span[(span == 0).any(axis=1)] = 0
        count = span[:, 0] * span[:, 1]  # (x, y) columns per box
        box = np.repeat(np.arange(len(boxes), dtype=np.int64), count)
        local = np.arange(int(count.sum()), dtype=np.int64) - np.repeat(np.cumsum(count) - count, count)
        nx = span[box, 0]
        column = (lo[box, 0] + local % nx) * self.dims[1] + lo[box, 1] + local // nx
        left = np.searchsorted(self.keys, column * self.dims[2] + lo[box, 2], side="left")
        right = np.searchsorted(self.keys, column * self.dims[2] + hi[box, 2], side="right")
        found = right - left
        qi = np.repeat(box, found)
        at = np.repeat(left, found) + np.arange(int(found.sum()), dtype=np.int64) - np.repeat(np.cumsum(found) - found,
                                                                                               found)
        P = self.sorted_points[at]
        inside = np.all((boxes[qi, 0] <= P) & (P <= boxes[qi, 1]), axis=1)
        return qi[inside], self.order[at[inside]]
