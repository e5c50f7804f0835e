"""The JavaScript runtime reader (engines/web/fracture_runtime.js): conformance vectors and the Python reference.

Runs the reader under Node.js through engines/web/fracture_check.mjs, which speaks the
engine drivers' line protocol (tests/engine_support.py); skipped when node is missing.
The page of `fracture view` imports the same file.
"""

from __future__ import annotations

import os
import subprocess

import numpy as np
import pytest
from engine_support import (
    CORRUPT,
    JS_DRIVER,
    NODE,
    READER_FEATURES,
    check_answers,
    corrupt_cases,
    float_to_bits,
    hex_names,
    load_vectors,
    parse_answer,
    protocol_input,
    requires_node,
    runtime_paths,
    vector_names,
)

from fracture_cli.runtime.format import RuntimeData, write_runtime
from fracture_cli.runtime.impact import project_impact

DRIVER = JS_DRIVER
pytestmark = requires_node


def run_driver(header: str, binary: str, stdin: str = "", *flags: str) -> subprocess.CompletedProcess:
    return subprocess.run([NODE, DRIVER, *flags, header, binary], input=stdin, capture_output=True, text=True,
                          timeout=300, check=False)


@pytest.mark.parametrize("name", vector_names(READER_FEATURES["js"]))
def test_js_reader_passes_the_vectors(name):
    vectors = load_vectors(name)
    result = run_driver(*runtime_paths(name), protocol_input(vectors["impacts"]))
    assert result.returncode == 0, result.stdout + result.stderr
    assert check_answers(vectors, result.stdout) == []


@pytest.mark.parametrize("case", corrupt_cases(), ids=lambda c: c["name"])
def test_js_reader_on_damaged_files(case):
    header, binary = os.path.join(CORRUPT, case["header"]), os.path.join(CORRUPT, case["binary"])
    if case["expect"] == "rejected":
        result = run_driver(header, binary)
        assert result.returncode == 2 and result.stdout.startswith("load-error "), result.stdout + result.stderr
        if case.get("only_crc"):  # with the check off, the same file loads
            assert run_driver(header, binary, "", "--skip-crc").returncode == 0
    else:
        vectors = load_vectors(case["vectors"][: -len(".vectors.json")])
        result = run_driver(header, binary, protocol_input(vectors["impacts"]), "--names")
        assert result.returncode == 0, result.stdout + result.stderr
        assert result.stdout.splitlines()[0].split()[1:] == hex_names(case["fragment_names"])
        assert check_answers(vectors, result.stdout) == []


def _random_runtime(seed: int, d: int, s: int = 60, k: int = 6, p: int = 14) -> RuntimeData:
    """Random but valid runtime data: sites in a box, a connected fragment graph plus extra edges."""
    rng = np.random.default_rng(seed)
    chain = {(j, j + 1) for j in range(p - 1)}
    extra = {tuple(sorted(pair)) for pair in rng.integers(0, p, (2 * p, 2)).tolist() if pair[0] != pair[1]}
    edges = np.array(sorted(chain | extra), dtype=np.int32)
    return RuntimeData(sites=rng.uniform(-1, 1, (s, 3)).astype(np.float32),
                       B=rng.normal(size=(s, k, d)).astype(np.float32), W=rng.normal(size=(k, p, d)).astype(np.float32),
                       edges=edges, edge_areas=rng.uniform(0.1, 1, len(edges)).astype(np.float32),
                       fragment_names=tuple(f"fragment_{j:03d}" for j in range(p)), default_threshold=1.5)


@pytest.mark.parametrize("d", [1, 3])
def test_js_reader_agrees_with_the_python_reference(tmp_path, d):
    """Random hits at moderate magnitudes, where the Python reference and section 4 agree."""
    data = _random_runtime(seed=10 + d, d=d)
    json_path, bin_path = write_runtime(data, tmp_path / "r.fracture.json")
    rng = np.random.default_rng(d)
    hits = []
    for _ in range(200):
        point = data.sites[rng.integers(len(data.sites))] + rng.normal(scale=0.05, size=3)
        impulse = rng.normal(size=3) * rng.uniform(0.2, 3.0)
        hits.append((point.tolist(), impulse.tolist(), rng.choice([None, 0.5, 2.0, 4.0])))
    lines = [" ".join([float_to_bits(v) for v in point + impulse] + [float_to_bits(t) if t else "-"]) + "\n"
             for point, impulse, t in hits]
    result = run_driver(str(json_path), str(bin_path), "".join(lines))
    assert result.returncode == 0, result.stderr
    distinct = set()
    for (point, impulse, threshold), line in zip(hits, result.stdout.splitlines()):
        got = parse_answer(line)
        ref = project_impact(data, point, impulse, threshold)
        assert (got["site"], got["groups"]) == (ref.site, ref.groups.tolist())
        assert got["broken"] == np.flatnonzero(ref.broken).tolist()
        np.testing.assert_allclose(got["displacement"], ref.displacement.reshape(-1), rtol=1e-9, atol=1e-9)
        distinct.add(tuple(got["groups"]))
    assert len(distinct) > 20  # the hits exercise many different breaks
