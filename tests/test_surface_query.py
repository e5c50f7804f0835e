"""geometry.surface_query: distances and ray casts against brute force, ties by rule, the same bits every run."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from fracture_cli.geometry import surface_query as sq


def brute_distances(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Distance (k,) from points (k, 3) to the nearest of triangles (m, 3, 3): every pair, in numpy.

    The in-plane foot from the normal equations of the barycentric least-squares problem when it is inside,
    else the nearest of the three edges (the only candidates for a degenerate triangle).
    """
    p = points[:, None, :]  # (k, 1, 3)
    a, b, c = tris[None, :, 0], tris[None, :, 1], tris[None, :, 2]

    def segment(a, b):
        e = b - a
        length2 = np.einsum("...i,...i", e, e)
        t = np.where(length2 > 0, np.einsum("...i,...i", p - a, e) / np.where(length2 > 0, length2, 1.0), 0.0)
        t = np.clip(t, 0.0, 1.0)
        return np.linalg.norm(p - (a + t[..., None] * e), axis=-1)

    best = np.minimum(np.minimum(segment(a, b), segment(b, c)), segment(c, a))
    e1, e2 = b - a, c - a
    g11, g12, g22 = (np.einsum("...i,...i", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    det = g11 * g22 - g12 * g12
    ok = det > 1e-12 * g11 * g22
    r1, r2 = np.einsum("...i,...i", p - a, e1), np.einsum("...i,...i", p - a, e2)
    safe = np.where(ok, det, 1.0)
    u, v = (g22 * r1 - g12 * r2) / safe, (g11 * r2 - g12 * r1) / safe
    foot = a + u[..., None] * e1 + v[..., None] * e2
    face = np.where(ok & (u >= 0) & (v >= 0) & (u + v <= 1), np.linalg.norm(p - foot, axis=-1), np.inf)
    return np.minimum(best, face).min(axis=1)


def brute_hits(origins: np.ndarray, directions: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Hit distances (k, m) of every ray on every triangle (Moeller-Trumbore; inf for a miss or t <= 0)."""
    o, d = origins[:, None, :], directions[:, None, :]
    a, e1, e2 = tris[None, :, 0], tris[None, :, 1] - tris[None, :, 0], tris[None, :, 2] - tris[None, :, 0]
    pv = np.cross(d, e2)
    det = np.einsum("...i,...i", e1, pv)
    safe = np.where(det != 0, det, 1.0)
    s = o - a
    u = np.einsum("...i,...i", s, pv) / safe
    q = np.cross(s, e1)
    v = np.einsum("...i,...i", d, q) / safe
    t = np.einsum("...i,...i", e2, q) / safe
    ok = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return np.where(ok, t, np.inf)


def random_mesh(rng, m: int) -> np.ndarray:
    """Triangles (m, 3, 3): random ones, slivers, a collapsed edge and a point triangle among them."""
    centres = rng.uniform(-1, 1, (m, 1, 3))
    tris = centres + 0.3 * rng.normal(size=(m, 3, 3))
    tris[0, 2] = tris[0, 1]  # two corners equal
    tris[1] = tris[1, 0]  # one point
    tris[2, 2] = 0.3 * tris[2, 0] + 0.7 * tris[2, 1]  # collinear
    tris[3, 2] = 0.5 * tris[3, 0] + 0.5 * tris[3, 1] + 1e-9  # a sliver
    return tris


def query_of(tris: np.ndarray) -> sq.SurfaceQuery:
    return sq.build(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_distances_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    tris = random_mesh(rng, 300)
    query = query_of(tris)
    on_vertices = tris.reshape(-1, 3)[rng.choice(900, 40)]
    w = rng.uniform(0, 1, (40, 1))
    on_edges = w * tris[:40, 0] + (1 - w) * tris[:40, 1]
    bary = rng.dirichlet(np.ones(3), 40)
    on_faces = np.einsum("kc,kcd->kd", bary, tris[-40:])
    points = np.vstack([rng.uniform(-1.5, 1.5, (300, 3)), rng.normal(size=(20, 3)) * 50.0,
                        on_vertices, on_edges, on_faces])
    got = sq.distances(query, points)
    want = brute_distances(points, tris)
    assert np.allclose(got, want, rtol=1e-12, atol=1e-12)
    assert np.all(got[320:360] == 0.0)  # on a corner: exactly 0
    assert np.all(got[360:] < 1e-12)
    # With an upper bound: the same values up to it, inf beyond.
    for bound in (np.quantile(want, 0.4), rng.uniform(0, 0.5, len(points)), got):
        bounded = sq.distances(query, points, bound)
        assert np.array_equal(bounded, np.where(got <= bound * (1 + 1e-9), got, np.inf))
    positive = got > 0
    below = sq.distances(query, points[positive], got[positive] * (1 - 1e-8))
    assert np.all(below == np.inf)


def test_distance_to_degenerate_triangles_is_to_their_edges():
    tris = np.array([[[0.0, 0, 0], [2, 0, 0], [1, 0, 0]],  # collinear: the segment from 0 to 2
                     [[5.0, 0, 0], [5, 0, 0], [5, 0, 0]]])  # a point
    query = query_of(tris)
    points = np.array([[1.0, 1, 0], [-1.0, 0, 0], [3.0, 0, 0], [5.0, 0, 2], [4.0, 0, 0]])
    assert sq.distances(query, points).tolist() == [1.0, 1.0, 1.0, 2.0, 1.0]


@pytest.mark.parametrize("kind", ["random", "copies", "progression"])
def test_hierarchy_holds_every_triangle_once_in_nested_boxes(kind):
    rng = np.random.default_rng(5)
    if kind == "random":
        tris = random_mesh(rng, 500)
    elif kind == "copies":  # all box centres equal: middle splits
        tris = np.repeat(rng.normal(size=(1, 3, 3)), 300, axis=0)
    else:  # sizes halving along a line: the area heuristic splits off one triangle at a time
        x = 0.5 ** np.arange(200.0)
        tris = np.stack([np.stack([x, 0 * x, 0 * x], 1), np.stack([x, x, 0 * x], 1), np.stack([x, 0 * x, x], 1)], 1)
    query = query_of(tris)
    leaves = query.right < 0
    assert np.array_equal(np.sort(np.concatenate([np.arange(s, s + c) for s, c in
                                                  zip(query.start[leaves], query.count[leaves])])),
                          np.arange(len(tris)))
    assert np.all(query.count[leaves] <= sq.LEAF_SIZE)
    assert query.depth <= sq._SAH_LEVELS + int(np.ceil(np.log2(len(tris)))) + 1
    assert sorted(map(tuple, query.corners.reshape(len(tris), -1))) == sorted(map(tuple, tris.reshape(len(tris), -1)))
    for node in np.flatnonzero(~leaves):
        for child in (node + 1, query.right[node]):
            assert np.all(query.box[node, 0] <= query.box[child, 0])
            assert np.all(query.box[child, 1] <= query.box[node, 1])
    points = rng.uniform(-1.5, 1.5, (200, 3))
    assert np.allclose(sq.distances(query, points), brute_distances(points, tris), rtol=1e-12, atol=1e-12)


def test_empty_mesh_and_no_points():
    empty = sq.build(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    assert sq.distances(empty, np.zeros((2, 3))).tolist() == [np.inf, np.inf]
    assert sq.first_hits(empty, np.zeros((1, 3)), [1.0, 0, 0]).tolist() == [np.inf]
    assert sq.hit_counts(empty, np.zeros((1, 3)), [1.0, 0, 0]).tolist() == [0]
    query = query_of(random_mesh(np.random.default_rng(0), 10))
    assert sq.distances(query, np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError):
        sq.first_hits(query, np.zeros((1, 3)), [0.0, 0, 0])


@pytest.mark.parametrize("seed", [0, 1])
def test_rays_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    tris = random_mesh(rng, 300)
    query = query_of(tris)
    origins = rng.uniform(-1.5, 1.5, (400, 3))
    directions = rng.normal(size=(400, 3))
    directions[:50] *= 1e-3  # t is in units of the direction's length
    directions[50:60] = [1.0, 0.0, 0.0]
    t = brute_hits(origins, directions, tris)
    got = sq.first_hits(query, origins, directions)
    assert np.allclose(got, t.min(axis=1), rtol=1e-12, atol=1e-12)
    assert np.array_equal(sq.hit_counts(query, origins, directions), np.isfinite(t).sum(axis=1))
    # Many rays along one direction go through the grid: the same counts as the hierarchy's.
    one = directions[100]
    grid = sq.hit_counts(query, origins, one)
    assert np.array_equal(grid, sq.hit_counts(query, origins, np.broadcast_to(one, origins.shape).copy()))
    assert np.array_equal(grid, np.isfinite(brute_hits(origins, np.broadcast_to(one, origins.shape), tris)).sum(axis=1))


def cube(subdivisions: int = 0) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    for _ in range(subdivisions):
        mesh = mesh.subdivide()
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


@pytest.mark.parametrize("subdivisions", [0, 2])
def test_rays_through_edges_and_corners_keep_the_parity(subdivisions):
    """From lattice points of a cube's own grid, along axes and diagonals, rays run exactly through edges
    and corners of the triangulated cube, and along its faces: the parity is still inside/outside."""
    V, F = cube(subdivisions)
    query = sq.build(V, F)
    g = np.arange(-1.5, 1.51, 0.25)
    points = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    points = points[np.abs(points).max(axis=1) != 1.0]  # not on the surface
    inner = np.abs(points).max(axis=1) < 1.0
    for direction in ([1.0, 0, 0], [0, -1.0, 0], [1.0, 1, 0], [1.0, 1, 1], [-1.0, 1, 0.5], [0, 0.5, -1.0]):
        counts = sq.hit_counts(query, points, direction)  # through the grid
        assert np.array_equal(counts % 2 == 1, inner), direction
        each = np.ascontiguousarray(np.broadcast_to(direction, points.shape))  # through the hierarchy
        assert np.array_equal(sq.hit_counts(query, points, each), counts), direction
    assert np.array_equal(sq.inside(query, points), inner)
    # First hits from the centre: through a face centre, an edge and a corner.
    centre = np.zeros((3, 3))
    assert sq.first_hits(query, centre, np.array([[1.0, 0, 0], [1, 1, 0], [-1, -1, 1]])).tolist() == [1.0] * 3


def test_inside_of_a_closed_mesh():
    mesh = trimesh.creation.icosphere(3)
    query = sq.build(mesh.vertices, mesh.faces)
    rng = np.random.default_rng(3)
    points = rng.uniform(-1.2, 1.2, (3000, 3))
    radius = np.linalg.norm(points, axis=1)
    keep = np.abs(radius - 1.0) > 0.02  # the icosphere is within 0.01 of the unit sphere
    assert np.array_equal(sq.inside(query, points[keep]), radius[keep] < 1.0)


def test_results_are_the_same_bits_every_run():
    rng = np.random.default_rng(7)
    tris = random_mesh(rng, 2000)
    points = rng.uniform(-1.5, 1.5, (3000, 3))
    directions = rng.normal(size=(3000, 3))
    first, second = query_of(tris), query_of(tris.copy())
    for name in ("corners", "box", "right", "start", "count"):
        assert getattr(first, name).tobytes() == getattr(second, name).tobytes()
    assert sq.distances(first, points).tobytes() == sq.distances(second, points).tobytes()
    assert sq.first_hits(first, points, directions).tobytes() == sq.first_hits(second, points, directions).tobytes()
    assert sq.distances(first, points[::-1]).tobytes() == sq.distances(first, points)[::-1].tobytes()


def test_warm_kernels():
    sq.warm_kernels()
