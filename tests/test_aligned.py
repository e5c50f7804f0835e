"""Aligned fracture in pieces: convex clipping, the patterns, the companion file's codec, the stage."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest
from aligned_support import ALIGNED_CONFORMANCE, closed_and_convex

from fracture_cli.errors import RuntimeFileError, StageError, UsageError
from fracture_cli.runtime.aligned import aligned_fracture, pattern_frame, piece_volumes
from fracture_cli.runtime.aligned_clip import clip_polygon, clip_polyhedron, polyhedron_mass
from fracture_cli.runtime.aligned_data import AlignedData, check_aligned, decode, encode, load_aligned
from fracture_cli.stages.aligned import aligned
from fracture_cli.stages.aligned.options import AlignedOptions
from fracture_cli.stages.aligned.pattern import bounded_cells, dodecahedron_planes, fracture_pattern, graded_sites
from fracture_cli.stages.aligned.pieces import convex_piece


def cube(lo=0.0, hi=1.0):
    piece = convex_piece(np.array([[x, y, z] for x in (lo, hi) for y in (lo, hi) for z in (lo, hi)], float), 0)
    faces = [(loop, tuple(plane), False) for loop, plane in zip(piece.loops, piece.planes.tolist())]
    return [tuple(v) for v in piece.vertices.tolist()], faces


def test_a_cube_has_six_square_faces():
    vertices, faces = cube()
    assert len(vertices) == 8 and len(faces) == 6 and all(len(loop) == 4 for loop, _, _ in faces)
    volume, centroid = polyhedron_mass((vertices, faces))
    assert volume == pytest.approx(1.0) and centroid == pytest.approx((0.5, 0.5, 0.5))


@pytest.mark.parametrize("plane", [(1, 0, 0, 0.3), (0.6, 0.8, 0, 0.7), (-1, -1, -1, -0.5)])
def test_clipping_a_cube_keeps_it_convex_and_closed_and_splits_its_volume(plane):
    n = np.array(plane[:3], float)
    unit = (*(n / np.linalg.norm(n)), plane[3] / np.linalg.norm(n))
    flipped = tuple(-x for x in unit)
    kept, cut = clip_polyhedron(cube(), unit, 1e-12), clip_polyhedron(cube(), flipped, 1e-12)
    assert kept is not None and cut is not None
    for poly in (kept, cut):
        vertices, faces = poly
        assert closed_and_convex(np.array(vertices), [f[0] for f in faces], np.array([f[1] for f in faces]), 1.0) \
            is None
        assert sum(new for _, _, new in faces) == 1  # one cap
    assert polyhedron_mass(kept)[0] + polyhedron_mass(cut)[0] == pytest.approx(1.0, abs=1e-15)


def test_clipping_returns_the_same_or_nothing():
    poly = cube()
    assert clip_polyhedron(poly, (1.0, 0.0, 0.0, 2.0), 1e-12) is poly
    assert clip_polyhedron(poly, (1.0, 0.0, 0.0, -1.0), 1e-12) is None


def test_polygon_clipping_interpolates_and_normalizes():
    corners = [(0, 0, 0, 0, 0, 1, 0, 0), (2, 0, 0, 1, 0, 0, 1, 0), (0, 2, 0, 0, 0, 1, 0, 1)]
    out = clip_polygon([tuple(map(float, c)) for c in corners], (1.0, 0.0, 0.0, 1.0), 1e-12)
    assert len(out) == 4
    new = out[1]
    assert new[:3] == pytest.approx((1, 0, 0)) and new[6:] == pytest.approx((0.5, 0))
    assert np.linalg.norm(new[3:6]) == pytest.approx(1.0)


def test_sites_are_seeded_graded_and_inside_the_unit_ball():
    a, b = graded_sites(60, 1.5, 0.35, 4), graded_sites(60, 1.5, 0.35, 4)
    assert np.array_equal(a, b) and a.dtype == np.float32 and len(a) == 60
    assert np.all(a[0] == 0) and np.all(np.linalg.norm(a, axis=1) < 1)
    even = np.median(np.linalg.norm(graded_sites(200, 1 / 3, 0.0, 4), axis=1))
    graded = np.median(np.linalg.norm(graded_sites(200, 2.0, 0.0, 4), axis=1))
    assert graded < 0.5 * even


def test_bounded_cells_tile_the_dodecahedron():
    """The cells cut to the boundary, with the planes they keep, add up to the dodecahedron's volume."""
    boundary = dodecahedron_planes()
    pattern = fracture_pattern(25, 1.0, 0.35, 2, boundary)
    sites = pattern.sites.astype(np.float64)
    total = 0.0
    for i, (nbs, walls) in enumerate(zip(pattern.neighbors, pattern.boundary)):
        poly = cube(-2.0, 2.0)
        for j in nbs:
            n = sites[j] - sites[i]
            n /= np.linalg.norm(n)
            poly = clip_polyhedron(poly, (*n, float(n @ (sites[i] + sites[j]) / 2)), 1e-12)
        for b in walls:
            poly = clip_polyhedron(poly, tuple(boundary[b]), 1e-12)
        total += polyhedron_mass(poly)[0]
    # the regular dodecahedron of inradius 1: edge a with inradius a / 2 * sqrt((25 + 11 sqrt 5) / 10)
    edge = 2 / np.sqrt((25 + 11 * 5 ** 0.5) / 10)
    assert total == pytest.approx((15 + 7 * 5 ** 0.5) / 4 * edge ** 3, rel=1e-9)
    neighbors, _ = bounded_cells(pattern.sites, pattern.neighbors, boundary)
    assert all(i in neighbors[j] for i, nbs in enumerate(neighbors) for j in nbs)


def test_the_frame_takes_the_pattern_axis_to_the_impulse():
    for direction in ((0, 0, 1), (1, 2, 3), (-1e-300, 0, 0), (1e300, 1e300, -1e300)):
        u, v, d = (np.array(x) for x in pattern_frame(direction))
        dn = np.array(direction, float) / np.max(np.abs(direction))
        assert d == pytest.approx(dn / np.linalg.norm(dn))
        assert np.cross(u, v) == pytest.approx(d) and u @ d == pytest.approx(0, abs=1e-15)
    with pytest.raises(UsageError):
        pattern_frame((0.0, 0.0, 0.0))


def test_the_file_round_trips_and_damage_is_refused():
    data = load_aligned(os.path.join(ALIGNED_CONFORMANCE, "boxes.aligned.json"))
    header, binary = encode(data, "x.aligned.bin")
    again = decode(header, binary)
    assert all(np.array_equal(data[k], again[k]) for k in data.arrays) and again.materials == data.materials
    with pytest.raises(RuntimeFileError):
        decode(header, binary[:-4])
    with pytest.raises(RuntimeFileError):
        decode(header.replace(b'"version": 1', b'"version": 2'), binary)
    broken = dict(data.arrays)
    broken["face_loops"] = np.full_like(data["face_loops"], 99)
    assert "out of range" in check_aligned(dataclasses.replace(data, arrays=broken))


def test_a_hit_far_away_leaves_the_boxes_whole():
    data = load_aligned(os.path.join(ALIGNED_CONFORMANCE, "boxes.aligned.json"))
    fragments = aligned_fracture(data, (50.0, 0.0, 0.0), (1.0, 0.0, 0.0), 1.0)
    assert len(fragments) == 1 and fragments[0].whole_pieces == tuple(range(data.num_pieces))
    assert fragments[0].volume == pytest.approx(sum(piece_volumes(data)))


def test_a_hit_cuts_near_the_hit_only():
    data = load_aligned(os.path.join(ALIGNED_CONFORMANCE, "boxes.aligned.json"))
    fragments = aligned_fracture(data, (0.0, 0.5, 0.5), (1.0, 0.0, 0.0), 0.3)
    rest = fragments[-1]
    assert len(fragments) > 2 and rest.cell == 12  # the rest of the object: one past the pattern's 12 cells
    assert set(rest.whole_pieces) == {1, 2}  # the second box, far from the hit, stays whole
    assert sum(f.volume for f in fragments) == pytest.approx(2.0, rel=1e-9)
    assert all(m in (0, 1) for f in fragments for m in f.materials)
    assert all(np.any(f.materials == data.interior_material) for f in fragments)  # every one has new faces


def test_the_stage_is_off_by_default_and_needs_collision_parts():
    assert aligned(None, None, AlignedOptions()) is None  # type: ignore[arg-type]
    with pytest.raises(StageError, match="collision"):
        aligned(object(), ((),), AlignedOptions(enabled=True))  # type: ignore[arg-type]


def test_pieces_own_every_triangle_once():
    data: AlignedData = load_aligned(os.path.join(ALIGNED_CONFORMANCE, "boxes.aligned.json"))
    # two boxes of 12 triangles, plus the faces where the second box's two parts meet (2 x 2 interior triangles)
    assert len(data["triangle_materials"]) == 24 + 4
    assert int((data["triangle_materials"] == data.interior_material).sum()) == 4 + 4
