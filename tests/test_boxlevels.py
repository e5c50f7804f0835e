"""LevelGrid: the pairs of one BoxGrid over boxes of very different sizes, in its order, with few entries."""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.boxlevels import LevelGrid
from fracture_cli.geometry.trigeom import BoxGrid, default_cell


def _mixed_boxes(rng, m):
    # Mostly tiny boxes (surface triangles) and a tenth of large ones (fault triangles across a fragment).
    lo = rng.uniform(-1, 1, (m, 3))
    size = np.where(rng.random(m) < 0.1, rng.uniform(0.2, 1.5, m), rng.uniform(0, 0.01, m))[:, None]
    return np.stack([lo, lo + size * rng.random((m, 3))], axis=1)


def test_same_pairs_in_the_same_order_as_one_grid():
    rng = np.random.default_rng(1)
    for _ in range(6):
        boxes = _mixed_boxes(rng, int(rng.integers(50, 1500)))
        centres = rng.uniform(-1.2, 1.5, (int(rng.integers(10, 1000)), 3))
        queries = np.stack([centres, centres + rng.uniform(0, 0.02, (len(centres), 1)) * rng.random((len(centres), 3))],
                           axis=1)
        pad = float(rng.choice([0.0, 1e-3, 0.05]))
        expected = BoxGrid(boxes, default_cell(boxes)).query(queries, pad)
        found = LevelGrid(boxes).query(queries, pad)
        assert np.array_equal(found[0], expected[0]) and np.array_equal(found[1], expected[1])


def test_large_boxes_take_few_entries():
    boxes = _mixed_boxes(np.random.default_rng(2), 1000)
    single = BoxGrid(boxes, default_cell(boxes))
    levels = LevelGrid(boxes)
    entries = sum(len(grid.ids) for _, grid in levels.levels)
    assert entries * 20 < len(single.ids)
    assert entries <= 5**3 * len(boxes)  # at most 5 cells per axis each


def test_queries_in_chunks_give_the_same_pairs(monkeypatch):
    # A dense cell (a fan of slivers) splits the queries into many small BoxGrid queries: same result.
    import fracture_cli.geometry.boxlevels as boxlevels

    rng = np.random.default_rng(3)
    boxes = _mixed_boxes(rng, 800)
    centres = rng.uniform(-1, 1, (600, 3))
    queries = np.stack([centres, centres], axis=1)
    whole = LevelGrid(boxes).query(queries, 0.01)
    monkeypatch.setattr(boxlevels, "_CANDIDATES", 25)
    chunked = LevelGrid(boxes).query(queries, 0.01)
    assert len(whole[0]) > 100
    assert np.array_equal(whole[0], chunked[0]) and np.array_equal(whole[1], chunked[1])


def _point_and_box_queries(rng: np.random.Generator, n: int, points: float) -> np.ndarray:
    """(n, 2, 3) query boxes around [-1.1, 1.1]^3: about ``points`` of them points, the rest cubes of side 0.05
    (the same random draws, in the same order, as the tests had inline)."""
    centres = rng.uniform(-1.1, 1.1, (n, 3))
    sizes = np.where(rng.random(n) < points, 0.0, 0.05)[:, None]
    return np.stack([centres, centres + sizes], axis=1)


def test_point_queries_match_one_grid():
    # Face centroids (point boxes, most inside one cell: the looked-up-in-one-cell path) next to boxes across cells.
    rng = np.random.default_rng(4)
    boxes = _mixed_boxes(rng, 1200)
    queries = _point_and_box_queries(rng, 3000, 0.9)
    for pad in (0.0, 1e-4):
        expected = BoxGrid(boxes, default_cell(boxes)).query(queries, pad)
        found = LevelGrid(boxes).query(queries, pad)
        assert len(found[0]) > 1000
        assert np.array_equal(found[0], expected[0]) and np.array_equal(found[1], expected[1])


def test_kept_pairs_in_order_are_the_query_filtered():
    # coincident_faces filters the unordered pairs, then orders what it keeps: the query's order, filtered.
    rng = np.random.default_rng(5)
    boxes = _mixed_boxes(rng, 1000)
    queries = _point_and_box_queries(rng, 2000, 0.8)
    grid = LevelGrid(boxes)
    q, j = grid.query(queries, 1e-3)
    pq, pj = grid.pairs(queries, 1e-3)
    assert len(pq) == len(q) and set(zip(pq.tolist(), pj.tolist())) == set(zip(q.tolist(), j.tolist()))
    keep = (pq + pj) % 3 == 0
    kq, kj = grid.in_order(queries, 1e-3, pq[keep], pj[keep])
    expected = (q + j) % 3 == 0
    assert np.array_equal(kq, q[expected]) and np.array_equal(kj, j[expected])
