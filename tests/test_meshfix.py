"""Unit tests of fracture_cli.meshfix on tiny meshes built in code (milliseconds each)."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from fracture_cli.errors import StageError
from fracture_cli.geometry.trigeom import winding_numbers
from fracture_cli.geometry.weld_check import as_written, check_mesh
from fracture_cli.stages.repair.faces import orient_consistently, unique_faces
from fracture_cli.stages.repair.holes import FillOptions, boundary_loops, fill_holes, plan_fill
from fracture_cli.stages.repair.nonmanifold import split_nonmanifold
from fracture_cli.stages.repair.thicken import thicken_inward

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "data"))
from make_realworld_corpus import grid_faces

# ----------------------------------------------------------------------------
# Shapes

_CUBE_F = np.array(
    [
        [0, 1, 3],
        [0, 3, 2],
        [4, 6, 7],
        [4, 7, 5],
        [0, 4, 5],
        [0, 5, 1],
        [2, 3, 7],
        [2, 7, 6],
        [0, 2, 6],
        [0, 6, 4],
        [1, 5, 7],
        [1, 7, 3],
    ],
    dtype=np.int64,
)
# Faces 0-1: x = 0 side, 2-3: x = 1, 4-5: y = 0, 6-7: y = 1, 8-9: z = 0, 10-11: z = 1.


def cube(lo=(0.0, 0.0, 0.0), size=1.0, flip_diagonals=False):
    """8 vertices, 12 outward triangles; ``flip_diagonals`` splits every side along its other diagonal."""
    V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64) * size
    F = _CUBE_F.copy()
    if flip_diagonals:
        quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
        F = np.array([t for a, b, c, d in quads for t in ([a, b, d], [b, c, d])], dtype=np.int64)
    return V + np.asarray(lo, dtype=np.float64), F


def welded(*parts):
    """Concatenate (V, F) parts and weld vertices by exact position."""
    V = np.vstack([p[0] for p in parts])
    offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    F = np.vstack([p[1] + o for p, o in zip(parts, offsets)])
    U, index = np.unique(V, axis=0, return_inverse=True)
    return U, index.reshape(-1)[F]


def grid_sheet(nx=6, ny=6, height=lambda x, y: 0.0 * x):
    """A sheet over [0, 1]^2 with z = height(x, y), normals towards +z."""
    x, y = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny), indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), height(x, y).ravel()]), grid_faces(nx, ny)


def open_tube(radius=1.0, height=0.2, segments=16, z0=0.0):
    """A cylinder wall without caps (two planar circular holes), outward."""
    a = 2 * np.pi * np.arange(segments) / segments
    ring = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    V = np.vstack(
        [np.column_stack([ring, np.full(segments, z0)]), np.column_stack([ring, np.full(segments, z0 + height)])]
    )
    F = []
    for i in range(segments):
        j = (i + 1) % segments
        F += [[i, j, segments + j], [i, segments + j, segments + i]]
    return V, np.array(F, dtype=np.int64)


def volume(V, F):
    return float(np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0)


# ----------------------------------------------------------------------------
# weld_check


def test_closed_cube_passes():
    c = check_mesh(*cube())
    assert c.closed and c.bodies == 1 and c.volume == pytest.approx(1.0) and not c.problems()


def test_seamed_cube_is_welded_by_position():
    V, F = cube()
    V24 = V[F.reshape(-1)]  # every corner its own vertex, as after splitting UV seams
    assert check_mesh(V24, np.arange(len(V24)).reshape(-1, 3)).closed


def test_open_misoriented_and_inverted_are_reported():
    V, F = cube()
    assert check_mesh(V, F[1:]).open_edges == 3
    flipped = F.copy()
    flipped[0] = flipped[0][::-1]
    c = check_mesh(V, flipped)
    assert c.misoriented_edges == 3 and not c.closed
    inverted = check_mesh(V, F[:, ::-1])
    assert inverted.volume == pytest.approx(-1.0) and not inverted.closed


def test_bodies_touching_along_an_edge_or_a_vertex():
    edge = check_mesh(*welded(cube(), cube((1.0, 1.0, 0.0))))
    assert edge.pinched_edges == 1 and edge.bodies == 2 and not edge.closed
    vertex = check_mesh(*welded(cube(), cube((1.0, 1.0, 1.0))))
    assert vertex.pinched_edges == 0 and vertex.pinched_vertices == 1 and vertex.bodies == 2 and not vertex.closed


def test_as_written_rounds_like_the_glb_writer():
    V, F = cube(lo=(1000.0, 0.0, 0.0))
    V = np.vstack([V, V[0] + [1e-9, 0.0, 0.0]])  # a vertex 1e-9 from another: one float32 value apart from none
    F = np.vstack([F, [[0, 8, 1]]])
    local = as_written(V, origin=np.zeros(3))
    assert np.array_equal(local[0], local[8])
    assert check_mesh(local, F).degenerate_faces == 1
    assert check_mesh(V, F).degenerate_faces == 0


# ----------------------------------------------------------------------------
# faces


def test_repeated_surface_faces_keep_one_copy_whatever_their_winding():
    V, F = cube()
    soup = np.vstack([F, F[:4][:, ::-1], F[4:6]])  # faces repeated reversed and as they are
    unique = unique_faces(soup)
    assert unique.keep.sum() == 12 and unique.duplicates == 6 and unique.enclosing_nothing == 0
    kept = soup[unique.keep]
    flip, _ = orient_consistently(kept)
    kept[flip] = kept[flip][:, ::-1]
    c = check_mesh(V, kept)
    assert c.open_edges == c.misoriented_edges == 0 and abs(c.volume) == pytest.approx(1.0)


def test_double_sided_card_encloses_nothing():
    unique = unique_faces(np.array([[0, 1, 2], [0, 2, 1]]))
    assert not unique.keep.any() and unique.enclosing_nothing == 1
    assert any(r.what == "removed_double_sided_faces" for r in unique.records)


def test_orientation_propagates_across_each_patch():
    V, F = cube()
    F = F.copy()
    F[[0, 5, 7]] = F[[0, 5, 7]][:, ::-1]
    flip, records = orient_consistently(F)
    assert np.array_equal(np.flatnonzero(flip), [0, 5, 7]) and records[0].count == 3
    F[flip] = F[flip][:, ::-1]
    assert check_mesh(V, F).closed


# ----------------------------------------------------------------------------
# nonmanifold


def _bodies_closed(split):
    out = []
    for b in range(len(split.body_closed)):
        out.append(check_mesh(split.vertices, split.faces[split.body == b]))
    return out


def test_manifold_input_is_unchanged():
    V, F = cube()
    split = split_nonmanifold(V, F)
    assert np.array_equal(split.faces, F) and np.array_equal(split.vertices, V) and not split.records


@pytest.mark.parametrize("second", [(1.0, 1.0, 0.0), (1.0, 1.0, 1.0)], ids=["edge", "vertex"])
def test_touching_cubes_split_into_closed_bodies(second):
    V, F = welded(cube(), cube(second))
    split = split_nonmanifold(V, F)
    checks = _bodies_closed(split)
    assert len(checks) == 2 and all(c.closed for c in checks)
    assert split.body_closed.all() and np.allclose(split.body_volume, 1.0)
    assert np.array_equal(split.vertices, V[split.source_vertex])
    kinds = {r.what for r in split.records}
    assert "split_nonmanifold_vertices" in kinds
    assert ("split_nonmanifold_edges" in kinds) == (second[2] == 0.0)


def test_face_to_face_contact_with_other_triangulation():
    V, F = welded(cube(), cube((1.0, 0.0, 0.0), flip_diagonals=True))
    assert check_mesh(V, F).pinched_edges == 4
    split = split_nonmanifold(V, F)
    assert len(split.body_closed) == 2 and all(c.closed for c in _bodies_closed(split))


def test_internal_wall_is_doubled_one_copy_per_cell():
    V, F = welded(cube(), cube((1.0, 0.0, 0.0)))
    cen = V[F].mean(axis=1)
    # Drop the second cube's copy of the shared wall (x = 1): the wall is stored once, for the first cube.
    wall_of_second = np.isclose(cen[:, 0], 1.0) & (np.arange(len(F)) >= 12)
    split = split_nonmanifold(V, F[~wall_of_second])
    assert len(split.body_closed) == 2 and all(c.closed for c in _bodies_closed(split))
    assert np.allclose(split.body_volume, 1.0)
    assert any(r.what == "doubled_wall_faces" and r.count == 2 for r in split.records)
    # The copies point back to the wall's corners, reversed.
    copies = split.source_corner[len(F) - 2 :]
    assert np.array_equal(np.sort(copies // 3, axis=1)[:, 0], np.sort(copies // 3, axis=1)[:, 2])


def test_three_wedges_around_one_edge():
    """Three closed triangular prisms meeting at one edge: six faces alternate solid and empty."""
    parts = []
    for k in range(3):
        a0, a1 = 2 * np.pi * k / 3, 2 * np.pi * k / 3 + 1.0
        tri = np.array([[0, 0], [np.cos(a0), np.sin(a0)], [np.cos(a1), np.sin(a1)]])
        V = np.vstack([np.column_stack([tri, np.zeros(3)]), np.column_stack([tri, np.ones(3)])])
        F = np.array([[0, 2, 1], [3, 4, 5], [0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [2, 0, 3], [2, 3, 5]])
        parts.append((V, F))
    V, F = welded(*parts)
    split = split_nonmanifold(V, F)
    assert len(split.body_closed) == 3 and all(c.closed for c in _bodies_closed(split))


def test_open_fins_have_no_inside():
    """Three single quads hinged on one edge (a book's pages): nothing to pair into a solid."""
    V = np.array(
        [[0, 0, 0], [0, 0, 1], [1, 0, 0], [1, 0, 1], [-0.5, 0.8, 0], [-0.5, 0.8, 1], [-0.5, -0.8, 0], [-0.5, -0.8, 1]],
        dtype=np.float64,
    )
    F = np.array([[0, 2, 3], [0, 3, 1], [0, 1, 5], [0, 5, 4], [0, 6, 7], [0, 7, 1]])
    split = split_nonmanifold(V, F)
    assert not split.body_closed.any()
    assert any(r.what in ("unclosed_body", "unresolved_nonmanifold_edges") for r in split.records)


# ----------------------------------------------------------------------------
# holes


def test_boundary_loops_split_where_two_holes_touch():
    _, F = cube()
    loops = boundary_loops(F[2:])  # the x = 0 side missing: one loop of 4
    assert [len(loop) for loop in loops] == [4]
    # Two triangles removed that share only vertex 0 (on the x = 0 and the z = 0 side).
    loops = boundary_loops(np.delete(F, [0, 9], axis=0))
    assert sorted(len(loop) for loop in loops) == [3, 3]


def test_open_box_is_a_container_kept_hollow():
    """A box without its lid is a rim around an opening as wide as the box, at its top: a thin wall (issue 39)."""
    V, F = cube()
    plan = plan_fill(V, F[2:])
    assert [b.action for b in plan.bodies] == ["thicken"] and plan.bodies[0].container
    assert "open container" in plan.bodies[0].reason
    # A hole narrower than half the box's width is not an opening of a container.
    assert not plan_fill(V, F[2:], FillOptions(container_opening=1.01)).bodies[0].container


def test_open_box_is_filled_whatever_the_share():
    V, F = cube()
    open_box = F[2:]
    plan = plan_fill(V, open_box, FillOptions(container_opening=2.0))
    assert [b.action for b in plan.bodies] == ["fill"]
    filled = fill_holes(V, open_box, plan)
    c = check_mesh(filled.vertices, filled.faces)
    assert c.closed and c.volume == pytest.approx(1.0)
    assert filled.patch.sum() >= 2 and any(r.what == "filled_hole" for r in filled.records)
    record = next(r for r in filled.records if r.what == "filled_hole").to_dict()
    assert record["area"] == pytest.approx(1.0) and 0 < record["share"] < 1


def test_inside_out_open_box_is_turned_outward():
    V, F = cube()
    plan = plan_fill(V, F[2:, ::-1], FillOptions(container_opening=2.0))
    assert plan.bodies[0].action == "fill" and plan.bodies[0].flip
    filled = fill_holes(V, F[2:, ::-1], plan)
    assert check_mesh(filled.vertices, filled.faces).volume == pytest.approx(1.0)


def test_non_star_shaped_hole_is_ear_clipped():
    """A U-shaped hole in the top of a block: its outline is not star-shaped about its centroid."""
    outline = np.array([[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]], dtype=np.float64)
    k = len(outline)
    V = np.vstack([np.column_stack([outline, np.zeros(k)]), np.column_stack([outline, np.ones(k)])])
    # The bottom (z = 0, facing -z): the U split into a trapezoid and two arms, counter-clockwise, then reversed.
    F = [f[::-1] for f in ([0, 1, 4], [0, 4, 5], [1, 2, 3], [1, 3, 4], [0, 5, 6], [0, 6, 7])]
    for i in range(k):
        j = (i + 1) % k
        F += [[i, j, k + j], [i, k + j, k + i]]
    F = np.array(F, dtype=np.int64)
    plan = plan_fill(V, F, FillOptions(container_opening=2.0))  # the whole top is open: not a container here
    assert plan.bodies[0].action == "fill"
    filled = fill_holes(V, F, plan)
    c = check_mesh(filled.vertices, filled.faces)
    assert c.closed and c.volume == pytest.approx(7.0)
    assert not (filled.faces >= len(V)).any()  # ear clipping adds no vertex


def test_patch_crossing_the_surface_is_not_filled():
    """An open box whose bottom is a tent rising above the rim: a cap over the rim would cut the tent."""
    c = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    V = np.vstack([c, c + [0.0, 0.0, 1.0], [[0.5, 0.5, 1.5]]])
    F = []
    for i in range(4):
        j = (i + 1) % 4
        F += [[i, j, 4 + j], [i, 4 + j, 4 + i], [j, i, 8]]  # outward walls; tent facing into the pyramid
    plan = plan_fill(V, np.array(F, dtype=np.int64))
    assert plan.bodies[0].action == "thicken" and "cross" in plan.bodies[0].reason


def test_sheet_edge_is_not_a_hole():
    V, F = grid_sheet(height=lambda x, y: 0.3 * np.sin(3 * x) * np.cos(2 * y))
    plan = plan_fill(V, F)
    assert [b.action for b in plan.bodies] == ["thicken"]


def test_flat_sheet_encloses_no_volume():
    V, F = grid_sheet()
    plan = plan_fill(V, F)
    assert plan.bodies[0].action == "thicken" and "no volume" in plan.bodies[0].reason


def test_large_holes_are_filled_only_when_hidden():
    V, F = open_tube(radius=1.0, height=0.2)
    alone = plan_fill(V, F, FillOptions(container_opening=2.0))
    assert alone.bodies[0].action == "thicken" and "not inside another body" in alone.bodies[0].reason
    assert plan_fill(V, F).bodies[0].container  # open at its top: a container as well
    box_V, box_F = cube(lo=(-2.0, -2.0, -1.0), size=4.0)
    V2, F2 = welded((V, F), (box_V, box_F))
    inside = plan_fill(V2, F2)
    assert [b.action for b in inside.bodies] == ["fill"] and inside.bodies[0].hidden
    loose = plan_fill(V, F, FillOptions(max_fill_share=0.9, container_opening=2.0))
    assert loose.bodies[0].action == "fill"


def test_winding_numbers_of_a_cube():
    V, F = cube()
    w = winding_numbers(np.array([[0.5, 0.5, 0.5], [2.0, 0.5, 0.5]]), V, F)
    assert w == pytest.approx([1.0, 0.0], abs=1e-9)


# ----------------------------------------------------------------------------
# thicken


def test_curved_sheet_thickened_inward_inside_its_box():
    V, F = grid_sheet(height=lambda x, y: 0.5 - 0.5 * ((x - 0.5) ** 2 + (y - 0.5) ** 2))  # a dome, normals up
    box = np.stack([V.min(axis=0), V.max(axis=0)])
    sheet = thicken_inward(V, F, 0.02, box=box)
    c = check_mesh(sheet.vertices, sheet.faces)
    assert c.closed and c.volume > 0
    assert np.array_equal(sheet.vertices[: len(V)], V) and np.array_equal(sheet.faces[: len(F)], F)
    assert np.all(sheet.vertices >= box[0]) and np.all(sheet.vertices <= box[1])
    assert np.all(sheet.vertices[sheet.faces[sheet.kind == 1]][..., 2] <= V[:, 2].max())
    record = sheet.records[0].to_dict()
    assert record["what"] == "thickened_sheet" and record["direction"] == "inward"


def test_flat_sheet_cannot_be_thickened_inside_its_box():
    V, F = grid_sheet()
    box = np.stack([V.min(axis=0), V.max(axis=0)])
    with pytest.raises(StageError, match="cannot thicken"):
        thicken_inward(V, F, 0.02, box=box)
    free = thicken_inward(V, F, 0.02)
    assert check_mesh(free.vertices, free.faces).volume == pytest.approx(0.02)
