"""The click command chain: every stage from the command line, with inspection saves."""

from __future__ import annotations

import json
import os

import numpy as np
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.io.cage_io import load_tetmesh
from fracture_cli.pipeline import STEPS

from conftest import SAMPLE_ASSETS

SMALL = ["--set", "cage.target_faces=600", "--set", "modes.num_modes=3", "--set", "material.grain_axis=y",
         "--set", "material.grain_strength=4"]
BYTES = ("chair.glb", "chair.fracture.json", "chair.fracture.bin")


def test_chain_of_every_stage_writes_what_bake_writes_byte_for_byte(tmp_path):
    chair = os.path.join(SAMPLE_ASSETS, "chair.glb")
    chain = SMALL + ["load", chair, "repair", "cage", "save-cage", str(tmp_path / "cage.obj"), "tetra", "save-tets",
                     str(tmp_path / "tets.npz"), "material", "pattern", "modes", "pieces", "smooth", "faults",
                     "fragments", "simplify",
                     "collision", "anchors",
                     "runtime", "export", str(tmp_path / "chain")]
    result = CliRunner().invoke(cli, chain)
    assert result.exit_code == 0, result.output
    result = CliRunner().invoke(cli, ["bake", chair, "-o", str(tmp_path / "bake")] + SMALL)
    assert result.exit_code == 0, result.output
    for name in BYTES:
        assert (tmp_path / "chain" / name).read_bytes() == (tmp_path / "bake" / name).read_bytes(), name
    reports = [json.loads((tmp_path / d / "chair.report.json").read_text()) for d in ("chain", "bake")]
    for report in reports:
        report.pop("seconds")
    assert reports[0] == reports[1]
    # The written report times every step (export's clock stops where the total is taken, before the report is
    # written), from the start-up to the report (total).
    assert set(json.loads((tmp_path / "bake" / "chair.report.json").read_text())["seconds"]) == {
        "startup", *STEPS, "total"}
    assert (tmp_path / "cage.obj").stat().st_size > 0
    tets = load_tetmesh(str(tmp_path / "tets.npz"))
    assert tets.num_tets > 0 and np.all(tets.tet_volumes > 0)
    header = json.loads((tmp_path / "chain" / "chair.fracture.json").read_text())
    assert header["counts"]["modes"] == 3


def test_chain_resumes_from_saved_tets(tmp_path):
    chair = os.path.join(SAMPLE_ASSETS, "chair.glb")
    runner = CliRunner()
    assert runner.invoke(cli, ["load", chair, "cage", "--target-faces", "500", "tetra", "save-tets",
                               str(tmp_path / "t.npz")]).exit_code == 0
    result = runner.invoke(cli, ["load", chair, "load-tets", str(tmp_path / "t.npz"), "modes", "-k", "2", "pieces",
                                 "smooth",
                                 "fragments", "runtime", "export", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / "chair.glb").is_file()


def test_stage_out_of_order_is_a_usage_error():
    result = CliRunner().invoke(cli, ["modes"])
    assert result.exit_code == 2
    assert "'modes' needs a tet mesh" in result.output and "tetra" in result.output


def test_option_ranges_are_enforced_on_the_command_line():
    result = CliRunner().invoke(cli, ["load", os.path.join(SAMPLE_ASSETS, "chair.glb"), "cage", "--target-faces", "5"])
    assert result.exit_code == 2
    assert "--target-faces 5 is out of range" in result.output
