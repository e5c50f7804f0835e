"""The compiled separating-axis test (fracture_cli.geometry.trigeom_kernels) against its vectorised numpy statement.

The numpy reference below is the test as it was written before it was compiled:
every axis of every pair at once. The kernel must give the same verdicts on
random pairs, on touching, coplanar and degenerate ones, and across a chunk
boundary (the degenerate-axis threshold scales per chunk).
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.trigeom_kernels import PAIR_CHUNK, intersect_pairs, warm_kernels


def _separated(axes, a, b, scale, eps):
    """Whether any of ``axes`` (p, k, 3) separates triangles ``a``, ``b`` (p, 3, 3) by more than ``eps``."""
    length = np.sqrt(np.sum(axes * axes, axis=2))
    valid = length > 1e-12 * scale * scale
    axes = axes / np.where(valid, length, 1.0)[:, :, None]
    pa = np.einsum("pkd,pcd->pkc", axes, a)
    pb = np.einsum("pkd,pcd->pkc", axes, b)
    gap = np.maximum(pa.min(axis=2) - pb.max(axis=2), pb.min(axis=2) - pa.max(axis=2))
    return np.any(valid & (gap > eps), axis=1)


def reference(A, B, eps=tol.ZERO_LENGTH):
    """All 17 axes of every pair in arrays: both normals, 9 edge x edge, 12 normal x edge."""
    hit = np.zeros(len(A), dtype=bool)
    for s in range(0, len(A), PAIR_CHUNK):
        a, b = A[s:s + PAIR_CHUNK], B[s:s + PAIR_CHUNK]
        origin = a[:, :1, :]
        a, b = a - origin, b - origin
        scale = max(float(np.abs(a).max(initial=0.0)), float(np.abs(b).max(initial=0.0)), 1e-300)
        ea, eb = a[:, [1, 2, 0]] - a, b[:, [1, 2, 0]] - b
        na, nb = np.cross(ea[:, 0], ea[:, 1]), np.cross(eb[:, 0], eb[:, 1])
        axes = np.concatenate([
            na[:, None], nb[:, None],
            np.cross(ea[:, :, None, :], eb[:, None, :, :]).reshape(-1, 9, 3),
            np.cross(na[:, None, :], ea), np.cross(nb[:, None, :], eb),
            np.cross(na[:, None, :], eb), np.cross(nb[:, None, :], ea)], axis=1)
        hit[s:s + PAIR_CHUNK] = ~_separated(axes, a, b, scale, eps)
    return hit


def _pairs(count, seed):
    rng = np.random.default_rng(seed)
    A = rng.random((count, 3, 3))
    B = A[rng.permutation(count)] * 0.3 + rng.random((count, 1, 3)) * 0.8
    return A, B


def test_random_pairs_match_the_reference_across_chunks():
    A, B = _pairs(PAIR_CHUNK + 5_000, 0)
    A[-10:] *= 1e6  # a larger last chunk scales its own threshold only
    hit = trigeom.triangles_intersect(A, B)
    assert hit.dtype == bool and 0 < hit.sum() < len(hit)
    np.testing.assert_array_equal(hit, reference(A, B))


def test_touching_coplanar_and_degenerate_pairs_match_the_reference():
    A, B = _pairs(3_000, 1)
    B[:500] = A[:500] + np.array([1e-13, 0.0, 0.0])  # within eps: touching
    B[500:1000] = A[500:1000] + np.array([0.0, 0.0, 1e-9])  # parallel, clearly apart
    B[1000:1500, 2] = B[1000:1500, 1]  # segments
    A[1500:2500, :, 2] = 0.0  # coplanar pairs
    B[1500:2500, :, 2] = 0.0
    A[2500:2600] = A[2500:2600, :1]  # points: only the other triangle's normal is an axis
    hit = trigeom.triangles_intersect(A, B)
    np.testing.assert_array_equal(hit, reference(A, B))
    assert hit[:500].all() and not hit[500:1000].any()


def test_eps_and_empty_input():
    A = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    B = A + np.array([0.0, 0.0, 1e-6])
    assert not trigeom.triangles_intersect(A, B)[0]
    assert trigeom.triangles_intersect(A, B, eps=1e-5)[0]
    assert trigeom.triangles_intersect(np.zeros((0, 3, 3)), np.zeros((0, 3, 3))).shape == (0,)
    assert intersect_pairs(np.full((1, 3, 3), np.nan), A, 1e-12)[0]  # nan proves nothing separate
    assert warm_kernels() == 1
