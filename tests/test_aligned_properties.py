"""Aligned fracture on every sample asset (fast bakes): 100 random hits each, through the C reader.

For every hit: the new fragments' volumes sum to the volume of the pieces (the clipped region is all of
them: the pattern's cells and the rest of the object cover space), every part is convex and closed,
no two parts overlap (random points lie inside at most one part), and the fragments nearest the hit
are the smallest. A few hits per asset also go through the Python reference and the JavaScript reader,
which must agree with the C reader.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from aligned_support import (
    JS_DRIVER,
    NODE,
    closed_and_convex,
    compare,
    compile_c_driver,
    data_scales,
    part_geometry,
    random_hits,
    run_driver,
    summarize,
)
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.runtime.aligned import aligned_fracture
from fracture_cli.runtime.aligned_data import load_aligned

from conftest import SAMPLE_ASSETS

pytestmark = pytest.mark.slow
FAST = ["--set", "cage.target_faces=600", "--set", "modes.num_modes=4", "--set", "aligned.enabled=true"]
ASSETS = ("chair.glb", "pillar.glb", "vase.obj")
HITS = 100
SAMPLES = 3000  # random points per hit for the overlap check


@pytest.fixture(scope="module")
def c_driver(tmp_path_factory) -> str:
    return compile_c_driver(str(tmp_path_factory.mktemp("aligned_c") / "fracture_aligned_check"))


@pytest.fixture(scope="module", params=ASSETS)
def baked(request, tmp_path_factory) -> str:
    out = tmp_path_factory.mktemp("aligned_bake")
    result = CliRunner().invoke(cli, ["bake", os.path.join(SAMPLE_ASSETS, request.param), "-o", str(out), *FAST, "-q"])
    assert result.exit_code == 0, result.output
    stem = os.path.splitext(request.param)[0]
    return str(out / f"{stem}.aligned.json")


@pytest.fixture(scope="module")
def answers(baked, c_driver):
    data = load_aligned(baked)
    hits = random_hits(data, HITS, seed=35)
    return data, hits, run_driver([c_driver], baked, hits, "--full")


def test_volumes_add_up_to_the_pieces(answers):
    data, _, results = answers
    volume, _ = data_scales(data)
    errors = [abs(sum(f["volume"] for f in r["fragments"]) - volume) / volume for r in results]
    assert max(errors) < 1e-6, max(errors)


def test_every_part_is_convex_and_closed(answers):
    data, _, results = answers
    _, size = data_scales(data)
    problems = []
    for i, result in enumerate(results):
        for f in result["fragments"]:
            for part in f["parts"]:
                if part["whole"] and i:
                    continue  # the stored pieces: checked on the first hit
                why = closed_and_convex(*part_geometry(data, part), size)
                if why:
                    problems.append(f"hit {i}, cell {f['cell']}, piece {part['piece']}: {why}")
    assert problems == [], problems[:10]


def _inside(points: np.ndarray, planes: np.ndarray, margin: float) -> np.ndarray:
    return np.all(points @ planes[:, :3].T - planes[:, 3] < -margin, axis=1)


def test_parts_do_not_overlap(answers):
    """Random points near the hit (and anywhere in the asset's box) lie strictly inside at most one part."""
    data, hits, results = answers
    _, size = data_scales(data)
    rng = np.random.default_rng(1)
    spheres = data["piece_sphere"].astype(np.float64)
    lo, hi = (spheres[:, :3] - spheres[:, 3:]).min(axis=0), (spheres[:, :3] + spheres[:, 3:]).max(axis=0)
    worst = 0
    for (_, point, _, scale), result in zip(hits, results):
        near = np.asarray(point) + rng.uniform(-scale, scale, (SAMPLES, 3))
        points = np.vstack([near, rng.uniform(lo, hi, (SAMPLES // 3, 3))])
        count = np.zeros(len(points), int)
        for f in result["fragments"]:
            for part in f["parts"]:
                count += _inside(points, part_geometry(data, part)[2], 1e-7 * size)
        worst = max(worst, int(count.max()))
    assert worst <= 1


def test_fragments_nearest_the_hit_are_the_smallest(answers):
    """Ranked by distance from the hit to their centre of mass, the nearest third of the new fragments holds
    less volume on average than the farthest third (the rest of the object left out), for almost every hit."""
    data, hits, results = answers
    holds = total = 0
    sites = data["pattern_site_offsets"]
    for (q, point, _, _), result in zip(hits, results):
        outer = int(sites[q + 1] - sites[q])  # the rest of the object's cell: one past the pattern's
        frags = [f for f in result["fragments"] if f["cell"] < outer]
        if len(frags) < 6:
            continue
        order = sorted(frags, key=lambda f: np.linalg.norm(np.subtract(f["center_of_mass"], point)))
        third = len(order) // 3
        total += 1
        holds += np.mean([f["volume"] for f in order[:third]]) < np.mean([f["volume"] for f in order[-third:]])
    assert total >= HITS // 2 and holds >= 0.9 * total, (holds, total)


def test_the_reference_and_the_javascript_reader_agree(answers, baked, c_driver):
    data, hits, _ = answers
    volume, size = data_scales(data)
    few = hits[:3]
    c_answers = run_driver([c_driver], baked, few)
    for i, (hit, c_answer) in enumerate(zip(few, c_answers)):
        q, p, d, s = hit
        assert compare(summarize(data, aligned_fracture(data, p, d, s, q)), c_answer, volume, size, f"hit {i}") == []
    if NODE is not None:
        js_answers = run_driver([NODE, JS_DRIVER], baked, hits)
        c_all = run_driver([c_driver], baked, hits)
        differ = [p for i, (c, j) in enumerate(zip(c_all, js_answers)) for p in compare(c, j, volume, size, f"hit {i}")]
        assert differ == []


def test_the_pair_is_part_of_the_bake_set(tmp_path):
    """The companion pair: written only when asked, the same bytes every time, listed in the report (outputs and
    hashes), and removed with the publish of a bake that does not ask for it."""
    chair = os.path.join(SAMPLE_ASSETS, "chair.glb")
    names = ("chair.aligned.json", "chair.aligned.bin")
    first, second = tmp_path / "a", tmp_path / "b"
    for out in (first, second):
        result = CliRunner().invoke(cli, ["bake", chair, "-o", str(out), *FAST, "-q"])
        assert result.exit_code == 0, result.output
    for name in names:
        assert (first / name).read_bytes() == (second / name).read_bytes()
    report = json.loads((first / "chair.report.json").read_text())
    assert all(name in report["outputs"] and name in report["files"] for name in names)
    result = CliRunner().invoke(cli, ["bake", chair, "-o", str(first), *FAST[:4], "-q"])
    assert result.exit_code == 0, result.output
    assert not any((first / name).exists() for name in names)
    report = json.loads((first / "chair.report.json").read_text())
    assert not any(name in report["outputs"] or name in report["files"] for name in names)
