"""End-to-end `fracture bake`: outputs, determinism, atomicity, glTF structure."""

from __future__ import annotations

import json
import os
import struct

import numpy as np
import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli

from conftest import SAMPLE_ASSETS

# Small settings so an end-to-end bake takes seconds; goldens use the real recipes.
FAST = ["--set", "cage.target_faces=600", "--set", "modes.num_modes=4"]
CHAIR = os.path.join(SAMPLE_ASSETS, "chair.glb")


def bake(*args):
    return CliRunner().invoke(cli, ["bake", *args])


@pytest.fixture(scope="module")
def chair_bake(tmp_path_factory):
    out = tmp_path_factory.mktemp("bake")
    result = bake(CHAIR, "-o", str(out), *FAST, "--json")
    assert result.exit_code == 0, result.output
    return out, result


def read_glb(path):
    data = open(path, "rb").read()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2 and length == len(data)
    json_len, json_type = struct.unpack_from("<I4s", data, 12)
    assert json_type == b"JSON" and json_len % 4 == 0
    doc = json.loads(data[20:20 + json_len])
    bin_len, bin_type = struct.unpack_from("<I4s", data, 20 + json_len)
    assert bin_type == b"BIN\x00" and bin_len % 4 == 0
    binary = data[28 + json_len:28 + json_len + bin_len]
    return doc, binary


def test_bake_writes_all_outputs(chair_bake):
    out, result = chair_bake
    for name in ("chair.glb", "chair.fracture.json", "chair.fracture.bin", "chair.report.json"):
        assert (out / name).is_file(), name
    assert not [p for p in os.listdir(out) if p.startswith(".")]  # no staging leftovers
    report = json.loads(result.stdout)
    assert report["recipe"]["name"] == "default"
    assert report["recipe"]["parameters"]["modes"]["num_modes"] == 4
    assert report["counts"]["fragments"] >= 2
    assert report["checks"]["watertight"] is True
    assert abs(report["checks"]["volume_error"]) < 1e-3
    assert set(report["seconds"]) >= {"startup", "load", "cage", "modes", "fragments", "total"}
    # Honest seconds: counted from the process's start (the test process: long before this bake), so the
    # start-up, every step and the writing of the outputs fit in the total.
    seconds = report["seconds"]
    steps = sum(v for k, v in seconds.items() if k not in ("startup", "total"))
    assert 0 < seconds["startup"] and seconds["startup"] + steps <= seconds["total"] + 0.01
    assert os.sep + "tmp" not in json.dumps({k: v for k, v in report.items() if k != "seconds"})


def test_glb_structure_is_valid_gltf(chair_bake):
    out, result = chair_bake
    doc, binary = read_glb(out / "chair.glb")
    report = json.loads(result.stdout)
    assert doc["asset"]["version"] == "2.0"
    names = [doc["nodes"][i]["name"] for i in doc["scenes"][0]["nodes"]]
    assert names == [f"chair_fragment_{i:03d}" for i in range(report["counts"]["fragments"])]
    assert [m["name"] for m in doc["materials"]][-1] == "chair_interior"
    assert set(doc["extensionsUsed"]) >= {"OMI_physics_body", "OMI_physics_shape"}  # the default collision format
    for acc in doc["accessors"]:
        view = doc["bufferViews"][acc["bufferView"]]
        size = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[acc["type"]] * {5126: 4, 5125: 4, 5123: 2}[acc["componentType"]]
        assert view["byteOffset"] % 4 == 0
        assert view["byteOffset"] + acc["count"] * size <= len(binary)
    fragment_meshes = [doc["nodes"][i]["mesh"] for i in doc["scenes"][0]["nodes"]]  # (the rest: collision parts)
    for mesh in (doc["meshes"][m] for m in fragment_meshes):
        for prim in mesh["primitives"]:
            pos = doc["accessors"][prim["attributes"]["POSITION"]]
            assert "min" in pos and "max" in pos
            idx = doc["accessors"][prim["indices"]]
            view = doc["bufferViews"][idx["bufferView"]]
            indices = np.frombuffer(binary, "<u4", idx["count"], view["byteOffset"])
            assert indices.max() < pos["count"]
            assert {"NORMAL", "TEXCOORD_0"} <= set(prim["attributes"])


def test_fragments_sit_where_the_input_was(chair_bake):
    import trimesh

    out, _ = chair_bake
    original = trimesh.load_scene(CHAIR).to_geometry()
    baked = trimesh.load_scene(str(out / "chair.glb")).to_geometry()
    np.testing.assert_allclose(baked.bounds, original.bounds, atol=1e-4)


def test_repeat_bake_is_byte_identical(chair_bake, tmp_path):
    out, _ = chair_bake
    result = bake(CHAIR, "-o", str(tmp_path), *FAST, "--quiet")
    assert result.exit_code == 0, result.output
    for name in ("chair.glb", "chair.fracture.json", "chair.fracture.bin"):
        assert (tmp_path / name).read_bytes() == (out / name).read_bytes(), name
    a = json.loads((tmp_path / "chair.report.json").read_text())
    b = json.loads((out / "chair.report.json").read_text())
    a.pop("seconds"), b.pop("seconds")
    assert a == b


def test_failed_bake_leaves_previous_outputs_untouched(chair_bake, tmp_path, monkeypatch):
    import shutil

    out, _ = chair_bake
    for name in os.listdir(out):
        shutil.copy(out / name, tmp_path / name)
    before = {name: (tmp_path / name).read_bytes() for name in os.listdir(tmp_path)}

    import fracture_cli.stages.runtime as runtime_stage

    def explode(*args, **kwargs):
        raise RuntimeError("injected failure")

    monkeypatch.setattr(runtime_stage, "runtime", explode)
    result = bake(CHAIR, "-o", str(tmp_path), *FAST)
    assert result.exit_code == 1
    assert "injected failure" in result.output and "Traceback" not in result.output
    after = {name: (tmp_path / name).read_bytes() for name in os.listdir(tmp_path)}
    assert after == before


def test_missing_input_is_one_line(tmp_path):
    result = bake(str(tmp_path / "nope.glb"), "-o", str(tmp_path / "out"))
    assert result.exit_code == 1
    assert result.output.strip().count("\n") == 0 and "nope.glb" in result.output
    assert not (tmp_path / "out").exists() or not os.listdir(tmp_path / "out")


def test_impact_cli_on_baked_chair(chair_bake, tmp_path):
    out, _ = chair_bake
    runtime = str(out / "chair.fracture.json")
    result = CliRunner().invoke(cli, ["impact", runtime, "--point", "0.45", "0.85", "-0.45",
                                      "--impulse", "0", "-50", "0", "--json", "-o", str(tmp_path / "broken.glb")])
    assert result.exit_code == 0, result.output
    groups = json.loads(result.stdout)["groups"]
    doc = read_glb(out / "chair.glb")[0]
    assert sum(len(g) for g in groups) == len(doc["scenes"][0]["nodes"])  # every fragment node (not its parts)
    broken, _ = read_glb(tmp_path / "broken.glb")
    assert [n["name"] for n in broken["nodes"] if n["name"].startswith("group_")] == [f"group_{g:03d}" for g in
                                                                                      range(len(groups))]
    assert "OMI_physics_shape" not in broken.get("extensionsUsed", [])  # shapes point at meshes it renumbers
    zero = CliRunner().invoke(cli, ["impact", runtime, "--point", "0", "0", "0", "--impulse", "0", "0", "0", "--json"])
    assert zero.exit_code == 0
    assert len(json.loads(zero.stdout)["groups"]) == 1


def test_khronos_gltf_validator_accepts_output(chair_bake):
    """The Khronos validator (installed by `make test` when npm exists) finds no errors."""
    import shutil
    import subprocess

    from conftest import REPO

    modules = os.path.join(REPO, "build", "node", "node_modules")
    if not shutil.which("node") or not os.path.isdir(os.path.join(modules, "gltf-validator")):
        pytest.skip("gltf-validator not installed (needs npm); structure is checked by "
                    "test_glb_structure_is_valid_gltf")
    out, _ = chair_bake
    proc = subprocess.run(["node", os.path.join(REPO, "scripts", "validate_gltf.cjs"), modules, str(out / "chair.glb")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    report = json.loads(proc.stdout.splitlines()[0])
    assert report["errors"] == 0 and report["warnings"] == 0, report


def test_stage_cache_reuses_modes_and_gives_identical_output(tmp_path):
    cache = tmp_path / "cache"
    first, second, third = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    r1 = bake(CHAIR, "-o", str(first), *FAST, "--cache", str(cache), "--json")
    assert r1.exit_code == 0, r1.output
    assert json.loads(r1.stdout)["cache"] == {"cage": "miss", "tetra": "miss", "modes": "miss"}
    r2 = bake(CHAIR, "-o", str(second), *FAST, "--cache", str(cache), "--json")
    assert json.loads(r2.stdout)["cache"] == {"cage": "hit", "tetra": "hit", "modes": "hit"}
    for name in ("chair.glb", "chair.fracture.json", "chair.fracture.bin"):
        assert (first / name).read_bytes() == (second / name).read_bytes()
    # Changing only a later stage's option keeps the cached modes.
    r3 = bake(CHAIR, "-o", str(third), *FAST, "--cache", str(cache), "--set", "smooth.smoothing=0", "--json")
    assert json.loads(r3.stdout)["cache"] == {"cage": "hit", "tetra": "hit", "modes": "hit"}
    # Changing the modes recomputes them but keeps the cage.
    r4 = bake(CHAIR, "-o", str(third), *FAST[:2], "--set", "modes.num_modes=3", "--cache", str(cache), "--json")
    assert json.loads(r4.stdout)["cache"] == {"cage": "hit", "tetra": "hit", "modes": "miss"}
    # A damaged entry is recomputed, not trusted.
    for entry in cache.iterdir():
        entry.write_bytes(b"garbage")
    r5 = bake(CHAIR, "-o", str(third), *FAST, "--cache", str(cache), "--json")
    assert r5.exit_code == 0 and json.loads(r5.stdout)["cache"] == {"cage": "miss", "tetra": "miss", "modes": "miss"}


def test_keep_going_bakes_the_others_and_fails_at_the_end(tmp_path):
    bad = tmp_path / "broken.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")  # a single triangle: no inside
    out = tmp_path / "out"
    result = bake(str(bad), CHAIR, "-o", str(out), *FAST, "--keep-going", "--quiet")
    assert result.exit_code == 1
    assert "broken.obj" in result.output and "1 of 2 inputs failed" in result.output
    assert (out / "chair.glb").is_file() and not (out / "broken.glb").exists()
    # Without --keep-going the first failure stops the bake.
    result = bake(str(bad), CHAIR, "-o", str(tmp_path / "out2"), *FAST, "--quiet")
    assert result.exit_code == 1 and not (tmp_path / "out2" / "chair.glb").exists()


def test_inputs_with_the_same_stem_are_refused(tmp_path):
    other = tmp_path / "sub"
    other.mkdir()
    import shutil

    shutil.copy(CHAIR, other / "chair.glb")
    result = bake(CHAIR, str(other / "chair.glb"), "-o", str(tmp_path / "out"))
    assert result.exit_code == 2 and "both write chair.*" in result.output


def test_hits_at_different_places_break_different_fragments(chair_bake):
    from fracture_cli.runtime.format import load_runtime
    from fracture_cli.runtime.impact import project_impact

    out, _ = chair_bake
    data = load_runtime(str(out / "chair.fracture.json"))
    sites = np.asarray(data.sites, dtype=np.float64)
    top = sites[np.argmax(sites[:, 1])]  # top of the back rest
    low = sites[np.argmin(sites[:, 1])]  # bottom of a leg
    partitions = []
    for point in (top, low):
        for magnitude in np.geomspace(0.5, 512, 11):
            result = project_impact(data, point, (0.0, -magnitude, 0.0))
            if len(np.unique(result.groups)) > 1:
                break
        assert len(np.unique(result.groups)) > 1
        partitions.append(tuple(result.groups))
    assert partitions[0] != partitions[1]


def test_two_bakes_into_different_folders_run_in_parallel(tmp_path):
    """Separate processes (as `make -j2 assets` runs them) do not disturb each other."""
    import subprocess
    import sys

    procs = [subprocess.Popen([sys.executable, "-m", "fracture_cli", "bake", CHAIR, "-o", str(tmp_path / name),
                               *FAST, "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for name in ("a", "b")]
    for proc in procs:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err.decode()
    for name in ("chair.glb", "chair.fracture.bin"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
