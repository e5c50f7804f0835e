"""The runtime conformance vectors: they regenerate identically, and the Python reference passes them."""

from __future__ import annotations

import filecmp
import math
import os
import subprocess
import sys

import pytest
from engine_support import CONFORMANCE, CORRUPT, corrupt_cases, impact_inputs, load_vectors, vector_names

from fracture_cli.errors import InputError
from fracture_cli.runtime.format import load_runtime
from fracture_cli.runtime.impact import project_impact
from fracture_cli.runtime.stress import KNOWN_FEATURES


def _files(folder: str) -> list[str]:
    names = []
    for root, _, files in os.walk(folder):
        names += [os.path.relpath(os.path.join(root, f), folder) for f in files
                  if not f.endswith((".py", ".md", ".pyc")) and "__pycache__" not in root]
    return sorted(names)


def test_vectors_regenerate_identically(tmp_path):
    out = tmp_path / "vectors"
    subprocess.run([sys.executable, os.path.join(CONFORMANCE, "generate.py"), "--out", str(out)],
                   check=True, capture_output=True)
    committed, fresh = _files(CONFORMANCE), _files(str(out))
    assert fresh == committed, "the set of conformance files changed"
    _, mismatch, errors = filecmp.cmpfiles(CONFORMANCE, out, committed, shallow=False)
    assert not mismatch and not errors, (
        f"conformance files differ from what the generator writes: {mismatch + errors}; "
        "run .venv/bin/python tests/data/runtime_conformance/generate.py and review the diff")


def _reference_has_scale_rule() -> bool:
    """Whether project_impact implements docs/FORMAT.md's scale-invariant rule (+inf threshold, 1e155 impulses)."""
    data = load_runtime(os.path.join(CONFORMANCE, "example.fracture.json"))
    try:
        huge = project_impact(data, (0.1, 0, 0), (0, 0, -2e155), 1.5e155)
        unbreakable = project_impact(data, (0.1, 0, 0), (0, 0, -2), math.inf)
    except InputError:
        return False
    return huge.groups.tolist() == [0, 1, 1] and unbreakable.groups.tolist() == [0, 0, 0]


def _extreme(impact: dict) -> bool:
    _, impulse, threshold = impact_inputs(impact)
    values = [abs(c) for c in impulse if c] + ([threshold] if threshold else [])
    return any(v > 1e100 or v < 1e-100 for v in values)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # numpy on the "every distance overflows" point
@pytest.mark.parametrize("name", vector_names(features=KNOWN_FEATURES))
def test_python_reference_passes_the_vectors(name):
    vectors = load_vectors(name)
    data = load_runtime(os.path.join(CONFORMANCE, vectors["runtime"]))
    scale_rule = _reference_has_scale_rule()
    skipped, problems = 0, []
    for impact in vectors["impacts"]:
        if not scale_rule and _extreme(impact):
            skipped += 1
            continue
        point, impulse, threshold = impact_inputs(impact)
        try:
            result = project_impact(data, point, impulse, threshold)
        except InputError:
            if impact["expect"] != "error":
                problems.append(f"{impact['name']}: unexpected error")
            continue
        if impact["expect"] == "error":
            problems.append(f"{impact['name']}: expected an error")
        elif (result.site, result.groups.tolist(), result.broken.nonzero()[0].tolist()) != (
                impact["site"], impact["groups"], impact["broken"]):
            problems.append(f"{impact['name']}: site/groups/broken differ")
        elif "cracked" in impact and (result.cracked.nonzero()[0].tolist(), result.anchored.astype(int).tolist()) != (
                impact["cracked"], impact["anchored"]):
            problems.append(f"{impact['name']}: cracked/anchored differ")
    assert not problems, problems
    if skipped:
        pytest.skip(f"{skipped} extreme-magnitude / +inf-threshold impacts not compared: the Python reference "
                    "predates the scale-invariant rule of docs/FORMAT.md section 4")


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # numpy on the "every distance overflows" point
@pytest.mark.parametrize("case", corrupt_cases(KNOWN_FEATURES), ids=lambda c: c["name"])
def test_python_reference_on_damaged_files(case):
    if "python_reference_bug" in case:
        pytest.skip(f"known gap in the Python reference: {case['python_reference_bug']}")
    path = os.path.join(CORRUPT, case["header"])
    if case["expect"] == "rejected":
        with pytest.raises(InputError):
            load_runtime(path)
    else:
        data = load_runtime(path)
        assert list(data.fragment_names) == case["fragment_names"]
        impacts = [i for i in load_vectors(case["vectors"][: -len(".vectors.json")])["impacts"]
                   if i["expect"] == "ok" and not _extreme(i)]
        for impact in impacts:
            assert project_impact(data, *impact_inputs(impact)).groups.tolist() == impact["groups"]
