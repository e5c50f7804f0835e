"""meshfix.rows returns what np.unique does."""

import numpy as np
import pytest

from fracture_cli.geometry.rows import unique_inverse, unique_rows, used_vertices


@pytest.mark.parametrize("rows", [
    np.random.default_rng(0).integers(0, 5, (2000, 3)),
    np.random.default_rng(1).integers(0, 3, (500, 2)).astype(np.float64),
    np.array([[0.0, 1.0], [-0.0, 1.0], [0.0, 1.0], [2.0, -0.0]]),  # -0.0 equals 0.0, as in np.unique
    np.random.default_rng(2).normal(size=(300, 3)).round(1),
    np.zeros((0, 3)),
])
def test_unique_rows_is_np_unique(rows):
    expected = np.unique(rows, axis=0, return_index=True, return_inverse=True, return_counts=True)
    got = unique_rows(rows, return_index=True, return_inverse=True, return_counts=True)
    for e, g in zip(expected, got):
        assert e.dtype == g.dtype
        assert np.array_equal(e.reshape(g.shape), g)
    assert np.array_equal(np.signbit(expected[0]), np.signbit(got[0]))
    assert np.array_equal(unique_rows(rows), expected[0])


def test_unique_inverse_and_used_vertices():
    keys = np.random.default_rng(3).integers(0, 1000, 5000)
    u, inv = unique_inverse(keys)
    eu, einv = np.unique(keys, return_inverse=True)
    assert np.array_equal(u, eu) and np.array_equal(inv, einv)
    F = np.random.default_rng(4).integers(0, 50, (40, 3))
    assert np.array_equal(used_vertices(F), np.unique(F))
    assert np.array_equal(used_vertices(F, 100), np.unique(F))
    assert len(used_vertices(np.zeros((0, 3), dtype=np.int64))) == 0
