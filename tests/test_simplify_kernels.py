"""The compiled collapse kernels give bit for bit what the numpy expressions they replace give."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from fracture_cli.geometry.trigeom import point_triangle_distance
from fracture_cli.stages.simplify import collapse_kernels as kernels


def _cases(seed: int, n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) and triangles (n, 3, 3), with degenerate triangles and points close to them."""
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-3, 1)
    T = rng.normal(size=(n, 3, 3))
    T[::7, 2] = T[::7, 1]  # a segment
    T[::11, 1] = T[::11, 0] + 1e-17  # a point, almost
    T[::13, 2] = T[::13, 0] + (T[::13, 1] - T[::13, 0]) * 0.5  # collinear
    T[::17] = T[::17, :1]  # one point three times
    P[::5] = T[::5].mean(axis=1) + rng.normal(size=(len(P[::5]), 3)) * 1e-9
    return P, T


def test_point_triangle_distances_match_numpy_bit_for_bit():
    for seed in range(5):
        P, T = _cases(seed)
        with np.errstate(all="ignore"):
            expected = point_triangle_distance(P, T)
        got = kernels.point_triangle_distances(P, T)
        assert np.array_equal(got.view(np.int64), expected.view(np.int64))


def test_probes_are_centroids_then_edge_midpoints():
    rng = np.random.default_rng(1)
    V = rng.normal(size=(50, 3))
    tris = rng.integers(0, 50, size=(7, 3))
    T = V[tris]
    expected = np.concatenate([T.mean(axis=1), (T + T[:, [1, 2, 0]]).reshape(-1, 3) / 2.0])
    assert np.array_equal(kernels.probes(V, tris), expected)


def test_quadric_costs_match_einsum():
    rng = np.random.default_rng(2)
    H = np.column_stack([rng.normal(size=(40, 3)), np.ones(40)])
    quadric = rng.normal(size=(40, 4, 4))
    quadric = quadric + quadric.transpose(0, 2, 1)
    for u in range(10):
        targets = rng.choice(40, size=int(rng.integers(0, 9)), replace=False).astype(np.int64)
        P = H[targets]
        expected = np.einsum("ij,jk,ik->i", P, quadric[u], P)
        assert np.array_equal(kernels.quadric_costs(H, quadric, u, targets), expected)


def test_nearest_finds_the_k_nearest_as_a_kd_tree():
    rng = np.random.default_rng(3)
    # Points on a wavy sheet (as fault centroids are), queries near it and far off it.
    uv = rng.random((4000, 2))
    X = np.column_stack([uv, 0.05 * np.sin(9 * uv[:, 0])])
    Q = np.concatenate([X[rng.integers(0, 4000, 300)] + rng.normal(size=(300, 3)) * 0.01,
                        rng.normal(size=(50, 3)) * 2.0])
    for k, cell in ((8, 0.03), (8, 0.2), (1, 0.03), (3, 0.5)):
        grid = kernels.grid_index(X, cell)
        got = kernels.nearest(X, grid, cell, Q, k)
        _, expected = cKDTree(X).query(Q, k=k)
        assert np.array_equal(np.sort(got, axis=1), np.sort(expected.reshape(len(Q), k), axis=1))


def test_nearest_breaks_ties_by_id():
    X = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, 0, 5.0]])
    got = kernels.nearest(X, kernels.grid_index(X, 0.7), 0.7, np.zeros((1, 3)), 2)
    assert got.tolist() == [[0, 1]]


def test_within_tolerance_as_the_numpy_bound():
    rng = np.random.default_rng(4)
    V = rng.random((200, 3))
    reference = V[rng.integers(0, 200, size=(300, 3))]
    centroids = np.ascontiguousarray(reference.mean(axis=1))
    grid = kernels.grid_index(centroids, 0.1)
    for _ in range(50):
        tris = rng.integers(0, 200, size=(int(rng.integers(1, 6)), 3))
        points = rng.integers(0, 200, size=int(rng.integers(1, 8))).astype(np.int64)
        Q = kernels.probes(V, tris)
        near = kernels.nearest(centroids, grid, 0.1, Q, 8)
        T = V[tris]
        distance = point_triangle_distance(np.tile(V[points], (len(T), 1)), np.repeat(T, len(points), axis=0))
        distance = distance.reshape(len(T), len(points))
        strays = point_triangle_distance(np.repeat(Q, 8, axis=0), reference[near.reshape(-1)])
        strays = strays.reshape(len(Q), 8).min(axis=1).max()
        bound = max(float(distance.min(axis=0).max()), float(strays))
        for tolerance in (bound, bound * (1 - 1e-12)):
            found = kernels.within_tolerance(V, points, tris, Q, reference, near, tolerance)
            if tolerance >= bound:
                assert found.tolist() == np.argmin(distance, axis=0).tolist()
            else:
                assert len(found) == 0


def test_warm_kernels_simplifies_its_patch():
    """What ``make install`` runs to compile the kernels does collapses (so it reaches every kernel)."""
    from fracture_cli.stages.simplify.warm import warm_kernels

    assert warm_kernels() > 0


def _patch_complex(n: int = 14):
    """A wavy grid: its left half a fault between fragments 0 and 1, its right half outer faces of fragment 0
    on one input polygon; the border locked."""
    from fracture_cli.stages.simplify.decimate import SurfaceComplex

    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n), indexing="ij")
    V = np.column_stack([x.ravel(), y.ravel(), 0.02 * np.sin(4.0 * x.ravel()) * np.cos(3.0 * y.ravel())])
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    faces = np.concatenate([np.column_stack([a, a + n, a + n + 1]), np.column_stack([a, a + n + 1, a + 1])])
    fault = V[faces].mean(axis=1)[:, 0] < 0.5
    owners = [(0, 1) if f else (0,) for f in fault.tolist()]
    border = {int(v) for v in range(n * n) if v // n in (0, n - 1) or v % n in (0, n - 1)}
    return SurfaceComplex(V, faces, np.where(fault, -1, 5), owners, fault, border)


def _state(c) -> tuple:
    """What a complex holds after collapses (points as sets: their order in a list does not matter)."""
    return (c.faces, {u: sorted(f) for u, f in c.vertex_faces.items()},
            [(u, v, b, sorted(zip(p, q))) for u, v, b, p, q in c.done], {t: sorted(p) for t, p in c.assigned.items()},
            c.refused, c.modified, c.clock, c.quadric.tobytes(), c.behind(list(c.faces)), c._changed)


def test_compiled_collapse_loops_make_the_python_loops_collapses():
    states = []
    for compiled in (False, True):
        base = _patch_complex()
        base._finite = compiled  # False: decimate_python and replay_python
        first = base.copy()
        first.decimate({0: 0.01, 1: 0.01})
        first.decimate({0: 0.04, 1: 0.01}, sorted(first.vertex_faces)[::2])
        again = base.copy()
        again.locked |= {c[0] for c in first.done[::5]}
        again.damp = {c[0]: 0.25 for c in first.done[2::5]}
        again.replay(first.done, {0: 0.01, 1: 0.01}, first.final_refusals())
        again.decimate({0: 0.01, 1: 0.01})
        assert len(first.done) > 20 and len(again.done) > 10
        states.append((_state(first), _state(again)))
    assert states[0] == states[1]
