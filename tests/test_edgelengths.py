"""fracture_cli.geometry.edgelengths: the longest edges, bit for bit what np.linalg.norm gives."""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.edgelengths import longest_edges


def test_same_bits_as_norm():
    rng = np.random.default_rng(3)
    V = rng.normal(size=(300, 3)) * 10.0 ** rng.integers(-6, 3, size=(300, 1))
    F = rng.integers(0, 300, size=(2000, 3))
    T = V[F]
    assert np.array_equal(longest_edges(V, F), np.linalg.norm(T - T[:, [1, 2, 0]], axis=2).max(axis=1))
    assert longest_edges(V, np.zeros((0, 3), dtype=np.int64)).shape == (0,)
