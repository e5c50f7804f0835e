"""The JavaScript runtime reader (engines/web/fracture_runtime.js) against the Python reference.

Runs the reader under Node.js through engines/web/project_cli.mjs; skipped when
node is missing. The runtime conformance vectors (tests/data/runtime_conformance/)
are checked by :func:`test_conformance_vectors` once they exist.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess

import numpy as np
import pytest

from fracture_cli.runtime.format import RuntimeData, write_runtime
from fracture_cli.runtime.impact import project_impact

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(REPO, "engines", "web", "project_cli.mjs")
FORMAT_DOC = os.path.join(REPO, "docs", "FORMAT.md")
NODE = shutil.which("node")

pytestmark = pytest.mark.skipif(NODE is None, reason="node (Node.js) is not installed; the JavaScript reader "
                                "runs under it (apt-get install nodejs)")


def _encode(value):
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_encode(float(v)) if isinstance(v, (float, np.floating)) else _encode(v) for v in value]
    return value


def run_js(json_path, hits) -> dict:
    """Project ``hits`` (dicts with point, impulse, threshold) with the JavaScript reader."""
    request = {"runtime": str(json_path),
               "hits": [{key: _encode(value) for key, value in hit.items()} for hit in hits]}
    out = subprocess.run([NODE, CLI], input=json.dumps(request), capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def random_runtime(seed: int, d: int, s: int = 60, k: int = 6, p: int = 14) -> RuntimeData:
    """Random but valid runtime data: sites in a box, a connected fragment graph plus extra edges."""
    rng = np.random.default_rng(seed)
    chain = [(j, j + 1) for j in range(p - 1)]
    extra = {tuple(sorted(pair)) for pair in rng.integers(0, p, (2 * p, 2)).tolist() if pair[0] != pair[1]}
    edges = np.array(sorted(set(chain) | extra), dtype=np.int32)
    return RuntimeData(sites=rng.uniform(-1, 1, (s, 3)).astype(np.float32),
                       B=rng.normal(size=(s, k, d)).astype(np.float32),
                       W=rng.normal(size=(k, p, d)).astype(np.float32),
                       edges=edges, edge_areas=rng.uniform(0.1, 1, len(edges)).astype(np.float32),
                       fragment_names=tuple(f"fragment_{j:03d}" for j in range(p)), default_threshold=1.5)


def random_hits(data: RuntimeData, count: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    sites = data.sites.astype(float)
    points = sites[rng.integers(0, len(sites), count)] + rng.normal(scale=0.05, size=(count, 3))
    impulses = rng.normal(size=(count, 3)) * rng.uniform(0.2, 3.0, size=(count, 1))
    thresholds = rng.choice([None, 0.5, 2.0, 4.0], size=count)
    return [{"point": pt.tolist(), "impulse": n.tolist(), "threshold": None if t is None else float(t)}
            for pt, n, t in zip(points, impulses, thresholds)]


def test_worked_example_of_the_format_doc(tmp_path):
    import re

    text = open(FORMAT_DOC, encoding="utf-8").read()
    block = re.search(r"<!-- example-data -->\s*```json\n(.*?)```", text, re.S).group(1)
    ex = json.loads(block)
    data = RuntimeData(sites=np.array(ex["sites"], np.float32), B=np.array(ex["B"], np.float32),
                       W=np.array(ex["W"], np.float32), edges=np.array(ex["edges"], np.int32),
                       edge_areas=np.array(ex["edge_areas"], np.float32), fragment_names=tuple(ex["fragment_names"]),
                       default_threshold=ex["default_threshold"], radius=ex["impact_radius"])
    json_path, _ = write_runtime(data, tmp_path / "example.fracture.json")
    results = run_js(json_path, [{k: case[k] for k in ("point", "impulse", "threshold")} for case in ex["cases"]])
    for case, got in zip(ex["cases"], results["results"]):
        assert got["site"] == case["site"]
        np.testing.assert_allclose(got["alpha"], case["alpha"])
        np.testing.assert_allclose(got["displacement"], case["displacement"])
        np.testing.assert_allclose(np.abs(got["jumps"]), case["jumps"])  # the doc lists |jump|
        assert got["broken"] == case["broken"]
        assert got["groups"] == case["groups"]


@pytest.mark.parametrize("d", [1, 3])
def test_agrees_with_the_python_reference(tmp_path, d):
    data = random_runtime(seed=10 + d, d=d)
    json_path, _ = write_runtime(data, tmp_path / "r.fracture.json")
    hits = random_hits(data, 200, seed=d)
    results = run_js(json_path, hits)["results"]
    distinct = set()
    for hit, got in zip(hits, results):
        ref = project_impact(data, hit["point"], hit["impulse"], hit["threshold"])
        assert got["site"] == ref.site
        np.testing.assert_allclose(got["alpha"], ref.alpha, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(got["displacement"], ref.displacement.reshape(-1), rtol=1e-9, atol=1e-9)
        assert got["groups"] == ref.groups.tolist()
        assert got["broken"] == ref.broken.tolist()
        distinct.add(tuple(got["groups"]))
    assert len(distinct) > 20  # the hits exercise many different breaks


@pytest.mark.parametrize("d", [1, 3])
def test_scale_invariant_rule(tmp_path, d):
    data = random_runtime(seed=30 + d, d=d)
    json_path, _ = write_runtime(data, tmp_path / "r.fracture.json")
    base = random_hits(data, 20, seed=40 + d)
    hits = []
    for hit in base:
        n, t = np.asarray(hit["impulse"]), hit["threshold"] or data.default_threshold
        hits.append({"point": hit["point"], "impulse": n.tolist(), "threshold": t})
        for factor in (1e-300, 1e-160, 1e160, 1e300):  # the squares of these would underflow or overflow
            hits.append({"point": hit["point"], "impulse": (n * factor).tolist(), "threshold": t * factor})
    results = run_js(json_path, hits)["results"]
    for i in range(0, len(hits), 5):
        reference = results[i]["groups"]
        for scaled in results[i + 1:i + 5]:
            assert scaled["groups"] == reference
    # Limits: +inf threshold breaks nothing; zero threshold breaks every edge with a nonzero jump;
    # a threshold far above any jump (T / m overflows to inf) breaks nothing either.
    point, impulse = base[0]["point"], base[0]["impulse"]
    edge_cases = [
        {"point": point, "impulse": impulse, "threshold": float("inf")},
        {"point": point, "impulse": impulse, "threshold": 0.0},
        {"point": point, "impulse": [1e-300, 0.0, 0.0], "threshold": 1e300},
        {"point": point, "impulse": [1e300, -1e300, 1e300], "threshold": 1e-300},
        {"point": point, "impulse": [0.0, 0.0, 0.0], "threshold": 0.0},
    ]
    inf, zero, overflow, underflow, nothing = run_js(json_path, edge_cases)["results"]
    assert not any(inf["broken"]) and inf["groups"] == [0] * data.p
    assert zero["broken"] == [any(abs(float(j)) > 0 for j in zero["jumps"][m * d:(m + 1) * d])
                              for m in range(len(data.edges))]
    assert all(zero["broken"])  # random data: no jump is exactly zero
    assert not any(overflow["broken"])
    assert all(underflow["broken"]) and underflow["num_groups"] == data.p
    assert not any(nothing["broken"]) and nothing["displacement"] == [0.0] * (data.p * d)


def test_bad_hits_throw(tmp_path):
    data = random_runtime(seed=1, d=1)
    json_path, _ = write_runtime(data, tmp_path / "r.fracture.json")
    bad = [
        {"point": [0, 0], "impulse": [1, 0, 0], "threshold": None},
        {"point": [0, 0, "nan"], "impulse": [1, 0, 0], "threshold": None},
        {"point": [0, 0, 0], "impulse": [1, "inf", 0], "threshold": None},
        {"point": [0, 0, 0], "impulse": [1, 0, 0], "threshold": -1.0},
        {"point": [0, 0, 0], "impulse": [1, 0, 0], "threshold": "nan"},
        {"point": [0, 0, 0], "impulse": [1, 0, 0], "threshold": "3"},
    ]
    for result in run_js(json_path, bad)["results"]:
        assert "error" in result


def _damage(json_path, bin_path, damage):
    header = json.loads(json_path.read_text())
    raw = bytearray(bin_path.read_bytes())
    if damage == "truncated":
        bin_path.write_bytes(bytes(raw[:-20]))
        return
    if damage == "crc":
        raw[0] ^= 0xFF
        bin_path.write_bytes(bytes(raw))
        return
    if damage == "edge_index":  # an edge pointing past the last fragment, crc updated to match
        import zlib

        entry = header["arrays"]["edges"]
        raw[entry["byte_offset"] + 4:entry["byte_offset"] + 8] = (10_000).to_bytes(4, "little")
        bin_path.write_bytes(bytes(raw))
        header["buffer"]["crc32"] = zlib.crc32(bytes(raw))
    elif damage == "not_json":
        json_path.write_text("{oops")
        return
    elif damage == "format":
        header["format"] = "something-else"
    elif damage == "version":
        header["version"] = 99
    elif damage == "shape":
        header["arrays"]["W"]["shape"] = [1, 2, 3]
    elif damage == "counts":
        header["counts"]["fragments"] = 99
    elif damage == "offset":
        header["arrays"]["edge_areas"]["byte_offset"] = len(raw)
    elif damage == "no_arrays":
        header.pop("arrays")
    elif damage == "dtype":
        header["arrays"]["edges"]["dtype"] = "float32"
    json_path.write_text(json.dumps(header))


@pytest.mark.parametrize("damage, message", [
    ("truncated", "truncated"), ("crc", "crc32"), ("edge_index", "edges must be pairs"), ("not_json", "not a JSON"),
    ("format", "not a fracture runtime file"), ("version", "version 99 is not supported"), ("shape", "do not agree"),
    ("counts", "fragment names for 99"), ("offset", "outside the binary file"), ("no_arrays", "no arrays"),
    ("dtype", "dtype"),
])
def test_corrupt_files_throw(tmp_path, damage, message):
    json_path, bin_path = write_runtime(random_runtime(seed=2, d=3), tmp_path / "r.fracture.json")
    _damage(json_path, bin_path, damage)
    result = run_js(json_path, [])
    assert "load_error" in result and message in result["load_error"], result
    assert result["load_error"].startswith("RuntimeFileError")


CONFORMANCE = os.path.join(REPO, "tests", "data", "runtime_conformance")


def test_conformance_vectors():
    if not os.path.isdir(CONFORMANCE):
        pytest.skip("tests/data/runtime_conformance/ is not in this tree yet (the engines branch generates it)")
    from conformance_js import check_vectors  # noqa: PLC0415  (next to this file; written for their format)

    check_vectors(CONFORMANCE, run_js)
