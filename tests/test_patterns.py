"""Authored fracture patterns (issue 32): every kind bakes closed, one-body fragments that break by the impact.

Each bake is small (a box or the pane and wall samples, a 600-face cage, few
cells) so the file runs in about a minute.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import trimesh

from fracture_cli.pipeline import PipelineState
from fracture_cli.pipeline.bake import bake
from fracture_cli.pipeline.recipe import load_recipe
from fracture_cli.pipeline.runner import Runner
from fracture_cli.runtime.format import load_runtime
from fracture_cli.stages.pattern import PatternOptions, pattern
from fracture_cli.stages.pattern.cells import held_volumes

from conftest import SAMPLE_ASSETS

FAST = ["cage.target_faces=600", "modes.num_modes=4"]
ZIGZAG = {"points": [[0.0, 0.0], [0.25, 0.08], [0.5, -0.08], [0.75, 0.08], [1.0, 0.0]], "weight": 1.0}
KINDS = {
    "voronoi": ["pattern.count=6"],
    "clustered": ["pattern.clusters=2", "pattern.count=3", "pattern.spread=0.1"],
    "radial": ["pattern.axis=z", "pattern.rings=2", "pattern.spokes=4"],
    "slices": ["pattern.slice_axes=x", "pattern.slices=3", "pattern.angle_jitter=10.0"],
    "bricks": ["pattern.brick_size=[0.3, 0.2, 1.0]"],
    "profile": ["pattern.cuts=3", "pattern.profiles=[{ points = [[0.0, 0.0], [0.5, 0.1], [1.0, 0.0]] }]"],
}


@pytest.fixture(scope="module")
def box(tmp_path_factory) -> str:
    """A 1.0 x 0.5 x 0.25 box (OBJ)."""
    path = str(tmp_path_factory.mktemp("box") / "box.obj")
    trimesh.creation.box(extents=(1.0, 0.5, 0.25)).export(path)
    return path


def _bake(asset: str, out: str, recipe: str = "default", sets=(), fast=FAST) -> dict:
    result = bake(asset, out, load_recipe(recipe, [*fast, *sets]))
    return result.report


def _assert_game_ready(report: dict, out: str, stem: str) -> None:
    checks = report["checks"]
    assert checks["watertight"] and checks["connected"], checks
    assert checks["fragment_bodies_max"] == 1
    assert checks["volume_error"] <= 1e-6
    total = sum(f["volume"] for f in report["fragments"])
    assert abs(total - checks["input_volume"]) <= 1e-6 * checks["input_volume"]
    data = load_runtime(os.path.join(out, f"{stem}.fracture.json"))
    assert data.p == len(report["fragments"]) >= 2 and data.num_edges >= 1


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_kind_bakes_closed_single_body_fragments(kind, box, tmp_path):
    out = str(tmp_path / kind)
    report = _bake(box, out, sets=[f"pattern.kind={kind}", *KINDS[kind]])
    _assert_game_ready(report, out, "box")
    assert report["recipe"]["parameters"]["pattern"]["kind"] == kind
    # The cells are the pieces; a smoothed cell that leaves the input in two bodies gives two fragments.
    assert report["counts"]["fragments"] >= report["counts"]["pieces"] >= 2
    print(kind, report["counts"]["fragments"], "fragments,", report["seconds"]["total"], "s, overlap",
          report["checks"]["collision_max_overlap"])


def test_collision_parts_of_a_coarse_radial_box_do_not_overlap(box, tmp_path):
    # Two parts of one fragment overlapped by 72% here: the decomposition numbered the halves of a piece that
    # shared its cell as cells of their own, and the separation skipped their pairs with the cell's other piece.
    report = _bake(box, str(tmp_path / "o"), sets=["pattern.kind=radial", *KINDS["radial"]])
    assert report["checks"]["collision_max_overlap"] < 0.01


def test_modes_kind_is_the_default_and_changes_nothing():
    assert load_recipe("default")["pattern"] == PatternOptions()
    assert PatternOptions().kind == "modes"


def test_a_pattern_bake_is_byte_identical_when_repeated(box, tmp_path):
    hashes = []
    for name in ("a", "b"):
        _bake(box, str(tmp_path / name), sets=["pattern.kind=voronoi", "pattern.count=5"])
        hashes.append(_hashes(str(tmp_path / name)))
    assert hashes[0] == hashes[1]


def _hashes(out: str) -> dict:
    import hashlib

    return {n: hashlib.sha256(open(os.path.join(out, n), "rb").read()).hexdigest()
            for n in ("box.glb", "box.fracture.json", "box.fracture.bin")}


@pytest.fixture(scope="module")
def pane_bake(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("pane"))
    # The recipe's pattern and modes (what decides where it breaks), on a coarser cage.
    report = _bake(os.path.join(SAMPLE_ASSETS, "pane.glb"), out, "glass_pane", fast=["cage.target_faces=600"])
    return out, report


def test_glass_pane_recipe_bakes_the_pane(pane_bake):
    out, report = pane_bake
    _assert_game_ready(report, out, "pane")
    assert report["recipe"]["parameters"]["pattern"]["kind"] == "radial"


# "Near" for the pane hit (fractions of the pane's in-plane diagonal): what comes off first lies within NEAR of
# the hit, and a hit near a corner detaches pieces at least FAR from the pane's centre.
NEAR, FAR = 0.15, 0.25


def _first_detachment(data, glb: str, point, direction=(0.0, 0.0, -1.0)) -> tuple[np.ndarray, np.ndarray, bool]:
    """The atlas's analysis of one hit at its first detachment (just above ``d1``): the detached fragments'
    centroids (k, 3), the hit point (3,), and whether the fragment hit (nearest centroid) is among them."""
    from fracture_cli.atlas.hits import analyse_hit, detached, groups_at, nearest_fragment, rest_groups
    from fracture_cli.atlas.layout import fragment_layout
    from fracture_cli.atlas.sweep import JUST_ABOVE

    layout = fragment_layout(data, glb)
    assert layout.centroids is not None
    hit = analyse_hit(data, np.asarray(point, dtype=np.float64), direction)
    assert np.isfinite(hit.d1), "no impulse detaches anything"
    gone = detached(groups_at(data, hit, hit.d1 * JUST_ABOVE), rest_groups(data), layout.volumes)
    return layout.centroids[gone], hit.point, bool(gone[nearest_fragment(layout.centroids, hit.point)])


def test_a_hit_near_the_panes_centre_breaks_near_its_centre(pane_bake):
    """Hit the pane's front face at the site nearest its centre, impulse into the pane: at the first detachment
    the fragment hit comes off and every detached fragment's centroid lies within NEAR of the pane's in-plane
    diagonal from the hit; hit near a corner, what comes off first is at least FAR from the centre."""
    out, report = pane_bake
    data = load_runtime(os.path.join(out, "pane.fracture.json"))
    glb = os.path.join(out, "pane.glb")
    sites = np.asarray(data.sites, dtype=np.float64)
    lo, hi = sites.min(axis=0), sites.max(axis=0)
    middle = (lo + hi) / 2
    diagonal = float(np.linalg.norm((hi - lo)[:2]))  # the pane faces +z: its plane is x, y
    front = sites[sites[:, 2] > middle[2] + 0.25 * (hi[2] - lo[2])]  # the front face's sites
    centre = front[np.argmin(np.linalg.norm(front[:, :2] - middle[:2], axis=1))]
    corner = front[np.argmin(np.linalg.norm(front[:, :2] - (lo[:2] + 0.1 * (hi[:2] - lo[:2])), axis=1))]
    offset = float(np.linalg.norm(centre[:2] - middle[:2])) / diagonal
    print(f"hit site {offset:.3f} of the diagonal from the centre")
    assert offset < 0.1  # the contact sites nearest the centre (a coarse bake has few)

    near, point, hit_detached = _first_detachment(data, glb, centre)
    reach = np.linalg.norm(near[:, :2] - point[:2], axis=1) / diagonal
    print(f"centre hit: {len(near)} fragment(s) detached, farthest centroid {reach.max():.3f} of the diagonal")
    assert hit_detached and len(near) >= 1
    assert reach.max() < NEAR, reach

    far, _, _ = _first_detachment(data, glb, corner)
    away = np.linalg.norm(far[:, :2] - middle[:2], axis=1) / diagonal
    print(f"corner hit: {len(far)} fragment(s) detached, nearest centroid {away.min():.3f} of the diagonal "
          "from the centre")
    assert away.min() > FAR, away


def test_brick_wall_recipe_bakes_the_wall(tmp_path):
    out = str(tmp_path / "wall")
    report = _bake(os.path.join(SAMPLE_ASSETS, "wall.glb"), out, "brick_wall",
                   ["pattern.brick_size=[0.34, 0.17, 1.0]"])
    _assert_game_ready(report, out, "wall")
    assert report["counts"]["fragments"] >= 8


# --- profile parameters, on the tet mesh of the box (no bake) ---------------------------------------------------

@pytest.fixture(scope="module")
def box_tets(box):
    recipe = load_recipe("default", FAST)
    state = PipelineState(source=box)
    runner = Runner("test")
    for name in ("load", "repair", "cage", "tetra"):
        state = runner.run(name, state, recipe[name])
    return state.need("tet_mesh", "test"), state.need("surface", "test")


def _cells(box_tets, **values) -> np.ndarray:
    tets, surface = box_tets
    cells = pattern(tets, surface, PatternOptions(kind="profile", **values))
    assert cells is not None
    return cells


def _shares(box_tets, cells) -> np.ndarray:
    held = held_volumes(*box_tets)
    return np.bincount(cells, weights=held) / held.sum()


def test_profile_volume_ratio_sets_the_share_of_the_cut(box_tets):
    for ratio in (0.2, 0.5, 0.7):
        cells = _cells(box_tets, cuts=1, profiles=[{**ZIGZAG, "volume_ratio": ratio}])
        shares = np.sort(_shares(box_tets, cells))
        assert len(shares) == 2
        assert abs(shares[0] - min(ratio, 1 - ratio)) < 0.05, (ratio, shares)


def test_profile_rotation_turns_the_cut_from_lengthwise_to_across(box_tets):
    tets, _ = box_tets
    x = tets.tet_centroids
    lengths = {}
    for rotation in (0.0, 90.0):
        cells = _cells(box_tets, cuts=1, profiles=[{"rotation": rotation}])
        # Extent along the box's long axis (x) of each part: the whole length when cut lengthwise.
        lengths[rotation] = [float(np.ptp(x[cells == c, 0])) for c in range(2)]
    assert max(lengths[90.0]) < 0.7 * min(lengths[0.0]), lengths


def test_profile_weights_pick_the_pattern(box_tets):
    straight = {"points": [[0.0, 0.0], [1.0, 0.0]], "rotation": 90.0}
    zigzag = {**ZIGZAG, "rotation": 90.0}
    only_zigzag = _cells(box_tets, cuts=2, profiles=[{**zigzag, "weight": 1.0}])
    only_straight = _cells(box_tets, cuts=2, profiles=[{**straight, "weight": 1.0}])
    first = _cells(box_tets, cuts=2, profiles=[{**zigzag, "weight": 1.0}, {**straight, "weight": 0.0}])
    second = _cells(box_tets, cuts=2, profiles=[{**zigzag, "weight": 0.0}, {**straight, "weight": 1.0}])
    assert np.array_equal(first, only_zigzag) and np.array_equal(second, only_straight)
    assert not np.array_equal(first, second)


def test_bad_profiles_are_refused_with_the_key(box_tets):
    from fracture_cli.errors import RecipeError

    tets, surface = box_tets
    with pytest.raises(RecipeError, match="volume_ratio"):
        pattern(tets, surface, PatternOptions(kind="profile", profiles=[{"volume_ratio": 1.5}]))
    with pytest.raises(RecipeError, match="unknown key"):
        pattern(tets, surface, PatternOptions(kind="profile", profiles=[{"angle": 3}]))


def test_every_cell_is_one_connected_set_of_tets(box_tets):
    from fracture_cli.geometry.edges import components

    tets, surface = box_tets
    for kind, values in (("voronoi", {"count": 12}), ("slices", {"slice_axes": "xz", "slices": 2}),
                         ("radial", {"rings": 2, "spokes": 5})):
        cells = pattern(tets, surface, PatternOptions(kind=kind, **values))
        face_tets = tets.interior_face_tets
        same = cells[face_tets[:, 0]] == cells[face_tets[:, 1]]
        assert int(components(len(cells), face_tets[same]).max()) == int(cells.max()), kind


def test_the_report_names_the_pattern(box, tmp_path):
    out = str(tmp_path / "o")
    _bake(box, out, sets=["pattern.kind=slices", "pattern.slices=1"])
    with open(os.path.join(out, "box.report.json")) as fh:
        report = json.load(fh)
    assert report["recipe"]["parameters"]["pattern"]["kind"] == "slices"
    assert "pattern" in report["seconds"]


# --- faults.noise ---------------------------------------------------------------------------------------------

def test_noise_is_a_function_of_position_only():
    from fracture_cli.stages.faults import value_noise

    rng = np.random.default_rng(3)
    points = rng.uniform(-0.5, 0.5, (200, 3))
    a = value_noise(points, 20.0, 3)
    b = value_noise(points[::-1], 20.0, 3)[::-1]
    assert np.array_equal(a, b) and np.all(np.abs(a) <= 1.0) and a.std() > 0.05
    assert not np.array_equal(a, value_noise(points, 20.0, 3, seed=1))


def test_noise_off_leaves_the_regions_alone():
    from fracture_cli.stages.faults import FaultOptions, faults
    from fracture_cli.types import Regions

    regions = Regions(meshes=((np.zeros((3, 3)), np.array([[0, 1, 2]])),))
    assert faults(regions, FaultOptions()) is regions
    assert load_recipe("default")["faults"] == FaultOptions()


def test_noisy_faults_keep_fragments_closed(box, tmp_path):
    plain, noisy = str(tmp_path / "plain"), str(tmp_path / "noisy")
    sets = ["pattern.kind=voronoi", "pattern.count=5"]
    _bake(box, plain, sets=sets)
    report = _bake(box, noisy, sets=[*sets, "faults.noise=0.005", "faults.noise_octaves=2"])
    _assert_game_ready(report, noisy, "box")
    assert _hashes(plain)["box.glb"] != _hashes(noisy)["box.glb"]


def test_the_cell_graph_has_the_energy_and_mass_of_the_prolongated_field(box_tets):
    from fracture_cli.stages.modes.solver import discontinuity_energy, face_weights
    from fracture_cli.stages.pattern.restrict import cell_problem

    tets, surface = box_tets
    cells = pattern(tets, surface, PatternOptions(kind="voronoi", count=9))
    rng = np.random.default_rng(0)
    f = len(tets.interior_face_tets)
    eta = rng.uniform(0.5, 4.0, (f, 1))  # a material (grain, strength map) weights the cell graph too
    volumes = np.asarray(tets.tet_volumes)
    problem = cell_problem(cells, tets.interior_face_tets, face_weights(tets), eta, volumes,
                           rng.uniform(-1, 1, (2, len(volumes))), 12)
    w = rng.uniform(-1.0, 1.0, (int(cells.max()) + 1, 1))
    on_tets = discontinuity_energy(w[cells], tets.interior_face_tets, face_weights(tets), eta)
    on_cells = discontinuity_energy(w, problem.edges, problem.areas, problem.eta)
    assert abs(on_tets - on_cells) <= 1e-12 * on_tets
    assert abs(float(np.sum(volumes * w[cells, 0] ** 2)) - float(np.sum(problem.volumes * w[:, 0] ** 2))) < 1e-12
    assert problem.num_modes == min(12, int(cells.max()))


def test_pattern_bakes_use_the_stage_cache(box, tmp_path):
    sets = ["pattern.kind=slices", "pattern.slices=2"]
    recipe = load_recipe("default", [*FAST, *sets])
    cache = str(tmp_path / "cache")
    bake(box, str(tmp_path / "a"), recipe, cache_dir=cache)
    second = bake(box, str(tmp_path / "b"), recipe, cache_dir=cache).report
    assert second["cache"]["modes"] == "hit"
    assert _hashes(str(tmp_path / "a")) == _hashes(str(tmp_path / "b"))
    other = bake(box, str(tmp_path / "c"), load_recipe("default", [*FAST, *sets, "pattern.slices=3"]),
                 cache_dir=cache).report
    assert other["cache"]["modes"] == "miss"
