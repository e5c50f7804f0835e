"""Fragments cut from the input (fracture_cli.stages.fragments) and their invariants, checked independently."""

import itertools
import logging

import manifold3d
import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from fracture_cli.checks import fragment_invariants
from fracture_cli.errors import StageError
from fracture_cli.stages.fragments import FragmentOptions, fragments
from fracture_cli.stages.pieces import pieces
from fracture_cli.stages.repair import RepairOptions, repair
from fracture_cli.stages.smooth import SmoothOptions, smooth
from fracture_cli.testing import jittered_grid_tetmesh
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Material, Modes, Normalization, SurfaceMesh


def surface(V, F, uvs=None, normals=None, material_ids=None, materials=(Material("stone"),), scale=1.0):
    V = np.asarray(V, float) * scale
    norm = Normalization.from_points(V)
    if normals is None:
        normals = trimesh.Trimesh(V, F, process=False).vertex_normals
    return SurfaceMesh(vertices=norm.to_normalized(V), faces=np.asarray(F, np.int64), uvs=uvs,
                       normals=np.asarray(normals, float), colors=None,
                       material_ids=np.zeros(len(F), np.int32) if material_ids is None else material_ids,
                       materials=materials, normalization=norm)


def uv_sphere(scale=1.0):
    ico = trimesh.creation.icosphere(subdivisions=3)
    n = ico.vertices / np.linalg.norm(ico.vertices, axis=1, keepdims=True)
    uv = np.column_stack([np.arctan2(n[:, 1], n[:, 0]) / (2 * np.pi) + 0.5, np.arccos(n[:, 2]) / np.pi])
    return surface(ico.vertices, ico.faces, uvs=uv, normals=n, scale=scale)


def seamed_box():
    """A box with every face's vertices split (UV seams), two materials."""
    box = trimesh.creation.box(extents=(1.0, 0.8, 0.6))
    V = box.vertices[box.faces].reshape(-1, 3)
    F = np.arange(len(V)).reshape(-1, 3)
    uv = np.tile([[0, 0], [1, 0], [0, 1]], (len(box.faces), 1)).astype(float)
    normals = np.repeat(box.face_normals, 3, axis=0)
    mats = (np.arange(len(F)) % 2).astype(np.int32)
    return surface(V, F, uvs=uv, normals=normals, material_ids=mats, materials=(Material("a"), Material("b")))


def open_cylinder():
    cyl = trimesh.creation.cylinder(radius=0.3, height=1.0, sections=24)
    side = np.abs(cyl.face_normals[:, 2]) < 0.5
    m = trimesh.Trimesh(cyl.vertices, cyl.faces[side], process=False)
    m.remove_unreferenced_vertices()
    return surface(m.vertices, m.faces)


def cage_tets(n=6, seed=0):
    """Jittered grid covering the normalized input's bbox (unit diagonal) with a margin."""
    return jittered_grid_tetmesh(n, 0.4, 0.08 / n, seed)


def octant_pieces(tm):
    c = tm.tet_centroids
    lab = (c[:, 0] > 0.03).astype(int) + 2 * (c[:, 1] > -0.05) + 4 * (c[:, 2] + 0.2 * c[:, 0] > 0.02)
    ft = tm.interior_face_tets
    modes = Modes(U=lab[None, :, None].astype(float), labels=lab[None].astype(np.int32),
                  cut=(lab[ft[:, 0]] != lab[ft[:, 1]])[None], piece_counts=np.array([8]),
                  energies=np.zeros(1), iterations=np.ones(1, np.int32))
    return pieces(tm, modes)


def to_solid(V, F):
    _, first, pos = np.unique(V, axis=0, return_index=True, return_inverse=True)
    target = first[pos.reshape(-1)]
    src = np.flatnonzero(target != np.arange(len(V)))
    return manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(V), tri_verts=np.ascontiguousarray(F, dtype=np.uint64),
        merge_from_vert=src.astype(np.uint64), merge_to_vert=target[src].astype(np.uint64)))


def closest_distance(p, tris):
    """Smallest float64 distance from point ``p`` (3,) to triangles ``tris`` (m, 3, 3) (closest-point regions)."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    n = np.cross(ab, ac)
    n2 = np.einsum("ij,ij->i", n, n)
    flat = n2 <= 0  # degenerate triangles: only their edges count
    n2 = np.where(flat, 1.0, n2)
    # inside the prism over the triangle: distance to the plane
    w_c = np.einsum("ij,ij->i", np.cross(ab, ap), n) / n2
    w_b = np.einsum("ij,ij->i", np.cross(ap, ac), n) / n2
    inside = ~flat & (w_b >= 0) & (w_c >= 0) & (w_b + w_c <= 1)
    plane = np.abs(np.einsum("ij,ij->i", ap, n)) / np.sqrt(n2)

    # otherwise: distance to the nearest of the three edges
    def segment(u, v):
        d = v - u
        dd = np.einsum("ij,ij->i", d, d)
        t = np.clip(np.einsum("ij,ij->i", p - u, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
        return np.linalg.norm(p - (u + t[:, None] * d), axis=1)

    edges = np.minimum(np.minimum(segment(a, b), segment(b, c)), segment(c, a))
    return float(np.where(inside, np.minimum(plane, edges), edges).min())


def check_invariants(surf, frags, input_volume):
    """The section-6 promises, measured with trimesh/manifold3d/open3d, not with the stage's code."""
    assert frags.materials[-1].name == INTERIOR_MATERIAL_NAME
    interior = len(frags.materials) - 1
    volumes = []
    solids = []
    for f in frags.fragments:
        tm = trimesh.Trimesh(f.vertices, f.faces)  # merges vertices by position
        assert tm.is_watertight and tm.is_winding_consistent
        s = to_solid(f.vertices, f.faces)
        assert s.status() == manifold3d.Error.NoError
        volumes.append(tm.volume)
        solids.append(s)
        assert f.uvs.shape == (len(f.vertices), 2) and f.normals.shape == (len(f.vertices), 3)
        np.testing.assert_allclose(np.linalg.norm(f.normals, axis=1), 1.0, atol=1e-6)
        # interior faces: flat normals equal to the face normal
        inner = f.faces[f.material_ids == interior]
        P = f.vertices[inner]
        fn = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
        big = np.linalg.norm(fn, axis=1) > 1e-8
        fn = fn[big] / np.linalg.norm(fn[big], axis=1, keepdims=True)
        for k in range(3):
            assert np.all(np.einsum("ij,ij->i", f.normals[inner[big, k]], fn) > 0.999)
    volumes = np.array(volumes)
    assert abs(volumes.sum() - input_volume) < 1e-3 * input_volume
    boxes = [(f.vertices.min(axis=0), f.vertices.max(axis=0)) for f in frags.fragments]
    for a, b in itertools.combinations(range(len(solids)), 2):
        if np.all(boxes[a][0] <= boxes[b][1]) and np.all(boxes[b][0] <= boxes[a][1]):  # else they cannot overlap
            assert (solids[a] ^ solids[b]).volume() < 1e-3 * min(volumes[a], volumes[b])
    # outer faces lie on the input (float64 distances to the nearest input triangles)
    triangles = surf.vertices[surf.faces]
    tree = cKDTree(triangles.mean(axis=1))
    reach = np.linalg.norm(triangles - triangles.mean(axis=1, keepdims=True), axis=2).max()
    for f in frags.fragments:
        outer = np.unique(f.faces[f.material_ids != interior])
        for point in f.vertices[outer]:
            near = tree.query_ball_point(point, reach + 1e-9)
            assert near, "an outer vertex is farther than a triangle's size from the input"
            assert closest_distance(point, triangles[near]) < 1e-6
    return volumes


@pytest.mark.parametrize("smoothing", [0.0, 1e-3])
def test_sphere_fragments(smoothing):
    surf = uv_sphere(scale=3.0)
    tm = cage_tets()
    P = octant_pieces(tm)
    R = smooth(tm, P, SmoothOptions(smoothing=smoothing))
    frags = fragments(surf, R)
    input_volume = trimesh.Trimesh(surf.vertices, surf.faces).volume
    assert frags.input_volume == pytest.approx(input_volume, rel=1e-9)
    check_invariants(surf, frags, input_volume)
    # jittered tets make the plane labels leave a few small extra pieces; each gives at most one fragment
    ids = [f.piece for f in frags.fragments]
    assert len(ids) >= 8 and len(set(ids)) == len(ids) and max(ids) < P.num_pieces
    # UVs kept: outer vertices at an input vertex position carry that vertex's UV
    lookup = {tuple(v): uv for v, uv in zip(surf.vertices.round(12).tolist(), surf.uvs.tolist())}
    hits = 0
    for f in frags.fragments:
        outer = np.unique(f.faces[f.material_ids == 0])
        for v, uv in zip(f.vertices[outer].round(12).tolist(), f.uvs[outer].tolist()):
            if tuple(v) in lookup:
                np.testing.assert_allclose(uv, lookup[tuple(v)], atol=1e-9)
                hits += 1
    assert hits > 0.9 * surf.num_vertices
    # stable order: by rounded centroid
    report = fragment_invariants(surf, frags)
    assert report["watertight"] and report["volume_error"] < 1e-3 and report["max_outer_distance"] < 1e-6
    assert report["max_overlap"] < 1e-3


def test_interior_uvs_scale_with_world_units():
    tm = cage_tets(4)
    P = octant_pieces(tm)
    R = smooth(tm, P, SmoothOptions(smoothing=0.0))
    small, large = uv_sphere(scale=1.0), uv_sphere(scale=10.0)
    a = fragments(small, R, FragmentOptions(uv_scale=1.0))
    b = fragments(large, R, FragmentOptions(uv_scale=10.0))
    for fa, fb in zip(a.fragments, b.fragments):
        np.testing.assert_allclose(fa.vertices, fb.vertices, atol=1e-12)
        inner = np.unique(fa.faces[fa.material_ids == 1])
        # same shape, scale and uv_scale together: same interior UVs up to the centre offset
        du_a = fa.uvs[inner] - fa.uvs[inner].mean(axis=0)
        du_b = fb.uvs[inner] - fb.uvs[inner].mean(axis=0)
        np.testing.assert_allclose(du_a, du_b, atol=1e-9)


def test_seamed_box_keeps_materials_and_seams():
    surf = seamed_box()
    tm = cage_tets(4)
    R = smooth(tm, octant_pieces(tm), SmoothOptions(smoothing=0.0))
    frags = fragments(surf, R)
    assert [m.name for m in frags.materials] == ["a", "b", INTERIOR_MATERIAL_NAME]
    check_invariants(surf, frags, 1.0 * 0.8 * 0.6 / surf.normalization.scale ** 3)
    ids = np.concatenate([f.material_ids for f in frags.fragments])
    assert set(np.unique(ids)) == {0, 1, 2}
    # outer UVs stay within the input's UV range
    for f in frags.fragments:
        outer = np.unique(f.faces[f.material_ids < 2])
        assert f.uvs[outer].min() >= -1e-9 and f.uvs[outer].max() <= 1 + 1e-9


def test_open_input_is_refused_until_repaired():
    surf = open_cylinder()
    tm = cage_tets(4)
    R = smooth(tm, octant_pieces(tm), SmoothOptions(smoothing=0.0))
    with pytest.raises(StageError, match="repair"):
        fragments(surf, R)
    repaired = repair(surf, RepairOptions(open_surface="fill"))
    frags = fragments(repaired, R)
    # the interior slot repair added is reused, not duplicated
    assert [m.name for m in frags.materials] == ["stone", INTERIOR_MATERIAL_NAME]
    closed = trimesh.creation.cylinder(radius=0.3, height=1.0, sections=24)
    check_invariants(repaired, frags, closed.volume / surf.normalization.scale ** 3)


def test_overlapping_bodies_are_united():
    a = trimesh.creation.box(extents=(1, 1, 1))
    b = trimesh.creation.box(extents=(1, 1, 1))
    b.apply_translation((0.5, 0.25, 0.0))
    both = trimesh.util.concatenate([a, b])
    surf = surface(both.vertices, both.faces)
    tm = cage_tets(4)
    frags = fragments(surf, smooth(tm, octant_pieces(tm), SmoothOptions(smoothing=0.0)))
    union_volume = (2 - 0.5 * 0.75) / surf.normalization.scale ** 3  # two unit boxes minus their overlap
    assert frags.input_volume == pytest.approx(union_volume, rel=1e-9)
    assert sum(trimesh.Trimesh(f.vertices, f.faces).volume for f in frags.fragments) == pytest.approx(
        union_volume, rel=1e-3)


def test_region_missing_the_input_gives_no_fragment(caplog):
    surf = uv_sphere()
    tm = cage_tets(6)
    c = tm.tet_centroids
    # piece 1: the eight corner voxels' tets, far outside the sphere (|c| > 0.5 of the unit-diagonal box)
    lab = (np.linalg.norm(c, axis=1) > 0.55).astype(int)
    ft = tm.interior_face_tets
    modes = Modes(U=lab[None, :, None].astype(float), labels=lab[None].astype(np.int32),
                  cut=(lab[ft[:, 0]] != lab[ft[:, 1]])[None], piece_counts=np.array([2]),
                  energies=np.zeros(1), iterations=np.ones(1, np.int32))
    P = pieces(tm, modes)
    with caplog.at_level(logging.WARNING):
        frags = fragments(surf, smooth(tm, P, SmoothOptions(smoothing=0.0)))
    assert 0 < len(frags.fragments) < P.num_pieces
    assert any("do not reach" in r.message for r in caplog.records)
    assert all(trimesh.Trimesh(f.vertices, f.faces).volume > 0 for f in frags.fragments)


def test_deterministic_and_ordered():
    surf = uv_sphere()
    tm = cage_tets(4)
    R = smooth(tm, octant_pieces(tm), SmoothOptions(smoothing=0.0))
    a, b = fragments(surf, R), fragments(surf, R)
    for fa, fb in zip(a.fragments, b.fragments):
        assert fa.piece == fb.piece
        for name in ("vertices", "faces", "uvs", "normals", "material_ids"):
            assert getattr(fa, name).tobytes() == getattr(fb, name).tobytes()
    keys = [tuple(np.round(trimesh.Trimesh(f.vertices, f.faces).center_mass, 6)) for f in a.fragments]
    assert keys == sorted(keys)


def test_box_uv_axis_ties_do_not_depend_on_rounding():
    from fracture_cli.geometry.uvs import box_uvs

    s = np.sqrt(0.5)
    # A 45-degree face whose normal carries rounding noise either way projects the same way.
    normals = np.array([[s, s + 1e-15, 0.0], [s + 1e-15, s, 0.0], [s, s, 0.0]])
    world = np.array([[0.3, 0.7, 0.2]] * 3)
    uvs = box_uvs(world, normals, 1.0)
    np.testing.assert_array_equal(uvs, np.repeat(uvs[:1], 3, axis=0))
    # A clear winner still wins.
    assert not np.array_equal(box_uvs(world, np.array([[0.1, 0.99, 0.0]]), 1.0), uvs[:1])


def test_one_body_cuts_give_what_split_fragments_gives():
    """The stage skips split_fragments when the workers found one body per cut: the same fragments and report."""
    from fracture_cli.stages.fragments import fragments_with_split
    from fracture_cli.stages.fragments.bodies import split_fragments

    surf = uv_sphere()
    tm = cage_tets(4)
    R = smooth(tm, octant_pieces(tm), SmoothOptions(smoothing=0.0))
    options = FragmentOptions()
    frags, report = fragments_with_split(surf, R, options)
    again, expected = split_fragments(frags, options.min_body_fraction)
    assert again is frags and report == expected
