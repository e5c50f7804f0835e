"""The repair stage (fracture_cli.stages.repair): any input -> one closed, outward solid, checked independently."""

import logging
import os

import manifold3d
import numpy as np
import pytest
import trimesh

from fracture_cli.errors import StageError
from fracture_cli.stages.load import load_surface
from fracture_cli.stages.repair import RepairOptions, repair, repair_surface
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Material, Normalization, SurfaceMesh

from conftest import SAMPLE_ASSETS

VASE = os.path.join(SAMPLE_ASSETS, "vase.obj")


def surface(V, F, uvs=None, normals=None, material_ids=None, materials=(Material("stone"),)):
    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)
    norm = Normalization.from_points(V)
    return SurfaceMesh(vertices=norm.to_normalized(V), faces=F, uvs=uvs,
                       normals=None if normals is None else np.asarray(normals, float), colors=None,
                       material_ids=np.zeros(len(F), np.int32) if material_ids is None else material_ids,
                       materials=materials, normalization=norm)


def seamed_box(extents=(1.0, 0.8, 0.6)):
    """A box with every face's vertices split (UV seams) and a UV per corner."""
    box = trimesh.creation.box(extents=extents)
    V = box.vertices[box.faces].reshape(-1, 3)
    F = np.arange(len(V)).reshape(-1, 3)
    uv = np.tile([[0, 0], [1, 0], [0, 1]], (len(box.faces), 1)).astype(float)
    return surface(V, F, uvs=uv, normals=np.repeat(box.face_normals, 3, axis=0))


def closed_by_position(s: SurfaceMesh) -> trimesh.Trimesh:
    """The surface welded by position (trimesh merges vertices) and checked closed and consistently wound."""
    tm = trimesh.Trimesh(s.vertices, s.faces)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume > 0
    return tm


def manifold_accepts(s: SurfaceMesh) -> manifold3d.Manifold:
    _, first, pos = np.unique(s.vertices, axis=0, return_index=True, return_inverse=True)
    target = first[pos.reshape(-1)]
    src = np.flatnonzero(target != np.arange(len(target)))
    solid = manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(s.vertices), tri_verts=np.ascontiguousarray(s.faces, dtype=np.uint64),
        merge_from_vert=src.astype(np.uint64), merge_to_vert=target[src].astype(np.uint64)))
    assert solid.status() == manifold3d.Error.NoError
    return solid


def check_attributes(s: SurfaceMesh):
    n = s.num_vertices
    assert s.uvs.shape == (n, 2) and s.normals.shape == (n, 3) and s.material_ids.shape == (s.num_faces,)
    np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0, atol=1e-6)
    assert s.material_ids.max() < len(s.materials)


@pytest.fixture(scope="module")
def vase():
    return load_surface(VASE)


@pytest.mark.parametrize("mode", ["fill", "shell"])
def test_open_vase_becomes_a_solid(vase, mode):
    assert not trimesh.Trimesh(vase.vertices, vase.faces).is_watertight
    r = repair(vase, RepairOptions(open_surface=mode))
    tm = closed_by_position(r)
    solid = manifold_accepts(r)
    assert solid.volume() == pytest.approx(tm.volume, rel=1e-9)
    check_attributes(r)
    assert r.materials[-1].name == INTERIOR_MATERIAL_NAME and r.materials[0].name == vase.materials[0].name
    # the artist's faces are all kept, with their UVs; added faces are interior
    assert (r.material_ids == 0).sum() == vase.num_faces
    np.testing.assert_array_equal(r.vertices[: vase.num_vertices], vase.vertices)
    np.testing.assert_array_equal(r.uvs[: vase.num_vertices], vase.uvs)
    np.testing.assert_allclose(r.normalization.matrix(), vase.normalization.matrix())
    if mode == "fill":
        # the filled vase: the sheet's own (divergence-theorem) volume around the top fan's apex
        assert tm.volume == pytest.approx(trimesh.Trimesh(vase.vertices, vase.faces).volume, rel=0.05)
    else:
        # a slab of the requested thickness: volume ~ area * thickness
        area = trimesh.Trimesh(vase.vertices, vase.faces).area
        assert 0.7 * area * 0.01 < tm.volume < 1.05 * area * 0.01
        assert r.vertices.min(axis=0) == pytest.approx(vase.vertices.min(axis=0), abs=0.011)


def test_auto_fills_holes_that_close_into_a_solid(vase, caplog):
    with caplog.at_level(logging.WARNING, logger="fracture_cli.stages.repair"):
        result = repair_surface(vase)  # the top opening: a planar loop, ~0.5% of the surface
    warnings = [r.message for r in caplog.records]
    assert any("filled" in m and "--set repair.open_surface=shell" in m for m in warnings), warnings
    assert result.records[0].what == "decision" and result.records[0].extra["decision"] == "solid"
    assert [r.what for r in result.records].count("filled_hole") == 1
    filled = result.surface
    assert (filled.material_ids == 1).sum() < 0.05 * filled.num_faces
    # a body whose patches would be more than max_fill_share of its surface is a sheet: thickened inward
    shelled = repair_surface(vase, RepairOptions(max_fill_share=0.001))
    assert shelled.records[0].extra["decision"] == "shell"
    assert closed_by_position(shelled.surface).volume < 0.2 * closed_by_position(filled).volume


def test_open_error_mode_names_the_loops(vase):
    with pytest.raises(StageError, match=r"open at 1 boundary loop.*open_surface=fill.*open_surface=shell"):
        repair(vase, RepairOptions(open_surface="error"))


def test_seamed_box_is_welded_keeping_seams():
    s = seamed_box()
    assert not trimesh.Trimesh(s.vertices, s.faces, process=False).is_watertight  # split at every seam
    r = repair(s)
    closed_by_position(r)
    manifold_accepts(r)
    assert r.num_faces == 12
    # seams stay split: every corner keeps its own UV and its face's flat normal
    assert r.num_vertices == s.num_vertices
    np.testing.assert_array_equal(r.uvs, s.uvs)
    np.testing.assert_array_equal(r.normals, s.normals)
    assert trimesh.Trimesh(r.vertices, r.faces).volume == pytest.approx(0.48 / s.normalization.scale**3, rel=1e-9)
    assert [m.name for m in r.materials] == ["stone"]  # nothing added


def test_overlapping_boxes_are_united():
    a = trimesh.creation.box(extents=(1, 1, 1))
    b = trimesh.creation.box(extents=(1, 1, 1))
    b.apply_translation((0.5, 0.25, 0.0))
    both = trimesh.util.concatenate([a, b])
    s = surface(both.vertices, both.faces, normals=both.vertex_normals)
    r = repair(s)
    tm = closed_by_position(r)
    manifold_accepts(r)
    assert len(tm.split(only_watertight=False)) == 1
    assert tm.volume == pytest.approx((2 - 0.5 * 0.75) / s.normalization.scale**3, rel=1e-9)


def test_cavity_is_kept():
    outer = trimesh.creation.box(extents=(2, 2, 2))
    inner = trimesh.creation.box(extents=(1, 1, 1))
    inner.invert()
    both = trimesh.util.concatenate([outer, inner])
    s = surface(both.vertices, both.faces)
    r = repair(s)
    assert trimesh.Trimesh(r.vertices, r.faces).volume == pytest.approx(7 / s.normalization.scale**3, rel=1e-9)


def test_inverted_normals_and_mixed_winding_are_fixed():
    box = trimesh.creation.box(extents=(1, 2, 3))
    F = box.faces[:, ::-1].copy()  # inside out
    F[::3] = F[::3, ::-1]  # and every third face wound the other way
    normals = -box.vertex_normals
    s = surface(box.vertices, F, normals=normals)
    r = repair(s)
    tm = closed_by_position(r)
    assert tm.volume == pytest.approx(6 / s.normalization.scale**3, rel=1e-9)
    # shading normals point out with the faces
    centre = r.vertices.mean(axis=0)
    assert np.all(np.einsum("ij,ij->i", r.normals, r.vertices - centre) > 0)


def test_duplicated_and_degenerate_faces_are_removed(caplog):
    box = trimesh.creation.box(extents=(1, 1, 1))
    V = np.vstack([box.vertices, box.vertices[:1]])  # an extra vertex at corner 0's position
    F = np.vstack([box.faces, box.faces[:3],  # repeated faces
                   [[0, 1, 1], [2, 2, 2], [0, len(box.vertices), 3]]])  # degenerate (one by position)
    s = surface(V, F)
    with caplog.at_level(logging.INFO, logger="fracture_cli.stages.repair"):
        r = repair(s)
    assert r.num_faces == 12
    assert trimesh.Trimesh(r.vertices, r.faces).volume == pytest.approx(1 / s.normalization.scale**3, rel=1e-9)
    message = " ".join(rec.message for rec in caplog.records)
    assert "removed 3 degenerate faces" in message and "removed 3 repeated copies of faces" in message


@pytest.mark.parametrize("mode", ["auto", "fill"])
def test_single_triangle_has_no_inside(mode):
    s = surface([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(StageError, match=r"flat: all vertices lie in one plane.*open_surface=shell"):
        repair(s, RepairOptions(open_surface=mode))


def test_flat_quad_has_no_inside():
    quad = surface([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    with pytest.raises(StageError, match="flat"):
        repair(quad)
    # a closed but zero-thickness quad (front and back faces) encloses nothing either
    both = surface([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3], [2, 1, 0], [3, 2, 0]])
    with pytest.raises(StageError, match="flat"):
        repair(both)


def test_flat_quad_can_be_shelled_on_request():
    quad = surface([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]],
                   uvs=np.zeros((4, 2)), normals=np.tile([0.0, 0.0, 1.0], (4, 1)))
    r = repair(quad, RepairOptions(open_surface="shell", shell_thickness=0.02))
    tm = closed_by_position(r)
    manifold_accepts(r)
    assert tm.volume == pytest.approx(0.5 * 0.02, rel=1e-6)  # unit-diagonal square times thickness
    assert r.vertices[:, 2].max() == pytest.approx(quad.vertices[:, 2].max())  # grows behind its normals


def test_closed_input_is_returned_unchanged():
    s = surface(*(lambda m: (m.vertices, m.faces))(trimesh.creation.icosphere(2)))
    assert repair(s) is s


def test_bake_of_open_vase_keeps_its_volume(tmp_path):
    from fracture_cli.pipeline.bake import bake
    from fracture_cli.pipeline.recipe import load_recipe

    result = bake(VASE, str(tmp_path), load_recipe("default", ["cage.target_faces=600", "modes.num_modes=4"]))
    checks = result.report["checks"]
    assert checks["watertight"]
    assert checks["volume_error"] < 1e-3
    assert "repair" in result.report["seconds"]


def test_deterministic(vase):
    for mode in ("fill", "shell"):
        a = repair(vase, RepairOptions(open_surface=mode))
        b = repair(vase, RepairOptions(open_surface=mode))
        for name in ("vertices", "faces", "uvs", "normals", "material_ids"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes()


def test_open_sheet_with_mixed_winding_is_filled_outward():
    cyl = trimesh.creation.cylinder(radius=0.3, height=1.0, sections=24)
    side = np.abs(cyl.face_normals[:, 2]) < 0.5
    sheet = trimesh.Trimesh(cyl.vertices, cyl.faces[side], process=False)
    sheet.remove_unreferenced_vertices()
    F = sheet.faces.copy()
    F[1::4] = F[1::4, ::-1]
    s = surface(sheet.vertices, F)
    r = repair(s, RepairOptions(open_surface="fill"))
    assert closed_by_position(r).volume == pytest.approx(cyl.volume / s.normalization.scale**3, rel=1e-9)


def test_fin_hinged_on_a_solid_is_cut_off_thickened_dropped_or_refused():
    """A zero-thickness fin on a box's edge (three faces at the edge): issue 39's ``repair.fins`` policy."""
    box = trimesh.creation.box(extents=(1, 1, 1))
    fin = np.vstack([box.vertices, [[2.0, 2.0, 2.0]]])
    a, b = box.edges_unique[0]
    F = np.vstack([box.faces, [[a, b, len(box.vertices)]]])
    with pytest.raises(StageError, match="shared by more than two faces"):
        repair(surface(fin, F), RepairOptions(fins="error"))
    thickened = repair_surface(surface(fin, F))
    assert [r.what for r in thickened.records].count("detached_fins") == 1
    assert "thickened_sheet" in [r.what for r in thickened.records]
    check = closed_by_position(thickened.surface)
    assert check.volume > 1.0 / surface(fin, F).normalization.scale ** 3  # the box and a thin fin
    dropped = repair_surface(surface(fin, F), RepairOptions(fins="drop"))
    assert "dropped_fins" in [r.what for r in dropped.records]
    assert closed_by_position(dropped.surface).volume == pytest.approx(1.0 / surface(fin, F).normalization.scale**3)


def test_two_bodies_one_hollow():
    """A hollow box (with a cavity) next to a second body: the union subtracts the cavity (once an internal error:
    manifold3d's read-only buffers were passed back to it)."""
    outer = trimesh.creation.box(extents=(2, 2, 2))
    inner = trimesh.creation.box(extents=(1, 1, 1))
    inner.invert()
    other = trimesh.creation.box(extents=(1, 1, 1))
    other.apply_translation((1.2, 0.0, 0.0))  # partly inside the hollow box's wall, not touching its cavity
    parts = trimesh.util.concatenate([outer, inner, other])
    s = surface(parts.vertices, parts.faces)
    r = repair_surface(s)
    assert trimesh.Trimesh(r.surface.vertices, r.surface.faces).volume == pytest.approx(
        (8 - 1 + 0.7) / s.normalization.scale**3, rel=1e-9)
    assert any(rec.what == "unioned_bodies" and rec.extra["cavities"] == 1 for rec in r.records)


def test_bodies_a_rounding_step_apart_are_snapped_and_united():
    """Two boxes sharing a face, one moved by 1e-9 of the diagonal (a baked GLB's fragments read back): snapped;
    kept apart as two closed bodies touching face to face (issue 39), or with repair.touching=unite united into
    one closed body, no hairline gap."""
    from fracture_cli.geometry.weld_check import check_mesh

    a = trimesh.creation.box(extents=(1, 1, 1))
    b = trimesh.creation.box(extents=(1, 1, 1))
    b.apply_translation((1.0 + 2e-9, 1e-9, 0.0))
    both = trimesh.util.concatenate([a, b])
    s = surface(both.vertices, both.faces)
    apart = repair_surface(s)
    assert [rec for rec in apart.records if rec.what == "kept_bodies_apart"][0].count == 2
    V, F = apart.surface.vertices, apart.surface.faces
    half = len(F) // 2
    for faces in (F[:half], F[half:]):
        body = check_mesh(V, faces)
        assert body.closed and body.volume == pytest.approx(1 / s.normalization.scale**3, rel=1e-6)
    r = repair_surface(s, RepairOptions(touching="unite"))
    assert [rec for rec in r.records if rec.what == "snapped_vertices"][0].count == 4
    check = check_mesh(r.surface.vertices, r.surface.faces)
    assert check.closed and check.pinched_vertices == 0, check.problems()
    assert check.volume == pytest.approx(2 / s.normalization.scale**3, rel=1e-6)


def test_shell_stays_inside_the_input_box(vase):
    r = repair(vase, RepairOptions(open_surface="shell"))
    lo, hi = vase.vertices.min(axis=0), vase.vertices.max(axis=0)
    assert np.all(r.vertices >= lo - 1e-6) and np.all(r.vertices <= hi + 1e-6)  # unit diagonal: 1e-6 of it


def test_repairs_are_warned_with_the_override(vase, caplog):
    with caplog.at_level(logging.WARNING, logger="fracture_cli.stages.repair"):
        repair(vase, RepairOptions(open_surface="shell"))
    warnings = [r.message for r in caplog.records if r.levelno == logging.WARNING]
    assert any("thickened" in m and "--set repair.open_surface=fill" in m for m in warnings), warnings
