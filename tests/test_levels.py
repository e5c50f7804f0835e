"""The ``levels`` stage: fragments broken again (issue 34; docs/ALGORITHM.md section 13, docs/FORMAT.md section 14).

Properties on tiny meshes (the tets a child is computed on, the rule, the leaf cap, the GLB tree), then one
fast 2-level bake of the sample pillar checked for exact nesting: every child closed and one body, the
children's volumes summing to their parent's within 1e-6, their faces on the parent's surface tiling it
(its outer surface and its faults to its neighbours, unchanged), the leaf cap, and the runtime file's bodies.
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np
import pytest
from invariants import GlbFragment, check_fragment, read_glb_fragments

from fracture_cli.geometry import trigeom
from fracture_cli.geometry.scenes import surface_scene
from fracture_cli.geometry.surface_query import distances
from fracture_cli.geometry.tetgeom import triangle_areas
from fracture_cli.io.gltf import read_glb_chunks
from fracture_cli.io.physics import fragment_physics
from fracture_cli.io.write import write_fragments_glb
from fracture_cli.pipeline import STAGE_NAMES, PipelineState
from fracture_cli.pipeline.bake import write_outputs
from fracture_cli.pipeline.recipe import load_recipe
from fracture_cli.pipeline.runner import Runner
from fracture_cli.runtime import levels as lv
from fracture_cli.runtime.format import load_runtime
from fracture_cli.runtime.impact import project_impact
from fracture_cli.stages import levels as stage
from fracture_cli.stages.levels import refine as refine_module
from fracture_cli.stages.levels.options import LevelsOptions
from fracture_cli.stages.levels.submesh import (
    covering_tets,
    manifold_cover,
    propagate_labels,
    submesh,
    submesh_eta,
)
from fracture_cli.testing import grid_tetmesh
from fracture_cli.types import Fragment, Fragments, Material, Normalization

from conftest import SAMPLE_ASSETS

# ---------------------------------------------------------------- tiny meshes


def test_submesh_keeps_tets_and_maps_material_weights():
    mesh = grid_tetmesh((2, 2, 2))
    tets = np.arange(0, mesh.num_tets, 3)
    sub = submesh(mesh, tets)
    assert sub.num_tets == len(tets)
    assert np.allclose(sub.vertices[sub.tets], mesh.vertices[mesh.tets[tets]])
    assert np.allclose(sub.tet_volumes, mesh.tet_volumes[tets])
    # The weight of every interior face of the sub-mesh is the full mesh's weight of the same face.
    eta = np.arange(1, len(mesh.interior_faces) + 1, dtype=np.float64)
    sub_eta = submesh_eta(mesh, tets, sub, eta)
    keys = {tuple(np.sort(mesh.interior_faces[i])): eta[i] for i in range(len(eta))}
    used = np.unique(mesh.tets[tets])
    for face, weight in zip(sub.interior_faces, sub_eta):
        assert keys[tuple(np.sort(used[face]))] == weight
    assert submesh_eta(mesh, tets, sub, None) is None


def test_covering_tets_hold_the_box_and_labels_grow_over_faces():
    mesh = grid_tetmesh((3, 3, 3))
    lo, hi = np.array([0.2, 0.2, 0.2]), np.array([1.1, 1.1, 1.1])
    cover = covering_tets(mesh, lo, hi)
    corners = mesh.vertices[mesh.tets]
    # Every tet that contains a point of the box is there (its box meets the box).
    outside = np.setdiff1d(np.arange(mesh.num_tets), cover)
    assert np.all(np.any((corners[outside].max(axis=1) < lo) | (corners[outside].min(axis=1) > hi), axis=1))
    labels = np.full(len(cover), -1)
    labels[0], labels[-1] = 7, 3
    grown = propagate_labels(mesh, cover, labels)
    assert set(grown.tolist()) == {3, 7} and grown[0] == 7 and grown[-1] == 3


def test_manifold_cover_leaves_no_edge_where_the_set_touches_itself():
    mesh = grid_tetmesh((3, 3, 3))
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    centroids = mesh.vertices[mesh.tets].mean(axis=1)
    # Two blocks of tets that meet along one edge of the grid (diagonal cells of a 2x2 layer): pinched there.
    cell = np.floor((centroids - lo) / (hi - lo) * 3).astype(int)
    chosen = np.flatnonzero(np.all(cell[:, :2] == 0, axis=1) | np.all(cell[:, :2] == 1, axis=1))

    def pinched(tets):
        faces = np.sort(mesh.tets[tets][:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3), axis=1)
        unique, counts = np.unique(faces, axis=0, return_counts=True)
        outer = unique[counts == 1]
        sides = np.concatenate([outer[:, [0, 1]], outer[:, [1, 2]], outer[:, [0, 2]]])
        return int((np.unique(sides, axis=0, return_counts=True)[1] > 2).sum())

    assert pinched(chosen) > 0
    cover = manifold_cover(mesh, chosen)
    assert np.all(np.isin(chosen, cover)) and np.all(np.diff(cover) > 0) and pinched(cover) == 0
    assert np.array_equal(manifold_cover(mesh, cover), cover)


def test_candidates_largest_first_ratio_min_volume_and_anchors():
    volumes = np.array([1.0, 5.0, 3.0, 5.0, 0.1, 2.0])
    assert stage.candidates(volumes, None, LevelsOptions(count=2, min_volume=0.0)) == [1, 3, 2, 5, 0, 4]
    assert stage.candidates(volumes, None, LevelsOptions(count=2, ratio=0.5, min_volume=0.0)) == [1, 3, 2]
    assert stage.candidates(volumes, None, LevelsOptions(count=2, min_volume=0.05)) == [1, 3, 2, 5, 0]
    assert stage.candidates(volumes, np.array([0, 1, 0, 0, 0, 0]), LevelsOptions(count=2, ratio=0.5,
                                                                               min_volume=0.0)) == [3, 2]


@dataclasses.dataclass(frozen=True, eq=False)
class _FakeChildren:
    fragments: tuple


def test_leaf_cap_is_enforced_in_the_rule_order(monkeypatch):
    """Fragments are accepted largest first while the leaves fit; a cut that gives more bodies is dropped."""
    cube = _cube(np.zeros(3), 1.0)
    frags = Fragments(fragments=tuple(dataclasses.replace(cube, vertices=cube.vertices * s) for s in (1.0, 1.3, 0.9,
                                                                                                       1.2)),
                      materials=(Material("stone"), Material("interior")), normalization=Normalization.identity(),
                      input_volume=1.0)
    expected = {0: 3, 1: 4, 2: 3, 3: 5}  # children each fragment's modes give
    actual = {0: 3, 1: 4, 2: 3, 3: 7}  # ... and its cut (fragment 3 falls into more bodies)

    def plan(ctx, index):
        return refine_module.Plan(fragment=index, tets=np.zeros(0), U=np.zeros((1, 0, 1)),
                          pieces=dataclasses.replace(_pieces(expected[index])))

    def refine(ctx, plan):
        return refine_module.Refinement(fragment=plan.fragment, children=_FakeChildren((None,) * actual[plan.fragment]),
                                parts=(), physics=(), body={}, checks={})

    monkeypatch.setattr(refine_module, "plan_refinement", plan)
    monkeypatch.setattr(refine_module, "refine_fragment", refine)
    ctx = refine_module.Context(tet_mesh=None, tet_piece=None, eta=None, fragments=frags,
                        options=LevelsOptions(count=2, min_volume=0.0, max_leaves=14), stages={}, radius=0.05,
                        threshold=1.0)
    result = stage.levels(ctx)
    # Order by volume: 1 (2.197), 3 (1.728), 0 (1), 2 (0.729). Leaves start at 4: +3 (1) = 7, +4 (3: planned 5)
    # = 11, 0 would give 13, 2 15 > 14: skipped. The cuts: 1 -> 7, 3 gives 7 children: 13, 0: 15 > 14 dropped.
    assert [r.fragment for r in result.refinements] == [1, 3]
    assert result.leaves == 13 <= 14
    assert set(result.skipped) == {0, 2}
    assert "max_leaves" in result.skipped[2] and "max_leaves" in result.skipped[0]


def _pieces(count: int):
    from fracture_cli.types import Pieces

    return Pieces(tet_piece=np.zeros(0, np.int32), W=np.zeros((1, count, 1)), volumes=np.ones(count),
                  centroids=np.zeros((count, 3)), edges=np.zeros((0, 2), np.int32), edge_areas=np.zeros(0),
                  edge_centroids=np.zeros((0, 3)), edge_normals=np.zeros((0, 3)))


def _cube(centre: np.ndarray, size: float) -> Fragment:
    V = (np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64) - 0.5) * size
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64)
    if trigeom.signed_volume(V, F) < 0:
        F = F[:, ::-1]
    return Fragment(vertices=V + centre, faces=F, uvs=None, normals=np.zeros_like(V),
                    material_ids=np.zeros(12, np.int32), piece=0)


@pytest.mark.parametrize("collision", ["omi", "godot", "unreal"])
def test_glb_puts_children_under_their_parents(tmp_path, collision):
    materials = (Material("stone"), Material("interior"))
    parent = Fragments(fragments=(_cube(np.zeros(3), 2.0), _cube(np.array([3.0, 0, 0]), 2.0)), materials=materials,
                       normalization=Normalization.identity(), input_volume=16.0)
    kids = Fragments(fragments=(_cube(np.array([-0.5, 0, 0]), 1.0), _cube(np.array([0.5, 0, 0]), 1.0)),
                     materials=materials, normalization=Normalization.identity(), input_volume=8.0)
    corners = [(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) + c,) for c in ((0, 0, 0), (3, 0, 0))]
    path = tmp_path / "a.glb"
    write_fragments_glb(path, parent, parts=corners, collision=collision, stem="a",
                        children=[(0, kids, fragment_physics(kids, [c[:1] for c in corners]))])
    doc, _ = read_glb_chunks(str(path))
    nodes = doc["nodes"]
    assert doc["scenes"][0]["nodes"] == [0, 1]
    names = {n["name"]: i for i, n in enumerate(nodes)}
    for j, x in enumerate((-0.5, 0.5)):
        child = nodes[names[f"a_fragment_000_c{j:02d}"]]
        assert names[f"a_fragment_000_c{j:02d}"] in nodes[0]["children"]
        assert child["translation"] == [x, 0.0, 0.0]  # relative to the parent's pivot (its centre of mass, 0)
        assert child["extras"]["fracture"]["level"] == 2
        assert "OMI_physics_body" not in child.get("extensions", {})
        has_parts = any(nodes[k]["name"].startswith(("UCX_a_fragment_000_c", f"a_fragment_000_c{j:02d}_"))
                        for k in child.get("children", []))
        assert has_parts == (collision != "omi")
    assert "level" not in nodes[0]["extras"]["fracture"]


# ---------------------------------------------------------------- a fast 2-level bake of the pillar


@pytest.fixture(scope="module")
def pillar_levels(tmp_path_factory):
    """The pillar baked with 2 levels (ratio 0.3: its 3 largest fragments), in-process so the state is kept."""
    recipe = load_recipe("stone", ["levels.count=2", "levels.ratio=0.3"])
    runner = Runner("pillar", jobs=2)
    state = PipelineState(source=os.path.join(SAMPLE_ASSETS, "pillar.glb"))
    for name in STAGE_NAMES:
        state = runner.run(name, state, recipe[name])
    out = tmp_path_factory.mktemp("pillar_levels")
    from fracture_cli.pipeline.bake import build_report

    report = build_report(state, recipe, runner)
    write_outputs(str(out), "pillar", state, report, runner)
    return state, report, str(out)


def _parent_surface(state, index):
    frag = state.fragments.fragments[index]
    return frag.vertices, frag.faces, frag.material_ids


def test_children_nest_exactly_in_their_parents(pillar_levels):
    state, report, _ = pillar_levels
    result = state.levels
    assert len(result.refinements) == 3 and report["levels"]["checks"]["watertight"]
    interior = state.fragments.interior_slot
    for refinement in result.refinements:
        V, F, material = _parent_surface(state, refinement.fragment)
        parent_volume = trigeom.signed_volume(V, F)
        children = refinement.children.fragments
        assert len(children) >= 2
        total = 0.0
        query = surface_scene(V, F)
        on_parent = {True: 0.0, False: 0.0}  # children's faces on the parent's faults / outer surface
        for child in children:
            check = check_fragment(GlbFragment("child", child.vertices, child.faces, np.eye(4)))
            assert check.ok, check.problems  # closed, consistently oriented, one body (welded by exact position)
            total += trigeom.signed_volume(child.vertices, child.faces)
            centroids = child.vertices[child.faces].mean(axis=1)
            on = distances(query, centroids) <= 1e-7
            for fault in (True, False):
                mine = on & ((child.material_ids == interior) == fault)
                on_parent[fault] += float(triangle_areas(child.vertices, child.faces[mine]).sum())
            # Corners of faces on the parent's surface lie on it (float64 rounding only).
            corners = np.unique(child.faces[on])
            assert distances(query, child.vertices[corners]).max() < 1e-12
        assert abs(total - parent_volume) <= 1e-6 * parent_volume, "volumes sum to the parent's"
        for fault in (True, False):  # the parent's faults to its neighbours, and its outer surface, tiled exactly
            area = float(triangle_areas(V, F[(material == interior) == fault]).sum())
            assert abs(on_parent[fault] - area) <= 1e-6 * area
        assert refinement.checks["volume_error"] <= 1e-6 and refinement.checks["parent_area_error"] <= 1e-6


def test_leaves_and_runtime_bodies(pillar_levels):
    state, report, out = pillar_levels
    result, p = state.levels, len(state.fragments.fragments)
    leaves = p + sum(len(r.children.fragments) - 1 for r in result.refinements)
    assert result.leaves == leaves == report["levels"]["leaves"] <= result.options.max_leaves
    data = load_runtime(os.path.join(out, "pillar.fracture.json"))
    assert "levels" in data.features and lv.num_bodies(data) == len(result.refinements) + 1
    assert data.levels_info["thresholds"] == [data.default_threshold, data.default_threshold]
    for b, refinement in enumerate(result.refinements, start=1):
        assert lv.body_of(data, refinement.fragment) == b
        view = lv.body_view(data, b)
        assert view.p == len(refinement.children.fragments)
        volumes = [trigeom.signed_volume(c.vertices, c.faces) * state.fragments.normalization.scale ** 3
                   for c in refinement.children.fragments]
        assert np.allclose(view.gameready["fragment_volume"], volumes, rtol=1e-6)
        assert np.all(np.diff(view.gameready["collision_fragment_offsets"]) >= 1), "every child has parts"
        hit = project_impact(data, view.sites[0], (0.0, -1e3, 0.0), body=b)
        assert hit.groups.shape == (view.p,) and hit.num_groups >= 2


def test_glb_holds_the_tree_the_runtime_file_names(pillar_levels):
    state, _, out = pillar_levels
    data = load_runtime(os.path.join(out, "pillar.fracture.json"))
    written = {f.name: check_fragment(f) for f in read_glb_fragments(os.path.join(out, "pillar.glb"))}
    children = [lv.fragment_name(data, g) for g in range(data.p, lv.num_fragments(data))]
    for name in children:  # as written (float32, in the node tree): closed one-body meshes
        assert written[name].ok, (name, written[name].problems)
    # Placed by the node tree, every parent's children fill it: their volumes as written sum to its own.
    for r in state.levels.refinements:
        parent = data.fragment_names[r.fragment]
        mine = [n for n in children if n.startswith(parent + "_c")]
        assert abs(sum(written[n].volume for n in mine) - written[parent].volume) <= 1e-5 * written[parent].volume
    doc, _ = read_glb_chunks(os.path.join(out, "pillar.glb"))
    nodes = doc["nodes"]
    names = {n["name"]: i for i, n in enumerate(nodes)}
    assert [nodes[i]["name"] for i in doc["scenes"][0]["nodes"]] == list(data.fragment_names)
    for g in range(data.p, lv.num_fragments(data)):
        parent = lv.fragment_name(data, int(data.levels["parent"][g]))
        assert names[lv.fragment_name(data, g)] in nodes[names[parent]]["children"]
    with open(os.path.join(out, "pillar.report.json")) as fh:
        report = json.load(fh)
    assert report["levels"]["refined"] == [data.fragment_names[r.fragment] for r in state.levels.refinements]
