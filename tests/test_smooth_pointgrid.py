"""PointGrid (stages/smooth/pointgrid.py) finds exactly the pairs BoxGrid finds for points as boxes."""

from __future__ import annotations

import numpy as np
import pytest

from fracture_cli.geometry import trigeom
from fracture_cli.stages.smooth.pointgrid import PointGrid


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("pad", [0.0, 0.01])
def test_same_pairs_as_boxgrid(seed, pad):
    rng = np.random.default_rng(seed)
    P = rng.random((5000, 3))
    P[:50] = P[50:100]  # repeated points
    P[:20, 0] = 0.5  # points on one plane, and boxes ending exactly on points below
    boxes = np.sort(rng.random((200, 2, 3)) * 0.3, axis=1) + rng.random((200, 1, 3)) * 0.9 - 0.1
    boxes[:5, 0] = boxes[:5, 1] = P[:5]
    boxes[5:10, 0, 0] = np.minimum(boxes[5:10, 0, 0], 0.5)
    boxes[5:10, 1, 0] = 0.5
    cell = 0.04
    expected = set(zip(*[a.tolist() for a in trigeom.BoxGrid(np.stack([P, P], axis=1), cell).query(boxes, pad)]))
    i, j = PointGrid(P, cell).query(boxes, pad)
    assert len(i) == len(expected) and set(zip(i.tolist(), j.tolist())) == expected


def test_empty_queries_and_boxes_outside():
    grid = PointGrid(np.random.default_rng(0).random((10, 3)), 0.1)
    i, j = grid.query(np.zeros((0, 2, 3)))
    assert len(i) == len(j) == 0
    i, j = grid.query(np.array([[[5.0, 5.0, 5.0], [6.0, 6.0, 6.0]], [[-3.0, -3.0, -3.0], [-2.0, -2.0, -2.0]]]))
    assert len(i) == len(j) == 0
