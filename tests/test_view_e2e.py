"""`fracture view` end to end in headless Chromium: click a known point, read back the groups.

Needs Node.js, Debian's chromium (/usr/bin/chromium; `.ci/run` installs it) and the
web build (`make web`: three.js in the package, playwright-core in build/web/);
skipped with the reason when one is missing. Two browser sessions: a baked chair (hits,
reloads, collision parts) and a structure (docs/FORMAT.md section 12: the conformance file
``structure_dyadic``, a column anchored at its foot with crack segments, served with a box
per fragment until bakes write anchors).
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
from fracture_cli.runtime.damage import hit as damage_hit
from fracture_cli.runtime.damage import new_state
from fracture_cli.runtime.format import load_runtime, write_runtime
from fracture_cli.runtime.impact import project_impact
from fracture_cli.view.server import VENDOR_DIR, VENDOR_FILES

from conftest import REPO, SAMPLE_ASSETS

CONFORMANCE = os.path.join(REPO, "tests", "data", "runtime_conformance")

NODE = shutil.which("node")
CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None)
MODULES = os.path.join(REPO, "build", "web", "node_modules")
DRIVER = os.path.join(REPO, "web", "e2e.cjs")
FAST = ["--set", "cage.target_faces=600", "--set", "modes.num_modes=4"]
STRUCTURE = "structure_dyadic"  # a conformance runtime file with anchors, damage and crack segments


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


def _add_structure(out) -> None:
    """The conformance file STRUCTURE with a GLB of unit boxes, fragment j centred at (0.5, j + 0.5, 0.5)."""
    trimesh = pytest.importorskip("trimesh")
    for suffix in (".fracture.json", ".fracture.bin"):
        shutil.copyfile(os.path.join(CONFORMANCE, STRUCTURE + suffix), out / (STRUCTURE + suffix))
    scene = trimesh.Scene()
    for j, name in enumerate(load_runtime(out / f"{STRUCTURE}.fracture.json").fragment_names):
        at = np.eye(4)
        at[:3, 3] = (0.5, j + 0.5, 0.5)
        scene.add_geometry(trimesh.creation.box(extents=(1, 1, 1)), node_name=name, geom_name=f"box_{j}", transform=at)
    scene.export(out / f"{STRUCTURE}.glb")


@pytest.fixture(scope="module")
def bake_folder(tmp_path_factory):
    """A FAST chair bake (no collision parts), two derived assets (a renamed copy and one with a UCX_ part), and
    the structure file."""
    out = tmp_path_factory.mktemp("view")
    result = CliRunner().invoke(cli, ["bake", os.path.join(SAMPLE_ASSETS, "chair.glb"), "-o", str(out), *FAST,
                                      "--set", "collision.glb=none", "--quiet"])
    assert result.exit_code == 0, result.output
    data = load_runtime(out / "chair.fracture.json")
    write_runtime(data, out / "chair_ucx.fracture.json")
    _add_collision_part(str(out / "chair.glb"), str(out / "chair_ucx.glb"))
    _add_structure(out)
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
    assert final["options"] == ["chair", "chair_ucx", STRUCTURE]
    assert final["model"]["collisionShapes"] == 1 and final["row"]


def _same_hit(got: dict, data, state) -> None:
    """The page's hit (its point, impulse and threshold) is the Python reader's on the same state, which it updates."""
    want = damage_hit(data, state, got["point"], got["impulse"], got["threshold"])
    assert (got["site"], got["groups"], got["broken"], got["cracked"], got["anchored"]) == (
        want.site, want.groups.tolist(), want.broken.tolist(), want.cracked.tolist(),
        want.anchored.astype(int).tolist())
    np.testing.assert_allclose(got["health"], state, rtol=0, atol=1e-9)


def test_structure_shows_anchors_cracks_and_health(bake_folder, server, tmp_path):
    """The column: the foot (bonded to the world) in the anchor colour; a first hit cracks bonds (lines along
    their segments, fragments tinted, the lowest health in the panel), a second on the same damage state breaks
    the top off: it falls, the anchored group stays still. Reset gives a fresh state."""
    data = load_runtime(bake_folder / f"{STRUCTURE}.fracture.json")
    point = [0.5, 4.5, 1.0]  # the top box's front face: nearest contact site 4
    structure = {"do": "eval", "expr": "fractureTest.structure()"}
    result = drive([
        {"do": "wait_ready"},
        structure,
        {"do": "set", "id": "threshold", "value": 1},
        {"do": "check", "id": "accumulate", "value": True},
        {"do": "set", "id": "magnitude", "value": 1.2},  # loads up to 0.825: cracks, no break
        {"do": "click_model", "point": point},
        {"do": "wait_animation"},
        structure,
        {"do": "set", "id": "magnitude", "value": 2},  # with the cracks: the top two fragments break off
        {"do": "click_model", "point": point},
        {"do": "wait_animation"},
        structure,
        {"do": "mouse", "x": 10, "y": 10},
        {"do": "eval", "expr": "document.getElementById('reset').click(), fractureTest.structure()"},
    ], server + "#" + STRUCTURE, tmp_path)
    assert result["console_errors"] == [], result["console_errors"]
    results = result["results"]
    before, first, cracked, second, broken, after_reset = (results[1], results[5]["hit"], results[7], results[9]["hit"],
                                                           results[11], results[13])
    anchor = before["anchorColor"]
    assert before["colorMode"] == "structure" and before["anchored"] == data.anchored.tolist()
    assert [c == anchor for c in before["colors"]] == [a == 1 for a in data.anchored]
    assert len(set(before["colors"])) == 2 and before["crackLines"] == [] and max(before["moved"]) == 0

    state = new_state(data)
    _same_hit(first, data, state)
    assert any(first["cracked"]) and not any(first["broken"])
    segments = data.cracks["crack_segments"]
    ptr = data.cracks["crack_ptr"]
    want_lines = [(int(data.edges[m][0]), segments[i].reshape(-1).tolist())
                  for m in np.flatnonzero(first["cracked"]) for i in range(ptr[m], ptr[m + 1])]
    assert [(line["fragment"], line["points"]) for line in cracked["crackLines"]] == want_lines
    weakened = {int(j) for m in np.flatnonzero(first["cracked"]) for j in data.edges[m]} - {0}
    assert {j for j, c in enumerate(cracked["colors"]) if c not in (anchor, before["colors"][1])} == weakened
    assert cracked["colors"][0] == anchor
    assert cracked["lowestHealth"] == pytest.approx(min(first["health"]), rel=1e-3)
    assert max(cracked["moved"]) == 0  # nothing broke, the column is held: no shudder either

    _same_hit(second, data, state)
    assert broken["health"] == second["health"] == pytest.approx(state.tolist(), abs=1e-9)
    held = [j for j, a in enumerate(second["anchored"]) if a == 1]
    free = [j for j, a in enumerate(second["anchored"]) if a == 0]
    assert held and free and any(second["broken"])
    assert all(broken["moved"][j] == 0 for j in held)
    assert all(broken["moved"][j] > 0.1 for j in free)
    assert broken["colors"][0] == anchor
    lines = {line["fragment"] for line in broken["crackLines"]}
    assert lines == {int(data.edges[m][0]) for m in np.flatnonzero(second["cracked"])}

    assert after_reset["health"] == [1.0] * data.num_edges and after_reset["crackLines"] == []
    assert max(after_reset["moved"]) == 0 and after_reset["colors"] == before["colors"]

