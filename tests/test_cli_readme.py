"""The README's and ``--help``'s chain is every stage and gives bake's bytes; global flags work after any command.

Issue 29: the "chain of every stage" example left out ``collision`` (its
output differed from ``bake``), and ``fracture recipes --recipes DIR`` was
refused although the README says global flags may follow the command.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil

import pytest
from click.testing import CliRunner

from fracture_cli.cli import EXAMPLES, cli, full_chain, wrapped_command
from fracture_cli.cli.options import hoist_global_flags
from fracture_cli.pipeline import STAGE_NAMES

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
FAST = ["--set", "cage.target_faces=500", "--set", "modes.num_modes=3"]


def readme_commands(section: str) -> list[list[str]]:
    """Every ``fracture`` command of the ``sh`` blocks in README.md's ``section``, as words (continuations joined)."""
    with open(os.path.join(REPO, "README.md"), encoding="utf-8") as fh:
        text = fh.read()
    body = text.split(f"\n## {section}\n", 1)[1].split("\n## ", 1)[0]
    commands = []
    for block in re.findall(r"```sh\n(.*?)```", body, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words and words[0] == "fracture":
                commands.append(words)
    return commands


def chains() -> list[list[str]]:
    return [w for w in readme_commands("The command chain") if "load" in w and "export" in w]


def test_every_readme_chain_runs_every_stage_in_order():
    found = chains()
    assert len(found) >= 1
    for words in found:
        assert [w for w in words if w in STAGE_NAMES] == list(STAGE_NAMES), words


def test_the_readme_and_help_chain_is_the_one_made_from_the_stage_table():
    assert chains()[0][1:] == full_chain()
    assert wrapped_command(full_chain()) in EXAMPLES
    help_text = CliRunner().invoke(cli, ["--help"]).output
    joined = " ".join(help_text.replace("\\\n", " ").split())
    assert "fracture " + " ".join(full_chain()) in joined


def test_the_readme_chain_gives_the_bytes_of_bake(tmp_path, monkeypatch):
    """Run the README's own chain (with two --set to make it quick) and `bake` of the same asset and recipe."""
    words = chains()[0][1:]
    asset = words[words.index("load") + 1]
    out = words[words.index("export") + 1]
    recipe = words[words.index("-r") + 1]
    monkeypatch.chdir(tmp_path)
    os.symlink(os.path.join(REPO, "sample_assets"), "sample_assets")  # the README's paths are the clone's
    result = CliRunner().invoke(cli, [*FAST, *words])
    assert result.exit_code == 0, result.output + result.stderr
    result = CliRunner().invoke(cli, ["bake", asset, "-o", "baked", "-r", recipe, *FAST])
    assert result.exit_code == 0, result.output + result.stderr
    stem = os.path.splitext(os.path.basename(asset))[0]
    for name in (f"{stem}.glb", f"{stem}.fracture.json", f"{stem}.fracture.bin"):
        with open(os.path.join(out, name), "rb") as a, open(os.path.join("baked", name), "rb") as b:
            assert a.read() == b.read(), name
    for saved in (words[words.index("save-cage") + 1], words[words.index("save-tets") + 1]):
        assert os.path.getsize(saved) > 0


# ---------------------------------------------------------------- global flags after any command

GLOBALS = ["-v", "-q", "--debug", "-j", "2", "-r", "wood", "--set", "modes.num_modes=7", "--recipes", "D",
           "--recipes=E", "--set=cage.initial_offset=0.01", "-j3", "--jobs=4", "--recipe=stone", "--jobs", "1"]


@pytest.mark.parametrize("command", sorted(set(STAGE_NAMES) | {"bake", "batch", "recipes", "impact", "preview",
                                                               "view", "save", "save-cage", "save-tets",
                                                               "load-tets", "export"}))
def test_every_global_flag_moves_before_any_command(command):
    assert set(cli.list_commands(None)) >= {command}
    assert hoist_global_flags([command, "x", *GLOBALS, "y"]) == [*GLOBALS, command, "x", "y"]
    assert hoist_global_flags([command, "--", "-v"]) == [command, "--", "-v"]  # nothing after -- moves


def test_recipes_takes_the_global_flags_after_it(tmp_path):
    (tmp_path / "mine.toml").write_text('description = "My own."\nextends = "stone"\n\n[modes]\nnum_modes = 5\n')
    listed = CliRunner().invoke(cli, ["recipes", "--recipes", str(tmp_path)])
    assert listed.exit_code == 0, listed.output + listed.stderr
    assert any(line.startswith("mine ") for line in listed.output.splitlines())
    shown = CliRunner().invoke(cli, ["recipes", "show", "mine", f"--recipes={tmp_path}", "-q",
                                     "--set", "cage.initial_offset=0.02"])
    assert shown.exit_code == 0, shown.output + shown.stderr
    assert "num_modes = 5" in shown.output and "initial_offset = 0.02" in shown.output


def test_a_chain_takes_the_global_flags_after_its_commands(tmp_path):
    box = tmp_path / "box.obj"
    shutil.copy(os.path.join(HERE, "data", "bad", "uv_seams.obj"), box)
    result = CliRunner().invoke(cli, ["load", str(box), "--set", "load.max_triangles=3", "-q"])
    assert result.exit_code == 1
    assert "max_triangles" in result.stderr


def test_batch_takes_the_global_flags_after_it(tmp_path):
    (tmp_path / "box.obj").write_text(open(os.path.join(HERE, "data", "bad", "uv_seams.obj")).read())
    (tmp_path / "m.toml").write_text('[assets]\n"box.obj" = "mine"\n')
    recipes = tmp_path / "my"
    recipes.mkdir()
    (recipes / "mine.toml").write_text('description = "Mine."\n')
    result = CliRunner().invoke(cli, ["batch", str(tmp_path / "m.toml"), "-o", str(tmp_path / "out"),
                                      "--recipes", str(recipes), "--set", "nosuch.key=1"])
    assert result.exit_code == 1  # the recipe was found in --recipes; the --set after it was applied (and refused)
    assert "nosuch" in result.stderr and "unknown recipe" not in result.stderr, result.stderr
    assert not os.path.exists(tmp_path / "out")
