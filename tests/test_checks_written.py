"""Checks on the fragments as written (fracture_cli.checks.written_fragments, require_sound, require_volume).

Tiny fragments built in code; the GLB writer's float32 rounding about each
fragment's pivot is what is checked, so a fragment that is closed in float64
but not once written is caught.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
import trimesh

from fracture_cli import checks
from fracture_cli.checks import (
    VOLUME_TOLERANCE,
    fragment_invariants,
    require_sound,
    require_volume,
    written_fragments,
)
from fracture_cli.errors import StageError
from fracture_cli.geometry.trigeom import edge_manifold_closed
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Fragment, Fragments, Material, Normalization, SurfaceMesh


def fragment(V, F, piece=0) -> Fragment:
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    return Fragment(vertices=V, faces=F, uvs=np.zeros((len(V), 2)), normals=np.zeros((len(V), 3)),
                    material_ids=np.zeros(len(F), np.int32), piece=piece)


def fragments(*frags: Fragment, volume: float = 1.0) -> Fragments:
    return Fragments(fragments=tuple(frags), materials=(Material("m"),), normalization=Normalization.identity(),
                     input_volume=volume)


def cube(offset=(0.0, 0.0, 0.0)):
    box = trimesh.creation.box(extents=(1, 1, 1))
    return box.vertices + np.asarray(offset), box.faces


def test_a_closed_fragment_is_watertight_and_connected():
    frags, checks = written_fragments(fragments(fragment(*cube())))
    assert checks[0].watertight and checks[0].bodies == 1
    require_sound(checks)


def test_faces_collapsed_by_float32_rounding_are_dropped():
    """An edge split at 1e-12 from its end: closed in float64, degenerate once written; the sliver faces go."""
    V, F = cube()
    (a, b), f1, f2 = _edge_and_faces(F)
    m = len(V)
    V = np.vstack([V, V[a] + 1e-12 * (V[b] - V[a])])
    c = [x for x in F[f1] if x not in (a, b)][0]
    d = [x for x in F[f2] if x not in (a, b)][0]
    faces = [f for i, f in enumerate(F.tolist()) if i not in (f1, f2)]
    faces += [_wound_like(F[f1], (a, m, c)), _wound_like(F[f1], (m, b, c)),
              _wound_like(F[f2], (b, m, d)), _wound_like(F[f2], (m, a, d))]
    frags, checks = written_fragments(fragments(fragment(V, faces)))
    assert len(frags.fragments[0].faces) == 12  # the two slivers at a are dropped
    assert checks[0].watertight and checks[0].degenerate_faces == 0
    # ... and the split point takes a's position, so later stages (welding by float64 position) find it closed.
    kept = frags.fragments[0]
    _, weld = np.unique(kept.vertices, axis=0, return_inverse=True)
    assert edge_manifold_closed(weld.reshape(-1)[kept.faces])


def _edge_and_faces(F):
    """An edge of the cube and the two faces on it."""
    a, b = F[0][0], F[0][1]
    on = [i for i, f in enumerate(F.tolist()) if a in f and b in f]
    return (a, b), on[0], on[1]


def _wound_like(face, tri):
    """``tri`` ordered so it runs the shared edge as ``face`` does (same orientation as the face it splits)."""
    face = list(face)
    pos = {v: i for i, v in enumerate(face)}
    known = [v for v in tri if v in pos]
    if len(known) == 2 and (pos[known[1]] - pos[known[0]]) % 3 != (tri.index(known[1]) - tri.index(known[0])) % 3:
        return list(tri[::-1])
    return list(tri)


def test_a_pinched_fragment_stops_the_bake_naming_it():
    """Two cubes sharing an edge in one fragment: 4-face edge, so the bake fails naming fragment_001."""
    A, FA = cube()
    B, FB = cube((1.0, 1.0, 0.0))
    V = np.vstack([A, B])
    frags, checks = written_fragments(fragments(fragment(*cube((5, 5, 5))), fragment(V, np.vstack([FA, FB + 8]))))
    assert checks[0].watertight and not checks[1].watertight and checks[1].pinched_edges == 1
    with pytest.raises(StageError, match=r"fragment_001 would be written as a broken mesh: 1 edges shared by more "
                                         r"than two faces, 2 separate bodies"):
        require_sound(checks)
    # With the fragments, the message says where the fragment is and which recipe key moves the cuts.
    with pytest.raises(StageError, match=r"fragment_001 at \(0\.5, 0\.5, 0\) .*--set cage\.target_faces="):
        require_sound(checks, frags)


def test_separate_bodies_are_reported_not_connected(caplog):
    A, FA = cube()
    B, FB = cube((3.0, 0.0, 0.0))
    frags, checks = written_fragments(fragments(fragment(np.vstack([A, B]), np.vstack([FA, FB + 8])), volume=2.0))
    with caplog.at_level(logging.WARNING, logger="fracture_cli.checks"):
        require_sound(checks)
    assert any("several separate bodies" in r.message for r in caplog.records)
    surface = SurfaceMesh(vertices=np.vstack([A, B]), faces=np.vstack([FA, FB + 8]), uvs=None, normals=None,
                          colors=None, material_ids=np.zeros(24, np.int32), materials=(Material("m"),),
                          normalization=Normalization.identity())
    report = fragment_invariants(surface, frags, written=checks)
    assert report["watertight"] is True and report["connected"] is False and report["fragment_bodies_max"] == 2
    assert report["open_edges"] == report["pinched_edges"] == 0
    assert report["fragment_volume_min"] == report["fragment_volume_median"] == report["fragment_volume_max"] == 1.0


def test_volume_error_above_the_tolerance_fails():
    require_volume({"volume_error": VOLUME_TOLERANCE / 2})
    with pytest.raises(StageError, match="volumes add up to the input's only within"):
        require_volume({"volume_error": 0.19})
    with pytest.raises(StageError):
        require_volume({"volume_error": float("nan")})


def test_overlap_pairs_in_groups_give_the_same_max_on_any_number_of_processes():
    """Every pair is measured once whatever the grouping; one and two processes agree bit for bit."""
    rng = np.random.default_rng(3)
    centres = rng.random((12, 3))
    sizes = rng.integers(10, 1000, 12)
    pairs = [(a, b) for a in range(12) for b in range(a + 1, 12) if rng.random() < 0.4]
    for count in (1, 2, 3, 5):
        groups = checks._pair_groups(pairs, centres, sizes, count)
        assert len(groups) <= count and sorted(p for g in groups for p in g) == sorted(pairs)
    # Two overlapping unit cubes (overlap 0.5 of the smaller) and a third that only touches the second.
    # All faces interior (fault faces), so the fragments are neighbours.
    parts = [fragment(*cube(offset)) for offset in ((0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (1.5, 0.0, 0.0))]
    parts = [dataclasses.replace(f, material_ids=np.ones(len(f.faces), np.int32)) for f in parts]
    frags = dataclasses.replace(fragments(*parts), materials=(Material("m"), Material(INTERIOR_MATERIAL_NAME)))
    assert checks.fragment_neighbours(frags).tolist() == [[0, 1], [1, 2]]
    volumes = np.ones(3)
    with_one = checks._max_overlap(frags, volumes, 2000, 1)
    assert with_one == pytest.approx(0.5, rel=1e-12)
    assert checks._max_overlap(frags, volumes, 2000, 2) == with_one


def test_outer_distance_skips_only_points_on_used_surface_vertices():
    V, F = cube()
    far = np.array([[5.0, 5.0, 5.0]])
    unused = np.vstack([V, far])  # a vertex no triangle uses is not on the surface
    points = np.vstack([V, far, V[:1] + [0.0, 0.0, 0.25]])
    on = checks._on_vertices(points, unused, F)
    assert on.tolist() == [True] * 8 + [False, False]
    distance = checks._max_distance_to_surface(points, unused, F)
    assert distance == pytest.approx(np.linalg.norm(far[0] - 0.5), rel=1e-6)
    assert checks._max_distance_to_surface(V, V, F) == 0.0


def test_volume_message_says_more_or_less():
    """Issue 39: the message states what was measured (the fragments hold more, or less, than the input)."""
    with pytest.raises(StageError, match="hold more volume than the input"):
        require_volume({"volume_error": 9.24e-5}, 9.24e-5)
    with pytest.raises(StageError, match="hold less volume than the input.*missing"):
        require_volume({"volume_error": 9.24e-5}, -9.24e-5)


def test_volume_tolerance_follows_float32_storage_on_thin_inputs():
    """A thin plate (much area per volume) far from its pivot's precision gets a tolerance above the default;
    a compact cube keeps the default."""
    from fracture_cli.checks import volume_tolerance

    A, FA = cube()
    assert volume_tolerance(fragments(fragment(A, FA), volume=1.0)) == VOLUME_TOLERANCE
    plate = A * np.array([1.0, 1.0, 1e-4])
    tolerance = volume_tolerance(fragments(fragment(plate, FA), volume=1e-4))
    assert tolerance > VOLUME_TOLERANCE
    assert tolerance < 1e-2  # still a check, not a pass
