"""`fracture view`'s "cut at the click" mode (aligned fracture) end to end in headless Chromium.

A fast chair bake with the companion file: the page offers the mode, a real click cuts the chair at the
click with the JavaScript reader, and the fragments it shows are the Python reference's for the same
point, direction, scale and pattern. Skipped like tests/test_view_e2e.py when a tool is missing.
"""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading

import numpy as np
import pytest
from click.testing import CliRunner
from test_view_e2e import FAST, _missing_tool, _not_blank, _target_point, drive

from fracture_cli.cli import cli
from fracture_cli.runtime.aligned import aligned_fracture
from fracture_cli.runtime.aligned_data import load_aligned

from conftest import SAMPLE_ASSETS

pytestmark = pytest.mark.skipif(_missing_tool() is not None, reason=str(_missing_tool()))


@pytest.fixture(scope="module")
def aligned_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("view_aligned")
    result = CliRunner().invoke(cli, ["bake", os.path.join(SAMPLE_ASSETS, "chair.glb"), "-o", str(out), *FAST,
                                      "--set", "aligned.enabled=true", "--quiet"])
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def aligned_server(aligned_folder):
    proc = subprocess.Popen([sys.executable, "-m", "fracture_cli", "view", str(aligned_folder), "--no-browser",
                             "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: lines.put(proc.stdout.readline()), daemon=True).start()
    try:
        first = lines.get(timeout=60)
    except queue.Empty:
        first = ""
    if not first.startswith("fracture view: http://127.0.0.1:"):
        proc.kill()
        pytest.fail(f"fracture view did not start: {first!r}")
    yield first.split()[2]
    proc.terminate()
    proc.wait(timeout=30)


def test_a_click_cuts_the_chair_where_it_is_hit(aligned_folder, aligned_server, tmp_path):
    point = _target_point(aligned_folder / "chair.glb")
    cut_png = str(tmp_path / "cut.png")
    result = drive([
        {"do": "wait_ready"},
        {"do": "eval", "expr": "fractureTest.aligned.available"},
        {"do": "check", "id": "aligned-on", "value": True},
        {"do": "click_model", "point": point},
        {"do": "wait", "ms": 1500},
        {"do": "screenshot", "path": cut_png},
        {"do": "eval", "expr": "fractureTest.aligned.last"},
    ], aligned_server + "#chair", tmp_path)
    assert result["console_errors"] == [], result["console_errors"]
    assert result["results"][1] is True
    last = result["results"][6]
    assert last is not None, "the click did not cut the chair"
    diagonal = result["results"][0]["model"]["diagonal"]
    assert np.linalg.norm(np.subtract(last["point"], point)) < 0.02 * diagonal
    data = load_aligned(aligned_folder / "chair.aligned.json")
    reference = aligned_fracture(data, last["point"], last["direction"], last["scale"], last["pattern"])
    assert [f["cell"] for f in last["fragments"]] == [f.cell for f in reference]
    assert [f["parts"] for f in last["fragments"]] == [len(f.parts) for f in reference]
    assert np.allclose([f["volume"] for f in last["fragments"]], [f.volume for f in reference], rtol=1e-9, atol=0)
    assert len(reference) >= 3
    assert _not_blank(cut_png) > 8.0
