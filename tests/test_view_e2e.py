"""`fracture view` end to end in headless Chromium: click a known point, read back the groups.

Needs Node.js, Debian's chromium (/usr/bin/chromium; `.ci/run` installs it) and the
web build (`make web`: three.js in the package, playwright-core in build/web/);
skipped with the reason when one is missing. One browser session does everything,
so the suite pays Chromium's start-up once.
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import subprocess
import sys
import threading

import numpy as np
import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.io.gltf import glb_meshes, pack_glb, read_glb_chunks
from fracture_cli.runtime.format import load_runtime, write_runtime
from fracture_cli.runtime.impact import project_impact
from fracture_cli.view.server import VENDOR_DIR, VENDOR_FILES

from conftest import REPO, SAMPLE_ASSETS

NODE = shutil.which("node")
CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None)
MODULES = os.path.join(REPO, "build", "web", "node_modules")
DRIVER = os.path.join(REPO, "web", "e2e.cjs")
FAST = ["--set", "cage.target_faces=600", "--set", "modes.num_modes=4"]


def _missing_tool() -> str | None:
    if NODE is None:
        return "node (Node.js) is not installed"
    if CHROMIUM is None:
        return "Debian's chromium is not installed (apt-get install -y chromium; .ci/run does)"
    if not os.path.isfile(os.path.join(MODULES, "playwright-core", "package.json")):
        return "playwright-core is not in build/web/node_modules (run 'make web')"
    if not all(os.path.isfile(os.path.join(VENDOR_DIR, name)) for name in VENDOR_FILES):
        return "the viewer's web files are not built (run 'make web')"
    return None


pytestmark = pytest.mark.skipif(_missing_tool() is not None, reason=str(_missing_tool()))


def _add_collision_part(glb_path: str, out_path: str) -> None:
    """Copy a fragments GLB with an Unreal-style UCX_ collision child under chair_fragment_000."""
    doc, binary = read_glb_chunks(glb_path)
    first = next(i for i, node in enumerate(doc["nodes"]) if node.get("name") == "chair_fragment_000")
    doc["nodes"].append({"name": "UCX_chair_fragment_000_00", "mesh": doc["nodes"][first]["mesh"]})
    doc["nodes"][first].setdefault("children", []).append(len(doc["nodes"]) - 1)
    with open(out_path, "wb") as fh:
        fh.write(pack_glb(doc, binary))


@pytest.fixture(scope="module")
def bake_folder(tmp_path_factory):
    """A FAST chair bake (no collision parts) plus two derived assets: a renamed copy and one with a UCX_ part."""
    out = tmp_path_factory.mktemp("view")
    result = CliRunner().invoke(cli, ["bake", os.path.join(SAMPLE_ASSETS, "chair.glb"), "-o", str(out), *FAST,
                                      "--set", "collision.glb=none", "--quiet"])
    assert result.exit_code == 0, result.output
    data = load_runtime(out / "chair.fracture.json")
    write_runtime(data, out / "chair_ucx.fracture.json")
    _add_collision_part(str(out / "chair.glb"), str(out / "chair_ucx.glb"))
    return out


@pytest.fixture(scope="module")
def server(bake_folder):
    """`fracture view FOLDER --no-browser --port 0` in a subprocess; yields its URL."""
    proc = subprocess.Popen([sys.executable, "-m", "fracture_cli", "view", str(bake_folder), "--no-browser",
                             "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: lines.put(proc.stdout.readline()), daemon=True).start()
    try:
        first = lines.get(timeout=60)
    except queue.Empty:
        first = ""
    if not first.startswith("fracture view: http://127.0.0.1:"):
        proc.kill()
        pytest.fail(f"fracture view did not start: {first!r} {proc.stderr.read() if proc.poll() is not None else ''}")
    yield first.split()[2]
    proc.terminate()
    proc.wait(timeout=30)


def drive(actions: list[dict], url: str, tmp_path) -> dict:
    script = tmp_path / "script.json"
    script.write_text(json.dumps({"url": url, "modules": MODULES, "chromium": CHROMIUM, "width": 1280,
                                  "height": 800, "actions": actions}))
    out = subprocess.run([NODE, DRIVER, str(script)], capture_output=True, text=True, timeout=600, check=False)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout)


def _target_point(glb_path) -> list[float]:
    """A known, visible model point: the chair back's top corner nearest the default camera."""
    doc, binary = read_glb_chunks(str(glb_path))
    points = np.concatenate([prim.positions for mesh in glb_meshes(doc, binary) for prim in mesh.primitives])
    return points[np.argmax(points[:, 1] + 0.3 * points[:, 0] + 0.3 * points[:, 2])].tolist()


def _breaking_magnitude(data, point) -> float:
    """Smallest magnitude of a geometric series that splits the chair into >= 3 groups (d = 1: direction-free)."""
    for magnitude in np.geomspace(0.5, 500.0, 19):
        if len(set(project_impact(data, point, (0.0, 0.0, -magnitude)).groups.tolist())) >= 3:
            return float(magnitude)
    pytest.fail("no magnitude up to 500 breaks the chair into 3 groups")


def _not_blank(png_path) -> float:
    from PIL import Image

    pixels = np.asarray(Image.open(png_path).convert("L"), dtype=np.float64)
    viewport = pixels[:, : int(pixels.shape[1] * 0.7)]  # the 3D view, left of the side panel
    return float(viewport.std())


def test_click_breaks_like_the_python_reference(bake_folder, server, tmp_path):
    data = load_runtime(bake_folder / "chair.fracture.json")
    point = _target_point(bake_folder / "chair.glb")
    magnitude = _breaking_magnitude(data, point)
    before, flying, landed = (str(tmp_path / name) for name in ("before.png", "flying.png", "landed.png"))
    chair_files = [str(bake_folder / f"chair{suffix}") for suffix in (".glb", ".fracture.json", ".fracture.bin",
                                                                        ".report.json")]
    result = drive([
        {"do": "wait_ready"},
        {"do": "screenshot", "path": before},
        {"do": "set", "id": "magnitude", "value": magnitude},
        {"do": "click_model", "point": point},
        {"do": "wait", "ms": 400},
        {"do": "screenshot", "path": flying},
        {"do": "wait_animation"},
        {"do": "check", "id": "bonds", "value": True},
        {"do": "select", "id": "color-mode", "value": "mode-0"},
        {"do": "screenshot", "path": landed},
        {"do": "touch", "paths": chair_files},  # a re-bake in miniature: the page must reload
        {"do": "wait_reload", "after": 1},
        {"do": "select", "id": "asset", "value": "chair_ucx"},
        {"do": "wait_reload", "after": 2},
        {"do": "eval", "expr": "({model: fractureTest.model(), row: !document.getElementById('collision-row').hidden,"
                               " options: [...document.getElementById('asset').options].map(o => o.textContent)})"},
    ], server + "#chair", tmp_path)
    assert result["console_errors"] == [], result["console_errors"]  # includes any request leaving the machine
    ready, hit = result["results"][0], result["results"][3]["hit"]
    assert ready["asset"] == "chair" and ready["model"]["fragments"] == list(data.fragment_names)
    assert hit is not None, "the click did not hit the chair"
    diagonal = ready["model"]["diagonal"]
    assert np.linalg.norm(np.subtract(hit["point"], point)) < 0.02 * diagonal
    assert np.linalg.norm(hit["impulse"]) == pytest.approx(magnitude, rel=1e-9)
    assert hit["threshold"] == data.default_threshold

    reference = project_impact(data, hit["point"], hit["impulse"], hit["threshold"])
    assert hit["site"] == reference.site
    assert hit["groups"] == reference.groups.tolist()
    assert hit["broken"] == reference.broken.tolist()
    assert hit["numGroups"] >= 2

    for png in (before, flying, landed):
        assert _not_blank(png) > 8.0, f"{png} looks blank"
    reloaded, switched, final = result["results"][11], result["results"][13], result["results"][14]
    assert reloaded["asset"] == "chair" and reloaded["reloads"] == 2
    assert switched["asset"] == "chair_ucx"
    assert final["options"] == ["chair", "chair_ucx"]
    assert final["model"]["collisionShapes"] == 1 and final["row"]
