"""The break atlas: exact per-hit figures against brute force, the sweep's figures, the gate, the PNG."""

from __future__ import annotations

import os

import numpy as np
import pytest
from PIL import Image

from fracture_cli.atlas import run_atlas
from fracture_cli.atlas.criterion import criterion_named, modes_breaking_impulses
from fracture_cli.atlas.hits import analyse_hit, detached, groups_at, maximum_spanning_forest, rest_groups
from fracture_cli.atlas.layout import fragment_layout
from fracture_cli.atlas.leaves import StruckHit
from fracture_cli.atlas.summary import FIGURE_KEYS, failed_requirements, parse_requirement, rounded
from fracture_cli.atlas.sweep import atlas_figures, farthest_point_sites, quantile, sweep_hits
from fracture_cli.errors import RuntimeFileError, UsageError
from fracture_cli.io.gltf import Primitive, glb_bytes
from fracture_cli.runtime.format import GAMEREADY_LAYOUT, RuntimeData, load_runtime, write_runtime
from fracture_cli.runtime.impact import project_impact
from fracture_cli.types import Material

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFORMANCE = os.path.join(REPO, "tests", "data", "runtime_conformance")
FILES = ["chair", "pillar", "vase", "example", "dyadic_d3", "random_d1", "random_d3", "single"]
SLACK = 1e-7  # relative distance from a breaking impulse at which the runtime's answer is unambiguous


def conformance(name: str) -> RuntimeData:
    return load_runtime(os.path.join(CONFORMANCE, f"{name}.fracture.json"))


def row_of_three(dim: int = 1) -> RuntimeData:
    """Three unit fragments in a row along x (volumes 1, 2, 1), bonds (0, 1) and (1, 2), two sites at the ends.

    With T = 2 the bonds break at impulses 2 and 1 (d = 1), whatever the direction.
    """
    W = np.zeros((1, 3, dim))
    W[0, :, 0] = (0.0, 1.0, 3.0)
    B = np.zeros((2, 1, dim))
    B[:, 0, 0] = (1.0, -1.0)
    centroids = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    gameready = {"fragment_volume": np.array([1.0, 2.0, 1.0]), "fragment_center_of_mass": centroids,
                 "fragment_inertia": np.zeros((3, 6)), "collision_vertices": np.zeros((0, 3)),
                 "collision_part_offsets": np.zeros(1, np.int32), "collision_fragment_offsets": np.zeros(4, np.int32)}
    assert set(gameready) == set(GAMEREADY_LAYOUT)
    return RuntimeData(sites=np.array([[-0.5, 0.0, 0.0], [2.5, 0.0, 0.0]], np.float32), B=B.astype(np.float32),
                       W=W.astype(np.float32), edges=np.array([[0, 1], [1, 2]], np.int32),
                       edge_areas=np.ones(2, np.float32), fragment_names=("f0", "f1", "f2"), default_threshold=2.0,
                       gameready=gameready)


def brute_force_check(data: RuntimeData, point, direction) -> None:
    """b0, d1, everything and the groups of one hit agree with project_impact just below and above each."""
    hit = analyse_hit(data, point, direction)
    rest = rest_groups(data)
    n_rest = len(np.unique(rest))
    u = hit.direction

    def runtime(magnitude):
        return project_impact(data, point, u * magnitude)

    if not np.isfinite(hit.b0):
        assert not runtime(1e30).broken.any()
        return
    assert not runtime(hit.b0 * (1 - SLACK)).broken.any()
    assert runtime(hit.b0 * (1 + SLACK)).broken.any()
    if np.isfinite(hit.d1):
        assert len(np.unique(runtime(hit.d1 * (1 - SLACK)).groups)) == n_rest
        assert len(np.unique(runtime(hit.d1 * (1 + SLACK)).groups)) > n_rest
    else:
        assert len(np.unique(runtime(1e30).groups)) == n_rest
    if np.isfinite(hit.everything):
        assert not runtime(hit.everything * (1 - SLACK)).broken.all()
        assert runtime(hit.everything * (1 + SLACK)).broken.all()
    # Groups at many magnitudes: a geometric grid and every breaking impulse, nudged off the ties.
    finite = hit.magnitudes[np.isfinite(hit.magnitudes) & (hit.magnitudes > 0)]
    grid = np.geomspace(hit.b0 / 4 if hit.b0 > 0 else 1e-6, max(hit.everything if np.isfinite(hit.everything)
                                                                  else 1.0, hit.b0) * 4, 40)
    magnitudes = np.concatenate([grid, finite * (1 - SLACK), finite * (1 + SLACK)])
    for magnitude in magnitudes.tolist():
        if np.any(np.abs(finite - magnitude) < 0.5 * SLACK * magnitude):
            continue  # within rounding of a tie: both answers are right
        result = runtime(magnitude)
        assert np.array_equal(groups_at(data, hit, magnitude), result.groups), magnitude
        assert np.array_equal(hit.magnitudes < magnitude, result.broken), magnitude


@pytest.mark.parametrize("name", FILES)
def test_first_break_detachment_and_everything_match_brute_force(name):
    data = conformance(name)
    layout = fragment_layout(data)
    center = layout.asset_center(data)
    sites = farthest_point_sites(data.sites, 6)
    rng = np.random.default_rng(3)
    for v in sites.tolist():
        point = np.asarray(data.sites[v], dtype=np.float64)
        direction = center - point if np.any(center != point) else np.array([0.0, -1.0, 0.0])
        brute_force_check(data, point, direction)
        brute_force_check(data, point, rng.uniform(-1, 1, 3))  # any direction (matters for d = 3)


def test_hand_made_row_exact_figures():
    data = row_of_three()
    hit = analyse_hit(data, 0, (1.0, 0.0, 0.0))
    np.testing.assert_array_equal(hit.magnitudes, [2.0, 1.0])
    assert (hit.b0, hit.d1, hit.everything) == (1.0, 1.0, 2.0)
    np.testing.assert_array_equal(groups_at(data, hit, 1.5), [0, 0, 2])
    np.testing.assert_array_equal(groups_at(data, hit, 2.0), [0, 0, 2])  # a jump equal to T holds
    np.testing.assert_array_equal(groups_at(data, hit, 2.5), [0, 1, 2])
    brute_force_check(data, data.sites[0], (1.0, 0.0, 0.0))
    layout = fragment_layout(data)
    assert layout.source == "gameready"
    np.testing.assert_allclose(layout.asset_center(data), [1.0, 0.0, 0.0])
    figures = atlas_figures(data, layout, sweep_hits(data, layout, np.arange(2)))
    # Just above d1 fragment 2 comes off: the hit near it sees its fragment go, the hit near fragment 0 does not.
    assert figures.hit_detached == 0.5
    # At 2 b0 = 2 still only fragment 2 is off: distances 2.5 (of 0.5, 1.5, 2.5) and 0.5 over a mean of 1.5.
    assert figures.locality_2x == pytest.approx((2.5 / 1.5 + 0.5 / 1.5) / 2)
    assert figures.locality_2x_hits == 2
    # At 8 b0 everything is broken; the heaviest fragment (1) is the main group, 0 and 2 are off.
    assert figures.locality_8x == pytest.approx(1.0)
    assert figures.first_break_splits == 1.0
    assert (figures.graded_median, figures.graded_p10) == (2.0, 2.0)
    assert (figures.b0_median, figures.d1_median) == (0.5, 0.5)


def test_d3_direction_and_zero_response():
    data = row_of_three(dim=3)  # W and B only along x: a hit along y or z loads nothing
    along_x = analyse_hit(data, 0, (2.0, 0.0, 0.0))
    np.testing.assert_allclose(along_x.magnitudes, [2.0, 1.0])
    tilted = analyse_hit(data, 0, (1.0, 1.0, 0.0))
    np.testing.assert_allclose(tilted.magnitudes, np.array([2.0, 1.0]) * np.sqrt(2.0))
    sideways = analyse_hit(data, 0, (0.0, 0.0, 1.0))
    assert np.all(np.isinf(sideways.magnitudes))
    assert sideways.b0 == sideways.d1 == sideways.everything == np.inf
    brute_force_check(data, data.sites[0], (1.0, 1.0, 0.0))


def test_detached_uses_volume_and_rest_components():
    volumes = np.array([1.0, 5.0, 1.0, 1.0])
    rest = np.array([0, 0, 0, 3])  # fragment 3 is separate at rest: never detached by itself
    np.testing.assert_array_equal(detached(np.array([0, 1, 1, 3]), rest, volumes), [True, False, False, False])
    np.testing.assert_array_equal(detached(np.array([0, 0, 2, 3]), rest, np.ones(4)), [False, False, True, False])


def test_spanning_forest_ties_and_components():
    edges = np.array([[0, 1], [1, 2], [0, 2], [3, 4]])
    forest = maximum_spanning_forest(5, edges, np.array([1.0, 1.0, 1.0, np.inf]))
    np.testing.assert_array_equal(forest, [3, 0, 1])  # inf first, then ties by index


def test_no_bonds_and_zero_threshold():
    single = conformance("single")
    hit = analyse_hit(single, 0, (0.0, -1.0, 0.0))
    assert hit.b0 == hit.d1 == hit.everything == np.inf
    figures = atlas_figures(single, fragment_layout(single), (StruckHit(hit=hit, struck=None),))
    assert figures.detaching_hits == 0 and figures.graded_median is None
    data = row_of_three()
    zero = RuntimeData(**{**{f: getattr(data, f) for f in ("sites", "B", "W", "edges", "edge_areas",
                                                           "fragment_names", "gameready")}, "default_threshold": 0.0})
    hit = analyse_hit(zero, 0, (1.0, 0.0, 0.0))
    assert hit.b0 == hit.d1 == 0.0
    assert project_impact(zero, zero.sites[0], (1e-300, 0.0, 0.0)).broken.all()
    assert atlas_figures(zero, fragment_layout(zero), (StruckHit(hit=hit, struck=None),)).b0_median is None


def test_farthest_point_sites_are_spread_and_deterministic():
    data = conformance("chair")
    chosen = farthest_point_sites(data.sites, 50)
    assert len(np.unique(chosen)) == 50 and 0 in chosen.tolist() and np.all(np.diff(chosen) > 0)
    np.testing.assert_array_equal(chosen, farthest_point_sites(data.sites, 50))
    np.testing.assert_array_equal(farthest_point_sites(data.sites[:10], 50), np.arange(10))
    duplicates = np.array([[0.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0]])
    np.testing.assert_array_equal(farthest_point_sites(duplicates, 2), [0, 2])


def test_quantile_matches_numpy_and_handles_inf():
    values = np.random.default_rng(0).uniform(0, 10, 37)
    for q in (0.0, 0.1, 0.5, 0.9, 1.0):
        assert quantile(values, q) == pytest.approx(float(np.quantile(values, q)), rel=1e-15)
    assert quantile([1.0, np.inf, np.inf], 0.5) == np.inf
    assert quantile([], 0.5) is None


def test_requirement_parser():
    assert str(parse_requirement("hit_detached>=0.95")) == "hit_detached>=0.95"
    requirement = parse_requirement("  locality_8x <= 0.5 ")
    assert (requirement.key, requirement.operator, requirement.value) == ("locality_8x", "<=", 0.5)
    for op in ("<", ">", "<=", ">="):
        assert parse_requirement(f"graded_p10{op}8").operator == op
    with pytest.raises(UsageError, match="unknown key 'hit'.*hit_detached.*locality_2x"):
        parse_requirement("hit>=0.9")
    for bad in ("hit_detached", "hit_detached=0.9", "hit_detached>=x", "hit_detached>=inf", "hit_detached>=nan",
                ">=0.9"):
        with pytest.raises(UsageError) as info:
            parse_requirement(bad)
        assert "\n" not in str(info.value)
    figures = {key: None for key in FIGURE_KEYS} | {"hit_detached": 0.6, "locality_8x": 0.5}
    assert failed_requirements(figures, ["hit_detached>=0.5", "locality_8x<=0.5"]) == ()
    assert failed_requirements(figures, ["hit_detached>0.6", "locality_8x<0.5", "graded_p10>=8"]) == (
        "hit_detached = 0.6, required > 0.6", "locality_8x = 0.5, required < 0.5",
        "graded_p10 = undefined, required >= 8")


def test_rounding():
    assert rounded(0.123456789) == 0.123457 and rounded(123456789.0) == 123457000.0
    assert rounded(np.inf) is None and rounded(None) is None and rounded(7) == 7


def test_run_atlas_summary_gate_and_determinism(tmp_path):
    path = os.path.join(CONFORMANCE, "pillar.fracture.json")
    first = run_atlas(path, sites=40, require=["hit_detached>=0.95", "hits>=40"])
    second = run_atlas(path, sites=40, require=["hit_detached>=0.95", "hits>=40"])
    assert first.json() == second.json()
    summary = first.summary
    assert list(summary) == ["format", "version", "runtime", "criterion", "threshold", "counts", "hits", "layout",
                             "figures", "examples", "requirements"]
    assert list(summary["figures"]) == list(FIGURE_KEYS)
    assert summary["layout"] == "gameready" and summary["figures"]["hits"] == 40
    assert first.failures == (f"hit_detached = {summary['figures']['hit_detached']:g}, required >= 0.95",)
    assert not first.passed
    assert run_atlas(path, sites=40, require=["hit_detached>=0"]).passed
    for value in summary["figures"].values():
        assert value is None or isinstance(value, int) or value == rounded(value)


def test_run_atlas_errors(tmp_path):
    with pytest.raises(RuntimeFileError, match="not found"):
        run_atlas(tmp_path / "missing.fracture.json")
    bad = tmp_path / "bad.fracture.json"
    bad.write_text("{not json")
    with pytest.raises(RuntimeFileError, match="bad.fracture.json: not a JSON runtime file"):
        run_atlas(bad)
    with pytest.raises(UsageError, match="unknown key"):
        run_atlas(tmp_path / "missing.fracture.json", require=["nope<1"])  # the gate is checked first
    with pytest.raises(UsageError, match="sites"):
        run_atlas(os.path.join(CONFORMANCE, "example.fracture.json"), sites=0)
    with pytest.raises(UsageError, match="pick one of modes, stress"):
        criterion_named("damage")
    with pytest.raises(UsageError, match="runtime.criterion = 'stress'"):  # a modes file has no stress gains
        run_atlas(os.path.join(CONFORMANCE, "example.fracture.json"), criterion="stress")
    assert criterion_named("modes") is modes_breaking_impulses


def _cube(center, half=0.5):
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half + center
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                      [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return corners, faces


def test_png_with_glb_and_layout_from_glb(tmp_path):
    gameready = row_of_three()
    data = RuntimeData(**{f: getattr(gameready, f) for f in ("sites", "B", "W", "edges", "edge_areas",
                                                             "fragment_names", "default_threshold")})
    json_path, _ = write_runtime(data, tmp_path / "row.fracture.json")
    meshes = []
    for j, name in enumerate(data.fragment_names):
        corners, faces = _cube(np.array([float(j), 0.0, 0.0]))
        meshes.append((name, [Primitive(corners, np.zeros_like(corners), None, faces, 0)]))
    (tmp_path / "row.glb").write_bytes(glb_bytes(meshes, (Material("surface"),)))
    layout = fragment_layout(data, tmp_path / "row.glb")
    assert layout.source == "glb"
    np.testing.assert_allclose(layout.volumes, [1.0, 1.0, 1.0])
    np.testing.assert_allclose(layout.centroids, gameready.gameready["fragment_center_of_mass"], atol=1e-6)
    png = tmp_path / "row.atlas.png"
    result = run_atlas(json_path, png_path=png)
    assert result.png_path == os.fspath(png) and result.summary["layout"] == "glb"
    image = np.asarray(Image.open(png).convert("RGB"))
    assert image.shape == (1000, 1500, 3) and len(np.unique(image.reshape(-1, 3), axis=0)) > 20
    again = tmp_path / "again.png"
    run_atlas(json_path, png_path=again)
    assert png.read_bytes() == again.read_bytes()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # atomic: no temp file left


@pytest.mark.parametrize("name", ["vase", "random_d3"])
def test_png_without_glb(tmp_path, name):
    png = tmp_path / f"{name}.png"
    run_atlas(os.path.join(CONFORMANCE, f"{name}.fracture.json"), sites=30, png_path=png)
    assert Image.open(png).size == (1500, 1000)
