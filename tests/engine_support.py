"""Shared by the engine reader tests: the conformance vectors and the drivers' text protocol.

Every engine reader (C, C#, GDScript) has a small driver that loads one runtime
file and answers impacts in the same line protocol, so one comparison checks them all.

Impacts in (one line each): 7 tokens, the IEEE-754 bits of point x y z, impulse
x y z and threshold as 16 hex digits, or ``-`` for the default threshold.

Answers out (one line each)::

    ok <site> <num_groups> g <groups...> b <broken edges...> a <alpha bits...> d <displacement bits...>
    error <reason>

Loading: a driver that cannot load the file prints ``load-error <reason>`` and
exits with status 2; ``--names`` prints ``names <hex of each name's UTF-8 bytes...>``.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import struct
import subprocess
from collections.abc import Callable

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFORMANCE = os.path.join(REPO, "tests", "data", "runtime_conformance")
CORRUPT = os.path.join(CONFORMANCE, "corrupt")
RELATIVE_TOLERANCE = 1e-9  # alpha and displacement, relative to the array's largest magnitude
SAMPLE_ASSETS = ("chair", "pillar", "vase")  # the conformance runtime files baked from sample_assets/
# The JavaScript reader's check driver, run under Node.js (tests of engines/web and of the viewer's copy).
JS_DRIVER = os.path.join(REPO, "engines", "web", "fracture_check.mjs")
NODE = shutil.which("node")
requires_node = pytest.mark.skipif(NODE is None, reason="node (Node.js) is not installed; the JavaScript reader "
                                   "runs under it (apt-get install nodejs)")


def require_tool(name: str, package: str) -> str:
    """Path of an executable, or skip the test saying what to install."""
    path = shutil.which(name)
    if path is None:
        pytest.skip(f"'{name}' not found: install the Debian package {package} "
                    "(.ci/run does: apt-get install -y --no-install-recommends mono-mcs mono-runtime godot3-server)")
    return path


# The format-2 features (docs/FORMAT.md section 11) each engine reader implements: its harness runs the
# vector files that need them (``vector_names(READER_FEATURES[reader])``) and skips only the others.
READER_FEATURES: dict[str, tuple[str, ...]] = {
    # engines/c
    "c": ("anchors", "damage", "levels", "stress"),
    # engines/csharp
    "csharp": ("anchors", "damage", "levels", "stress"),
    # engines/godot
    "gdscript": ("anchors", "damage", "levels", "sharing", "stress"),
    # engines/web
    "js": ("anchors", "damage", "levels", "sharing", "stress"),
}


def vector_names(features=()) -> list[str]:
    """Names of the runtime files that have vectors (``example``, ``pillar``, ...) a reader can run.

    Parameters
    ----------
    features : iterable of str, optional (default none: version-1 files only)
        The format-2 features the reader implements (docs/FORMAT.md section 11): vectors whose
        ``features`` need another one are left out (:func:`vectors_needing` lists them, to report skips by name).
    """
    known = set(features)
    return [name for name in _all_vector_names() if set(load_vectors(name).get("features", ())) <= known]


def vectors_needing(features=()) -> dict[str, list[str]]:
    """The vector files a reader implementing ``features`` cannot run, with the features each one needs."""
    known = set(features)
    out = {}
    for name in _all_vector_names():
        missing = sorted(set(load_vectors(name).get("features", ())) - known)
        if missing:
            out[name] = missing
    return out


def _all_vector_names() -> list[str]:
    return sorted(f[: -len(".vectors.json")] for f in os.listdir(CONFORMANCE) if f.endswith(".vectors.json"))


def load_vectors(name: str) -> dict:
    with open(os.path.join(CONFORMANCE, f"{name}.vectors.json"), encoding="utf-8") as fh:
        return json.load(fh)


def runtime_paths(name: str) -> tuple[str, str]:
    """(header, binary) paths of a conformance runtime file."""
    return (os.path.join(CONFORMANCE, f"{name}.fracture.json"), os.path.join(CONFORMANCE, f"{name}.fracture.bin"))


def corrupt_cases(features=()) -> list[dict]:
    """The ``corrupt/`` cases a reader implementing ``features`` can run (cases of feature files list theirs)."""
    with open(os.path.join(CORRUPT, "index.json"), encoding="utf-8") as fh:
        cases = json.load(fh)["cases"]
    return [case for case in cases if set(case.get("features", ())) <= set(features)]


def bits_to_float(bits: str) -> float:
    return struct.unpack(">d", bytes.fromhex(bits))[0]


def float_to_bits(value: float) -> str:
    return struct.pack(">d", value).hex()


def impact_inputs(impact: dict) -> tuple[list[float], list[float], float | None]:
    """The exact (point, impulse, threshold) of an impact, from its ``bits``."""
    bits = impact["bits"]
    threshold = None if bits["threshold"] is None else bits_to_float(bits["threshold"])
    return ([bits_to_float(b) for b in bits["point"]], [bits_to_float(b) for b in bits["impulse"]], threshold)


@functools.cache
def random_impacts(name: str, count: int, seed: int = 0) -> list[dict]:
    """Random hits on a conformance runtime file with the numpy reference's answers, shaped like vector impacts.

    Points near random sites, impulses in random directions with magnitudes from a tenth
    to twenty times the default threshold (from no break to shattering), default threshold.
    Cached: every engine's test gets the same list (do not modify it).
    """
    import numpy as np

    from fracture_cli.runtime.format import load_runtime
    from fracture_cli.runtime.impact import project_impact

    data = load_runtime(runtime_paths(name)[0])
    rng = np.random.default_rng(seed)
    scale = float(np.ptp(data.sites, axis=0).max())
    points = data.sites[rng.integers(0, data.num_sites, count)] + rng.normal(scale=0.02 * scale, size=(count, 3))
    directions = rng.normal(size=(count, 3))
    magnitudes = data.default_threshold * np.exp(rng.uniform(np.log(0.1), np.log(20.0), count))
    impulses = directions / np.linalg.norm(directions, axis=1, keepdims=True) * magnitudes[:, None]
    impacts = []
    for i, (point, impulse) in enumerate(zip(points.tolist(), impulses.tolist())):
        result = project_impact(data, np.array(point), np.array(impulse))
        impacts.append({"name": f"random {i}", "expect": "ok", "site": result.site,
                        "num_groups": result.num_groups, "groups": result.groups.tolist(),
                        "broken": np.flatnonzero(result.broken).tolist(), "alpha": result.alpha.tolist(),
                        "displacement": result.displacement.tolist(),
                        "bits": {"point": [float_to_bits(x) for x in point],
                                 "impulse": [float_to_bits(x) for x in impulse], "threshold": None}})
    return impacts


def protocol_input(impacts: list[dict]) -> str:
    """The driver input for a list of impacts."""
    lines = []
    for impact in impacts:
        bits = impact["bits"]
        lines.append(" ".join(bits["point"] + bits["impulse"] + [bits["threshold"] or "-"]))
    return "\n".join(lines) + "\n"


def parse_answer(line: str) -> dict:
    """One driver output line as a dict (``expect``, ``site``, ``groups``, ...)."""
    tokens = line.split()
    if not tokens or tokens[0] not in ("ok", "error"):
        raise ValueError(f"unexpected driver output line: {line!r}")
    if tokens[0] == "error":
        return {"expect": "error", "reason": " ".join(tokens[1:])}
    sections: dict[str, list[str]] = {"": []}
    key = ""
    for token in tokens[3:]:
        if token in ("g", "b", "a", "d"):
            key = token
            sections[key] = []
        else:
            sections[key].append(token)
    return {"expect": "ok", "site": int(tokens[1]), "num_groups": int(tokens[2]),
            "groups": [int(t) for t in sections.get("g", [])], "broken": [int(t) for t in sections.get("b", [])],
            "alpha": [bits_to_float(t) for t in sections.get("a", [])],
            "displacement": [bits_to_float(t) for t in sections.get("d", [])]}


def _close(got: list[float], want: list[float]) -> bool:
    if len(got) != len(want):
        return False
    scale = max((abs(w) for w in want), default=0.0)
    return all(g == w or abs(g - w) <= RELATIVE_TOLERANCE * scale for g, w in zip(got, want))


def compare(impact: dict, got: dict, check_values: bool = True) -> str | None:
    """Why ``got`` (a parsed answer) does not conform to ``impact``, or None."""
    if impact["expect"] == "error":
        return None if got["expect"] == "error" else "expected an error, got a result"
    if got["expect"] != "ok":
        return f"expected a result, got error {got.get('reason')!r}"
    for key in ("site", "groups", "broken", "num_groups"):
        if got[key] != impact[key]:
            return f"{key}: got {got[key]}, expected {impact[key]}"
    if check_values:
        want_alpha = [float(a) for a in impact["alpha"]]
        want_disp = [float(x) for row in impact["displacement"] for x in row]
        if not _close(got["alpha"], want_alpha):
            return f"alpha: got {got['alpha']}, expected {want_alpha}"
        if not _close(got["displacement"], want_disp):
            return "displacement differs beyond the tolerance"
    return None


def check_answers(vectors: dict, output: str, check_values: bool = True) -> list[str]:
    """Every mismatch between a driver's output and the vectors (empty when it conforms)."""
    lines = [line for line in output.splitlines() if line.startswith(("ok", "error"))]
    impacts = vectors["impacts"]
    if len(lines) != len(impacts):
        return [f"driver answered {len(lines)} impacts of {len(impacts)}"]
    problems = []
    for impact, line in zip(impacts, lines):
        why = compare(impact, parse_answer(line), check_values)
        if why:
            problems.append(f"{vectors['runtime']}: {impact['name']}: {why}")
    return problems


def hex_names(names: list[str]) -> list[str]:
    """Fragment names as the drivers print them (hex of the UTF-8 bytes; ``-`` for an empty name)."""
    return [name.encode("utf-8").hex() or "-" for name in names]


def check_damaged_file(case: dict, run: Callable[..., subprocess.CompletedProcess]) -> None:
    """Assert a driver's handling of one ``corrupt/`` case: rejected with exit 2, or loaded with the right
    names and answers. ``run(header, binary, stdin, *flags)`` runs the driver."""
    header, binary = os.path.join(CORRUPT, case["header"]), os.path.join(CORRUPT, case["binary"])
    if case["expect"] == "rejected":
        result = run(header, binary, "")
        assert result.returncode == 2 and result.stdout.startswith("load-error "), result.stdout + result.stderr
        if case.get("only_crc"):  # with the check off, the same file loads
            assert run(header, binary, "", "--skip-crc").returncode == 0
        return
    vectors = load_vectors(case["vectors"][: -len(".vectors.json")])
    result = run(header, binary, protocol_input(vectors["impacts"]), "--names")
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.splitlines()[0].split()[1:] == hex_names(case["fragment_names"])
    assert check_answers(vectors, result.stdout) == []
