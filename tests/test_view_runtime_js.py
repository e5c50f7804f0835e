"""The JavaScript runtime reader (engines/web/fracture_runtime.js): conformance vectors and the Python reference.

Runs the reader under Node.js through engines/web/fracture_check.mjs, which speaks the
engine drivers' line protocol (tests/engine_support.py); skipped when node is missing.
The page of `fracture view` imports the same file.

Damage states (docs/FORMAT.md section 12) extend the protocol, as the JavaScript and GDScript
drivers speak it (:func:`structure_input`, :func:`check_structure_answers`, also used by
tests/test_engine_js.py and tests/test_engine_godot.py): an input line ``state -`` (a fresh
state) or ``state <e hex healths>`` starts a sequence whose impacts are hits on that state,
each answer followed by ``health <e hex healths>``; on a file with ``"anchors"`` or
``"damage"`` (and in a sequence) every ``ok`` line is followed by
``more c <cracked bonds...> n <anchored flag per fragment...>``. The answer lines stay those
of engine_support, whose helpers skip the extra lines.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess

import numpy as np
import pytest
from engine_support import (
    CONFORMANCE,
    CORRUPT,
    JS_DRIVER,
    NODE,
    READER_FEATURES,
    bits_to_float,
    compare,
    corrupt_cases,
    float_to_bits,
    hex_names,
    impact_inputs,
    load_vectors,
    parse_answer,
    protocol_input,
    requires_node,
    runtime_paths,
    vector_names,
)

from fracture_cli.errors import ImpactArgumentError
from fracture_cli.runtime.damage import hit, new_state, state_to_bytes
from fracture_cli.runtime.format import RuntimeData, load_runtime, write_runtime
from fracture_cli.runtime.impact import project_impact

DRIVER = JS_DRIVER
pytestmark = requires_node
HEALTH_TOLERANCE = 1e-9  # docs/FORMAT.md section 12.5, absolute


def structure_input(vectors: dict) -> str:
    """Driver input for a vector file: its impacts, then each sequence (a ``state`` line and its hits)."""
    text = protocol_input(vectors["impacts"])
    for seq in vectors.get("sequences", []):
        start = "-" if seq["start"] is None else " ".join(seq["start"])
        text += f"state {start}\n" + protocol_input(seq["hits"])
    return text


def _records(output: str) -> list[dict]:
    """One record per answered impact: the parsed answer, with its ``more`` and ``health`` lines."""
    records: list[dict] = []
    for line in output.splitlines():
        kind, _, rest = line.partition(" ")
        if kind in ("ok", "error"):
            records.append({"answer": parse_answer(line)})
        elif kind == "state-error":
            records.append({"refused": line})
        elif kind == "more" and records:
            tokens = rest.split()
            split = tokens.index("n")
            records[-1]["cracked"] = [int(t) for t in tokens[1:split]]
            records[-1]["anchored"] = [int(t) for t in tokens[split + 1:]]
        elif kind == "health" and records:
            records[-1]["health"] = [bits_to_float(t) for t in rest.split()]
    return records


def check_structure_answers(vectors: dict, output: str) -> list[str]:
    """Every mismatch of a driver's output for :func:`structure_input` (empty when it conforms).

    Impacts as engine_support's ``check_answers`` (site, groups, broken equal; alpha and displacement
    within its tolerance) plus ``cracked`` and ``anchored`` where the vectors give them; sequence
    hits likewise, and the state after each within ``HEALTH_TOLERANCE`` (docs/FORMAT.md section 12.5).
    """
    wanted = [(impact["name"], impact, False) for impact in vectors["impacts"]]
    for seq in vectors.get("sequences", []):
        wanted += [(f"{seq['name']} / {h['name']}", h, True) for h in seq["hits"]]
    records = _records(output)
    if len(records) != len(wanted):
        return [f"driver answered {len(records)} impacts of {len(wanted)}"]
    problems = []
    for (name, want, in_sequence), got in zip(wanted, records):
        why = got["refused"] if "refused" in got else compare(want, got["answer"])
        if why is None and want["expect"] == "ok" and "cracked" in want:
            pair = (got.get("cracked"), got.get("anchored"))
            if pair != (want["cracked"], want["anchored"]):
                why = f"cracked, anchored: got {pair}, expected {(want['cracked'], want['anchored'])}"
        if why is None and in_sequence:
            health = [bits_to_float(b) for b in want["health"]]
            got_health = got.get("health")
            if got_health is None or len(got_health) != len(health):
                why = f"state: got {got_health}, expected {len(health)} healths"
            elif max((abs(a - b) for a, b in zip(got_health, health)), default=0.0) > HEALTH_TOLERANCE:
                why = f"health: got {got_health}, expected {health}"
        if why:
            problems.append(f"{vectors['runtime']}: {name}: {why}")
    return problems


# Files with one of section 12's features: a conformance file without the other (name, the field dropped).
VARIANTS = [("structure_dyadic", "damage"), ("structure_dyadic", "anchored"), ("damage_stress", "damage"),
            ("random_structure", "anchored")]


def variant_vectors(name: str, drop: str, folder) -> tuple[str, str, dict]:
    """Conformance file ``name`` without its damage or anchors, written to ``folder``, and vectors for it: the
    impacts and sequences of ``name`` with the Python reader's answers (tie-safe: the measures are the file's)."""
    data = load_runtime(os.path.join(CONFORMANCE, f"{name}.fracture.json"))
    data = dataclasses.replace(data, **({"damage": {}} if drop == "damage" else {"anchored": None, "anchors_info": {}}))
    header, binary = write_runtime(data, os.path.join(folder, f"{name}_no_{drop}.fracture.json"))
    source = load_vectors(name)

    def answer(impact: dict, state) -> dict:
        entry = {key: impact[key] for key in ("name", "bits")}
        try:
            result = hit(data, state, *impact_inputs(impact)) if state is not None else project_impact(
                data, *impact_inputs(impact))
        except ImpactArgumentError:
            entry["expect"] = "error"
        else:
            entry.update(expect="ok", site=result.site, groups=result.groups.tolist(), num_groups=result.num_groups,
                         broken=np.flatnonzero(result.broken).tolist(), alpha=result.alpha.tolist(),
                         displacement=result.displacement.tolist(), cracked=np.flatnonzero(result.cracked).tolist(),
                         anchored=result.anchored.astype(int).tolist())
        if state is not None:
            entry["health"] = [float_to_bits(h) for h in state]
        return entry

    sequences = []
    for seq in source["sequences"]:
        state = new_state(data) if seq["start"] is None else np.array([bits_to_float(b) for b in seq["start"]])
        sequences.append({"name": seq["name"], "start": seq["start"], "hits": [answer(h, state) for h in seq["hits"]]})
    vectors = {"runtime": os.path.basename(header), "impacts": [answer(i, None) for i in source["impacts"]],
               "sequences": sequences}
    return str(header), str(binary), vectors


def run_driver(header: str, binary: str, stdin: str = "", *flags: str) -> subprocess.CompletedProcess:
    return subprocess.run([NODE, DRIVER, *flags, header, binary], input=stdin, capture_output=True, text=True,
                          timeout=300, check=False)


@pytest.mark.parametrize("name", vector_names(READER_FEATURES["js"]))
def test_js_reader_passes_the_vectors(name):
    vectors = load_vectors(name)
    result = run_driver(*runtime_paths(name), structure_input(vectors))
    assert result.returncode == 0, result.stdout + result.stderr
    assert check_structure_answers(vectors, result.stdout) == []


@pytest.mark.parametrize(("name", "drop"), VARIANTS)
def test_js_reader_on_files_with_one_structure_feature(tmp_path, name, drop):
    """Anchors without damage (stateless hits crack nothing; a state only remembers breaks), damage without anchors."""
    header, binary, vectors = variant_vectors(name, drop, tmp_path)
    result = run_driver(header, binary, structure_input(vectors))
    assert result.returncode == 0, result.stdout + result.stderr
    assert check_structure_answers(vectors, result.stdout) == []


@pytest.mark.parametrize("case", corrupt_cases(READER_FEATURES["js"]), ids=lambda c: c["name"])
def test_js_reader_on_damaged_files(case):
    header, binary = os.path.join(CORRUPT, case["header"]), os.path.join(CORRUPT, case["binary"])
    if case["expect"] == "rejected":
        result = run_driver(header, binary)
        assert result.returncode == 2 and result.stdout.startswith("load-error "), result.stdout + result.stderr
        if case.get("only_crc"):  # with the check off, the same file loads
            assert run_driver(header, binary, "", "--skip-crc").returncode == 0
        if case["name"] == "feature_unknown" and "levels" not in READER_FEATURES["js"]:
            assert "'levels'" in result.stdout
    else:
        vectors = load_vectors(case["vectors"][: -len(".vectors.json")])
        result = run_driver(header, binary, structure_input(vectors), "--names")
        assert result.returncode == 0, result.stdout + result.stderr
        assert result.stdout.splitlines()[0].split()[1:] == hex_names(case["fragment_names"])
        assert check_structure_answers(vectors, result.stdout) == []


STATE_SCRIPT = """
import { readFileSync } from 'node:fs';
import { parseRuntime } from %(module)s;
const rt = parseRuntime(readFileSync(%(header)s), readFileSync(%(binary)s));
const out = {};
const refused = (f) => { try { f(); return null; } catch (err) { return err.name; } };
const state = rt.newState();
out.fresh = Array.from(state);
const before = Float64Array.from(state);
out.nanImpulse = refused(() => rt.hit(state, [0, 0, 0], [NaN, 0, 0]));
out.unchanged = state.every((h, e) => Object.is(h, before[e]));
out.short = refused(() => rt.hit(new Float64Array(state.length - 1), [0, 0, 0], [1, 0, 0]));
out.nan = refused(() => rt.hit(Float64Array.from(state, (h, e) => (e ? h : NaN)), [0, 0, 0], [1, 0, 0]));
out.above = refused(() => rt.hit(Float64Array.from(state, (h, e) => (e ? h : 1.5)), [0, 0, 0], [1, 0, 0]));
out.array = refused(() => rt.hit(Array.from(state), [0, 0, 0], [1, 0, 0]));
const res = rt.hit(state, [0, 0, 0], [1, 0, 0], 0.78125);
out.cracked = Array.from(res.cracked);
out.bytes = Buffer.from(rt.stateToBytes(state)).toString('hex');
out.roundTrip = Array.from(rt.stateFromBytes(rt.stateToBytes(state)));
out.badBytes = refused(() => rt.stateFromBytes(new Uint8Array(3)));
out.segments = Array.from(rt.crackSegmentsOf(3));
process.stdout.write(JSON.stringify(out));
"""


def test_js_damage_state_api(tmp_path):
    """new_state, refused states and hits (the state unchanged), the saved bytes as the Python reader's, cracks."""
    header, binary = runtime_paths("structure_dyadic")
    script = tmp_path / "state.mjs"
    module = "file://" + os.path.join(os.path.dirname(JS_DRIVER), "fracture_runtime.js")
    script.write_text(STATE_SCRIPT % {"module": json.dumps(module), "header": json.dumps(header),
                                      "binary": json.dumps(binary)})
    result = subprocess.run([NODE, str(script)], capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    data = load_runtime(os.path.join(CONFORMANCE, "structure_dyadic.fracture.json"))
    state = new_state(data)
    reference = hit(data, state, (0, 0, 0), (1, 0, 0), 0.78125)
    assert out["fresh"] == [1.0] * data.num_edges
    assert out["nanImpulse"] == "RangeError" and out["unchanged"]
    assert (out["short"], out["nan"], out["above"], out["array"]) == ("TypeError", "RangeError", "RangeError",
                                                                       "TypeError")
    assert out["cracked"] == reference.cracked.astype(int).tolist()
    assert out["bytes"] == state_to_bytes(state).hex() and out["roundTrip"] == state.tolist()
    assert out["badBytes"] == "RangeError"
    assert out["segments"] == data.cracks["crack_segments"][3:5].reshape(-1).tolist()


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
