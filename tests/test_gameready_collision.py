"""Convex collision parts: decomposition, vertex cap, separation, overlap checker."""

from __future__ import annotations

import manifold3d
import numpy as np
import pytest
import trimesh

from fracture_cli.geometry.mass import mass_properties
from fracture_cli.stages.collision.convex import (
    CollisionOptions,
    collision_shapes,
    hull_mesh,
    max_overlap_fraction,
    separate_parts,
    simplify_hull,
    volume_beyond,
)


def _mesh(solid: manifold3d.Manifold):
    mesh = solid.to_mesh64()
    return (np.array(mesh.vert_properties, dtype=float)[:, :3].copy(),
            np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3))


def _ridge_pair():
    """A 2 x 1 x 1 box cut by a ridge-shaped fault: the left piece is convex, the right one wraps around it."""
    box = manifold3d.Manifold.cube([2.0, 1.0, 1.0])
    left = box.trim_by_plane([-1.0, 0.6, 0.0], -1.0).trim_by_plane([-1.0, -0.6, 0.0], -1.6)
    return _mesh(left), _mesh(box - left)


def _l_shape():
    return _mesh(manifold3d.Manifold.cube([2.0, 1.0, 1.0]) + manifold3d.Manifold.cube([1.0, 2.0, 1.0]))


def _volume(parts):
    return sum(mass_properties(*hull_mesh(p)).volume for p in parts)


def test_nearly_convex_fragment_is_its_hull():
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    shapes = collision_shapes([(np.asarray(box.vertices), np.asarray(box.faces))])
    (parts,) = shapes.parts
    assert len(parts) == 1 and len(parts[0]) == 8
    assert shapes.hull_ratio[0] == pytest.approx(1.0) and shapes.coverage[0] == pytest.approx(1.0)


def test_concave_fragment_is_decomposed_into_disjoint_parts():
    V, F = _l_shape()
    shapes = collision_shapes([(V, F)], CollisionOptions(max_parts=4, concavity=0.05))
    (parts,) = shapes.parts
    assert 2 <= len(parts) <= 4
    assert shapes.hull_ratio[0] == pytest.approx(3.5 / 3.0)  # the L's hull is a pentagonal prism
    assert max_overlap_fraction(parts) < 1e-9
    assert _volume(parts) == pytest.approx(3.0, rel=0.05)
    assert shapes.coverage[0] > 0.99


def _interlocking_hooks():
    """A slab with two hooks whose arms interleave: cutting the slab off leaves two components on one side
    whose hulls overlap (the coarse radial box of issue 32 had such a fragment)."""
    solid = None
    for x, z, a, c in ((0, 0, 3, 0.37), (0, 0, 0.37, 1.86), (0, 1.49, 2.29, 0.37), (2.63, 0, 0.37, 1.47),
                       (0.89, 1.1, 2.11, 0.37)):
        box = manifold3d.Manifold.cube([a, 1.0, c]).translate([x, 0.0, z])
        solid = box if solid is None else solid + box
    return solid


def test_pieces_in_different_cells_do_not_overlap_when_a_cell_held_several():
    """Cutting one of several components that share a cell keeps its halves in that cell: the others may
    reach into both halves, so their pairs must be separated (they were skipped, leaving 4.6% overlap)."""
    from fracture_cli.stages.collision import decompose

    solid = _interlocking_hooks()
    leaves, cells = decompose.decomposition_cells(solid, 8, 0.05)
    assert len(leaves) == 8 and len(set(cells)) < len(cells)  # some cell held several pieces
    hulls = [leaf.hull() for leaf in leaves]
    for i in range(len(leaves)):
        for j in range(i + 1, len(leaves)):
            if cells[i] != cells[j]:
                assert (hulls[i] ^ hulls[j]).volume() <= 1e-9 * min(hulls[i].volume(), hulls[j].volume())
    (parts,) = collision_shapes([_mesh(solid)], CollisionOptions(max_parts=8, concavity=0.05)).parts
    assert len(parts) == 8 and max_overlap_fraction(parts) < 1e-9


def test_vertex_cap_keeps_a_subset_that_covers_the_part():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    points = np.asarray(sphere.vertices)
    simplified = simplify_hull(points, 64)
    assert len(simplified) <= 64
    # A subset of the corners: the simplified part lies inside the original one.
    assert np.all(np.min(np.linalg.norm(simplified[:, None] - points[None], axis=2), axis=1) == 0)
    assert _volume([simplified]) > 0.9 * sphere.volume
    assert np.array_equal(simplify_hull(points, 64), simplified)  # deterministic


def test_neighbours_with_a_curved_fault_do_not_overlap():
    left, right = _ridge_pair()
    from fracture_cli.stages.collision.convex import hull_corners
    hulls = [hull_corners(manifold3d.Manifold(manifold3d.Mesh64(vert_properties=V, tri_verts=F.astype(np.uint64))))
             for V, F in (left, right)]
    assert max_overlap_fraction([hulls[0]], [hulls[1]]) > 0.15  # plain hulls collide
    for options in (CollisionOptions(), CollisionOptions(max_parts=1)):
        shapes = collision_shapes([left, right], options)
        assert max_overlap_fraction(shapes.parts[0], shapes.parts[1]) < 1e-9
        assert max_overlap_fraction([p for parts in shapes.parts for p in parts]) < 1e-9
    # With room for parts, the wrapping piece is decomposed and both keep (nearly) all their material.
    shapes = collision_shapes([left, right])
    assert len(shapes.parts[1]) >= 2 and np.all(shapes.coverage > 0.98)


def test_separation_by_one_plane_loses_little_material():
    """Two hulls that overlap by a sixth of the smaller one: one plane separates them, each keeps >= 90%."""
    left, right = _ridge_pair()
    parts = [hull_mesh(V)[0] for V, _ in (left, right)]
    a, b = separate_parts(parts, [left, right])
    assert max_overlap_fraction([a], [b]) < 1e-9
    for kept, (V, F) in ((a, left), (b, right)):
        solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=V, tri_verts=F.astype(np.uint64)))
        hull = manifold3d.Manifold.hull_points(kept)
        assert (solid ^ hull).volume() > 0.9 * solid.volume()


def test_collision_shapes_are_deterministic():
    meshes = [_l_shape(), *_ridge_pair()]
    first = collision_shapes(meshes)
    second = collision_shapes(meshes)
    assert all(np.array_equal(p, q) for a, b in zip(first.parts, second.parts) for p, q in zip(a, b))


def test_max_overlap_fraction_is_exact():
    cube = np.array(np.meshgrid([0, 1], [0, 1], [0, 1])).reshape(3, -1).T.astype(float)
    assert max_overlap_fraction([cube], [cube + [0.5, 0, 0]]) == pytest.approx(0.5)
    assert max_overlap_fraction([cube], [cube * 2 + [0.5, 0.5, 0.5]]) == pytest.approx(0.125)
    assert max_overlap_fraction([cube, cube + [1.0, 0, 0]]) == 0.0  # touching faces
    assert max_overlap_fraction([cube], [cube + [3.0, 0, 0]]) == 0.0


def test_volume_beyond_matches_a_boolean():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.asarray(sphere.vertices),
                                                  tri_verts=np.asarray(sphere.faces, dtype=np.uint64)))
    normal = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    offsets = np.array([-1.5, -0.3, 0.0, 0.6, 1.5])
    expected = [solid.trim_by_plane(normal, o).volume() for o in offsets]
    assert np.allclose(volume_beyond(sphere.vertices, sphere.faces, normal, offsets), expected, atol=1e-12)


def test_max_overlap_fraction_matches_booleans_on_many_pairs():
    """The face-plane shortcut never hides an overlap (parts with coplanar corners, whose hulls have flat faces)."""
    rng = np.random.default_rng(7)
    grid = np.array(np.meshgrid(*[np.linspace(0, 1, 4)] * 3)).reshape(3, -1).T
    parts = [grid * rng.uniform(0.3, 1.0, 3) + rng.uniform(-0.5, 0.5, 3) for _ in range(8)]
    hulls = [manifold3d.Manifold.hull_points(p) for p in parts]
    expected = max((hulls[i] ^ hulls[j]).volume() / min(hulls[i].volume(), hulls[j].volume())
                   for i in range(len(parts)) for j in range(i + 1, len(parts)))
    assert expected > 0.01
    assert max_overlap_fraction(parts) == pytest.approx(expected, rel=1e-9)


def test_collision_shapes_are_the_same_with_one_job_and_two():
    from fracture_cli.system import parallel

    meshes = [_l_shape(), *_ridge_pair()]
    with parallel.using(1):
        serial = collision_shapes(meshes)
    with parallel.using(2):
        forked = collision_shapes(meshes)
    assert [len(p) for p in serial.parts] == [len(p) for p in forked.parts]
    assert all(p.tobytes() == q.tobytes() for a, b in zip(serial.parts, forked.parts) for p, q in zip(a, b))
    assert serial.coverage.tobytes() == forked.coverage.tobytes()


def test_bounded_cut_search_chooses_as_trying_every_cut(monkeypatch):
    """Parts with many vertices rank candidate cuts by lower bounds (thinned hulls) first: same pieces as
    computing every candidate's cost."""
    from fracture_cli.stages.collision import decompose

    # A bumpy torus of ~5,000 vertices: concave, dense, above the bound threshold.
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.35, major_sections=96, minor_sections=48)
    V = np.asarray(torus.vertices)
    V = V * (1.0 + 0.05 * np.sin(9 * V[:, :1]) * np.sin(7 * V[:, 1:2]))
    solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(V),
                                                   tri_verts=np.asarray(torus.faces, dtype=np.uint64)))
    assert solid.num_vert() > decompose._BOUND_VERTICES
    bounded = decompose.decomposition_cells(solid, 6, 0.05)
    monkeypatch.setattr(decompose, "_BOUND_VERTICES", 10 ** 9)
    exhaustive = decompose.decomposition_cells(solid, 6, 0.05)
    assert bounded[1] == exhaustive[1] and len(bounded[0]) == len(exhaustive[0]) > 1
    for a, b in zip(bounded[0], exhaustive[0]):
        assert np.array_equal(_mesh(a)[0], _mesh(b)[0])
