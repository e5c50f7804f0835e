"""Tests of the cage stage: the cage is closed, manifold and strictly contains the input.

Containment is checked here independently of fracture_cli.geometry.trigeom and of the
stage's own check: generalized winding numbers (solid angles) for the input
vertices, point-to-triangle distances, and segment-triangle crossing tests by
signed volumes in both directions.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from fracture_cli.errors import StageError
from fracture_cli.geometry import trigeom
from fracture_cli.stages.cage import CageOptions, cage
from fracture_cli.stages.tetra import tetgen as _tetgen
from fracture_cli.types import Material, Normalization, SurfaceMesh

SAMPLE_ASSETS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "sample_assets")
SAMPLE_FILES = ("pillar.glb", "chair.glb", "vase.obj")


# ----------------------------------------------------------------------------- inputs

def surface_from(vertices, faces, name="mesh") -> SurfaceMesh:
    vertices = np.asarray(vertices, dtype=np.float64)
    norm = Normalization.from_points(vertices)
    return SurfaceMesh(vertices=norm.to_normalized(vertices), faces=np.asarray(faces, dtype=np.int64),
                       uvs=None, normals=None, colors=None,
                       material_ids=np.zeros(len(faces), dtype=np.int32), materials=(Material("m"),),
                       normalization=norm, name=name)


def open_cylinder(sections=24, rings=6, radius=0.3, height=1.0):
    """A tube without caps whose seam column of vertices is duplicated (as UV seams do)."""
    angle = np.linspace(0.0, 2.0 * np.pi, sections + 1)  # last column duplicates the first
    z = np.linspace(0.0, height, rings + 1)
    A, Z = np.meshgrid(angle, z, indexing="ij")
    V = np.stack([radius * np.cos(A), radius * np.sin(A), Z], axis=-1).reshape(-1, 3)
    V[sections * (rings + 1):] = V[:rings + 1]  # exact duplicates on the seam

    def vid(i, j):
        return i * (rings + 1) + j

    faces = []
    for i in range(sections):
        for j in range(rings):
            a, b, c, d = vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)
            faces += [[a, b, c], [a, c, d]]
    return V, np.array(faces)


PRIMITIVES = {
    "sphere": lambda: (trimesh.creation.icosphere(subdivisions=3).vertices, trimesh.creation.icosphere(3).faces),
    "plank": lambda: (trimesh.creation.box((1.0, 0.25, 0.03)).vertices, trimesh.creation.box((1.0, 0.25, 0.03)).faces),
    "open_cylinder": open_cylinder,
}


def primitive(name) -> SurfaceMesh:
    V, F = PRIMITIVES[name]()
    return surface_from(V, F, name)


def sample(name) -> SurfaceMesh:
    path = os.path.join(SAMPLE_ASSETS, name)
    if not os.path.exists(path):
        pytest.skip(f"{name} not generated yet")
    from fracture_cli.stages.load import load_surface

    return load_surface(path)


# ----------------------------------------------------------------------------- independent checks

def winding_numbers(points, V, F, chunk=2000):
    """Generalized winding number of closed surface (V, F) at points (Van Oosterom-Strackee solid angles)."""
    T = V[F]
    w = np.zeros(len(points))
    for s in range(0, len(points), chunk):
        p = points[s:s + chunk]
        a = T[None, :, 0, :] - p[:, None, :]
        b = T[None, :, 1, :] - p[:, None, :]
        c = T[None, :, 2, :] - p[:, None, :]
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc
               + np.einsum("pfi,pfi->pf", b, c) * la + np.einsum("pfi,pfi->pf", c, a) * lb)
        w[s:s + chunk] = np.arctan2(det, den).sum(axis=1) / (2.0 * np.pi)
    return w


def point_surface_distance(points, V, F):
    """Exact distance from each point to surface (V, F): closest points on nearby triangles (trimesh)."""
    T = V[F]
    centroid = T.mean(axis=1)
    radius = np.linalg.norm(T - centroid[:, None], axis=2).max()
    tree = cKDTree(centroid)
    d_near, _ = tree.query(points)
    # The nearest triangle's centroid is within (distance + radius) <= (d_near + radius).
    lists = [tree.query_ball_point(p, r + radius + 1e-12) for p, r in zip(points, d_near)]
    pi = np.repeat(np.arange(len(points)), [len(x) for x in lists])
    ti = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists])
    closest = trimesh.triangles.closest_point(T[ti], points[pi])
    dist = np.linalg.norm(closest - points[pi], axis=1)
    best = np.full(len(points), np.inf)
    np.minimum.at(best, pi, dist)
    return best


def segments_cross_triangles(P, Q, T):
    """Whether segment (P, Q) properly crosses triangle T, for aligned arrays (signed volumes)."""
    def vol(x, y, z, w):
        return np.einsum("ij,ij->i", np.cross(y - x, z - x), w - x)

    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    s1, s2 = vol(a, b, c, P), vol(a, b, c, Q)
    t1, t2, t3 = vol(P, Q, a, b), vol(P, Q, b, c), vol(P, Q, c, a)
    opposite = s1 * s2 <= 0
    inside = ((t1 >= 0) & (t2 >= 0) & (t3 >= 0)) | ((t1 <= 0) & (t2 <= 0) & (t3 <= 0))
    return opposite & inside


def count_crossings(V1, F1, V2, F2, piece=0.02):
    """Edges of mesh 1 crossing triangles of mesh 2.

    Long edges are split and big triangles subdivided to at most ``piece`` so a
    KD-tree on centroids with one small radius is a complete broad phase.
    """
    edges = np.unique(np.sort(np.concatenate([F1[:, [0, 1]], F1[:, [1, 2]], F1[:, [2, 0]]]), axis=1), axis=0)
    P, Q = V1[edges[:, 0]], V1[edges[:, 1]]
    parts = np.maximum(1, np.ceil(np.linalg.norm(Q - P, axis=1) / piece).astype(int))
    k = np.repeat(np.arange(len(P)), parts)
    t0 = (np.arange(len(k)) - np.repeat(np.cumsum(parts) - parts, parts)) / parts[k]
    t1 = t0 + 1.0 / parts[k]
    P, Q = P[k] + t0[:, None] * (Q[k] - P[k]), P[k] + t1[:, None] * (Q[k] - P[k])
    V2s, F2s = trimesh.remesh.subdivide_to_size(V2, F2, max_edge=piece, max_iter=20)
    T = V2s[F2s]
    # Zero-area triangles cannot be crossed (their edges belong to other triangles too).
    area = np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
    T = T[area > 1e-14]
    centroid = T.mean(axis=1)
    tri_radius = np.linalg.norm(T - centroid[:, None], axis=2).max()
    seg_radius = 0.5 * np.linalg.norm(Q - P, axis=1).max()
    tree = cKDTree(centroid)
    lists = tree.query_ball_point(0.5 * (P + Q), tri_radius + seg_radius + 1e-9)
    ei = np.repeat(np.arange(len(P)), [len(x) for x in lists])
    ti = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists]) if len(ei) else np.zeros(0, np.int64)
    return int(segments_cross_triangles(P[ei], Q[ei], T[ti]).sum())


def component_representatives(F, stride=10):
    """Every ``stride``-th used vertex plus at least one vertex of every connected component."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n = int(F.max()) + 1
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]]])
    _, labels = connected_components(sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)),
                                     directed=False)
    used = np.unique(F)
    _, first = np.unique(labels[used], return_index=True)
    return np.union1d(used[first], used[::stride])


def assert_valid_cage(surface: SurfaceMesh, result, target: int):
    V, F = result.vertices, result.faces
    assert V.dtype == np.float64 and F.dtype == np.int64
    # Closed, manifold, consistently oriented outward (trimesh's own checks).
    mesh = trimesh.Trimesh(V, F, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    assert trigeom.vertex_manifold(F)
    assert abs(len(F) - target) <= 0.1 * target
    # Strict containment: every input vertex inside (winding number ~1) and off the surface.
    # With no crossing (checked below), each connected part of the input is all
    # inside or all outside, so a subset with a vertex of every part suffices.
    points = surface.vertices[component_representatives(surface.faces)]
    w = winding_numbers(points, V, F)
    assert np.all(w > 0.5), f"{int(np.sum(w <= 0.5))} input vertices outside the cage"
    # No crossing in either direction.
    assert count_crossings(surface.vertices, surface.faces, V, F) == 0
    assert count_crossings(V, F, surface.vertices, surface.faces) == 0


# ----------------------------------------------------------------------------- tests

@pytest.mark.parametrize("name", sorted(PRIMITIVES))
def test_cage_of_primitive_is_valid(name):
    surface = primitive(name)
    result = cage(surface, CageOptions(target_faces=500))
    assert_valid_cage(surface, result, 500)
    assert 0 < result.offset < 0.1
    # Vertices clear the cage by more than float noise.
    points = surface.vertices[np.unique(surface.faces)]
    assert point_surface_distance(points, result.vertices, result.faces).min() > 1e-6


@pytest.mark.parametrize("name", SAMPLE_FILES)
def test_cage_of_sample_asset_at_2000_faces(name):
    surface = sample(name)
    result = cage(surface, CageOptions(target_faces=2000))
    assert_valid_cage(surface, result, 2000)
    assert result.offset < 0.02
    assert result.normalization is surface.normalization


def test_cage_is_deterministic():
    surface = primitive("plank")
    first = cage(surface, CageOptions(target_faces=300))
    second = cage(surface, CageOptions(target_faces=300))
    assert first.offset == second.offset
    assert first.vertices.tobytes() == second.vertices.tobytes()
    assert first.faces.tobytes() == second.faces.tobytes()


def test_cage_log_records_iterations(caplog):
    surface = primitive("sphere")
    with caplog.at_level(logging.INFO, logger="fracture_cli.stages.cage"):
        result = cage(surface, CageOptions(target_faces=200, max_iterations=3))
    assert 1 <= len(result.log) <= 3
    keys = {"distance", "marching_cubes", "decimation", "self_intersection", "tetgen", "check"}
    for entry in result.log:
        assert set(entry["seconds"]) == keys
        assert entry["ok"] or entry["reason"]
    assert any(e["ok"] and e["offset"] == result.offset for e in result.log)
    assert sum("cage: iteration" in r.getMessage() for r in caplog.records) == len(result.log)


def test_cage_open3d_decimator_also_works():
    surface = primitive("sphere")
    result = cage(surface, CageOptions(target_faces=300, decimator="open3d"))
    assert_valid_cage(surface, result, 300)


def test_default_bake_never_imports_open3d(tmp_path):
    """open3d (1.4 s to import, float32 and CPU-dependent) is only for the optional decimator: a bake of the
    default recipe runs with a stand-in that refuses to load, in every process, and never has it loaded."""
    blocker = tmp_path / "blocker" / "open3d"
    blocker.mkdir(parents=True)
    (blocker / "__init__.py").write_text("raise ImportError('open3d imported by a default bake')\n")
    repo = os.path.dirname(SAMPLE_ASSETS)
    code = ("import sys\nfrom fracture_cli.cli import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit as stop:\n    assert not stop.code, stop.code\n"
            "print('loaded' if 'open3d' in sys.modules else 'never')\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(blocker.parent), repo]))
    out = subprocess.run([sys.executable, "-c", code, "bake", os.path.join(SAMPLE_ASSETS, "chair.glb"), "-o",
                          str(tmp_path / "out"), "--quiet", "--set", "cage.target_faces=600", "--set",
                          "modes.num_modes=4"], capture_output=True, text=True, env=env, cwd=repo)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "never"
    assert (tmp_path / "out" / "chair.glb").exists()


def test_cage_reports_when_nothing_works():
    surface = primitive("sphere")
    with pytest.raises(StageError, match="no valid cage"):
        cage(surface, CageOptions(target_faces=200, initial_offset=0.2, max_offset=0.1))


def test_cage_rejects_empty_input():
    surface = surface_from(np.eye(3), np.zeros((0, 3), dtype=np.int64))
    with pytest.raises(StageError, match="no triangles"):
        cage(surface)


# ----------------------------------------------------------------------------- helpers used by the stage

def test_triangles_intersect_agrees_with_segment_tests():
    rng = np.random.default_rng(7)
    A = rng.normal(size=(5000, 3, 3))
    B = rng.normal(size=(5000, 3, 3)) + 0.4
    reference = np.zeros(len(A), dtype=bool)
    for k in range(3):
        reference |= segments_cross_triangles(A[:, k], A[:, (k + 1) % 3], B)
        reference |= segments_cross_triangles(B[:, k], B[:, (k + 1) % 3], A)
    assert np.array_equal(trigeom.triangles_intersect(A, B), reference)


def test_triangles_intersect_coplanar_and_touching():
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    far = tri + [2.0, 0, 0]
    overlapping = tri + [0.2, 0.2, 0]
    touching = np.array([[1.0, 0, 0], [2, 0, 0], [2, 1, 0]])  # shares a corner point
    segment_beside = np.array([[0.6, 0.6, 0], [2.0, -0.5, 0], [2.0, -0.5, 0]])  # coplanar, outside
    hit = trigeom.triangles_intersect(np.array([tri] * 4), np.array([far, overlapping, touching, segment_beside]))
    assert hit.tolist() == [False, True, True, False]


def test_self_intersections_and_manifold_checks():
    sphere = trimesh.creation.icosphere(2)
    V, F = sphere.vertices.copy(), sphere.faces
    assert trigeom.edge_manifold_closed(F) and trigeom.vertex_manifold(F)
    assert len(trigeom.self_intersections(V, F)) == 0
    V[0] = -1.1 * V[0]  # pull one vertex through the sphere
    assert len(trigeom.self_intersections(V, F)) > 0
    # Two spheres sharing one vertex: edge-manifold, not vertex-manifold.
    G = np.vstack([F, F + len(sphere.vertices)])
    a, b = int(np.argmax(sphere.vertices[:, 0])), int(np.argmin(sphere.vertices[:, 0])) + len(sphere.vertices)
    G[G == b] = a
    assert trigeom.edge_manifold_closed(G) and not trigeom.vertex_manifold(G)
    flipped = F.copy()
    flipped[0] = flipped[0, ::-1]
    assert not trigeom.edge_manifold_closed(flipped)


def test_tetgen_prestart_starts_the_worker_that_runs_next():
    _tetgen.shutdown()
    _tetgen.prestart()
    process = _tetgen._worker._process
    assert process is not None and process.poll() is None
    _tetgen.prestart()  # running: nothing happens
    assert _tetgen._worker._process is process
    sphere = trimesh.creation.icosphere(1)
    nodes, tets = _tetgen.tetrahedralize(sphere.vertices, sphere.faces, "pYQ", timeout=30)
    assert len(tets) > 0 and _tetgen._worker._process is process


def test_tetgen_crash_is_reported_not_fatal(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _tetgen.shutdown()  # the next worker starts from this directory
    sphere = trimesh.creation.icosphere(1)
    V = np.vstack([sphere.vertices, sphere.vertices + [0.5, 0, 0]])
    F = np.vstack([sphere.faces, sphere.faces + len(sphere.vertices)])  # two overlapping shells
    with pytest.raises(_tetgen.TetGenFailure):
        _tetgen.tetrahedralize(V, F, "pYQ", timeout=30)
    nodes, tets = _tetgen.tetrahedralize(sphere.vertices, sphere.faces, "pYQ", timeout=30)
    assert len(tets) > 0 and len(nodes) >= len(sphere.vertices)
    assert list(tmp_path.iterdir()) == []  # TetGen's debug files stay out of the user's directory
