"""The clock of a bake's ``startup`` and ``total``, and the console script's quick exit."""

import os
import subprocess
import sys
import time

from fracture_cli.system import clock

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_process_age_counts_from_the_process_start():
    child = subprocess.run(
        [sys.executable, "-c", "import time; time.sleep(0.3); from fracture_cli.system import clock; "
                               "print(clock.process_age())"],
        capture_output=True, text=True, check=True, cwd=REPO)
    age = float(child.stdout)
    assert 0.3 <= age < 30  # the sleep before the import is counted: the origin is the process, not the module
    assert abs(clock.process_origin() - (time.monotonic() - clock.process_age())) < 0.05


def test_console_exit_keeps_the_exit_code_and_the_output(tmp_path):
    ok = subprocess.run([sys.executable, "-m", "fracture_cli", "recipes", "list"], capture_output=True, text=True,
                        cwd=REPO)
    assert ok.returncode == 0 and "default" in ok.stdout  # stdout flushed before the quick exit
    missing = subprocess.run([sys.executable, "-m", "fracture_cli", "bake", str(tmp_path / "none.obj"),
                              "-o", str(tmp_path / "out")], capture_output=True, text=True, cwd=REPO)
    assert missing.returncode == 1
    assert missing.stderr.strip().splitlines() == [f"error: {tmp_path / 'none.obj'}: no such file"]
    shown = subprocess.run([sys.executable, "-m", "fracture_cli", "recipes", "show", "default", "--set",
                            "modes.num_modes=5"], capture_output=True, text=True, cwd=REPO)
    assert shown.returncode == 0 and "num_modes = 5" in shown.stdout


_FIRST_STAGE = """
import os, sys
from fracture_cli.pipeline import runner

def first(self, name):
    heavy = ('numba', 'open3d', 'scipy', 'trimesh')
    print(sorted(m for m in heavy if m in sys.modules), flush=True)
    os._exit(0)

runner.Runner.step = first
from fracture_cli.cli import main
main(sys.argv[1:])
"""


def test_start_up_loads_no_heavy_package_before_the_first_stage(tmp_path):
    """Issue 33: resolving the recipe (every stage's options, levels included) loads none of the packages whose
    import costs tenths of a second; the stage that needs one imports it."""
    out = subprocess.run([sys.executable, "-c", _FIRST_STAGE, "-q", "bake", os.path.join(REPO, "sample_assets",
                          "chair.glb"), "-r", "wood", "--set", "levels.count=2", "-o", str(tmp_path / "out")],
                         capture_output=True, text=True, cwd=REPO)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
