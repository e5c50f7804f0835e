"""Golden-file tests: bake every sample asset with its manifest recipe and compare.

Goldens live in tests/golden/<asset>.<recipe>.json. Regenerate after an intended
change with `make goldens` (pytest --update-goldens) and review the diff.
The GLB and runtime file must be the same bytes (their SHA-256, the same on every
machine: fracture_cli/system/numeric_env.py); the readable quantities before the hashes
are compared with explicit tolerances first, so a failure names the asset, the
quantity, the expected and the obtained value.
"""

from __future__ import annotations

import hashlib
import json
import os
import tomllib

import numpy as np
import pytest

from fracture_cli.io.gltf import read_glb
from fracture_cli.pipeline.bake import bake
from fracture_cli.pipeline.recipe import load_recipe

from conftest import REPO, SAMPLE_ASSETS

GOLDEN_DIR = os.path.join(REPO, "tests", "golden")
with open(os.path.join(SAMPLE_ASSETS, "manifest.toml"), "rb") as _fh:
    MANIFEST = sorted(tomllib.load(_fh)["assets"].items())

# Tolerances: counts exact, volumes and boxes relative to the asset's size.
VOLUME_RTOL = 1e-4
BBOX_ATOL_REL = 1e-5  # of the bounding-box diagonal
FAULT_RTOL = 1e-3  # fault shape (mean dihedral angle, crease density): what the smoothing makes of the faults
SHAPE_ATOL_REL = 1e-5  # vertex mean and spread per mesh, of the asset's diagonal


def summarize(out_dir: str, stem: str) -> dict:
    """The reviewable summary of a bake: counts, rounded volumes and boxes, a geometry hash."""
    with open(os.path.join(out_dir, f"{stem}.report.json")) as fh:
        report = json.load(fh)
    # Our own reader: node names exactly as written (trimesh adds random suffixes).
    meshes, _ = read_glb(os.path.join(out_dir, f"{stem}.glb"))
    # Per mesh: vertex count and the mean and spread of its positions (with a tolerance: what moved, when
    # the bytes differ).
    shapes = {}
    for mesh in meshes:
        verts = np.concatenate([prim.positions for prim in mesh.primitives]).astype(np.float64)
        shapes[mesh.name] = {"vertices": int(len(verts)),
                             "mean": [float(x) for x in verts.mean(axis=0)],
                             "std": [float(x) for x in verts.std(axis=0)]}
    counts = {k: v for k, v in report["counts"].items() if k != "cage_offset"}
    return {
        "asset": report["input"]["name"],
        "recipe": report["recipe"]["name"],
        "counts": counts,
        "cage_offset": round(report["counts"]["cage_offset"], 6),
        "input_volume": report["checks"]["input_volume"],
        "faults": {k: report["checks"][k] for k in ("fault_mean_dihedral_degrees", "fault_crease_density")},
        "fragments": [
            {"name": f["name"], "volume": f["volume"], "bbox_min": f["bbox_min"], "bbox_max": f["bbox_max"]}
            for f in report["fragments"]
        ],
        "mesh_shapes": shapes,
        "sha256": output_hashes(out_dir, stem),
    }


def output_hashes(out_dir: str, stem: str) -> dict[str, str]:
    """SHA-256 of the GLB and the runtime file (JSON and binary) of a bake."""
    hashes = {}
    for suffix in (".glb", ".fracture.json", ".fracture.bin"):
        with open(os.path.join(out_dir, stem + suffix), "rb") as fh:
            hashes[suffix.lstrip(".")] = hashlib.sha256(fh.read()).hexdigest()
    return hashes


def compare(expected: dict, got: dict, asset: str) -> list[str]:
    problems = []
    first = expected["fragments"][0]
    diag = float(np.linalg.norm(np.subtract(first["bbox_max"], first["bbox_min"])))
    for key, value in expected["counts"].items():
        if got["counts"].get(key) != value:
            problems.append(f"{asset}: counts.{key}: expected {value}, got {got['counts'].get(key)}")
    if len(expected["fragments"]) != len(got["fragments"]):
        return problems + [f"{asset}: fragment count: expected {len(expected['fragments'])}, "
                           f"got {len(got['fragments'])}"]
    if not np.isclose(expected["input_volume"], got["input_volume"], rtol=VOLUME_RTOL):
        problems.append(f"{asset}: input_volume: expected {expected['input_volume']}, got {got['input_volume']}")
    for key, value in expected.get("faults", {}).items():
        if not np.isclose(value, got["faults"][key], rtol=FAULT_RTOL):
            problems.append(f"{asset}: faults.{key}: expected {value:.6g}, got {got['faults'][key]:.6g}")
    for e, g in zip(expected["fragments"], got["fragments"]):
        if not np.isclose(e["volume"], g["volume"], rtol=VOLUME_RTOL, atol=1e-12):
            problems.append(f"{asset}: {e['name']}.volume: expected {e['volume']:.6g}, got {g['volume']:.6g}")
        for key in ("bbox_min", "bbox_max"):
            if not np.allclose(e[key], g[key], atol=BBOX_ATOL_REL * max(diag, 1e-12) * 100):
                problems.append(f"{asset}: {e['name']}.{key}: expected {e[key]}, got {g[key]}")
    lo = np.min([f["bbox_min"] for f in expected["fragments"]], axis=0)
    hi = np.max([f["bbox_max"] for f in expected["fragments"]], axis=0)
    asset_diag = float(np.linalg.norm(hi - lo))
    for name, e in expected["mesh_shapes"].items():
        g = got["mesh_shapes"].get(name)
        if g is None:
            problems.append(f"{asset}: mesh {name} missing")
        elif g["vertices"] != e["vertices"]:
            problems.append(f"{asset}: {name}: {e['vertices']} vertices expected, got {g['vertices']}")
        elif not (np.allclose(e["mean"], g["mean"], atol=SHAPE_ATOL_REL * asset_diag)
                  and np.allclose(e["std"], g["std"], atol=SHAPE_ATOL_REL * asset_diag)):
            problems.append(f"{asset}: {name}: vertex mean/spread moved (expected {e['mean']}/{e['std']}, "
                            f"got {g['mean']}/{g['std']}); inspect and `make goldens` if intended")
    if not problems:
        for name, digest in expected.get("sha256", {}).items():
            if got["sha256"].get(name) != digest:
                problems.append(f"{asset}: {name}: other bytes (sha256 {got['sha256'].get(name)}, expected {digest}) "
                                "with every summarized quantity within its tolerance")
    return problems


@pytest.mark.slow
@pytest.mark.parametrize("asset, recipe", MANIFEST, ids=[a for a, _ in MANIFEST])
def test_golden(asset, recipe, tmp_path, update_goldens):
    stem = os.path.splitext(asset)[0]
    bake(os.path.join(SAMPLE_ASSETS, asset), str(tmp_path), load_recipe(recipe))
    got = summarize(str(tmp_path), stem)
    path = os.path.join(GOLDEN_DIR, f"{stem}.{recipe}.json")
    if update_goldens or not os.path.exists(path):
        if not update_goldens:
            pytest.fail(f"{asset}: no golden file {os.path.relpath(path, REPO)}; run `make goldens` and review it")
        os.makedirs(GOLDEN_DIR, exist_ok=True)
        with open(path, "w") as fh:
            json.dump(got, fh, indent=2, sort_keys=True)
            fh.write("\n")
        return
    with open(path) as fh:
        expected = json.load(fh)
    problems = compare(expected, got, asset)
    assert not problems, "\n".join(problems)
