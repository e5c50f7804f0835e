"""The collision stage's compiled kernels give the bits of the numpy expressions they replaced.

Each kernel spells out numpy's operation order (the einsum of three-term rows, the pinned OpenBLAS products of
three-vectors, numpy's pairwise and row sums); a numpy or OpenBLAS that summed otherwise would change the bakes'
bytes, and these comparisons on random data say where.
"""

from __future__ import annotations

import numpy as np
import pytest

from fracture_cli.geometry import hull_kernels, mass_kernels
from fracture_cli.geometry.hulls import face_planes, hull_mesh
from fracture_cli.geometry.mass import mass_properties
from fracture_cli.geometry.mass_kernels import mass_properties as compiled_mass_properties
from fracture_cli.stages.collision import kernels
from fracture_cli.stages.collision.separate import _Material, _volume_beyond
from fracture_cli.system import detmath

RNG_SEEDS = range(20)


def _points(rng: np.random.Generator, count: int) -> np.ndarray:
    """Points (count, 3) with coordinates over several magnitudes (another summation order shows there)."""
    return rng.normal(size=(count, 3)) * 10.0 ** rng.integers(-3, 2, size=(count, 3))


def _volume_beyond_numpy(material: _Material, normal: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """volume_beyond as numpy expressions (before the kernels)."""
    near = np.flatnonzero(material.centroid @ normal + material.radius > offsets.min())
    h = np.sort(material.triangles[near] @ normal, axis=1)
    weight = material.area[near] @ normal
    full = h[:, 0] > offsets.max()
    result = weight[full] @ h[full].mean(axis=1) - offsets * weight[full].sum()
    reach = ~full & (h[:, 2] > offsets.min())
    x = h[None, reach, :] - offsets[:, None, None]
    x0, x1, x2 = x[..., 0], x[..., 1], x[..., 2]
    mean = (x0 + x1 + x2) / 3.0
    positive = np.zeros_like(mean)
    every = x0 > 0
    positive[every] = mean[every]
    two = ~every & (x1 > 0)
    a0, a1, a2 = x0[two], x1[two], x2[two]
    positive[two] = mean[two] + detmath.cube(np.maximum(-a0, 0.0)) / (3.0 * (a1 - a0) * (a2 - a0))
    one = ~every & ~(x1 > 0) & (x2 > 0)
    a0, a1, a2 = x0[one], x1[one], x2[one]
    positive[one] = detmath.cube(a2) / (3.0 * (a2 - a0) * (a2 - a1))
    return result + positive @ weight[reach]


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_volume_beyond_is_its_numpy_form_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    V, F = hull_mesh(_points(rng, int(rng.integers(8, 200))))
    material = _Material(V, F)
    for _ in range(10):
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        s = V @ normal
        offsets = np.sort(rng.uniform(s.min() - 0.1, s.max() + 0.1, size=int(rng.integers(1, 12))))
        assert np.array_equal(_volume_beyond(material, normal, offsets),
                              _volume_beyond_numpy(material, normal, offsets))


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_cut_and_split_points_are_the_numpy_ones(seed):
    rng = np.random.default_rng(seed)
    V, F = hull_mesh(_points(rng, int(rng.integers(8, 200))))
    edges = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
    s = V @ rng.normal(size=3)
    offsets = s.min() + (s.max() - s.min()) * np.arange(1, 8) / 8.0
    cut, start = kernels.cut_points(V, edges, s, offsets)
    for k, offset in enumerate(offsets):
        sa, sb = s[edges[:, 0]], s[edges[:, 1]]
        crossing = np.flatnonzero((sa > offset) != (sb > offset))
        da, db = sa[crossing] - offset, sb[crossing] - offset
        a = V[edges[crossing, 0]]
        expected = a + (da / (da - db))[:, None] * (V[edges[crossing, 1]] - a)
        assert np.array_equal(cut[start[k]:start[k + 1]], expected)
        above, below = kernels.split_points(V, s, float(offset), expected)
        assert np.array_equal(above, np.vstack([V[s - offset > 0], expected]))
        assert np.array_equal(below, np.vstack([V[s - offset <= 0], expected]))


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_hull_distances_are_the_numpy_ones(seed):
    rng = np.random.default_rng(seed)
    V, F = hull_mesh(_points(rng, int(rng.integers(8, 80))))
    points = _points(rng, int(rng.integers(1, 300)))
    normal, offset = face_planes(V, F)
    heights = points @ normal.T - offset
    outside, planes = hull_kernels.outside_distances(points, V, F)
    assert planes == len(normal)
    assert np.array_equal(outside, heights.max(axis=1))
    assert np.array_equal(hull_kernels.max_beyond(points, normal, offset), heights.max(axis=1))
    for slack in (0.0, 1e-3, 1.0):
        supports = (V @ normal.T).max(axis=0) - offset <= slack
        beyond = (points @ normal.T).min(axis=0) - offset >= -slack
        assert hull_kernels.plane_separates(V, normal, offset, points, slack) == bool((supports & beyond).any())
    # A part beyond a face plane of the other: that plane separates them (up to the rounding of the plane).
    size = np.abs(V).max()
    assert hull_kernels.plane_separates(V, normal, offset, V + 10.0 * size * normal[0], 1e-9 * size)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_compiled_mass_properties_are_numpys(seed):
    rng = np.random.default_rng(seed)
    V, F = hull_mesh(_points(rng, int(rng.integers(4, 3000))) + rng.normal(size=3) * 10.0)
    # Unused vertices and a shuffled face order as well (the origin is the used vertices' box centre).
    V = np.vstack([V, _points(rng, 5)])
    F = F[rng.permutation(len(F))]
    for faces in (F, F[:, ::-1], F[:0]):
        expected, got = mass_properties(V, faces), compiled_mass_properties(V, faces)
        assert got.volume == expected.volume
        assert np.array_equal(got.center, expected.center)
        assert np.array_equal(got.inertia, expected.inertia)


def test_pairwise_sum_is_numpys():
    rng = np.random.default_rng(7)
    for count in list(range(0, 300)) + [511, 1024, 1031, 4096, 9999, 70001]:
        v = rng.normal(size=count) * 10.0 ** rng.integers(-6, 6, size=count)
        assert mass_kernels._pairwise_sum(v) == v.sum()
