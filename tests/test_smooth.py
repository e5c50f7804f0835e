"""Fault smoothing and piece regions (fracture_cli.stages.smooth), checked independently."""

import itertools
import logging
from pathlib import Path

import manifold3d
import numpy as np
import pytest

from fracture_cli.checks.faultshape import fault_roughness, region_fault_roughness
from fracture_cli.geometry import tetgeom
from fracture_cli.geometry.trigeom import point_triangle_distance
from fracture_cli.stages.pieces import pieces
from fracture_cli.stages.smooth import SmoothOptions, smooth
from fracture_cli.stages.smooth.cells import union_regions as _union_regions
from fracture_cli.stages.smooth.field import smoothed_field as _smoothed_field
from fracture_cli.stages.smooth.field import winning_field as _winning_field
from fracture_cli.stages.smooth.geometric import smoothed_vertices as _smoothed_vertices
from fracture_cli.stages.smooth.topology import Topology as _Topology
from fracture_cli.testing import grid_tetmesh, jittered_grid_tetmesh
from fracture_cli.types import Modes, Regions, TetMesh

# The field method at the strength it was tuned for (the stage's default is the geometric method), on the cage
# tets themselves: these tests are about the level-set regions, not the refinement.
FIELD = SmoothOptions(smoothing=2.5e-4, method="field", refine=0)


def jittered_grid(n=6, seed=0):
    """Unit cube centred at 0, interior vertices jittered (generic faults), boundary kept flat."""
    return jittered_grid_tetmesh(n, 0.5, 0.1 / n, seed)


def label_modes(tm, labels):
    labels = np.atleast_2d(labels)
    ft = tm.interior_face_tets
    cut = labels[:, ft[:, 0]] != labels[:, ft[:, 1]]
    return Modes(U=labels[:, :, None].astype(float), labels=labels.astype(np.int32), cut=cut,
                 piece_counts=labels.max(axis=1) + 1, energies=np.zeros(len(labels)),
                 iterations=np.ones(len(labels), np.int32))


def plane_pieces(tm):
    c = tm.tet_centroids
    lab = (c[:, 0] > 0.02).astype(int) + 2 * (c[:, 1] + 0.4 * c[:, 2] > -0.1)
    return pieces(tm, label_modes(tm, lab))


def signed_volume(V, F):
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0


def edge_manifold_by_index(F):
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    # every directed edge once, and its reverse present
    as_set = {tuple(e) for e in directed.tolist()}
    return len(as_set) == len(directed) and all((b, a) in as_set for a, b in as_set)


def closed_by_position(V, F):
    _, pos = np.unique(V, axis=0, return_inverse=True)
    return edge_manifold_by_index(pos.reshape(-1)[F])


def solid(V, F):
    return manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(V, dtype=np.float64),
                                                 tri_verts=np.ascontiguousarray(F, dtype=np.uint64)))


def check_partition(tm, regions, tol):
    total = np.abs(tm.tet_volumes).sum()
    solids = [solid(V, F) for V, F in regions.meshes]
    volumes = np.array([signed_volume(V, F) for V, F in regions.meshes])
    assert np.all(volumes > 0)
    assert abs(volumes.sum() - total) < tol * total
    for a, b in itertools.combinations(range(len(solids)), 2):
        assert (solids[a] ^ solids[b]).volume() < tol * min(volumes[a], volumes[b])
    return volumes


def inner_roughness(regions):
    """Independent roughness: length-weighted dihedral angle over area of faces off the cube's boundary."""
    total_turn, total_area = 0.0, 0.0
    for V, F in regions.meshes:
        P = V[F]
        on_box = np.any(np.all(np.abs(np.abs(P) - 0.5) < 1e-9, axis=1), axis=1)
        F, P = F[~on_box], P[~on_box]
        n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
        area = np.linalg.norm(n, axis=1)
        n = n / area[:, None]
        total_area += area.sum() / 2
        edges = {}
        for f, tri in enumerate(F.tolist()):
            for k in range(3):
                key = tuple(sorted((tri[k], tri[(k + 1) % 3])))
                edges.setdefault(key, []).append(f)
        for (a, b), fs in edges.items():
            if len(fs) == 2:
                angle = np.arccos(np.clip(n[fs[0]] @ n[fs[1]], -1, 1))
                total_turn += np.linalg.norm(V[a] - V[b]) * angle
    return total_turn / total_area


def test_lambda_zero_is_tet_aligned():
    tm = jittered_grid()
    P = plane_pieces(tm)
    R = smooth(tm, P, SmoothOptions(smoothing=0.0))
    assert len(R.meshes) == P.num_pieces and R.vanished == ()
    volumes = check_partition(tm, R, 1e-9)
    np.testing.assert_allclose(volumes, P.volumes, rtol=1e-9)
    for V, F in R.meshes:
        assert edge_manifold_by_index(F) and closed_by_position(V, F)
        # every region vertex is a tet mesh vertex (or within the pinch separation of one)
        d = np.min(np.linalg.norm(V[:, None, :] - tm.vertices[None, :, :], axis=2), axis=1)
        assert d.max() < 1e-6


def test_lambda_zero_piece_touching_itself_along_an_edge():
    # 2x2x2 voxels; piece A wraps around the vertical edge x=y=1 where its two bottom voxels touch.
    mask_a = {(0, 0, 0), (1, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1)}
    tm = grid_tetmesh((2, 2, 2))
    c = tm.tet_centroids
    voxel = [tuple(v) for v in np.floor(c).astype(int).tolist()]
    lab = np.array([0 if v in mask_a else 1 + v[0] + 2 * v[1] + 4 * v[2] for v in voxel])
    _, lab = np.unique(lab, return_inverse=True)
    P = pieces(tm, label_modes(tm, lab))
    R = smooth(tm, P, SmoothOptions(smoothing=0.0))
    # A thin spindle (2% wide) around the pinched edge goes to one piece: volumes change by 4e-4 of the
    # tets around the edge, the partition stays exact.
    volumes = check_partition(tm, R, 1e-9)
    np.testing.assert_allclose(volumes, P.volumes, rtol=1e-3)
    for V, F in R.meshes:
        assert edge_manifold_by_index(F)
        assert closed_by_position(V, F)
        # Still closed after rounding to float32 and welding by position (what engine importers do).
        assert closed_by_position(V.astype(np.float32), F)


def test_direct_regions_match_cell_unions():
    tm = jittered_grid(5)
    P = plane_pieces(tm)
    tet_piece = P.tet_piece.astype(np.int64)
    lam = 2e-3
    R = smooth(tm, P, SmoothOptions(smoothing=lam, method="field", refine=0))
    Z, vanished, _ = _winning_field(tm, _Topology(tm.tets, tm.num_vertices), tet_piece, P, lam, 0.01)
    assert list(R.vanished) == vanished
    unions = _union_regions(tm.vertices, tm.tets, Z, tet_piece, P.num_pieces, list(R.vanished),
                            list(range(P.num_pieces)))
    direct = np.array([signed_volume(V, F) for V, F in R.meshes])
    union = np.array([signed_volume(V, F) for V, F in unions])
    # The union path snaps cell corners (1e-10), so agreement is limited to a few 1e-9 of the cage volume.
    np.testing.assert_allclose(direct, union, rtol=0, atol=1e-8)
    # lambda = 0: tet unions, up to the spindles carved at pinched edges (eps^2 = 4e-4 of their tets).
    R0 = smooth(tm, P, SmoothOptions(smoothing=0.0))
    direct0 = np.array([signed_volume(V, F) for V, F in R0.meshes])
    np.testing.assert_allclose(direct0, P.volumes, rtol=1e-4)
    assert abs(direct0.sum() - P.volumes.sum()) < 1e-12


def test_vanished_piece_between_others_stays_closed_by_position():
    # Single-tet pieces that vanish under strong smoothing are tet-aligned inside smoothed neighbours.
    tm = jittered_grid(6, seed=3)
    c = tm.tet_centroids
    lab = (c[:, 0] > 0.0).astype(int)
    rng = np.random.default_rng(5)
    for k, tet in enumerate(rng.choice(tm.num_tets, 12, replace=False)):
        lab[tet] = 2 + k
    P = pieces(tm, label_modes(tm, lab))
    R = smooth(tm, P, SmoothOptions(smoothing=5e-3, method="field", refine=0))
    assert len(R.vanished) > 0
    check_partition(tm, R, 1e-7)
    for V, F in R.meshes:
        assert edge_manifold_by_index(F) and closed_by_position(V, F)


def test_smoothing_partitions_and_rounds_faults():
    tm = jittered_grid(7)
    P = plane_pieces(tm)
    R0 = smooth(tm, P, SmoothOptions(smoothing=0.0))
    R1 = smooth(tm, P, FIELD)
    assert R1.smoothing == FIELD.smoothing
    volumes = check_partition(tm, R1, 1e-7)
    assert len(volumes) == P.num_pieces
    for V, F in R1.meshes:
        assert edge_manifold_by_index(F) and closed_by_position(V, F)
    rough0, rough1 = inner_roughness(R0), inner_roughness(R1)
    print(f"inner-face roughness: lambda=0 {rough0:.2f}, default lambda {rough1:.2f}")
    assert rough1 < 0.8 * rough0


def lonely_piece_case():
    tm = jittered_grid(5)
    c = tm.tet_centroids
    lab = (c[:, 0] > 0.0).astype(int)
    lonely = int(np.argmin(np.linalg.norm(c - [-0.2, 0.1, 0.1], axis=1)))
    lab[lonely] = 2
    P = pieces(tm, label_modes(tm, lab))
    return tm, P, lonely, int(P.tet_piece[lonely])


def test_vanishing_piece_is_raised_to_about_its_volume():
    tm, P, lonely, lonely_piece = lonely_piece_case()
    # Plain smoothing swallows the one-tet piece ...
    Z = _smoothed_field(tm, P.tet_piece.astype(np.int64), P.num_pieces, 1e-2)
    assert not np.any(Z[tm.tets[lonely]].argmax(axis=1) == lonely_piece)
    # ... so its field is raised: it keeps a smooth region of about its volume, not its tet.
    R = smooth(tm, P, SmoothOptions(smoothing=1e-2, method="field", refine=0))
    assert lonely_piece not in R.vanished
    volumes = check_partition(tm, R, 1e-7)
    assert 0.3 < volumes[lonely_piece] / abs(tm.tet_volumes[lonely]) < 3.0
    V, F = R.meshes[lonely_piece]
    assert closed_by_position(V, F)


def test_vanishing_piece_keeps_its_tets(caplog, monkeypatch):
    import fracture_cli.stages.smooth.field as smooth_module

    tm, P, lonely, lonely_piece = lonely_piece_case()
    # When no raise within bounds brings the piece back (here: no raise allowed), it keeps its tet.
    monkeypatch.setattr(smooth_module, "_MAX_BIAS", 0.0)
    with caplog.at_level(logging.WARNING):
        R = smooth(tm, P, SmoothOptions(smoothing=1e-2, method="field", refine=0))
    assert lonely_piece in R.vanished
    assert any("vanish" in r.message for r in caplog.records)
    volumes = check_partition(tm, R, 1e-7)
    np.testing.assert_allclose(volumes[lonely_piece], abs(tm.tet_volumes[lonely]), rtol=1e-6)


def test_deterministic():
    tm = jittered_grid(5)
    P = plane_pieces(tm)
    A, B = smooth(tm, P, FIELD), smooth(tm, P, FIELD)
    for (va, fa), (vb, fb) in zip(A.meshes, B.meshes):
        assert va.tobytes() == vb.tobytes() and fa.tobytes() == fb.tobytes()


def slanted_pieces(tm):
    """Four pieces from two planes at slanted angles: staircases when tet-aligned."""
    c = tm.tet_centroids
    lab = (c @ [0.8, 0.5, 0.3] > 0.05).astype(int) + 2 * (c @ [-0.3, 0.7, -0.6] > -0.08)
    return pieces(tm, label_modes(tm, lab))


def test_fault_roughness_ignores_flat_triangulation_and_fault_boundaries():
    # A flat square fanned two ways, with a near-degenerate sliver: no turning.
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 1e-12, 0], [0.5, 0.5, 0]], float)
    F = np.array([[0, 4, 5], [4, 1, 5], [1, 2, 5], [2, 3, 5], [3, 0, 5], [0, 1, 4]])
    turning, area = fault_roughness(V, F, np.zeros(len(F), int))
    assert turning == pytest.approx(0.0, abs=1e-12) and area == pytest.approx(1.0)
    # A fold of 90 degrees along an edge of length 1 inside one fault: turning pi/2.
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1]], float)
    F = np.array([[0, 1, 2], [0, 2, 3], [1, 0, 4], [1, 4, 5]])
    turning, area = fault_roughness(V, F, np.zeros(4, int))
    assert turning == pytest.approx(np.pi / 2) and area == pytest.approx(2.0)
    # The same fold where two faults meet (a junction): not roughness.
    turning, area = fault_roughness(V, F, np.array([0, 0, 1, 1]))
    assert turning == pytest.approx(0.0) and area == pytest.approx(2.0)
    # Faces on no fault are ignored.
    assert fault_roughness(V, F, np.array([0, 0, -1, -1])) == (pytest.approx(0.0), pytest.approx(1.0))


def test_region_fault_roughness_of_planar_faults_is_zero():
    tm = grid_tetmesh((4, 4, 4), spacing=0.25, origin=(-0.5, -0.5, -0.5))
    c = tm.tet_centroids
    P = pieces(tm, label_modes(tm, (c[:, 0] > 0).astype(int) + 2 * (c[:, 1] > 0)))
    R = smooth(tm, P, SmoothOptions(smoothing=0.0))
    assert region_fault_roughness(R) == pytest.approx(0.0, abs=1e-9)
    # Each region's fault copy is measured once, whichever side.
    assert region_fault_roughness(Regions(meshes=R.meshes[::-1])) == pytest.approx(0.0, abs=1e-9)


def test_smoothing_makes_slanted_faults_smoother():
    tm = jittered_grid(7)
    P = slanted_pieces(tm)
    R0 = smooth(tm, P, SmoothOptions(smoothing=0.0))
    R1 = smooth(tm, P, FIELD)
    assert R1.vanished == ()
    check_partition(tm, R1, 1e-7)
    rough0, rough1 = region_fault_roughness(R0), region_fault_roughness(R1)
    print(f"fault roughness (1/diagonal): lambda=0 {rough0:.2f}, default lambda {rough1:.2f}")
    assert rough0 > 5.0  # tet-aligned slanted faults are stair-stepped
    assert rough1 < 0.5 * rough0
    # More smoothing, smoother faults (until pieces start to shrink away).
    R2 = smooth(tm, P, SmoothOptions(smoothing=4 * FIELD.smoothing, method="field", refine=0))
    assert region_fault_roughness(R2) < rough1


# ---------------------------------------------------------------------------
# Geometric method (the default): tet vertices move, pieces keep their tets.
# ---------------------------------------------------------------------------


def geometric_vertices(tm, P, lam, surface=None):
    tet_piece = P.tet_piece.astype(np.int64)
    return _smoothed_vertices(tm, _Topology(tm.tets, tm.num_vertices), tet_piece, P.num_pieces, lam, surface)[0]


def check_geometric(tm, P, R, X, slid=False):
    """Exact partition of the (deformed) cage by the deformed tets; tets valid; boundary unmoved unless ``slid``."""
    assert len(R.meshes) == P.num_pieces and R.vanished == ()
    # Every tet is in exactly one region, so the regions partition the cage as deformed.
    volumes = check_partition(TetMesh(vertices=X, tets=tm.tets), R, 1e-9)
    deformed = tetgeom.tet_volumes(X, tm.tets)
    assert np.all(deformed > 0.0)
    per_piece = np.bincount(P.tet_piece, weights=deformed, minlength=P.num_pieces)
    # Spindles at pinched edges move eps^2 of the tets around them between pieces.
    np.testing.assert_allclose(volumes, per_piece, rtol=1e-3)
    b = tm.boundary_vertices
    if not slid:
        assert X[b].tobytes() == tm.vertices[b].tobytes()
    for V, F in R.meshes:
        assert edge_manifold_by_index(F) and closed_by_position(V, F)


def test_geometric_smooths_faults_and_partitions_exactly():
    tm = jittered_grid(7)
    P = slanted_pieces(tm)
    default = SmoothOptions()
    assert default.method == "geometric"
    R0 = smooth(tm, P, SmoothOptions(smoothing=0.0))
    R1 = smooth(tm, P, default)
    R2 = smooth(tm, P, SmoothOptions(smoothing=1e-2))
    check_geometric(tm, P, R1, geometric_vertices(tm, P, default.smoothing))
    check_geometric(tm, P, R2, geometric_vertices(tm, P, 1e-2))
    rough0, rough1, rough2 = (region_fault_roughness(R) for R in (R0, R1, R2))
    print(f"geometric fault roughness: lambda=0 {rough0:.2f}, default {rough1:.2f}, 1e-2 {rough2:.2f}")
    # This grid is coarse (tet edge 1/7 of the diagonal-ish): the default barely reaches across a tet.
    assert rough1 < rough0
    assert rough2 < 0.9 * rough0


def test_geometric_keeps_tets_valid_under_strong_smoothing():
    # Strong smoothing of a thin piece squeezed between others must not invert or flatten tets.
    tm = jittered_grid(6, seed=2)
    c = tm.tet_centroids
    lab = (c[:, 0] + 0.3 * np.sin(9 * c[:, 1]) > 0.0).astype(int) + 2 * (np.abs(c[:, 2] - 0.1) < 0.12)
    P = pieces(tm, label_modes(tm, lab))
    X = geometric_vertices(tm, P, 0.2)
    ratio = tetgeom.tet_volumes(X, tm.tets) / tm.tet_volumes
    assert ratio.min() >= 0.05 - 1e-12
    check_geometric(tm, P, smooth(tm, P, SmoothOptions(smoothing=0.2)), X)


def test_geometric_deterministic():
    tm = jittered_grid(6)
    P = slanted_pieces(tm)
    A, B = smooth(tm, P), smooth(tm, P)
    for (va, fa), (vb, fb) in zip(A.meshes, B.meshes):
        assert va.tobytes() == vb.tobytes() and fa.tobytes() == fb.tobytes()


@pytest.fixture(scope="module")
def chair_case():
    """The chair sample asset (repaired), a 600-face cage's tet mesh and its atomic pieces."""
    from fracture_cli.stages.cage import CageOptions, cage
    from fracture_cli.stages.load import load_surface
    from fracture_cli.stages.modes import ModesOptions, modes
    from fracture_cli.stages.repair import repair
    from fracture_cli.stages.tetra import tetra

    path = Path(__file__).resolve().parents[1] / "sample_assets" / "chair.glb"
    surface = repair(load_surface(path))
    tm = tetra(cage(surface, CageOptions(target_faces=600)))
    return surface, tm, pieces(tm, modes(tm, ModesOptions(num_modes=4)))


def test_geometric_smooths_faults_of_a_sample_asset(chair_case):
    _, tm, P = chair_case
    R0 = smooth(tm, P, SmoothOptions(smoothing=0.0))
    R1 = smooth(tm, P)
    check_geometric(tm, P, R1, geometric_vertices(tm, P, SmoothOptions().smoothing))
    rough0, rough1 = region_fault_roughness(R0), region_fault_roughness(R1)
    print(f"chair (600-face cage) fault roughness: lambda=0 {rough0:.2f}, default {rough1:.2f}")
    assert rough1 < rough0


# ---------------------------------------------------------------------------
# Geometric method with the input given: boundary fault curves slide along the cage.
# ---------------------------------------------------------------------------


def box_surface(lo, hi):
    """A closed box SurfaceMesh from corner ``lo`` to ``hi`` (already in normalized coordinates)."""
    import trimesh

    from fracture_cli.types import Material, Normalization, SurfaceMesh

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    box = trimesh.creation.box(extents=hi - lo)
    box.apply_translation((lo + hi) / 2.0)
    return SurfaceMesh(vertices=np.asarray(box.vertices, dtype=np.float64),
                       faces=np.asarray(box.faces, dtype=np.int64), uvs=None, normals=None, colors=None,
                       material_ids=np.zeros(len(box.faces), np.int32), materials=(Material("m"),),
                       normalization=Normalization.identity(), name="box")


def distance_to_triangles(points, V, F):
    """Brute-force distance (k,) from ``points`` to the triangles ``F`` over ``V`` (independent of smooth.py)."""
    k, m = len(points), len(F)
    d = point_triangle_distance(np.repeat(points, m, axis=0), np.tile(V[F], (k, 1, 1)))
    return d.reshape(k, m).min(axis=1)


def check_slid(tm, X, surface, clearance=1e-4):
    """Moved cage vertices stay on the original cage; the moved cage strictly contains ``surface``."""
    b = tm.boundary_vertices
    F = tm.boundary_faces
    moved = b[np.any(X[b] != tm.vertices[b], axis=1)]
    if len(moved):
        assert distance_to_triangles(X[moved], tm.vertices, F).max() < 1e-9
    # Containment, checked with manifold3d: nothing of the input outside the moved cage, and the input's
    # vertices keep a clearance from the moved cage.
    used, local = np.unique(F, return_inverse=True)
    cage_solid = solid(X[used], local.reshape(-1, 3))
    # Weld the input by position (attribute seams split its vertices).
    welded, weld = np.unique(surface.vertices, axis=0, return_inverse=True)
    input_solid = solid(welded, weld.reshape(-1)[surface.faces])
    assert cage_solid.status() == manifold3d.Error.NoError and input_solid.volume() > 0.0
    assert (input_solid - cage_solid).volume() < 1e-12 * input_solid.volume()
    assert distance_to_triangles(surface.vertices, X, F).min() > clearance
    return moved


def test_sliding_moves_boundary_along_the_cage_and_keeps_the_input_inside():
    tm = jittered_grid(7)
    P = slanted_pieces(tm)
    surface = box_surface((-0.4, -0.4, -0.4), (0.4, 0.4, 0.4))
    lam = SmoothOptions().smoothing
    X = geometric_vertices(tm, P, lam, surface)
    moved = check_slid(tm, X, surface)
    assert len(moved) > 10
    R = smooth(tm, P, surface=surface)
    check_geometric(tm, P, R, X, slid=True)
    X0 = geometric_vertices(tm, P, lam)
    rough0 = region_fault_roughness(smooth(tm, P, SmoothOptions(smoothing=0.0)))
    rough_fixed = region_fault_roughness(smooth(tm, P))
    rough_slid = region_fault_roughness(R)
    print(f"grid fault roughness: lambda=0 {rough0:.2f}, fixed cage {rough_fixed:.2f}, sliding {rough_slid:.2f}")
    assert rough_slid < rough_fixed < rough0
    assert not np.array_equal(X, X0)


def test_sliding_stops_where_the_input_is_too_close():
    # The input nearly touches the cage face x = 0.5: no cage triangle near it may move there.
    tm = jittered_grid(7)
    P = slanted_pieces(tm)
    surface = box_surface((-0.4, -0.4, -0.4), (0.4997, 0.4, 0.4))
    X = geometric_vertices(tm, P, SmoothOptions().smoothing, surface)
    moved = check_slid(tm, X, surface, clearance=2e-4)
    assert len(moved) > 5  # the other faces still slide
    F = tm.boundary_faces
    # Every cage triangle at a moved vertex keeps its clearance: no vertex of the face x = 0.5 moved.
    near = np.unique(F[np.all(tm.vertices[F][:, :, 0] > 0.5 - 1e-9, axis=1)])
    assert not np.isin(moved, near).any()
    # Without the input that close, some of them would have slid.
    free = geometric_vertices(tm, P, SmoothOptions().smoothing, box_surface((-0.4,) * 3, (0.4,) * 3))
    assert np.any(free[near] != tm.vertices[near])


def test_sliding_deterministic():
    tm = jittered_grid(6)
    P = slanted_pieces(tm)
    surface = box_surface((-0.4, -0.4, -0.4), (0.4, 0.4, 0.4))
    A, B = smooth(tm, P, surface=surface), smooth(tm, P, surface=surface)
    for (va, fa), (vb, fb) in zip(A.meshes, B.meshes):
        assert va.tobytes() == vb.tobytes() and fa.tobytes() == fb.tobytes()


def test_sliding_on_a_sample_asset(chair_case):
    from fracture_cli.checks import fragment_invariants
    from fracture_cli.pipeline.recipe import load_recipe
    from fracture_cli.stages.fragments import fragments

    surface, tm, P = chair_case
    lam = SmoothOptions().smoothing
    X = geometric_vertices(tm, P, lam, surface)
    check_slid(tm, X, surface)
    R = smooth(tm, P, surface=surface)
    check_geometric(tm, P, R, X, slid=True)
    rough0 = region_fault_roughness(smooth(tm, P, SmoothOptions(smoothing=0.0)))
    rough_fixed = region_fault_roughness(smooth(tm, P))
    rough_slid = region_fault_roughness(R)
    print(f"chair (600-face cage) fault roughness: lambda=0 {rough0:.2f}, fixed cage {rough_fixed:.2f}, "
          f"sliding {rough_slid:.2f}")
    assert rough0 - rough_slid > rough0 - rough_fixed
    # The fragments still hold the whole input.
    frags = fragments(surface, R, load_recipe("default")["fragments"])
    invariants = fragment_invariants(surface, frags)
    assert invariants["volume_error"] < 1e-6


# ---------------------------------------------------------------------------
# Field method on a refined mesh (regular 1:8 refinement of the cage tets).
# ---------------------------------------------------------------------------


def test_red_refinement_is_a_conforming_positive_split():
    tm = jittered_grid(3, seed=4)
    V2, T2, parent = tetgeom.refine_red(tm.vertices, tm.tets)
    assert T2.shape == (8 * tm.num_tets, 4) and np.array_equal(parent, np.repeat(np.arange(tm.num_tets), 8))
    child = tetgeom.tet_volumes(V2, T2)
    assert np.all(child > 0)
    # every parent is split exactly: children volumes add up to it
    np.testing.assert_allclose(child.reshape(-1, 8).sum(axis=1), tm.tet_volumes, rtol=1e-12)
    # conforming: every child face is shared by two children or lies on the boundary, which is the old
    # boundary split into 4
    fine = TetMesh(V2, T2)
    assert len(fine.boundary_faces) == 4 * len(tm.boundary_faces)
    faces = np.sort(np.concatenate([T2[:, [1, 2, 3]], T2[:, [0, 2, 3]], T2[:, [0, 1, 3]], T2[:, [0, 1, 2]]]), axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    assert counts.max() == 2 and (counts == 1).sum() == len(fine.boundary_faces)
    # the old vertices keep their positions and numbers
    np.testing.assert_array_equal(V2[: tm.num_vertices], tm.vertices)


def test_refined_field_partitions_the_cage_and_flattens_creases():
    from fracture_cli.checks.faultshape import fault_shape, region_faults

    tm = jittered_grid(5, seed=2)
    P = plane_pieces(tm)
    R0 = smooth(tm, P, SmoothOptions(smoothing=0.0))
    R = smooth(tm, P, SmoothOptions(smoothing=4e-3, method="field", refine=2))
    assert len(R.meshes) == P.num_pieces and not R.vanished
    for V, F in R.meshes:
        assert closed_by_position(V, F)
    check_partition(tm, R, 1e-9)
    shape0, shape = fault_shape(*region_faults(R0)), fault_shape(*region_faults(R))
    print(f"refined field: mean dihedral {shape0['mean_dihedral_degrees']:.1f} -> "
          f"{shape['mean_dihedral_degrees']:.1f}, "
          f"creases {shape0['crease_density']:.2f} -> {shape['crease_density']:.2f}")
    assert shape["mean_dihedral_degrees"] < 0.5 * shape0["mean_dihedral_degrees"]
    assert shape["crease_density"] < 0.5 * shape0["crease_density"]


def test_refinement_respects_the_tet_budget(caplog):
    tm = jittered_grid(3, seed=1)
    P = plane_pieces(tm)
    with caplog.at_level(logging.INFO, logger="fracture_cli.stages.smooth"):
        smooth(tm, P, SmoothOptions(smoothing=4e-3, method="field", refine=3, max_refined_tets=8 * tm.num_tets))
    assert "1 of 3 refinement level(s)" in caplog.text


def test_fault_shape_counts_creases_not_fans():
    from fracture_cli.checks.faultshape import fault_shape

    # A flat square fanned into 4 triangles: no dihedral, no crease.
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 0]], float)
    F = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    shape = fault_shape(V, F, np.zeros(4, int))
    assert shape["mean_dihedral_degrees"] == 0.0 and shape["crease_density"] == 0.0 and shape["area"] == 1.0
    # Fold the square along its diagonal by 90 degrees: one crease of length sqrt(2).
    V2 = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0.5, 0.5, np.sqrt(0.5)]], float)
    F2 = np.array([[0, 1, 2], [0, 2, 3]])
    shape = fault_shape(V2, F2, np.zeros(2, int))
    assert shape["mean_dihedral_degrees"] == pytest.approx(90.0, abs=1e-6)
    assert shape["crease_density"] == pytest.approx(np.sqrt(2) / shape["area"])
