"""Preview pictures: valid PNG, expected size, not blank, deterministic."""

from __future__ import annotations

import os

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from fracture_cli.cli import cli

from conftest import SAMPLE_ASSETS

FAST = ["--set", "cage.target_faces=600", "--set", "modes.num_modes=4"]


@pytest.fixture(scope="module", params=["chair.glb", "pillar.glb"])
def baked(request, tmp_path_factory):
    out = tmp_path_factory.mktemp("preview")
    result = CliRunner().invoke(cli, ["bake", os.path.join(SAMPLE_ASSETS, request.param), "-o", str(out),
                                      *FAST, "--preview", "--quiet"])
    assert result.exit_code == 0, result.output
    return out, os.path.splitext(request.param)[0]


def test_bake_preview_png_is_valid_and_not_blank(baked):
    out, stem = baked
    image = Image.open(out / f"{stem}.preview.png")
    image.verify()
    image = Image.open(out / f"{stem}.preview.png").convert("RGB")
    assert image.size == (1600, 1000)
    pixels = np.asarray(image)
    # The exploded-fragments panel (top middle) shows several distinct colours.
    panel = pixels[100:500, 400:1200].reshape(-1, 3)
    colours = {tuple(c) for c in panel[np.any(panel < 240, axis=1)] // 16}
    assert len(colours) >= 6
    assert (pixels < 240).any(axis=2).mean() > 0.05  # not blank


def test_bake_preview_belongs_to_the_output_set(baked):
    """The preview is published with the set: the report lists its hash, like the other files'."""
    import json

    from fracture_cli.io.outputs import verify_output_set

    out, stem = baked
    report = json.loads((out / f"{stem}.report.json").read_text())
    assert f"{stem}.preview.png" in report["files"] and f"{stem}.preview.png" in report["outputs"]
    assert verify_output_set(str(out), stem) is None


def test_preview_command_size_and_determinism(baked, tmp_path):
    out, stem = baked
    runtime = str(out / f"{stem}.fracture.json")
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    for target in (a, b):
        result = CliRunner().invoke(cli, ["preview", runtime, "-o", str(target), "--size", "800", "500"])
        assert result.exit_code == 0, result.output
    assert Image.open(a).size == (800, 500)
    assert a.read_bytes() == b.read_bytes()


def test_preview_fragments_panels_are_one_row_with_the_pattern_kind(baked, tmp_path):
    out, stem = baked
    target = tmp_path / "fragments.png"
    result = CliRunner().invoke(cli, ["preview", str(out / f"{stem}.fracture.json"), "-o", str(target),
                                      "--size", "720", "280", "--panels", "fragments"])
    assert result.exit_code == 0, result.output
    image = Image.open(target)
    assert image.size == (720, 280)
    assert "pattern: modes" in image.info["Title"] and "fragments" in image.info["Title"]
    pixels = np.asarray(image.convert("RGB"))
    # Three panels side by side: something drawn in each third.
    for third in range(3):
        assert (pixels[40:, third * 240:(third + 1) * 240] < 240).any(axis=2).mean() > 0.02


def test_impact_png(baked, tmp_path):
    out, stem = baked
    runtime = str(out / f"{stem}.fracture.json")
    result = CliRunner().invoke(cli, ["impact", runtime, "--point", "0", "1", "0", "--impulse", "0", "-5", "0",
                                      "--png", str(tmp_path / "hit.png")])
    assert result.exit_code == 0, result.output
    assert Image.open(tmp_path / "hit.png").size == (1600, 1000)


def test_preview_of_missing_file_is_one_line(tmp_path):
    result = CliRunner().invoke(cli, ["preview", str(tmp_path / "x.fracture.json"), "-o", str(tmp_path / "p.png")])
    assert result.exit_code == 1
    assert "x.fracture.json" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "p.png").exists()


def test_bake_preview_title_names_recipe_tets_and_cage(baked, tmp_path):
    """The title a bake's preview is given (the PNG's Title text) fills in what the report says, as
    `fracture preview` does: a bake renders it before its report is written, so it passes the report along."""
    import json

    out, stem = baked
    report = json.loads((out / f"{stem}.report.json").read_text())
    counts = report["counts"]
    title = Image.open(out / f"{stem}.preview.png").text["Title"]
    assert "?" not in title, title
    assert f"recipe: {report['recipe']['name']}" in title
    assert f"{counts['fragments']} fragments, {counts['modes']} modes, {counts['tets']} tets, " \
           f"cage {counts['cage_faces']} faces" in title
    again = tmp_path / "again.png"
    result = CliRunner().invoke(cli, ["preview", str(out / f"{stem}.fracture.json"), "-o", str(again)])
    assert result.exit_code == 0, result.output
    assert Image.open(again).text["Title"] == title
