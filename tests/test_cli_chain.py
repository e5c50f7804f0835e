"""The click command chain: every stage from the command line, with inspection saves."""

from __future__ import annotations

import json
import os

import numpy as np
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.io.cage_io import load_tetmesh

from conftest import SAMPLE_ASSETS


def test_full_chain_writes_inspection_files_and_outputs(tmp_path):
    chair = os.path.join(SAMPLE_ASSETS, "chair.glb")
    args = ["load", chair, "repair", "cage", "--target-faces", "600", "save-cage", str(tmp_path / "cage.obj"),
            "tetra", "save-tets", str(tmp_path / "tets.npz"), "material", "--grain-axis", "y",
            "--grain-strength", "4", "modes", "-k", "3", "pieces", "smooth", "--smoothing", "0",
            "fragments", "export", str(tmp_path / "out")]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert (tmp_path / "cage.obj").stat().st_size > 0
    tets = load_tetmesh(str(tmp_path / "tets.npz"))
    assert tets.num_tets > 0 and np.all(tets.tet_volumes > 0)
    for name in ("chair.glb", "chair.fracture.json", "chair.fracture.bin"):
        assert (tmp_path / "out" / name).is_file()
    header = json.loads((tmp_path / "out" / "chair.fracture.json").read_text())
    assert header["counts"]["modes"] == 3


def test_chain_resumes_from_saved_tets(tmp_path):
    chair = os.path.join(SAMPLE_ASSETS, "chair.glb")
    runner = CliRunner()
    assert runner.invoke(cli, ["load", chair, "cage", "--target-faces", "500", "tetra", "save-tets",
                               str(tmp_path / "t.npz")]).exit_code == 0
    result = runner.invoke(cli, ["load", chair, "load-tets", str(tmp_path / "t.npz"), "modes", "-k", "2", "pieces",
                                 "fragments", "export", str(tmp_path / "out")])
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
