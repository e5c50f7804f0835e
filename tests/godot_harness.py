"""Run Godot 3 headless on a throwaway project: the fracture add-on, some files, an import pass, a script.

The project gets res://addons/fracture/ and res://hex_bits.gd (doubles to and from hex bits).

Reusable by any engine test (conformance, breaking a baked asset, rigid bodies at rest)::

    project = GodotProject(tmp_path / "godot")          # skips the test when godot3-server is missing
    project.add_file(glb_path)                           # copied to res://<name>
    project.import_resources()                           # the editor's import pass (GLB -> scene)
    run = project.run_script(script_text, "arg1", "arg2")
    run.lines("ok ")                                     # stdout lines with a prefix

Godot 3's glTF import hangs with the default material storage, so project.godot sets
``[importer_defaults] scene={"materials/storage": 0}`` (materials built into the scene).
A script must print ``done`` as its last line: a run without it (a GDScript error, a
crash, a timeout) fails with the engine's output in the message.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
ADDON = REPO / "engines" / "godot" / "addons" / "fracture"
HEX_BITS = REPO / "engines" / "godot" / "tests" / "hex_bits.gd"  # exact doubles for test scripts
GODOT_NAMES = ("godot3-server", "godot3", "godot")
PROJECT_FILE = """config_version=4

[application]
config/name="{name}"

[importer_defaults]
scene={{"materials/storage": 0}}
"""


def godot_binary() -> str:
    """The Godot 3 executable (GODOT env var, else godot3-server/godot3/godot on PATH), or skip."""
    explicit = os.environ.get("GODOT")
    if explicit:
        return explicit
    for name in GODOT_NAMES:
        path = shutil.which(name)
        if path:
            return path
    pytest.skip(
        "Godot 3 not found: install the Debian package godot3-server (.ci/run does: apt-get install -y "
        "--no-install-recommends godot3-server) or set GODOT=/path/to/godot3"
    )


@dataclass(frozen=True)
class GodotRun:
    """What one headless run printed."""

    stdout: str
    stderr: str
    returncode: int

    def lines(self, prefix: str = "") -> list[str]:
        return [line for line in self.stdout.splitlines() if line.startswith(prefix)]

    @property
    def script_errors(self) -> list[str]:
        return [line for line in (self.stdout + "\n" + self.stderr).splitlines() if "SCRIPT ERROR" in line]


class GodotProject:
    """A Godot 3 project in ``root`` with the fracture add-on under res://addons/fracture/."""

    def __init__(self, root: str | os.PathLike, name: str = "fracture-test"):
        self.godot = godot_binary()
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        (self.root / "project.godot").write_text(PROJECT_FILE.format(name=name))
        shutil.copytree(ADDON, self.root / "addons" / "fracture", dirs_exist_ok=True)
        shutil.copyfile(HEX_BITS, self.root / HEX_BITS.name)

    def add_file(self, source: str | os.PathLike, name: str | None = None) -> str:
        """Copy a file into the project; returns its res:// path."""
        name = name or Path(source).name
        shutil.copyfile(source, self.root / name)
        return "res://" + name

    def write(self, name: str, text: str) -> str:
        (self.root / name).write_text(text)
        return "res://" + name

    def import_resources(self, timeout: float = 300) -> None:
        """Run the editor's import pass (GLB files become importable scenes).

        ``--editor --quit`` sometimes quits before the file-system scan has
        finished ("Scan thread aborted"), leaving files unimported; the pass is
        repeated, up to three times, until every GLB has its ``.import`` file. The add-on is hidden from
        that scan (``addons/.gdignore``): the pass only imports the GLB files, and the scan's parse of the
        add-on's scripts (class_name registration) made the race lost every time once fracture_runtime.gd
        grew (issue 34's levels); the scripts load by path (preload) all the same.
        """
        hidden = self.root / "addons" / ".gdignore"
        hidden.write_text("")
        try:
            for _attempt in range(3):
                result = subprocess.run(
                    [self.godot, "--path", str(self.root), "--editor", "--quit"],
                    check=False,
                    capture_output=True,
                    text=True,
                    timeout=timeout,
                )
                missing = [p.name for p in self.root.glob("*.glb") if not (self.root / (p.name + ".import")).exists()]
                if not missing:
                    return
        finally:
            hidden.unlink()
        assert not missing, f"Godot did not import {missing} (exit {result.returncode}):\n{result.stderr[-3000:]}"

    def run_script(self, script: str, *args: str, timeout: float = 600, name: str = "run.gd",
                   flags: tuple[str, ...] = ()) -> GodotRun:
        """Write ``script`` (a GDScript extending SceneTree) and run it headless with ``-- args``.

        ``flags`` go to Godot before the script (e.g. ``("--fixed-fps", "60")``: every frame simulates 1/60 s).
        """
        self.write(name, script)
        try:
            result = subprocess.run(
                [self.godot, *flags, "--path", str(self.root), "--script", "res://" + name, "--", *args],
                check=False,
                capture_output=True,
                text=True,
                timeout=timeout,
            )
        except subprocess.TimeoutExpired as exc:
            raise AssertionError(f"Godot did not finish {name} within {timeout} s:\n{exc.stdout!r:.3000}") from None
        run = GodotRun(result.stdout, result.stderr, result.returncode)
        assert not run.script_errors, (
            "GDScript errors:\n" + "\n".join(run.script_errors[:20]) + "\n" + run.stderr[-3000:]
        )
        assert run.lines("done"), (
            f"{name} did not finish (exit {result.returncode}):\n{run.stdout[-2000:]}\n{run.stderr[-3000:]}"
        )
        return run
