"""The Godot add-on (engines/godot/addons/fracture/) headless: conformance vectors and breaking a baked asset."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from engine_support import (
    CORRUPT,
    READER_FEATURES,
    REPO,
    SAMPLE_ASSETS,
    check_answers,
    corrupt_cases,
    float_to_bits,
    hex_names,
    impact_inputs,
    load_vectors,
    protocol_input,
    random_impacts,
    runtime_paths,
    vector_names,
)
from godot_harness import GodotProject
from levels_support import body_input as levels_body_input
from levels_support import check_bodies, check_children, levels_files
from levels_support import check_sequences as check_level_sequences
from levels_support import sequence_input as levels_sequence_input
from test_view_runtime_js import VARIANTS, check_structure_answers, structure_input, variant_vectors

from fracture_cli.runtime.damage import hit, new_state, state_to_bytes
from fracture_cli.runtime.format import RuntimeData, load_runtime, write_runtime
from fracture_cli.runtime.impact import project_impact

CHECK_SCRIPT = os.path.join(REPO, "engines", "godot", "tests", "fracture_check.gd")
RANDOM_HITS = 100  # per sample asset


@pytest.fixture(scope="module")
def conformance_output(tmp_path_factory) -> dict[str, list[str]]:
    """Every vector file (with its damage-state sequences) and damaged file through the GDScript reader, in one
    Godot run."""
    root = tmp_path_factory.mktemp("godot_conformance")
    project = GodotProject(root / "project")
    jobs = []
    for name in vector_names(READER_FEATURES["gdscript"]):
        impacts = root / f"{name}.impacts"
        impacts.write_text(structure_input(load_vectors(name)))
        jobs.append((name, *runtime_paths(name), str(impacts), ""))
    for name in levels_files(READER_FEATURES["gdscript"]):
        vectors = load_vectors(name)
        impacts = root / f"{name}.levels"
        impacts.write_text(levels_body_input(vectors) + levels_sequence_input(vectors))
        jobs.append((f"levels-{name}", *runtime_paths(name), str(impacts), "--children"))
    for name, drop in VARIANTS:
        header, binary, vectors = variant_vectors(name, drop, root)
        impacts = root / f"{name}_no_{drop}.impacts"
        impacts.write_text(structure_input(vectors))
        jobs.append((f"{name}_no_{drop}", header, binary, str(impacts), ""))
    for name in SAMPLE_ASSETS:
        impacts = root / f"{name}.random"
        impacts.write_text(protocol_input(random_impacts(name, RANDOM_HITS)))
        jobs.append((f"random-{name}", *runtime_paths(name), str(impacts), ""))
    for case in corrupt_cases(READER_FEATURES["gdscript"]):
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


@pytest.mark.parametrize("name", vector_names(READER_FEATURES["gdscript"]))
def test_gdscript_reader_passes_the_vectors(conformance_output, name):
    vectors = load_vectors(name)
    assert check_structure_answers(vectors, "\n".join(conformance_output[name])) == []


@pytest.mark.parametrize("name", levels_files(READER_FEATURES["gdscript"]))
def test_gdscript_reader_runs_the_levels_vectors(conformance_output, name):
    """Section 14: every body's stateless impacts, the object sequences (hit_piece, object_pieces), child names."""
    vectors = load_vectors(name)
    output = "\n".join(conformance_output[f"levels-{name}"])
    assert check_bodies(vectors, output) == []
    assert check_level_sequences(vectors, output) == []
    assert check_children(runtime_paths(name)[0], output) == []


@pytest.mark.parametrize(("name", "drop"), VARIANTS)
def test_gdscript_reader_on_files_with_one_structure_feature(conformance_output, tmp_path, name, drop):
    """Anchors without damage (stateless hits crack nothing; a state only remembers breaks), damage without anchors."""
    vectors = variant_vectors(name, drop, tmp_path)[2]
    assert check_structure_answers(vectors, "\n".join(conformance_output[f"{name}_no_{drop}"])) == []


@pytest.mark.parametrize("name", SAMPLE_ASSETS)
def test_gdscript_reader_matches_the_reference_on_many_hits(conformance_output, name):
    """Random hits from gentle to shattering (fewer than the other readers get: GDScript is slow)."""
    impacts = random_impacts(name, RANDOM_HITS)
    assert check_answers({"runtime": name, "impacts": impacts}, "\n".join(conformance_output[f"random-{name}"])) == []


@pytest.mark.parametrize("case", corrupt_cases(READER_FEATURES["gdscript"]), ids=lambda c: c["name"])
def test_gdscript_reader_on_damaged_files(conformance_output, case):
    lines = conformance_output[case["name"]]
    if case["expect"] == "rejected":
        assert lines and lines[0].startswith("load-error "), lines
        if case.get("only_crc"):
            assert not conformance_output[case["name"] + "+skip-crc"], "loads with the CRC check off"
        if case["name"] == "feature_unknown" and "levels" not in READER_FEATURES["gdscript"]:
            assert "'levels'" in lines[0]
    else:
        assert lines == [], lines
        answers = conformance_output[case["name"] + "+vectors"]
        assert answers[0].split()[1:] == hex_names(case["fragment_names"])
        vectors = load_vectors(case["vectors"][: -len(".vectors.json")])
        assert check_structure_answers(vectors, "\n".join(answers)) == []


STATE_SCRIPT = """extends SceneTree
const HexBits = preload("res://hex_bits.gd")


func _read(path: String) -> PoolByteArray:
	var file := File.new()
	file.open(path, File.READ)
	var data := file.get_buffer(file.get_len())
	file.close()
	return data


func _init() -> void:
	var args := OS.get_cmdline_args()
	var rt = load("res://addons/fracture/fracture_runtime.gd").new()
	if rt.load_bytes(_read(args[args.size() - 2]), _read(args[args.size() - 1])) != OK:
		print("load-error " + rt.error_message)
	var state: Array = rt.new_state()
	print("fresh ", state)
	print("nan-impulse ", rt.hit(state, 0.0, 0.0, 0.0, NAN, 0.0, 0.0, 1.0)["ok"], " ", state == rt.new_state())
	var pool := PoolRealArray(state)
	var short := state.duplicate()
	short.pop_back()
	var above := state.duplicate()
	above[0] = 1.5
	var nan := state.duplicate()
	nan[0] = NAN
	for bad in [pool, short, above, nan]:
		print("refused ", rt.hit(bad, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0)["ok"])
	var res: Dictionary = rt.hit(state, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.78125)
	print("cracked ", res["cracked"])
	print("bytes ", rt.state_to_bytes(state).hex_encode())
	print("round-trip ", rt.state_from_bytes(rt.state_to_bytes(state)) == state)
	print("bad-bytes ", rt.state_from_bytes(PoolByteArray([1, 2, 3])) == null)
	print("segments ", rt.crack_segments_of(3))
	print("numbers ", HexBits.to_bits(rt.default_threshold), " ", HexBits.to_bits(rt.impact_radius), " ",
			HexBits.to_bits(rt.crack_level), " ", HexBits.to_bits(rt.damage_rate))
	print("done")
	quit()
"""


def test_gdscript_damage_state_api(tmp_path):
    """new_state, refused states and hits (the state unchanged), the saved bytes as the Python reader's, cracks,
    and header numbers parsed to the nearest double (Godot 3's String.to_float() rounds to 32 bits)."""
    header, binary = runtime_paths("structure_dyadic")
    with open(header, encoding="utf-8") as fh:
        edited = json.load(fh)
    edited.update(default_threshold=0.7, impact_radius=1e-05, damage={"crack_level": 0.6, "damage_rate": 0.3})
    (tmp_path / "s.fracture.json").write_text(json.dumps(edited))
    project = GodotProject(tmp_path / "project")
    run = project.run_script(STATE_SCRIPT, str(tmp_path / "s.fracture.json"), binary, name="state.gd")
    out = {line.split(" ", 1)[0]: line.split(" ", 1)[1] for line in run.lines() if " " in line}
    assert "load-error" not in out, out
    data = load_runtime(header)
    state = new_state(data)
    assert out["fresh"] == "[" + ", ".join(["1"] * data.num_edges) + "]"
    assert out["nan-impulse"] == "False True"
    assert run.lines("refused ") == ["refused False"] * 4
    edited_data = dataclasses.replace(data, damage={"crack_level": 0.6, "damage_rate": 0.3})
    reference = hit(edited_data, state, (0, 0, 0), (1, 0, 0), 0.78125)
    assert out["cracked"] == str(reference.cracked.tolist())  # Godot prints booleans as Python does
    assert out["bytes"] == state_to_bytes(state).hex()
    assert out["round-trip"] == "True" and out["bad-bytes"] == "True"
    segments = data.cracks["crack_segments"][3:5].reshape(-1, 3).tolist()
    vectors = ["(" + ", ".join(f"{c:g}" for c in v) + ")" for v in segments]  # Godot prints Vector3 as (x, y, z)
    assert out["segments"] == "[" + ", ".join(vectors) + "]"
    assert out["numbers"].split() == [float_to_bits(x) for x in (0.7, 1e-05, 0.6, 0.3)]


# ---------------------------------------------------------------- FractureBody in a scene

BREAK_SCRIPT = os.path.join(REPO, "engines", "godot", "tests", "break_scene.gd")


def _hits_file(path, hits) -> str:
    """Write hits (point, impulse, body index[, threshold]) in break_scene.gd's format."""
    lines = []
    for point, impulse, body, *threshold in hits:
        tokens = [float_to_bits(float(c)) for c in (*point, *impulse)] + [str(body)]
        lines.append(" ".join(tokens + [float_to_bits(float(t)) for t in threshold if t is not None]))
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _bodies_after_each_step(run) -> list[dict]:
    """Parse break_scene.gd's report: per step, {body index: (class, fragment names, shape counts, cracks drawn)}."""
    steps: list[dict] = []
    current: dict = {}
    for line in run.stdout.splitlines():
        fields = line.split()
        if fields[:1] == ["body"]:
            current[int(fields[1])] = (fields[2], fields[3:], {}, 0)
        elif fields[:1] == ["shapes"]:
            current[int(fields[1])][2].update(
                {name: int(count) for name, count in (field.rsplit(":", 1) for field in fields[2:])}
            )
        elif fields[:1] == ["cracks"]:
            current[int(fields[1])] = (*current[int(fields[1])][:3], int(fields[2]))
        elif fields[:1] == ["step"]:
            steps.append(current)
            current = {}
    return steps


def _row_of_boxes(tmp_path):
    """Four unit boxes in a row with every kind of exported collision part, and a runtime file for them."""
    trimesh = pytest.importorskip("trimesh")
    scene = trimesh.Scene()
    for j in range(4):
        at = np.eye(4)
        at[0, 3] = 1.0 * j
        scene.add_geometry(
            trimesh.creation.box(extents=(1, 1, 1)), node_name=f"fragment_{j:03d}", geom_name=f"mesh_{j}", transform=at
        )
    parts = {
        "fragment_000-convcolonly": "fragment_000",
        "fragment_001_00-convcolonly": "fragment_001",
        "fragment_001_01-convcolonly": "fragment_001",
        "UCX_fragment_002_00": "fragment_002",
    }
    for name, parent in parts.items():
        scene.add_geometry(
            trimesh.creation.box(extents=(0.9, 0.9, 0.45)),
            node_name=name,
            geom_name="c_" + name,
            parent_node_name=parent,
        )
    glb = tmp_path / "row.glb"
    scene.export(glb)
    # One mode, W = (1, 1, -1, -1): a unit impulse anywhere breaks only the edge (1, 2).
    data = RuntimeData(
        sites=np.array([[j, 0.5, 0] for j in range(4)], np.float32),
        B=np.ones((4, 1, 1), np.float32),
        W=np.array([[[1], [1], [-1], [-1]]], np.float32),
        edges=np.array([[0, 1], [1, 2], [2, 3]], np.int32),
        edge_areas=np.ones(3, np.float32),
        fragment_names=tuple(f"fragment_{j:03d}" for j in range(4)),
        default_threshold=1.0,
    )
    json_path, _ = write_runtime(data, tmp_path / "row.fracture.json")
    return glb, json_path


def _godot_break(tmp_path, glb, json_path, hits):
    project = GodotProject(tmp_path / "project")
    scene = project.add_file(glb)
    runtime = project.add_file(json_path)
    project.add_file(str(json_path).replace(".fracture.json", ".fracture.bin"))
    project.import_resources()
    with open(BREAK_SCRIPT, encoding="utf-8") as fh:
        run = project.run_script(
            fh.read(), scene, runtime, _hits_file(tmp_path / "hits.txt", hits), name="break_scene.gd"
        )
    assert not run.lines("setup-error"), run.lines("setup-error")
    return _bodies_after_each_step(run)


def test_fracture_body_uses_exported_collision_parts(tmp_path):
    glb, json_path = _row_of_boxes(tmp_path)
    steps = _godot_break(tmp_path, glb, json_path, [((0.0, 0.5, 0.0), (0.0, -1.0, 0.0), 0)])
    intact_class, names, shapes, _cracks = steps[0][0]
    assert intact_class == "StaticBody" and names == [f"fragment_{j:03d}" for j in range(4)]
    # -convcolonly child, two numbered -convcolonly parts, a UCX mesh, and the hull fallback.
    assert shapes == {"fragment_000": 1, "fragment_001": 2, "fragment_002": 1, "fragment_003": 1}
    after = steps[1]
    assert after[0][:2] == ("StaticBody", ["fragment_000", "fragment_001"])  # a tie: the smaller ids stay
    assert after[1][:2] == ("RigidBody", ["fragment_002", "fragment_003"])
    assert after[1][2] == {"fragment_002": 1, "fragment_003": 1}


def _robust(data, point, impulse) -> bool:
    """No edge within 1e-6 (relative) of the threshold, so float32 vs double cannot flip it."""
    result = project_impact(data, point, impulse)
    disp = result.displacement
    jumps = np.linalg.norm(disp[data.edges[:, 0]] - disp[data.edges[:, 1]], axis=1)
    return bool(np.all(np.abs(jumps - data.default_threshold) > 1e-6 * max(data.default_threshold, 1e-12)))


def _root(parent: dict[int, int], a: int) -> int:
    while parent[a] != a:
        a = parent[a]
    return a


def _expected_bodies(data, hits) -> list[list[list[int]]]:
    """FractureBody's rule replayed on the Python reference: per step, the fragments of each body."""
    bodies = [list(range(data.p))]
    steps = [[list(b) for b in bodies]]
    for point, impulse, index in hits:
        broken = project_impact(data, point, impulse).broken
        members = set(bodies[index])
        parent = {j: j for j in members}
        for (P, Q), cut in zip(data.edges.tolist(), broken.tolist()):
            if not cut and P in members and Q in members:
                a, b = _root(parent, P), _root(parent, Q)
                parent[max(a, b)] = min(a, b)
        pieces: dict[int, list[int]] = {}
        for j in sorted(members):
            pieces.setdefault(_root(parent, j), []).append(j)
        ordered = sorted(pieces.values(), key=lambda piece: (-len(piece), piece[0]))
        bodies[index] = ordered[0]
        bodies += ordered[1:]
        steps.append([list(b) for b in bodies])
    return steps


def _pick_hits(data) -> list:
    """A hit on the intact asset that splits it in three or more, then one more on the static rest."""
    directions = [(0, -8, 0), (8, 0, 0), (0, 0, 8), (-8, 0, 0), (0, 0, -8), (6, -6, 0)]
    sites = data.sites.astype(np.float64)
    for v in range(0, len(sites), 7):
        for n in directions:
            hit = (tuple(sites[v].tolist()), n, 0)
            if _robust(data, hit[0], n) and len(_expected_bodies(data, [hit])[-1]) >= 3:
                for w in range(len(sites) - 1, 0, -11):
                    second = (tuple(sites[w].tolist()), tuple(4 * c for c in n), 0)
                    steps = _expected_bodies(data, [hit, second])
                    if _robust(data, second[0], second[1]) and len(steps[-1]) > len(steps[-2]):
                        return [hit, second]
    raise AssertionError("no hit on the baked asset breaks it in three")


@pytest.mark.slow
def test_fracture_body_breaks_a_baked_asset_like_the_reference(tmp_path):
    """Bake the pillar, break it in Godot twice: the detached bodies are exactly the reference's groups."""
    out = tmp_path / "bake"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "fracture_cli",
            "-q",
            "bake",
            os.path.join(REPO, "sample_assets", "pillar.glb"),
            "-o",
            str(out),
            "--recipe",
            "stone",
        ],
        check=True,
        cwd=REPO,
    )
    json_path = out / "pillar.fracture.json"
    data = load_runtime(json_path)
    hits = _pick_hits(data)
    steps = _godot_break(tmp_path, out / "pillar.glb", json_path, hits)
    expected = _expected_bodies(data, hits)
    names = data.fragment_names
    assert len(steps) == len(expected) == 3
    for got, want in zip(steps, expected):
        assert [got[i][1] for i in sorted(got)] == [[names[j] for j in body] for body in want]
        assert [got[i][0] for i in sorted(got)] == ["StaticBody"] + ["RigidBody"] * (len(want) - 1)
        assert all(count >= 1 for body in got.values() for count in body[2].values())


def _boxes(tmp_path, names, centres, size: float):
    """A fragments GLB with one box of edge ``size`` per fragment, centred at ``centres[j]`` and named ``names[j]``."""
    trimesh = pytest.importorskip("trimesh")
    scene = trimesh.Scene()
    for j, (name, centre) in enumerate(zip(names, centres)):
        at = np.eye(4)
        at[:3, 3] = centre
        scene.add_geometry(trimesh.creation.box(extents=(size, size, size)), node_name=name, geom_name=f"mesh_{j}",
                           transform=at)
    glb = tmp_path / "boxes.glb"
    scene.export(glb)
    return glb


def test_fracture_body_keeps_anchored_groups_static_and_draws_cracks(tmp_path):
    """structure_dyadic (a column of five, the foot anchored, crack segments): its designed sequence in a scene.

    The first hit cracks bond 3 (fragments 3-4; two crack segments drawn, nothing breaks); the second
    breaks bonds 2, 3 and 4: the top two fragments fall, the foot's group stays static.
    """
    header, _ = runtime_paths("structure_dyadic")
    data = load_runtime(header)
    glb = _boxes(tmp_path, data.fragment_names, [(0.5, j + 0.5, 0.5) for j in range(data.p)], 1.0)
    hits = [((0.0, 4.0, 0.0), (0.0, 1.0, 0.0), 0, 1.125), ((0.0, 4.0, 0.0), (0.0, 8.0, 0.0), 0, 2.0)]
    steps = _godot_break(tmp_path, glb, header, hits)
    names = list(data.fragment_names)
    assert [(body[0], body[1], body[3]) for body in steps[0].values()] == [("StaticBody", names, 0)]
    assert [(body[0], body[1], body[3]) for body in steps[1].values()] == [("StaticBody", names, 2)]
    assert [(body[0], body[1], body[3]) for body in steps[2].values()] == [
        ("StaticBody", names[:3], 0), ("RigidBody", [names[3]], 0), ("RigidBody", [names[4]], 0)]


def test_fracture_body_keeps_a_pillars_anchored_base_static(tmp_path):
    """pillar_structure's "random hits" sequence (a refused hit and a zero impulse among them) in a scene.

    After every hit the bodies are the groups of the damage state and exactly the anchored ones are
    static; the first hit leaves the anchored base smaller than the free piece that falls (the rule is
    anchoring, not size), a later one splits that falling piece again.
    """
    header, _ = runtime_paths("pillar_structure")
    data = load_runtime(header)
    sequence = next(s for s in load_vectors("pillar_structure")["sequences"] if s["name"] == "random hits")
    centres = np.asarray(data.gameready["fragment_center_of_mass"], np.float64)
    glb = _boxes(tmp_path, data.fragment_names, centres, 0.02 * float(np.ptp(data.sites, axis=0).max()))
    hits = [(point, impulse, 0, threshold) for point, impulse, threshold in map(impact_inputs, sequence["hits"])]
    steps = _godot_break(tmp_path, glb, header, hits)
    assert len(steps) == len(hits) + 1
    expected, groups, anchored = [], [0] * data.p, [1] * data.p
    for h in sequence["hits"]:
        if h["expect"] == "ok":
            groups, anchored = h["groups"], h["anchored"]
        members: dict[int, list[str]] = {}
        for j, g in enumerate(groups):
            members.setdefault(g, []).append(data.fragment_names[j])
        expected.append(sorted((names, "StaticBody" if anchored[g] else "RigidBody") for g, names in members.items()))
    got = [sorted((body[1], body[0]) for body in step.values()) for step in steps[1:]]
    assert got == expected
    sizes = {kind: len(names) for names, kind in expected[0]}
    assert sizes["StaticBody"] < sizes["RigidBody"]  # the first hit: the anchored base is the smaller piece

