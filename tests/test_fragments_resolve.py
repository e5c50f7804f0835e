"""Issue 39: fragments that pinch as written are split, self-touching vertices moved apart, touching bodies kept
apart, non-planar holes patched (small meshes built here)."""

from __future__ import annotations

import manifold3d
import numpy as np
import pytest
import trimesh

from fracture_cli.geometry.solids import body_groups
from fracture_cli.geometry.weld_check import check_mesh
from fracture_cli.stages.fragments.resolve import (
    PINCH_GAPS,
    resolve_pinches,
    separate_pinched_vertices,
    split_at_pinches,
    written_check,
)
from fracture_cli.stages.repair.patch import least_area_patch
from fracture_cli.types import Fragment, Fragments, Material, Normalization


def box(lo, size=1.0):
    b = trimesh.creation.box(extents=(size, size, size))
    return b.vertices + np.asarray(lo, dtype=np.float64) + size / 2, np.asarray(b.faces, dtype=np.int64)


def fragment(V, F, piece=0):
    return Fragment(vertices=np.asarray(V, dtype=np.float64), faces=np.asarray(F, dtype=np.int64),
                    uvs=np.zeros((len(V), 2)), normals=np.zeros((len(V), 3)),
                    material_ids=np.zeros(len(F), np.int32), piece=piece)


def fragments(*frags, volume):
    return Fragments(fragments=tuple(frags), materials=(Material("m"),), normalization=Normalization.identity(),
                     input_volume=volume)


def test_two_boxes_touching_along_an_edge_become_two_fragments():
    A, FA = box((0.0, 0.0, 0.0))
    B, FB = box((1.0, 1.0, 0.0))  # shares the vertical edge x = y = 1
    frags = fragments(fragment(np.vstack([A, B]), np.vstack([FA, FB + len(A)]), piece=3), volume=2.0)
    before = written_check(frags.fragments[0], frags)
    assert before.pinched_edges == 1 and before.bodies == 2
    bodies, slivers = split_at_pinches(frags.fragments[0], frags)
    assert len(bodies) == 2 and slivers == 0
    for body in bodies:
        check = written_check(body, frags)
        assert check.closed and check.pinched_vertices == 0 and body.piece == 3
        assert check.volume == pytest.approx(1.0)
    resolved, report = resolve_pinches(frags)
    assert report.split == 1 and report.bodies == 2 and len(resolved.fragments) == 2


def test_sound_fragments_are_returned_as_they_are():
    A, FA = box((0.0, 0.0, 0.0))
    frags = fragments(fragment(A, FA), volume=1.0)
    assert resolve_pinches(frags)[0] is frags
    assert separate_pinched_vertices(frags) == (frags, 0)


def test_a_body_touching_itself_at_a_vertex_is_moved_apart():
    """Two boxes meeting at one corner, joined elsewhere by a bridge: one body, one pinched vertex."""
    A, FA = box((0.0, 0.0, 0.0))
    B, FB = box((1.0, 1.0, 1.0))
    shapes = [trimesh.Trimesh(A, FA), trimesh.Trimesh(B, FB),
              trimesh.creation.box(bounds=[[0.2, 0.2, 0.9], [0.4, 1.5, 1.1]]),
              trimesh.creation.box(bounds=[[0.2, 1.3, 0.9], [1.5, 1.5, 1.1]]),
              trimesh.creation.box(bounds=[[1.3, 1.3, 0.9], [1.5, 1.5, 1.2]])]
    solids = [manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(s.vertices, np.float32),
                                                  tri_verts=np.asarray(s.faces, np.uint32))) for s in shapes]
    union = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    mesh = union.to_mesh()
    V = np.asarray(mesh.vert_properties, np.float64)[:, :3]
    F = np.asarray(mesh.tri_verts, np.int64)
    frags = fragments(fragment(V, F), volume=float(union.volume()))
    check = written_check(frags.fragments[0], frags)
    if check.pinched_vertices == 0:
        pytest.skip("manifold3d kept no corner contact in this union")
    assert check.closed
    separated, moved = separate_pinched_vertices(frags)
    assert moved >= 1
    after = written_check(separated.fragments[0], frags)
    assert after.closed and after.pinched_vertices == 0
    # Each moved copy is appended, the smallest of PINCH_GAPS from the corner it copies (the corner both boxes share).
    copies = separated.fragments[0].vertices[len(V):]
    assert len(copies) == moved
    assert np.linalg.norm(copies - np.array([1.0, 1.0, 1.0]), axis=1) == pytest.approx(PINCH_GAPS[0])
    assert after.volume == pytest.approx(check.volume, rel=1e-4)


def test_bodies_that_only_touch_stay_apart_overlapping_ones_are_united():
    parts = [box((0.0, 0.0, 0.0)), box((1.0, 0.0, 0.0)), box((0.5, 0.5, 0.5))]
    offsets = np.cumsum([0] + [len(V) for V, _ in parts])
    V = np.vstack([V for V, _ in parts])
    F = np.vstack([F + o for (_, F), o in zip(parts, offsets)])
    solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=V, tri_verts=F.astype(np.uint64)))
    groups, bodies, cavities = body_groups(solid)
    assert bodies == 3 and cavities == 0
    # The third box overlaps both: all one group. Without it, the two touching boxes stay apart.
    assert len(groups) == 1
    two = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=V[:16], tri_verts=F[:24].astype(np.uint64)))
    apart, _, _ = body_groups(two)
    assert len(apart) == 2 and sum(g.volume() for g in apart) == pytest.approx(2.0)


def test_least_area_patch_closes_a_folded_loop():
    """A loop wrapping three quarters around a thin rod: no plane sees it as a simple polygon."""
    angles = np.linspace(-0.75 * np.pi, 0.75 * np.pi, 10)
    ring = np.column_stack([0.1 * np.cos(angles), 0.1 * np.sin(angles)])
    P = np.vstack([np.column_stack([ring, np.zeros(10)]), np.column_stack([ring[::-1], np.ones(10)])])
    loop = np.arange(len(P))
    patch = least_area_patch(loop, P)
    assert patch.shape == (len(P) - 2, 3)
    closed = check_mesh(P, np.vstack([patch, patch[:, ::-1]]))  # a patch and its back: every edge twice
    assert closed.open_edges == 0
    # Each loop edge a -> b appears in the patch as b -> a (the cap runs the boundary backwards).
    runs = {(int(f[k]), int(f[(k + 1) % 3])) for f in patch for k in range(3)}
    assert all((int(loop[(i + 1) % len(loop)]), int(loop[i])) in runs for i in range(len(loop)))
    assert least_area_patch(np.arange(300), np.zeros((300, 3))) is None
