"""A broad phase for boxes of very different sizes: one uniform grid per size class.

One :class:`~fracture_cli.geometry.trigeom.BoxGrid` over boxes of mixed size needs a
cell about the size of the small ones, and every large box is then entered in
every cell it covers: the fragments of the 1M-triangle bench input (tiny
surface triangles, fault triangles across the whole fragment) put 45M entries
in the grid of :func:`~fracture_cli.stages.fragments.interfaces.coincident_faces`
(3 GB of keys and temporaries, half a minute to build and query).
:class:`LevelGrid` sorts the boxes into classes by extent, each class on a grid
whose cells are about its size, so no box covers more than a few cells per
axis; it returns the same pairs in the same order as the single grid would.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.trigeom import BoxGrid, default_cell

# A box of level k spans at most this many cells of its level's grid per axis (plus one for alignment);
# the cells of level k are _RATIO ** k times the base cell.
_SPAN = 4.0
_RATIO = 4  # an int: _RATIO ** k is exact
# Candidates (query, box sharing a cell) one BoxGrid.query may hold at once: its temporaries take ~100 bytes each.
# A fan of slivers (a UV sphere's pole) puts ~1,500 boxes in one cell, and every one of their centres meets all.
_CANDIDATES = 2_000_000


class LevelGrid:
    """Boxes indexed by size class; :meth:`query` equals ``BoxGrid(boxes, default_cell(boxes)).query``.

    Parameters
    ----------
    boxes : (m, 2, 3) float
        Boxes to index (lower and upper corners).
    """

    def __init__(self, boxes: np.ndarray):
        self.boxes = np.asarray(boxes, dtype=np.float64)
        self.cell = default_cell(self.boxes)
        self.origin = self.boxes[:, 0].min(axis=0) - self.cell  # as BoxGrid's: its cells give the pair order
        self.lo_cells = np.floor((self.boxes[:, 0] - self.origin) / self.cell).astype(np.int64)
        extent = (self.boxes[:, 1] - self.boxes[:, 0]).max(axis=1)
        # The smallest k with _SPAN * cell * _RATIO**k >= extent, by products (a log rounds by the CPU).
        level = np.zeros(len(self.boxes), dtype=np.int64)
        reach = _SPAN * self.cell
        while np.any(grow := extent > reach):
            level[grow] += 1
            reach *= _RATIO
        self.levels = [(members, BoxGrid(self.boxes[members], self.cell * _RATIO ** int(k)))
                       for k in np.unique(level) for members in [np.flatnonzero(level == k)]]

    def query(self, boxes: np.ndarray, pad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The pairs :meth:`~fracture_cli.geometry.trigeom.BoxGrid.query` gives for the same ``boxes`` (q, 2, 3) and
        ``pad``, and in the single grid's order: by query, then by the grid cell holding the corner
        ``max(lo_i, lo_j)`` (x fastest over the query's cells), then by ``j``; ``i, j`` (p,) int64.
        """
        return self.in_order(boxes, pad, *self.pairs(boxes, pad))

    def pairs(self, boxes: np.ndarray, pad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The pairs of :meth:`query` (p,) int64 in no particular order (sort what is kept with :meth:`in_order`)."""
        grown = _grown(boxes, pad)
        found = [(q + chunk.start, members[j]) for members, grid in self.levels
                 for chunk in _chunks(grid, grown) for q, j in [_level_query(grid, grown[chunk.start:chunk.stop])]]
        q = np.concatenate([f[0] for f in found]) if found else np.zeros(0, dtype=np.int64)
        j = np.concatenate([f[1] for f in found]) if found else np.zeros(0, dtype=np.int64)
        return q, j

    def in_order(self, boxes: np.ndarray, pad: float, q: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distinct pairs ``q, j`` (p,) of :meth:`pairs` (or some of them) for the same ``boxes`` and ``pad``,
        sorted as :meth:`query` returns them (sorting only the pairs a caller keeps costs less)."""
        grown = _grown(boxes, pad)
        lo = np.floor((grown[:, 0] - self.origin) / self.cell).astype(np.int64)
        span = np.floor((grown[:, 1] - self.origin) / self.cell).astype(np.int64) - lo + 1
        local = np.maximum(lo[q], self.lo_cells[j]) - lo[q]
        rank = local[:, 0] + span[q, 0] * (local[:, 1] + span[q, 1] * local[:, 2])
        # Pairs are distinct, so (q, rank, j) is too: one int64 key sorts them as the lexsort does, faster.
        ranks = int(span.prod(axis=1).max()) if len(span) else 1
        if len(grown) * ranks * len(self.boxes) < 2 ** 62:
            order = np.argsort((q * ranks + rank) * len(self.boxes) + j)
        else:
            order = np.lexsort((j, rank, q))
        return q[order], j[order]


def _grown(boxes: np.ndarray, pad: float) -> np.ndarray:
    """Query boxes (q, 2, 3) grown by ``pad``: the same arithmetic as BoxGrid.query's, so the same cells."""
    grown = np.asarray(boxes, dtype=np.float64).copy()
    grown[:, 0] -= pad
    grown[:, 1] += pad
    return grown


def _level_query(grid: BoxGrid, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pairs ``grid.query(boxes)`` finds (p,) int64, in another order (:meth:`LevelGrid.query` sorts them).

    Queries inside one cell of ``grid`` (a face centroid's point box, nearly always) are looked up in that
    cell alone: each box there is a candidate once, so BoxGrid's once-per-pair cell test and its (p, 3) cell
    and (p, 2, 3) box temporaries are not needed; the overlap test is the same comparisons, axis by axis.
    The other queries go through :meth:`~fracture_cli.geometry.trigeom.BoxGrid.query`.
    """
    lo, hi = grid._cells(boxes)
    single = np.flatnonzero(np.all(lo == hi, axis=1))
    other = np.flatnonzero(~np.all(lo == hi, axis=1))
    ids, keys = grid._expand(boxes[single])
    left = np.searchsorted(grid.keys, keys, side="left")
    count = np.searchsorted(grid.keys, keys, side="right") - left
    q = np.repeat(single[ids], count)
    start = np.cumsum(count) - count
    j = grid.ids[np.repeat(left - start, count) + np.arange(int(count.sum()), dtype=np.int64)]
    keep = np.ones(len(q), dtype=bool)
    for axis in range(3):
        keep &= boxes[q, 0, axis] <= grid.boxes[j, 1, axis]
        keep &= grid.boxes[j, 0, axis] <= boxes[q, 1, axis]
    q, j = q[keep], j[keep]
    if len(other):
        qo, jo = grid.query(boxes[other])
        q, j = np.concatenate([q, other[qo]]), np.concatenate([j, jo])
    return q, j


def _chunks(grid: BoxGrid, boxes: np.ndarray) -> list[range]:
    """Consecutive ranges of the query ``boxes`` with at most :data:`_CANDIDATES` candidates each in ``grid``
    (a query with more is a range of its own)."""
    ids, keys = grid._expand(boxes)
    count = np.searchsorted(grid.keys, keys, side="right") - np.searchsorted(grid.keys, keys, side="left")
    total = np.cumsum(np.bincount(ids, weights=count, minlength=len(boxes)))
    ranges, start = [], 0
    while start < len(boxes):
        before = total[start - 1] if start else 0.0
        stop = max(int(np.searchsorted(total, before + _CANDIDATES, side="right")), start + 1)
        ranges.append(range(start, stop))
        start = stop
    return ranges
