"""The Godot add-on's FractureBody on a bake with levels (headless Godot 3, real physics).

The sample pillar baked with two levels (fast settings, Godot's ``-convcolonly`` collision parts) goes into a
FractureBody (engines/godot/tests/levels_scene.gd). A first hit on the intact asset detaches a group holding a
fragment with children; the group flies for half a second under gravity; a second hit on that fragment, where
it flew (model space through the body's transform and back), splits it; a third (when the bake has one) breaks
a flying piece of its children again, the add-on picking the child struck. Before and after each hit the
bodies must be the object's pieces as the Python reader has them (fracture_cli.runtime.levelstate, replayed with
the model-space inputs the GDScript reader got), the meshes shown exactly the shown fragments' GLB nodes
(level-2 nodes hidden until their parent splits), and the split fragment's children must start in the frame
of the body they split from.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from engine_support import bits_to_float, float_to_bits, impact_inputs, load_vectors, runtime_paths
from godot_harness import GodotProject
from structure_support import FAST

from fracture_cli.pipeline.bake import bake
from fracture_cli.pipeline.recipe import load_recipe
from fracture_cli.runtime.format import RuntimeData, load_runtime
from fracture_cli.runtime.levels import body_of, body_threshold, body_view, children_range, fragment_name
from fracture_cli.runtime.levelstate import hit_piece, nearest_fragment, new_object_state, shown_fragments, shown_pieces

from conftest import SAMPLE_ASSETS

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE_SCRIPT = os.path.join(REPO, "engines", "godot", "tests", "levels_scene.gd")
LEVELS = ["levels.count=2", "levels.ratio=0.5", "collision.glb=godot"]
FRAMES = 30  # half a second at 60 frames per second between the hits
FRAME_TOLERANCE = 1e-4  # float32 transforms of a body about a metre from the origin


@pytest.fixture(scope="module")
def pillar(tmp_path_factory) -> tuple[str, RuntimeData]:
    """The sample pillar baked with two levels: (GLB stem, runtime data)."""
    out = tmp_path_factory.mktemp("pillar_levels")
    bake(os.path.join(SAMPLE_ASSETS, "pillar.glb"), str(out), load_recipe("stone", FAST + LEVELS))
    return str(out / "pillar"), load_runtime(str(out / "pillar.fracture.json"))


def _first_hit(data: RuntimeData, rng, alone: bool) -> tuple[int, np.ndarray, np.ndarray, int]:
    """A hit on the intact asset that detaches a fragment with children (that one): ``alone``, or in a group of
    two or more fragments."""
    for _ in range(2000):
        state = new_object_state(data)
        point = data.sites[rng.integers(0, data.num_sites)].astype(np.float64)
        struck = nearest_fragment(data, range(data.p), point)
        impulse = rng.normal(size=3)
        impulse *= data.default_threshold * rng.uniform(1.0, 6.0) / np.linalg.norm(impulse)
        hit_piece(data, state, struck, point, impulse)
        pieces = shown_pieces(data, state)
        largest = max(pieces, key=lambda piece: len(piece.fragments))
        for piece in pieces:
            refined = [g for g in piece.fragments if body_of(data, g) >= 0]
            if piece is not largest and refined and (len(piece.fragments) == 1) == alone:
                return struck, point, impulse, refined[0]
    raise AssertionError(f"no hit detaches a fragment with children ({'alone' if alone else 'in a group'})")


def _second_hit(data: RuntimeData, state: np.ndarray, fragment: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """A hit on ``fragment`` at one of its body's sites that splits it by a margin (two to ten times its level's
    threshold), leaving a piece of two or more children where one is found."""
    body = body_of(data, fragment)
    view = body_view(data, body)
    splits = []
    for _ in range(500):
        point = view.sites[rng.integers(0, view.num_sites)].astype(np.float64)
        impulse = rng.normal(size=3)
        impulse *= rng.uniform(2.0, 10.0) * body_threshold(data, body) / np.linalg.norm(impulse)
        trial = state.copy()
        if hit_piece(data, trial, fragment, point, impulse).split:
            if any(piece.body == body and len(piece.fragments) >= 2 for piece in shown_pieces(data, trial)):
                return point, impulse
            splits.append((point, impulse))
    assert splits, f"no hit splits fragment {fragment}"
    return splits[0]


def _third_hit(data: RuntimeData, state: np.ndarray, body: int, rng) -> tuple[np.ndarray, np.ndarray, int] | None:
    """A hit on a piece of two or more children of ``body`` that breaks it: (point, impulse, the child struck),
    or None when there is no such piece or hit."""
    children = list(children_range(data, body))
    groups = [piece.fragments for piece in shown_pieces(data, state) if piece.body == body]
    if max(len(group) for group in groups) < 2:
        return None
    view = body_view(data, body)
    for _ in range(500):
        point = view.sites[rng.integers(0, view.num_sites)].astype(np.float64)
        struck = nearest_fragment(data, children, point)
        if not any(struck in group and len(group) >= 2 for group in groups):
            continue
        impulse = rng.normal(size=3)
        impulse *= 10.0 * body_threshold(data, body) / np.linalg.norm(impulse)
        trial = state.copy()
        hit_piece(data, trial, struck, point, impulse)
        if len(shown_pieces(data, trial)) > len(shown_pieces(data, state)):
            return point, impulse, struck
    return None


def _steps(stdout: str) -> tuple[list[dict], list[list[str]]]:
    """levels_scene.gd's report: per step {body index: (class, model frame (4, 4), fragments, names, shapes,
    shown)}, and the "hit" lines' fields."""
    steps: list[dict] = []
    hits: list[list[str]] = []
    current: dict = {}
    for line in stdout.splitlines():
        fields = line.split()
        if fields[:1] == ["body"]:
            frame = np.eye(4)
            frame[:3, :4] = np.array([float(v) for v in fields[3:15]]).reshape(4, 3).T
            f, n, s = fields.index("f"), fields.index("n"), fields.index("s")
            current[int(fields[1])] = (fields[2], frame, [int(g) for g in fields[f + 1: n]], fields[n + 1: s],
                                       [int(c) for c in fields[s + 1:]])
        elif fields[:1] == ["shown"]:
            current["shown"] = sorted(fields[1:])
        elif fields == ["step"]:
            steps.append(current)
            current = {}
        elif fields[:1] in (["hit"], ["hit-error"]):
            hits.append(fields)
    return steps, hits


def _names(data: RuntimeData, fragments) -> list[str]:
    return [fragment_name(data, int(g)) for g in fragments]


def _check_step(data: RuntimeData, step: dict, state: np.ndarray, label: str) -> None:
    """The bodies are the object's pieces, each with its fragments' meshes and shapes, anchored ones and the intact
    body's rest StaticBodies, the others RigidBodies; the meshes shown are exactly the shown fragments'."""
    bodies = {k: v for k, v in step.items() if k != "shown"}
    pieces = {piece.fragments: piece.anchored for piece in shown_pieces(data, state)}
    assert sorted(tuple(fragments) for _, _, fragments, _, _ in bodies.values()) == sorted(pieces), label
    for index, (kind, _, fragments, names, shapes) in bodies.items():
        static = index == 0 or pieces[tuple(fragments)]
        assert kind == ("StaticBody" if static else "RigidBody"), (label, index)
        assert sorted(names) == sorted(_names(data, fragments)), label
        assert all(count >= 1 for count in shapes), (label, fragments, shapes)
    assert step["shown"] == sorted(_names(data, np.flatnonzero(shown_fragments(data, state)))), label


@pytest.mark.slow
@pytest.mark.parametrize("alone", [False, True], ids=["in-a-group", "alone"])
def test_fracture_body_breaks_a_flying_piece_into_its_children(pillar, tmp_path, alone):
    """``alone``: the flying piece is the one fragment, so its body keeps a piece of the children."""
    stem, data = pillar
    rng = np.random.default_rng(5)
    struck, point, impulse, fragment = _first_hit(data, rng, alone)
    state = new_object_state(data)
    hit_piece(data, state, struck, point, impulse)
    second_point, second_impulse = _second_hit(data, state, fragment, rng)
    hits = [(point, impulse, struck), (second_point, second_impulse, fragment)]
    hit_piece(data, state, fragment, second_point, second_impulse)
    third = _third_hit(data, state, body_of(data, fragment), rng)  # on a flying piece of children, if any
    if third is not None:  # the add-on picks the child struck (nearest the point): the default of hit()
        hits.append((third[0], third[1], f"~{third[2]}"))

    project = GodotProject(tmp_path / "project")
    scene = project.add_file(stem + ".glb")
    runtime = project.add_file(stem + ".fracture.json")
    project.add_file(stem + ".fracture.bin")
    project.import_resources()
    lines = [" ".join([float_to_bits(float(c)) for c in (*p, *n)] + [str(g)]) for p, n, g in hits]
    (tmp_path / "hits.txt").write_text("\n".join(lines) + "\n")
    with open(SCENE_SCRIPT, encoding="utf-8") as fh:
        run = project.run_script(fh.read(), scene, runtime, str(tmp_path / "hits.txt"), str(FRAMES),
                                 name="levels_scene.gd", flags=("--fixed-fps", "60"))
    assert not run.lines("setup-error"), run.lines("setup-error")
    steps, answers = _steps(run.stdout)
    assert len(steps) == 1 + 2 * len(hits) and [a[0] for a in answers] == ["hit"] * len(hits), run.stdout[-3000:]

    # Setup: the intact asset, one static body of the level-1 fragments; no level-2 node shown.
    reference = new_object_state(data)
    _check_step(data, steps[0], reference, "setup")
    assert [kind for kind, *_ in (v for k, v in steps[0].items() if k != "shown")] == ["StaticBody"]
    # Each hit: the bodies are the pieces of the Python reader replayed with the inputs Godot's reader got, before
    # (after flying) and after the hit.
    for k, fields in enumerate(answers):
        _check_step(data, steps[1 + 2 * k], reference, f"before hit {k}")
        used = [bits_to_float(b) for b in fields[fields.index("used") + 1:]]
        assert np.allclose(used, [*hits[k][0], *hits[k][1]], atol=1e-5)  # model space there and back
        want = hit_piece(data, reference, int(fields[2]), used[:3], used[3:])
        assert (fields[1] == "1") == want.split, f"hit {k}"
        _check_step(data, steps[2 + 2 * k], reference, f"after hit {k}")

    # The group holding `fragment` flew; the second hit split `fragment` where it was: its children's bodies
    # start in the model frame of the body it left, and its own node is hidden.
    after_first, before_second, after_second = steps[2], steps[3], steps[4]
    flying = next(v for k, v in before_second.items() if k != "shown" and fragment in v[2])
    start = next(v for k, v in after_first.items() if k != "shown" and fragment in v[2])
    print(f"godot levels: {len(hits)} hits, bodies {[len(s) - 1 for s in steps]}, fragment {fragment} flew "
          f"{np.linalg.norm(flying[1][:3, 3] - start[1][:3, 3]):.3f} m with {flying[2]}, shown after: "
          f"{after_second['shown']}")
    assert flying[0] == "RigidBody" and (len(flying[2]) == 1) == alone
    assert np.abs(flying[1] - start[1]).max() > 0.02  # it moved (it may come to rest on the pillar's base)
    assert answers[1][1] == "1"
    children = list(children_range(data, body_of(data, fragment)))
    assert _names(data, [fragment])[0] not in after_second["shown"]
    assert set(_names(data, children)) <= set(after_second["shown"])
    child_bodies = [v for k, v in after_second.items() if k != "shown" and set(v[2]) & set(children)]
    assert len(child_bodies) >= 2
    for kind, frame, fragments, _, _ in child_bodies:
        assert kind == "RigidBody" and set(fragments) <= set(children)
        assert np.allclose(frame, flying[1], atol=FRAME_TOLERANCE), (frame, flying[1])


def _boxes(data: RuntimeData, path) -> str:
    """A fragments GLB of unit boxes, one node per fragment of every level, each child under its parent's node
    (docs/FORMAT.md section 14.6), none overlapping: level 1 along x, children along y, grandchildren along z."""
    trimesh = pytest.importorskip("trimesh")
    scene = trimesh.Scene()
    parent = np.asarray(data.levels["parent"])
    for g in range(len(parent)):
        at = np.eye(4)
        if parent[g] < 0:
            at[0, 3] = 3.0 * g
        else:
            siblings = np.flatnonzero(parent == parent[g])
            at[1 + int(parent[parent[g]] >= 0), 3] = 1.5 * (1 + int(np.searchsorted(siblings, g)))
        scene.add_geometry(trimesh.creation.box(extents=(1, 1, 1)), node_name=fragment_name(data, g),
                           geom_name=f"mesh_{g}", transform=at,
                           parent_node_name=None if parent[g] < 0 else fragment_name(data, int(parent[g])))
    scene.export(path)
    return str(path)


@pytest.mark.parametrize("name", ["levels_dyadic", "levels_stress", "levels_random"])
def test_fracture_body_runs_a_level_sequence(name, tmp_path):
    """A conformance file's sequence of hits from a new object state with the most splits (refused fragments too;
    hits with invalid inputs are the reader's business) through FractureBody on boxes: after every hit the
    bodies are the Python reader's pieces (anchored ones static) and the meshes shown the shown fragments'."""
    header, binary = runtime_paths(name)
    data = load_runtime(header)
    fresh = [seq for seq in load_vectors(name)["level_sequences"] if seq["start"] is None]
    sequence = max(fresh, key=lambda seq: sum(bool(h.get("split")) for h in seq["hits"]))  # the first, of most splits
    hits = [h for h in sequence["hits"] if h["expect"] == "ok" or h["error"] == "struck"]
    project = GodotProject(tmp_path / "project")
    scene = project.add_file(_boxes(data, tmp_path / f"{name}.glb"))
    runtime = project.add_file(header)
    project.add_file(binary)
    project.import_resources()
    lines = []
    for h in hits:
        point, impulse, threshold = impact_inputs(h)
        extra = [] if threshold is None else [float_to_bits(threshold)]
        lines.append(" ".join([float_to_bits(c) for c in (*point, *impulse)] + [str(h["struck"])] + extra))
    (tmp_path / "hits.txt").write_text("\n".join(lines) + "\n")
    with open(SCENE_SCRIPT, encoding="utf-8") as fh:
        run = project.run_script(fh.read(), scene, runtime, str(tmp_path / "hits.txt"), "0",
                                 name="levels_scene.gd", flags=("--fixed-fps", "60"))
    assert not run.lines("setup-error"), run.lines("setup-error")
    steps, answers = _steps(run.stdout)
    assert len(steps) == 1 + 2 * len(hits) and len(answers) == len(hits), run.stdout[-3000:]
    reference = new_object_state(data)
    _check_step(data, steps[0], reference, "setup")
    splits = 0
    for k, (h, fields) in enumerate(zip(hits, answers)):
        _check_step(data, steps[1 + 2 * k], reference, f"before hit {k}")
        assert (fields[0] == "hit") == (h["expect"] == "ok"), (k, fields)
        if fields[0] == "hit":
            used = [bits_to_float(b) for b in fields[fields.index("used") + 1:]]
            want = hit_piece(data, reference, h["struck"], used[:3], used[3:], impact_inputs(h)[2])
            assert (fields[1] == "1") == want.split, f"hit {k}"
            splits += want.split
        _check_step(data, steps[2 + 2 * k], reference, f"after hit {k}")
    assert splits >= 1
