"""The C reader (engines/c/) on the conformance vectors, damaged files and sanitizers.

Also the helpers for section 12 (anchors, damage states) that the C# test shares: the drivers'
``--structure`` lines and ``start`` lines (engines/c/tools/fracture_check.c describes them).
"""

from __future__ import annotations

import functools
import os
import subprocess

import pytest
from engine_support import (
    CORRUPT,
    REPO,
    SAMPLE_ASSETS,
    bits_to_float,
    check_answers,
    check_damaged_file,
    compare,
    corrupt_cases,
    float_to_bits,
    load_vectors,
    parse_answer,
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

C_DIR = os.path.join(REPO, "engines", "c")
SOURCES = [os.path.join(C_DIR, "fracture_runtime.c"), os.path.join(C_DIR, "tools", "fracture_check.c")]
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer", "-g"]
# The format-2 features the C reader implements (as engine_support.READER_FEATURES["c"]).
FEATURES = ("anchors", "damage", "levels", "stress")
HEALTH_TOLERANCE = 1e-9  # docs/FORMAT.md section 12.5: healths within 1e-9 absolute, everything else equal
SANITIZER_ENV = {"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0", "UBSAN_OPTIONS": "print_stacktrace=1"}


def sequence_files(features) -> list[str]:
    """The vector files with sequences of hits on a damage state that a reader implementing ``features`` runs."""
    return [name for name in vector_names(features) if "sequences" in load_vectors(name)]


def _structure(line: str) -> dict:
    """A driver's ``structure c ... y ... h ...`` line: cracked bonds, anchored flags, health bits (or None)."""
    tokens = line.split()
    assert tokens[0] == "structure", line
    sections: dict[str, list[str]] = {}
    key = None
    for token in tokens[1:]:
        if token in ("c", "y", "h"):
            key = token
            sections[key] = []
        else:
            sections[key].append(token)
    return {"cracked": [int(t) for t in sections.get("c", [])], "anchored": [int(t) for t in sections.get("y", [])],
            "health": sections.get("h")}


def _answers(output: str) -> list:
    """``(answer line, structure line or None)`` pairs of a driver's output, and ``start-error`` lines as is."""
    pairs: list = []
    for line in output.splitlines():
        if line.startswith(("ok", "error")):
            pairs.append((line, None))
        elif line.startswith("structure"):
            pairs[-1] = (pairs[-1][0], _structure(line))
        elif line.startswith("start-error"):
            pairs.append(line)
    return pairs


def check_structure(vectors: dict, output: str) -> list[str]:
    """Every mismatch in ``cracked`` and ``anchored`` of the stateless impacts (run with ``--structure``)."""
    pairs = [pair for pair in _answers(output) if isinstance(pair, tuple)]
    if len(pairs) != len(vectors["impacts"]):
        return [f"driver answered {len(pairs)} impacts of {len(vectors['impacts'])}"]
    problems = []
    for impact, (_, more) in zip(vectors["impacts"], pairs):
        if impact["expect"] != "ok" or "cracked" not in impact:
            continue
        if more is None or (more["cracked"], more["anchored"]) != (impact["cracked"], impact["anchored"]):
            problems.append(f"{impact['name']}: cracked/anchored {more}, expected {impact['cracked']}, "
                            f"{impact['anchored']}")
    return problems


@functools.cache
def random_sequences(name: str, count: int = 300, length: int = 12) -> tuple:
    """Sequences of ``length`` random hits (gentle to shattering, :func:`random_impacts`) on a fresh state each,
    with the Python reference's answers and healths (fracture_cli.runtime.damage), shaped like vector sequences.
    Cached: every engine's test gets the same ones (do not modify them)."""
    import numpy as np

    from fracture_cli.runtime.damage import hit, new_state
    from fracture_cli.runtime.format import load_runtime

    data = load_runtime(runtime_paths(name)[0])
    impacts = random_impacts(name, count)
    sequences = []
    for first in range(0, count, length):
        state = new_state(data)
        hits = []
        for impact in impacts[first: first + length]:
            point, impulse = ([bits_to_float(b) for b in impact["bits"][key]] for key in ("point", "impulse"))
            result = hit(data, state, np.array(point), np.array(impulse))
            hits.append({**impact, "groups": result.groups.tolist(), "num_groups": result.num_groups,
                         "broken": np.flatnonzero(result.broken).tolist(),
                         "cracked": np.flatnonzero(result.cracked).tolist(),
                         "anchored": result.anchored.astype(int).tolist(),
                         "health": [float_to_bits(h) for h in state.tolist()]})
        sequences.append({"name": f"random sequence {first // length}", "start": None, "hits": hits})
    return tuple(sequences)


# Files whose random sequences the readers must answer like the reference: d = 1 (jump table and compact), d = 3,
# the stress criterion; vase and chair_stress have no "damage" (a state there only remembers broken bonds).
RANDOM_SEQUENCE_FILES = ("pillar_structure", "random_structure", "vase", "chair_stress")


def described_files() -> list[tuple[str, str]]:
    """(header, binary) of every conformance runtime file and of the damaged files that load with section 12's data."""
    files = [runtime_paths(name) for name in vector_names(FEATURES)]
    return files + [(os.path.join(CORRUPT, case["header"]), os.path.join(CORRUPT, case["binary"]))
                    for case in corrupt_cases(FEATURES) if case["expect"] == "ok" and "features" in case]


def check_description(header: str, output: str) -> None:
    """A driver's ``--describe`` line against the Python reader: features, damage, anchored, crack segments."""
    import numpy as np

    from fracture_cli.runtime.format import load_runtime
    from fracture_cli.runtime.structure import crack_segments_of

    data = load_runtime(header)
    line = next(line for line in output.splitlines() if line.startswith("describe "))
    bits = {"stress": 1, "anchors": 2, "damage": 4, "levels": 8}
    counts = [len(crack_segments_of(data.cracks, m)) for m in range(data.num_edges)]
    segments = np.asarray(data.cracks.get("crack_segments", np.zeros((0, 2, 3))), dtype=np.float64).ravel()
    c, r = data.damage.get("crack_level", 1.0), data.damage.get("damage_rate", 0.0)
    want = (f"describe f {sum(bits[f] for f in data.features)} c {float_to_bits(c)} r {float_to_bits(r)} "
            f"y {' '.join(str(int(a)) for a in data.anchored) if data.anchored is not None else '-'} "
            f"n {' '.join(map(str, counts))} s {' '.join(float_to_bits(x) for x in segments.tolist())}")
    assert line.split() == want.split(), header


def sequence_input(sequences: list[dict]) -> str:
    """Driver input for sequences of hits: a ``start`` line (fresh or saved state), then the hits."""
    lines = []
    for seq in sequences:
        lines.append("start new" if seq["start"] is None else "start " + " ".join(seq["start"]))
        lines.append(protocol_input(seq["hits"]).rstrip("\n"))
    return "\n".join(lines) + "\n"


def check_sequences(sequences: list[dict], output: str) -> list[str]:
    """Every mismatch between a driver's answers to :func:`sequence_input` and the sequences (section 12.5).

    A refused hit must also leave the state bit for bit as the previous answer printed it.
    """
    answers = _answers(output)
    hits = [(seq, h) for seq in sequences for h in seq["hits"]]
    if len(answers) != len(hits) or any(not isinstance(a, tuple) or a[1] is None for a in answers):
        return [f"driver answered {len(answers)} hits of {len(hits)} (or a start or structure line is wrong): "
                f"{output[-2000:]}"]
    problems, previous = [], None
    for (seq, h), (line, more) in zip(hits, answers):
        where = f"{seq['name']} / {h['name']}"
        got = parse_answer(line)
        why = compare(h, got)
        if why:
            problems.append(f"{where}: {why}")
        elif got["expect"] == "ok" and (more["cracked"], more["anchored"]) != (h["cracked"], h["anchored"]):
            problems.append(f"{where}: cracked/anchored {more['cracked']}, {more['anchored']}, "
                            f"expected {h['cracked']}, {h['anchored']}")
        health = [bits_to_float(b) for b in more["health"]]
        want = [bits_to_float(b) for b in h["health"]]
        if len(health) != len(want) or any(abs(a - b) > HEALTH_TOLERANCE for a, b in zip(health, want)):
            problems.append(f"{where}: health {health}, expected {want}")
        if h["expect"] == "error" and h is not seq["hits"][0] and more["health"] != previous:
            problems.append(f"{where}: the refused hit changed the state")
        previous = more["health"]
    return problems


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
    result = run_driver(driver, *runtime_paths(name), protocol_input(vectors["impacts"]), "--structure",
                        *MODES[mode])
    _assert_clean(result)
    assert check_answers(vectors, result.stdout) == []
    assert check_structure(vectors, result.stdout) == []


@pytest.mark.parametrize("mode", sorted(MODES))
@pytest.mark.parametrize("name", sequence_files(FEATURES))
def test_c_reader_runs_the_sequences_of_hits(driver, name, mode):
    """Hits on a damage state (fr_hit), fresh or loaded from saved bytes: answers and healths of section 12.5."""
    sequences = load_vectors(name)["sequences"]
    result = run_driver(driver, *runtime_paths(name), sequence_input(sequences), "--structure", *MODES[mode])
    _assert_clean(result)
    assert check_sequences(sequences, result.stdout) == []


@pytest.mark.parametrize("name", RANDOM_SEQUENCE_FILES)
def test_c_reader_matches_the_reference_on_many_sequences(driver, name):
    """Hundreds of random hits on states that add up: both paths give the Python reference's answers."""
    sequences = list(random_sequences(name))
    for mode in sorted(MODES):
        result = run_driver(driver, *runtime_paths(name), sequence_input(sequences), "--structure", *MODES[mode])
        _assert_clean(result)
        assert check_sequences(sequences, result.stdout) == [], mode


@pytest.mark.parametrize("files", described_files(), ids=lambda f: os.path.basename(f[0]))
def test_c_reader_gives_anchors_damage_and_cracks(driver, files):
    result = run_driver(driver, *files, "", "--describe")
    _assert_clean(result)
    check_description(files[0], result.stdout)


def refused_hits_input(name: str) -> tuple[str, int]:
    """A state cracked by one hit, then hits and states the reader must refuse, then a hit that changes nothing.

    Returns the driver input and the number of answers (each with a ``--structure`` line) it expects.
    """
    seq = load_vectors(name)["sequences"][0]
    hit = seq["hits"][0]["bits"]
    point, impulse = hit["point"], hit["impulse"]
    nan, inf, one = "7ff8000000000000", "7ff0000000000000", "3ff0000000000000"
    e = len(seq["hits"][0]["health"])
    lines = ["start new", " ".join(point + impulse + [hit["threshold"] or "-"]),  # cracks: the state is not all 1
             " ".join(point + [nan] + impulse[1:] + ["-"]),  # NaN point
             " ".join(point + impulse[:2] + [inf, "-"]),  # infinite impulse
             " ".join(point + impulse + ["bff0000000000000"]),  # threshold -1
             " ".join(point + impulse + [nan]),  # NaN threshold
             "start " + " ".join([one] * (e - 1) + ["3ff8000000000000"]),  # a health of 1.5
             "start " + " ".join([one] * (e - 1) + [nan]),
             "start " + " ".join([one] * (e - 1)),  # one value short
             "start " + " ".join([one] * (e + 1)),
             "start " + " ".join([one] * (e - 1) + ["8000000000000001"]),  # the smallest negative subnormal
             " ".join(point + ["0000000000000000"] * 3 + ["-"])]  # a zero impulse changes nothing
    return "\n".join(lines) + "\n", 6


def check_refused_hits(output: str, answers: int) -> None:
    """What :func:`refused_hits_input` must give: every refusal reported, the first hit's state kept bit for bit."""
    pairs = _answers(output)
    errors = [p for p in pairs if not isinstance(p, tuple)]
    answered = [p for p in pairs if isinstance(p, tuple)]
    assert len(errors) == 5 and all(line.startswith("start-error ") for line in errors), output
    assert len(answered) == answers, output
    assert answered[0][0].startswith("ok") and all(line.startswith("error") for line, _ in answered[1:5]), output
    assert answered[5][0].startswith("ok"), output
    healths = [more["health"] for _, more in answered]
    assert any(bits_to_float(b) < 1 for b in healths[0]), "the first hit should crack a bond"
    assert all(h == healths[0] for h in healths), "a refused hit or state changed the state"


@pytest.mark.parametrize("name", ["structure_dyadic", "damage_stress", "random_structure"])
def test_c_reader_refused_hits_leave_the_state_unchanged(driver, name):
    stdin, answers = refused_hits_input(name)
    result = run_driver(driver, *runtime_paths(name), stdin, "--structure")
    _assert_clean(result)
    check_refused_hits(result.stdout, answers)


def round_trip_inputs(name: str) -> tuple[str, str, int]:
    """The "random hits" sequence in one go, and the same with the state saved and reloaded halfway.

    Returns both driver inputs and the index of the hit after which the state is reloaded.
    """
    seq = next(s for s in load_vectors(name)["sequences"] if s["name"] == "random hits")
    half = len(seq["hits"]) // 2
    first, rest = protocol_input(seq["hits"][:half]), protocol_input(seq["hits"][half:])
    return "start new\n" + first + rest, "start new\n" + first + "{saved}\n" + rest, half


def check_round_trip(run, modes: dict) -> None:
    """``run(name, stdin, *flags)`` runs a driver with ``--structure``: a saved and reloaded state continues
    bit for bit, on each projection path (``modes``: their flags)."""
    for name in ("structure_dyadic", "random_structure", "pillar_structure"):
        whole, split, half = round_trip_inputs(name)
        for flags in modes.values():
            straight = run(name, whole, *flags)
            saved = [more["health"] for _, more in _answers(straight)][half - 1]
            reloaded = run(name, split.replace("{saved}", "start " + " ".join(saved)), *flags)
            assert _answers(reloaded) == _answers(straight), (name, flags)


def test_c_reader_saves_and_loads_states(driver):
    def run(name, stdin, *flags):
        result = run_driver(driver, *runtime_paths(name), stdin, "--structure", *flags)
        _assert_clean(result)
        return result.stdout

    check_round_trip(run, MODES)


@pytest.mark.parametrize("name", SAMPLE_ASSETS)
def test_c_reader_matches_the_reference_on_many_hits(driver, name):
    """Hundreds of random hits from gentle to shattering: both paths give the Python reference's answers."""
    impacts = random_impacts(name, 400)
    for mode in sorted(MODES):
        result = run_driver(driver, *runtime_paths(name), protocol_input(impacts), *MODES[mode])
        _assert_clean(result)
        assert check_answers({"runtime": name, "impacts": impacts}, result.stdout) == [], mode


@pytest.mark.parametrize("case", corrupt_cases(FEATURES), ids=lambda c: c["name"])
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
            result = run_driver(sanitized_driver, *runtime_paths(name), protocol_input(vectors["impacts"]),
                                "--structure", *flags)
            _assert_clean(result)
            assert check_answers(vectors, result.stdout) == []
            if "sequences" in vectors:
                result = run_driver(sanitized_driver, *runtime_paths(name), sequence_input(vectors["sequences"]),
                                    "--structure", *flags)
                _assert_clean(result)
                assert check_sequences(vectors["sequences"], result.stdout) == []
    for case in corrupt_cases(FEATURES):
        result = run_driver(
            sanitized_driver, os.path.join(CORRUPT, case["header"]), os.path.join(CORRUPT, case["binary"])
        )
        _assert_clean(result, allowed=(0, 2))
        assert (result.returncode == 2) == (case["expect"] == "rejected"), case["name"]
    for name in ("example", "dyadic_d3", "pillar", "stress_dyadic", "structure_dyadic", "damage_stress"):
        result = run_driver(sanitized_driver, *runtime_paths(name), "", "--sweep")
        _assert_clean(result)
        assert result.stdout.startswith("sweep loads=")


@pytest.mark.parametrize("mode", sorted(MODES))
@pytest.mark.parametrize("name", levels_files(FEATURES))
def test_c_reader_runs_the_levels_vectors(driver, name, mode):
    """Section 14: every body's stateless impacts, the object sequences (fr_hit_piece, fr_object_pieces), names."""
    vectors = load_vectors(name)
    result = run_driver(driver, *runtime_paths(name), levels_body_input(vectors) + levels_sequence_input(vectors),
                        "--structure", "--children", *MODES[mode])
    _assert_clean(result)
    assert check_bodies(vectors, result.stdout) == []
    assert check_level_sequences(vectors, result.stdout) == []
    assert check_children(runtime_paths(name)[0], result.stdout) == []


def test_c_reader_levels_under_sanitizers(sanitized_driver):
    for name in levels_files(FEATURES):
        vectors = load_vectors(name)
        result = run_driver(sanitized_driver, *runtime_paths(name),
                            levels_body_input(vectors) + levels_sequence_input(vectors), "--structure")
        _assert_clean(result)
        assert check_level_sequences(vectors, result.stdout) == []
    result = run_driver(sanitized_driver, *runtime_paths("levels_dyadic"), "", "--sweep")
    _assert_clean(result)


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
