"""The C reader (engines/c/) on the conformance vectors, damaged files and sanitizers."""

from __future__ import annotations

import os
import subprocess

import pytest
from engine_support import (
    CORRUPT,
    READER_FEATURES,
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

C_DIR = os.path.join(REPO, "engines", "c")
SOURCES = [os.path.join(C_DIR, "fracture_runtime.c"), os.path.join(C_DIR, "tools", "fracture_check.c")]
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer", "-g"]
FEATURES = READER_FEATURES["c"]
SANITIZER_ENV = {"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0", "UBSAN_OPTIONS": "print_stacktrace=1"}


def _compile(out: str, flags: list[str]) -> str:
    compiler = require_tool("cc", "gcc (build-essential)")
    result = subprocess.run(
        [compiler, *STRICT, *flags, *SOURCES, "-o", out, "-lm"], check=False, capture_output=True, text=True
    )
    assert result.returncode == 0, f"the C reader does not compile with {' '.join(STRICT + flags)}:\n{result.stderr}"
    return out


@pytest.fixture(scope="module")
def driver(tmp_path_factory) -> str:
    return _compile(str(tmp_path_factory.mktemp("c") / "fracture_check"), ["-O2"])


@pytest.fixture(scope="module")
def sanitized_driver(tmp_path_factory) -> str:
    probe = subprocess.run(
        ["cc", "-fsanitize=address,undefined", "-x", "c", "-", "-o", os.devnull],
        input="int main(void){return 0;}",
        check=False,
        capture_output=True,
        text=True,
    )
    if probe.returncode != 0:
        pytest.skip(f"the C compiler cannot build with AddressSanitizer + UBSan: {probe.stderr.strip()[:200]}")
    return _compile(str(tmp_path_factory.mktemp("c_asan") / "fracture_check"), ["-O1", *SANITIZE])


def run_driver(driver: str, header: str, binary: str, stdin: str = "", *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, **SANITIZER_ENV}
    return subprocess.run(
        [driver, *args, header, binary], input=stdin, check=False, capture_output=True, text=True, env=env, timeout=300
    )


def _assert_clean(result: subprocess.CompletedProcess, allowed=(0,)):
    assert "Sanitizer" not in result.stderr and "runtime error" not in result.stderr, result.stderr[-3000:]
    assert result.returncode in allowed, f"exit {result.returncode}: {result.stderr[-2000:]}"


# The two projection paths: the d = 1 jump table (default) and FR_LOAD_COMPACT (displacements and edge tests).
MODES = {"table": (), "compact": ("--compact",)}


@pytest.mark.parametrize("mode", sorted(MODES))
@pytest.mark.parametrize("name", vector_names(FEATURES))
def test_c_reader_passes_the_vectors(driver, name, mode):
    vectors = load_vectors(name)
    result = run_driver(driver, *runtime_paths(name), protocol_input(vectors["impacts"]), *MODES[mode])
    _assert_clean(result)
    assert check_answers(vectors, result.stdout) == []


@pytest.mark.parametrize("name", SAMPLE_ASSETS)
def test_c_reader_matches_the_reference_on_many_hits(driver, name):
    """Hundreds of random hits from gentle to shattering: both paths give the Python reference's answers."""
    impacts = random_impacts(name, 400)
    for mode in sorted(MODES):
        result = run_driver(driver, *runtime_paths(name), protocol_input(impacts), *MODES[mode])
        _assert_clean(result)
        assert check_answers({"runtime": name, "impacts": impacts}, result.stdout) == [], mode


@pytest.mark.parametrize("case", corrupt_cases(), ids=lambda c: c["name"])
def test_c_reader_on_damaged_files(driver, case):
    def run(header, binary, stdin, *flags):
        result = run_driver(driver, header, binary, stdin, *flags)
        _assert_clean(result, allowed=(0, 2))
        return result

    check_damaged_file(case, run)


def test_c_reader_under_sanitizers(sanitized_driver):
    """Every vector and damaged file under ASan + UBSan, then truncations and mutations of two files."""
    for name in vector_names(FEATURES):
        vectors = load_vectors(name)
        for flags in MODES.values():
            result = run_driver(sanitized_driver, *runtime_paths(name), protocol_input(vectors["impacts"]), *flags)
            _assert_clean(result)
            assert check_answers(vectors, result.stdout) == []
    for case in corrupt_cases():
        result = run_driver(
            sanitized_driver, os.path.join(CORRUPT, case["header"]), os.path.join(CORRUPT, case["binary"])
        )
        _assert_clean(result, allowed=(0, 2))
        assert (result.returncode == 2) == (case["expect"] == "rejected"), case["name"]
    for name in ("example", "dyadic_d3", "pillar", "stress_dyadic"):
        result = run_driver(sanitized_driver, *runtime_paths(name), "", "--sweep")
        _assert_clean(result)
        assert result.stdout.startswith("sweep loads=")


def test_c_header_compiles_as_cxx(tmp_path):
    compiler = require_tool("c++", "g++")
    source = tmp_path / "use.cpp"
    source.write_text('#include "fracture_runtime.h"\nint main() { return fr_status_string(FR_OK)[0] == 0; }\n')
    result = subprocess.run(
        [
            compiler,
            "-std=c++11",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            "-I",
            C_DIR,
            str(source),
            os.path.join(C_DIR, "fracture_runtime.c"),
            "-o",
            str(tmp_path / "use"),
        ],
        check=False,
        capture_output=True,
        text=True,
    )
    # g++ compiles the .c file as C++ too: the source is valid C++ as well as C99.
    assert result.returncode == 0, result.stderr
