"""The Godot add-on (engines/godot/addons/fracture/) headless: conformance vectors and breaking a baked asset."""

from __future__ import annotations

import os

import pytest
from engine_support import (CORRUPT, REPO, check_answers, corrupt_cases, hex_names, load_vectors, protocol_input,
                            runtime_paths, vector_names)
from godot_harness import GodotProject

CHECK_SCRIPT = os.path.join(REPO, "engines", "godot", "tests", "fracture_check.gd")


@pytest.fixture(scope="module")
def conformance_output(tmp_path_factory) -> dict[str, list[str]]:
    """Every vector file and damaged file through the GDScript reader, in one Godot run."""
    root = tmp_path_factory.mktemp("godot_conformance")
    project = GodotProject(root / "project")
    jobs = []
    for name in vector_names():
        impacts = root / f"{name}.impacts"
        impacts.write_text(protocol_input(load_vectors(name)["impacts"]))
        jobs.append((name, *runtime_paths(name), str(impacts), ""))
    for case in corrupt_cases():
        header, binary = os.path.join(CORRUPT, case["header"]), os.path.join(CORRUPT, case["binary"])
        jobs.append((case["name"], header, binary, "-", ""))
        if case.get("only_crc"):
            jobs.append((case["name"] + "+skip-crc", header, binary, "-", "--skip-crc"))
        if case["expect"] == "ok":
            vectors = case["vectors"][: -len(".vectors.json")]
            impacts = root / f"{vectors}.impacts"
            jobs.append((case["name"] + "+vectors", header, binary, str(impacts), "--names"))
    (root / "jobs.txt").write_text("".join("\t".join(job) + "\n" for job in jobs))
    with open(CHECK_SCRIPT, encoding="utf-8") as fh:
        run = project.run_script(fh.read(), str(root / "jobs.txt"), name="fracture_check.gd")
    output: dict[str, list[str]] = {}
    current = None
    for line in run.stdout.splitlines():
        if line.startswith("job "):
            current = output.setdefault(line[4:], [])
        elif line == "end":
            current = None
        elif current is not None:
            current.append(line)
    return output


@pytest.mark.parametrize("name", vector_names())
def test_gdscript_reader_passes_the_vectors(conformance_output, name):
    vectors = load_vectors(name)
    assert check_answers(vectors, "\n".join(conformance_output[name])) == []


@pytest.mark.parametrize("case", corrupt_cases(), ids=lambda c: c["name"])
def test_gdscript_reader_on_damaged_files(conformance_output, case):
    lines = conformance_output[case["name"]]
    if case["expect"] == "rejected":
        assert lines and lines[0].startswith("load-error "), lines
        if case.get("only_crc"):
            assert not conformance_output[case["name"] + "+skip-crc"], "loads with the CRC check off"
    else:
        assert lines == [], lines
        answers = conformance_output[case["name"] + "+vectors"]
        assert answers[0].split()[1:] == hex_names(case["fragment_names"])
        assert check_answers(load_vectors(case["vectors"][: -len(".vectors.json")]), "\n".join(answers)) == []
