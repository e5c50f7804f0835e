"""The pipeline table and what is generated from it: recipe sections, CLI commands and --help, batches,
global flags, recipe lookup and progress."""

from __future__ import annotations

import io
import os
import re
import shutil
import time

import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.errors import RecipeError
from fracture_cli.options import option_fields
from fracture_cli.pipeline import STAGE_NAMES, STAGES, PipelineState
from fracture_cli.pipeline.recipe import SECTIONS, load_recipe, search_path
from fracture_cli.system import progress

from conftest import SAMPLE_ASSETS


def test_recipe_sections_are_the_pipeline_stages():
    assert SECTIONS == STAGE_NAMES == tuple(s.name for s in STAGES)
    fields = {f.name for f in PipelineState.__dataclass_fields__.values()}
    for s in STAGES:
        assert set(s.consumes + s.uses + s.produces) <= fields, s.name


@pytest.mark.parametrize("section", STAGE_NAMES)
def test_every_recipe_key_is_in_help_with_the_default_bake_uses(section):
    recipe = load_recipe("default")
    text = " ".join(CliRunner().invoke(cli, [section, "--help"], terminal_width=200).output.split())
    assert f" {section} [OPTIONS]" in text
    for f in option_fields(type(recipe[section])):
        flag = "--" + f.name.replace("_", "-")
        assert flag in text, (section, flag)
    if section == "pieces":  # the recipe's value, not the options class's
        assert "[recipe 'default': 0.01]" in text
    if section == "fragments":
        assert "--interior-color TOML" in text and "[recipe 'default': [0.55, 0.5, 0.45, 1.0]]" in text
    if section == "material":
        assert "--boxes TOML" in text


def test_help_follows_the_chosen_recipe():
    text = CliRunner().invoke(cli, ["-r", "stone", "modes", "--help"], terminal_width=200).output
    assert "[recipe 'stone': 6]" in " ".join(text.split())


def test_structured_flag_takes_a_toml_value(tmp_path):
    result = CliRunner().invoke(cli, ["fragments", "--interior-color", "[2, 0, 0, 1]"])
    assert result.exit_code == 2 and "--interior-color" in result.output and "out of range" in result.output


@pytest.mark.parametrize("flags", [["-q", "--debug"], ["-v"]])
def test_global_flags_work_before_and_after_the_command(flags):
    for args in (flags + ["recipes"], ["recipes"] + flags):
        result = CliRunner().invoke(cli, args)
        assert result.exit_code == 0, (args, result.output)
        assert "wood" in result.output


def test_quiet_after_bake_silences_the_summary(tmp_path):
    missing = str(tmp_path / "missing.glb")
    result = CliRunner().invoke(cli, ["bake", missing, "-o", str(tmp_path / "out"), "-q"])
    assert result.exit_code == 1
    assert result.output.count("\n") == 1 and "missing.glb" in result.output


def test_keep_going_survives_an_internal_error_and_names_the_file(tmp_path, monkeypatch):
    import fracture_cli.stages.pieces as pieces_stage

    a = tmp_path / "a.obj"
    a.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    b = tmp_path / "b.obj"
    shutil.copy(a, b)

    def explode(*args, **kwargs):
        raise TypeError("simulated bug")

    monkeypatch.setattr(pieces_stage, "pieces", explode)
    result = CliRunner().invoke(cli, ["bake", str(a), str(b), "-o", str(tmp_path / "out"), "--keep-going",
                                      "--set", "cage.target_faces=200", "--set", "modes.num_modes=2"])
    assert result.exit_code == 1
    lines = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(lines) == 3, result.output  # one per input, then the summary
    assert "pieces: " in lines[0] and str(a) in lines[0] and "internal error (TypeError: simulated bug)" in lines[0]
    assert str(b) in lines[1] and "2 of 2 inputs failed" in lines[2]
    assert "Traceback" not in result.output


def test_an_internal_error_without_keep_going_names_file_and_stage(tmp_path, monkeypatch):
    import fracture_cli.stages.pieces as pieces_stage

    monkeypatch.setattr(pieces_stage, "pieces", lambda *a, **k: 1 / 0)
    chair = os.path.join(SAMPLE_ASSETS, "pillar.glb")
    result = CliRunner().invoke(cli, ["bake", chair, "-o", str(tmp_path), "--set", "cage.target_faces=200",
                                      "--set", "modes.num_modes=2"])
    assert result.exit_code == 1
    assert re.search(r"error: pieces: .*pillar.glb: internal error \(ZeroDivisionError", result.output)


def test_recipe_lookup_order(tmp_path, monkeypatch):
    def write(folder, name, num_modes):
        os.makedirs(folder, exist_ok=True)
        with open(os.path.join(folder, f"{name}.toml"), "w") as fh:
            fh.write(f'description = "{folder}"\nextends = "default"\n[modes]\nnum_modes = {num_modes}\n')

    asset = tmp_path / "assets" / "x.glb"
    write(tmp_path / "flag", "mine", 3)
    write(tmp_path / "env", "mine", 4)
    write(tmp_path / "assets" / "recipes", "mine", 5)
    write(tmp_path / "cwd" / "recipes", "mine", 6)
    monkeypatch.chdir(tmp_path / "cwd")
    monkeypatch.setenv("FRACTURE_RECIPES", str(tmp_path / "env"))
    k = [load_recipe("mine", search=search_path(str(tmp_path / "flag"), [str(asset)]))["modes"].num_modes]
    k.append(load_recipe("mine", search=search_path(None, [str(asset)]))["modes"].num_modes)
    monkeypatch.delenv("FRACTURE_RECIPES")
    k.append(load_recipe("mine", search=search_path(None, [str(asset)]))["modes"].num_modes)
    k.append(load_recipe("mine", search=search_path())["modes"].num_modes)
    assert k == [3, 4, 5, 6]
    assert load_recipe("wood", search=search_path()).name == "wood"  # built-ins last


def test_extends_names_the_recipe_that_asked_and_resolves_paths_beside_it(tmp_path, monkeypatch):
    child = tmp_path / "sub" / "child.toml"
    child.parent.mkdir()
    child.write_text('extends = "granite"\n')
    with pytest.raises(RecipeError) as info:
        load_recipe(str(child))
    assert str(child) in str(info.value) and "granite" in str(info.value)
    (tmp_path / "sub" / "parent.toml").write_text('extends = "stone"\n[modes]\nnum_modes = 7\n')
    child.write_text('extends = "parent.toml"\n')
    monkeypatch.chdir(tmp_path)  # not where parent.toml is
    recipe = load_recipe(str(child))
    assert recipe["modes"].num_modes == 7 and recipe.chain == ("child", "parent", "stone", "default")


def test_progress_writes_a_line_every_few_seconds_when_not_a_terminal(monkeypatch):
    stream = io.StringIO()
    monkeypatch.setattr(progress, "HEARTBEAT_SECONDS", 0.2)
    progress.configure(stream, bars=False)
    try:
        with progress.task("chair: [6/11] modes"), progress.task("modes", total=4) as t:
            for _ in range(2):
                time.sleep(1.3)
                t.advance()
    finally:
        progress.configure(None)
    lines = stream.getvalue().splitlines()
    assert len(lines) >= 2
    assert lines[-1].startswith("progress: chair: [6/11] modes > modes ") and re.search(r"modes [12]/4", lines[-1])
    quiet = io.StringIO()
    with progress.task("modes", total=2) as t:  # not configured: silent
        t.advance()
    assert quiet.getvalue() == ""


def test_progress_counts_items_on_the_step_and_draws_bars(monkeypatch):
    stream = io.StringIO()
    monkeypatch.setattr(progress, "HEARTBEAT_SECONDS", 0.2)
    progress.configure(stream, bars=False)
    try:
        with progress.task("bake chair: [6/11] modes"):
            progress.items(3, "mode")
            time.sleep(1.3)
            progress.advance()
            time.sleep(1.3)
    finally:
        progress.configure(None)
    assert re.search(r"progress: bake chair: \[6/11\] modes: mode 1/3, \d+ s elapsed, about \d+ s left",
                     stream.getvalue()), stream.getvalue()
    bars = io.StringIO()
    progress.configure(bars, bars=True)
    try:
        with progress.task("bake chair: [6/11] modes"):
            progress.items(2, "mode")
            progress.advance()
            progress.advance()
    finally:
        progress.configure(None)
    assert re.search(r"modes: mode [0-2]/2", bars.getvalue()), bars.getvalue()
