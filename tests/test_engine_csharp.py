"""The C# reader (engines/csharp/) on the conformance vectors and damaged files, built with Mono's mcs."""

from __future__ import annotations

import os
import subprocess

import pytest
from engine_support import (
    REPO,
    SAMPLE_ASSETS,
    check_answers,
    check_damaged_file,
    corrupt_cases,
    load_vectors,
    protocol_input,
    random_impacts,
    require_tool,
    runtime_paths,
    vector_names,
)
from levels_support import body_input as levels_body_input
from levels_support import check_bodies, check_children, levels_files
from levels_support import check_sequences as check_level_sequences
from levels_support import sequence_input as levels_sequence_input

# Section 12's driver protocol (--structure, start lines) is the C driver's: its test has the helpers.
from test_engine_c import (
    RANDOM_SEQUENCE_FILES,
    check_description,
    check_refused_hits,
    check_round_trip,
    check_sequences,
    check_structure,
    described_files,
    random_sequences,
    refused_hits_input,
    sequence_files,
    sequence_input,
)

CS_DIR = os.path.join(REPO, "engines", "csharp")
# The format-2 features the C# reader implements (as engine_support.READER_FEATURES["csharp"]).
FEATURES = ("anchors", "damage", "levels", "stress")
SOURCES = [os.path.join(CS_DIR, "FractureRuntime.cs"), os.path.join(CS_DIR, "tools", "FractureCheck.cs")]


@pytest.fixture(scope="module")
def driver(tmp_path_factory) -> list[str]:
    mcs = require_tool("mcs", "mono-mcs")
    mono = require_tool("mono", "mono-runtime")
    exe = str(tmp_path_factory.mktemp("csharp") / "FractureCheck.exe")
    # C# 7.2 (mcs's newest) keeps the file buildable by mcs as well as by Unity's compiler (C# 8/9).
    result = subprocess.run(
        [mcs, "-langversion:7.2", "-warnaserror", "-checked-", "-out:" + exe, *SOURCES],
        check=False,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, f"the C# reader does not compile:\n{result.stdout}\n{result.stderr}"
    return [mono, exe]


def run_driver(driver, header: str, binary: str, stdin: str = "", *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*driver, header, binary, *args], input=stdin, check=False, capture_output=True, text=True, timeout=300
    )


# The two projection paths: the d = 1 jump table (default) and compact (displacements and edge tests).
MODES = {"table": (), "compact": ("--compact",)}


@pytest.mark.parametrize("mode", sorted(MODES))
@pytest.mark.parametrize("name", vector_names(FEATURES))
def test_csharp_reader_passes_the_vectors(driver, name, mode):
    vectors = load_vectors(name)
    result = run_driver(driver, *runtime_paths(name), protocol_input(vectors["impacts"]), "--structure",
                        *MODES[mode])
    assert result.returncode == 0, result.stdout + result.stderr
    assert check_answers(vectors, result.stdout) == []
    assert check_structure(vectors, result.stdout) == []


@pytest.mark.parametrize("mode", sorted(MODES))
@pytest.mark.parametrize("name", sequence_files(FEATURES))
def test_csharp_reader_runs_the_sequences_of_hits(driver, name, mode):
    """Hits on a damage state (Hit), fresh or loaded from saved bytes: answers and healths of section 12.5."""
    sequences = load_vectors(name)["sequences"]
    result = run_driver(driver, *runtime_paths(name), sequence_input(sequences), "--structure", *MODES[mode])
    assert result.returncode == 0, result.stdout + result.stderr
    assert check_sequences(sequences, result.stdout) == []


@pytest.mark.parametrize("name", RANDOM_SEQUENCE_FILES)
def test_csharp_reader_matches_the_reference_on_many_sequences(driver, name):
    """Hundreds of random hits on states that add up: both paths give the Python reference's answers."""
    sequences = list(random_sequences(name))
    for mode in sorted(MODES):
        result = run_driver(driver, *runtime_paths(name), sequence_input(sequences), "--structure", *MODES[mode])
        assert result.returncode == 0, result.stdout + result.stderr
        assert check_sequences(sequences, result.stdout) == [], mode


@pytest.mark.parametrize("files", described_files(), ids=lambda f: os.path.basename(f[0]))
def test_csharp_reader_gives_anchors_damage_and_cracks(driver, files):
    result = run_driver(driver, *files, "", "--describe")
    assert result.returncode == 0, result.stdout + result.stderr
    check_description(files[0], result.stdout)


@pytest.mark.parametrize("name", ["structure_dyadic", "damage_stress", "random_structure"])
def test_csharp_reader_refused_hits_leave_the_state_unchanged(driver, name):
    stdin, answers = refused_hits_input(name)
    result = run_driver(driver, *runtime_paths(name), stdin, "--structure")
    assert result.returncode == 0, result.stdout + result.stderr
    check_refused_hits(result.stdout, answers)


def test_csharp_reader_saves_and_loads_states(driver):
    def run(name, stdin, *flags):
        result = run_driver(driver, *runtime_paths(name), stdin, "--structure", *flags)
        assert result.returncode == 0, result.stdout + result.stderr
        return result.stdout

    check_round_trip(run, MODES)


@pytest.mark.parametrize("name", SAMPLE_ASSETS)
def test_csharp_reader_matches_the_reference_on_many_hits(driver, name):
    """Hundreds of random hits from gentle to shattering: both paths give the Python reference's answers."""
    impacts = random_impacts(name, 400)
    for mode in sorted(MODES):
        result = run_driver(driver, *runtime_paths(name), protocol_input(impacts), *MODES[mode])
        assert result.returncode == 0, result.stdout + result.stderr
        assert check_answers({"runtime": name, "impacts": impacts}, result.stdout) == [], mode


@pytest.mark.parametrize("case", corrupt_cases(FEATURES), ids=lambda c: c["name"])
def test_csharp_reader_on_damaged_files(driver, case):
    check_damaged_file(case, lambda *args: run_driver(driver, *args))


@pytest.mark.parametrize("mode", sorted(MODES))
@pytest.mark.parametrize("name", levels_files(FEATURES))
def test_csharp_reader_runs_the_levels_vectors(driver, name, mode):
    """Section 14: every body's stateless impacts, the object sequences (HitPiece, ObjectPieces), child names."""
    vectors = load_vectors(name)
    result = run_driver(driver, *runtime_paths(name), levels_body_input(vectors) + levels_sequence_input(vectors),
                        "--structure", "--children", *MODES[mode])
    assert result.returncode == 0, result.stdout + result.stderr
    assert check_bodies(vectors, result.stdout) == []
    assert check_level_sequences(vectors, result.stdout) == []
    assert check_children(runtime_paths(name)[0], result.stdout) == []
