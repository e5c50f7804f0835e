"""The compiled box search (fracture_cli.geometry.trigeom_grid) gives BoxGrid's pairs, in its order."""

import numpy as np
import pytest

from fracture_cli.geometry import trigeom, trigeom_grid


def _mesh(seed):
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(4, 80)), int(rng.integers(2, 200))
    V = rng.random((n, 3)) * rng.choice([1.0, 10.0, 1e-3])
    if seed % 3 == 0:
        V = np.round(V * 4) / 4  # shared coordinates: boxes that touch exactly
    return V, rng.integers(0, n, (m, 3)), rng


@pytest.mark.parametrize("seed", range(40))
def test_self_pairs_are_boxgrids(seed):
    V, F, _ = _mesh(seed)
    boxes = trigeom.triangle_boxes(V, F)
    i, j = trigeom.BoxGrid(boxes, trigeom.default_cell(boxes)).query(boxes)
    keep = i < j
    pairs = trigeom_grid.self_pairs(boxes, *trigeom._grid_cells(boxes))
    assert np.array_equal(pairs, np.stack([i[keep], j[keep]], axis=1))


@pytest.mark.parametrize("seed", range(40))
def test_among_pairs_are_boxgrids(seed):
    V, F, rng = _mesh(seed)
    faces = np.unique(rng.integers(0, len(F), int(rng.integers(1, len(F) + 1))))
    boxes = trigeom.triangle_boxes(V, F)
    qi, j = trigeom.BoxGrid(boxes, trigeom.default_cell(boxes)).query(boxes[faces])
    i = faces[qi]
    expected = np.stack([np.minimum(i, j), np.maximum(i, j)], axis=1)
    expected = np.unique(expected[expected[:, 0] < expected[:, 1]], axis=0).reshape(-1, 2)
    pairs = trigeom_grid.among_pairs(boxes, *trigeom._grid_cells(boxes), faces)
    assert np.array_equal(pairs, expected)


def test_warm_kernels():
    trigeom_grid.warm_kernels()


@pytest.mark.parametrize("seed", range(20))
def test_shared_corners_match_numpy(seed):
    _, F, rng = _mesh(seed)  # random faces, some with a repeated corner
    i, j = rng.integers(0, len(F), 50), rng.integers(0, len(F), 50)
    shared = F[i][:, :, None] == F[j][:, None, :]
    count, first_i, first_j = trigeom_grid.shared_corners(F, i, j)
    assert np.array_equal(count, shared.any(axis=2).sum(axis=1))
    some = count > 0
    assert np.array_equal(first_i[some], np.argmax(shared.any(axis=2), axis=1)[some])
    assert np.array_equal(first_j[some], np.argmax(shared.any(axis=1), axis=1)[some])
