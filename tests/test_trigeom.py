"""The shared triangle-mesh helpers (fracture_cli.geometry.trigeom), against trimesh and analytic values."""

from __future__ import annotations

import numpy as np
import trimesh

from fracture_cli.geometry import trigeom


def _sphere():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=2.0)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64), mesh


def test_signed_volume_matches_trimesh_and_flips_with_winding():
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    V, F = np.asarray(box.vertices), np.asarray(box.faces, dtype=np.int64)
    assert np.isclose(trigeom.signed_volume(V, F), 6.0)
    assert np.isclose(trigeom.signed_volume(V, F[:, ::-1]), -6.0)
    assert np.isclose(trigeom.face_signed_volumes(V, F).sum(), 6.0)
    V, F, mesh = _sphere()
    assert np.isclose(trigeom.signed_volume(V, F), mesh.volume, rtol=1e-12)


def test_vertex_normals_of_a_sphere_point_outward():
    V, F, _ = _sphere()
    normals = trigeom.vertex_normals(V, F)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    # Area-weighted normals of a fine sphere are close to the radial direction.
    assert np.min(np.einsum("ij,ij->i", normals, V / np.linalg.norm(V, axis=1, keepdims=True))) > 0.999
    raw = trigeom.vertex_normals(V, F, unit=False)
    assert np.allclose(raw / np.linalg.norm(raw, axis=1, keepdims=True), normals)
    # Vertices without faces stay zero.
    assert np.all(trigeom.vertex_normals(np.vstack([V, [[9.0, 9.0, 9.0]]]), F)[-1] == 0.0)


def test_winding_numbers_are_one_inside_and_zero_outside():
    V, F, _ = _sphere()
    rng = np.random.default_rng(1)
    points = rng.uniform(-3.0, 3.0, (400, 3))
    points = points[np.abs(np.linalg.norm(points, axis=1) - 2.0) > 0.05]  # not on the surface
    w = trigeom.winding_numbers(points, V, F)
    inside = np.linalg.norm(points, axis=1) < 2.0  # the icosphere is within 0.05 of the sphere
    assert inside.any() and (~inside).any()
    assert np.allclose(w[inside], 1.0, atol=1e-9)
    assert np.allclose(w[~inside], 0.0, atol=1e-9)
    assert np.allclose(trigeom.winding_numbers(points[:5], V, F[:, ::-1]), -w[:5])
    # Per triangle contributions sum to the same number.
    p = np.repeat(points[:1], len(F), axis=0)
    assert np.isclose(trigeom.triangle_winding(p, V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]).sum(), w[0])


def test_closest_points_and_distances_agree_with_trimesh():
    V, F, _ = _sphere()
    rng = np.random.default_rng(2)
    points = rng.uniform(-3.0, 3.0, (len(F), 3))
    tri = V[F]  # one (random point, triangle) pair per face: every Voronoi region gets hit
    expected = trimesh.triangles.closest_point(tri, points)
    got = trigeom.closest_points(points, tri[:, 0], tri[:, 1], tri[:, 2])
    assert np.allclose(got, expected, atol=1e-9)
    assert np.allclose(trigeom.point_triangle_distance(points, tri), np.linalg.norm(points - expected, axis=1),
                       atol=1e-9)
    # Vertex, edge and face regions of one triangle, and a degenerate triangle.
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    q = np.array([[-1.0, -1, 0], [0.5, -1, 0], [0.2, 0.2, 1], [1.0, 1.0, 0]])
    one = np.repeat([[a, b, c]], len(q), axis=0)
    assert np.allclose(trigeom.closest_points(q, one[:, 0], one[:, 1], one[:, 2]),
                       [[0, 0, 0], [0.5, 0, 0], [0.2, 0.2, 0], [0.5, 0.5, 0]])
    flat = trigeom.closest_points(q[:1], a[None], a[None], a[None])
    assert np.all(np.isfinite(flat))


def test_compact_drops_unused_vertices_and_keeps_order():
    V = np.arange(18, dtype=float).reshape(6, 3)
    F = np.array([[5, 1, 3]])
    W, G = trigeom.compact(V, F)
    assert np.array_equal(W, V[[1, 3, 5]]) and np.array_equal(G, [[2, 0, 1]])
    same, F2 = trigeom.compact(V[:3], np.array([[0, 1, 2]]))
    assert same is not None and np.array_equal(F2, [[0, 1, 2]])
