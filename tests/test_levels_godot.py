"""Levels in Godot 3 (headless): hit the sample pillar, then hit a detached group again where it flew to.

The committed conformance file pillar_levels is the sample pillar baked with two levels. A first hit on
the intact asset (the Python reader picks one that detaches a group holding a fragment with children),
then a second hit on that fragment after its piece has moved by a rigid transform: the GDScript reader
(engines/godot/tests/levels_hits.gd) gets the contact in world space through Godot's Transform, undoes the
piece's transform as a game does, and hits the piece (hit_piece). The fragment must split into the
children the runtime file lists, and every piece and health must be the Python reader's
(fracture_cli.runtime.levelstate) for the model-space point and impulse Godot used.
"""

from __future__ import annotations

import os

import numpy as np
from engine_support import bits_to_float, float_to_bits, runtime_paths
from godot_harness import GodotProject

from fracture_cli.runtime.format import RuntimeData, load_runtime
from fracture_cli.runtime.levels import body_of, body_threshold, body_view, children_range
from fracture_cli.runtime.levelstate import hit_piece, nearest_fragment, new_object_state, shown_pieces

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(REPO, "engines", "godot", "tests", "levels_hits.gd")
HEALTH_TOLERANCE = 1e-9
# Where the detached group flew: 40 degrees about (1, 2, 3), then 0.3 m, -1.2 m, 2 m (the pillar is in metres).
ANGLE, AXIS, SHIFT = np.radians(40.0), np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0), np.array([0.3, -1.2, 2.0])


def _rotation() -> np.ndarray:
    k = np.array([[0, -AXIS[2], AXIS[1]], [AXIS[2], 0, -AXIS[0]], [-AXIS[1], AXIS[0], 0]])
    return np.eye(3) + np.sin(ANGLE) * k + (1 - np.cos(ANGLE)) * k @ k


def _first_hit(data: RuntimeData, rng) -> tuple[int, np.ndarray, np.ndarray, int]:
    """A hit on the intact asset that detaches a small group holding a fragment with children (that fragment)."""
    for _ in range(2000):
        state = new_object_state(data)
        point = data.sites[rng.integers(0, data.num_sites)].astype(np.float64)
        struck = nearest_fragment(data, range(data.p), point)
        impulse = rng.normal(size=3)
        impulse *= data.default_threshold * rng.uniform(1.0, 15.0) / np.linalg.norm(impulse)
        hit_piece(data, state, struck, point, impulse)
        pieces = shown_pieces(data, state)
        largest = max(pieces, key=lambda piece: len(piece.fragments))
        for piece in pieces:
            refined = [g for g in piece.fragments if body_of(data, g) >= 0]
            if piece is not largest and refined:
                return struck, point, impulse, refined[0]
    raise AssertionError("no hit detaches a group holding a fragment with children")


def _second_hit(data: RuntimeData, state: np.ndarray, fragment: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """A hit on `fragment` at one of its body's sites that splits it, by a margin (ten times its level's threshold)."""
    body = body_of(data, fragment)
    view = body_view(data, body)
    for _ in range(500):
        point = view.sites[rng.integers(0, view.num_sites)].astype(np.float64)
        impulse = rng.normal(size=3)
        impulse *= 10.0 * body_threshold(data, body) / np.linalg.norm(impulse)
        if hit_piece(data, state.copy(), fragment, point, impulse).split:
            return point, impulse
    raise AssertionError(f"no hit splits fragment {fragment}")


def _line(kind: str, struck: int, point, impulse, extra: str = "") -> str:
    return " ".join([kind, str(struck), *(float_to_bits(float(x)) for x in (*point, *impulse)), "-"]) + extra + "\n"


def test_godot_hits_a_detached_group_where_it_flew(tmp_path):
    header, binary = runtime_paths("pillar_levels")
    data = load_runtime(header)
    rng = np.random.default_rng(3)
    struck, point, impulse, fragment = _first_hit(data, rng)
    state = new_object_state(data)
    hit_piece(data, state, struck, point, impulse)
    second_point, second_impulse = _second_hit(data, state, fragment, rng)
    rotation = _rotation()
    moved = " " + " ".join(f"{x:.17g}" for x in (*rotation[:, 0], *rotation[:, 1], *rotation[:, 2], *SHIFT))

    project = GodotProject(tmp_path / "godot")
    project.add_file(header)
    project.add_file(binary)
    hits = tmp_path / "hits.txt"
    hits.write_text(_line("hit", struck, point, impulse)
                    + _line("flying", fragment, second_point, second_impulse, moved))
    with open(SCRIPT, encoding="utf-8") as fh:
        run = project.run_script(fh.read(), "res://" + os.path.basename(header), str(hits), name="levels_hits.gd")
    used, answers = run.lines("used "), run.lines("piece ")
    assert len(used) == 2 and len(answers) == 2, run.stdout[-2000:]

    reference = new_object_state(data)
    for (kind, target), use, answer in zip((("hit", struck), ("flying", fragment)), used, answers):
        values = [bits_to_float(b) for b in use.split()[1:]]
        if kind == "flying":  # Godot's 32-bit Transform moved the contact there and back: close, not exact
            assert np.allclose(values, [*second_point, *second_impulse], atol=1e-5)
        want = hit_piece(data, reference, target, values[:3], values[3:])
        tokens = answer.split()
        assert tokens[1] == "ok", answer
        p, h = tokens.index("p"), tokens.index("h")
        pieces = [[int(g) for g in t.split(",")] for t in tokens[p + 1: h]]
        assert pieces == [list(piece.fragments) for piece in shown_pieces(data, reference)], kind
        health = [bits_to_float(b) for b in tokens[h + 1:]]
        assert np.allclose(health, reference, rtol=0, atol=HEALTH_TOLERANCE), kind
        assert (tokens[3] == "1") == want.split, kind
    # The second hit split the flying fragment into the children the runtime file lists, now shown as pieces.
    tokens = answers[1].split()
    assert tokens[3] == "1", answers[1]
    children = children_range(data, body_of(data, fragment))
    names = [bytes.fromhex(t).decode("utf-8") for t in tokens[tokens.index("s") + 1: tokens.index("p")]]
    assert names == [data.child_names[g - data.p] for g in children]
    flying = [piece for piece in shown_pieces(data, reference) if piece.fragments[0] in children]
    assert sorted(g for piece in flying for g in piece.fragments) == list(children)
    assert len(flying) >= 2
