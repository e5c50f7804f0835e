"""Levels in the runtime file (docs/FORMAT.md section 14): the Python reader against the conformance vectors.

Body 0's stateless impacts and the damaged files are run by tests/test_engine_conformance.py (like every
file); here: every other body's impacts on its view, the object sequences (hits on pieces), the views
themselves, and the reader's refusals.
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np
import pytest
from engine_support import CONFORMANCE, bits_to_float, impact_inputs, load_vectors, vector_names

from fracture_cli.errors import ImpactArgumentError, InputError
from fracture_cli.runtime import levels as lv
from fracture_cli.runtime.damage import hit, new_state
from fracture_cli.runtime.format import decode, encode, load_runtime
from fracture_cli.runtime.impact import project_impact
from fracture_cli.runtime.levelstate import (
    check_object_state,
    hit_piece,
    nearest_fragment,
    new_object_state,
    shown_fragments,
    shown_pieces,
)

LEVEL_FILES = [name for name in vector_names(features=("anchors", "damage", "levels", "stress"))
               if "levels" in load_vectors(name).get("features", ())]


def _data(name: str):
    return load_runtime(os.path.join(CONFORMANCE, f"{name}.fracture.json"))


def test_level_files_exist():
    assert set(LEVEL_FILES) == {"levels_dyadic", "levels_stress", "levels_random", "pillar_levels"}


@pytest.mark.parametrize("name", LEVEL_FILES)
def test_bodies_answer_their_impacts(name):
    vectors, data = load_vectors(name), _data(name)
    assert len(vectors["bodies"]) == lv.num_bodies(data) - 1
    problems = []
    for body in vectors["bodies"]:
        b = body["body"]
        view = lv.body_view(data, b)
        assert (view.num_sites, view.k, view.p, view.num_edges) == tuple(
            body["counts"][key] for key in ("sites", "modes", "fragments", "edges"))
        assert view.default_threshold == body["default_threshold"]
        assert lv.children_range(data, b).start == body["first"]
        assert lv.body_of(data, body["fragment"]) == b
        for impact in body["impacts"]:
            try:
                result = project_impact(data, *impact_inputs(impact), body=b)
            except InputError:
                if impact["expect"] != "error":
                    problems.append(f"body {b}, {impact['name']}: unexpected error")
                continue
            if impact["expect"] == "error":
                problems.append(f"body {b}, {impact['name']}: expected an error")
            elif (result.site, result.groups.tolist(), np.flatnonzero(result.broken).tolist()) != (
                    impact["site"], impact["groups"], impact["broken"]):
                problems.append(f"body {b}, {impact['name']}: site/groups/broken differ")
            elif "cracked" in impact and np.flatnonzero(result.cracked).tolist() != impact["cracked"]:
                problems.append(f"body {b}, {impact['name']}: cracked differs")
    assert not problems, problems


def _state(data, hexes):
    return np.array([bits_to_float(x) for x in hexes]) if hexes is not None else new_object_state(data)


@pytest.mark.parametrize("name", LEVEL_FILES)
def test_level_sequences(name):
    vectors, data = load_vectors(name), _data(name)
    assert vectors["level_sequences"], "every levels file has object sequences"
    for seq in vectors["level_sequences"]:
        state = _state(data, seq["start"])
        for step in seq["hits"]:
            point, impulse, threshold = impact_inputs(step)
            before = state.copy()
            where = f"{name}, {seq['name']}, {step['name']}"
            if step["expect"] == "error":
                with pytest.raises(ImpactArgumentError):
                    hit_piece(data, state, step["struck"], point, impulse, threshold)
                assert np.array_equal(state, before), where
                continue
            out = hit_piece(data, state, step["struck"], point, impulse, threshold)
            assert out.body == step["body"] and out.result.site == step["site"], where
            assert np.flatnonzero(out.result.broken).tolist() == step["broken"], where
            assert out.child_body == step["child_body"] and out.split == step["split"], where
            if out.child_result is not None:
                assert out.child_result.site == step["child_site"], where
                assert np.flatnonzero(out.child_result.broken).tolist() == step["child_broken"], where
            pieces = shown_pieces(data, state)
            assert [list(p.fragments) for p in pieces] == step["pieces"], where
            assert [p.anchored for p in pieces] == step["anchored"], where
            expected = np.array([bits_to_float(x) for x in step["health"]])
            assert np.allclose(state, expected, rtol=0, atol=1e-9), where
            # The pieces a hit returns replace the piece it hit.
            assert {out.struck} <= {g for p in out.pieces for g in p.fragments} | ({out.struck} if out.split else set())


def test_dyadic_sequence_is_exact():
    """The designed sequence of levels_dyadic (docs/FORMAT.md 14.5) as the hand computation in levels.py says."""
    data = _data("levels_dyadic")
    state = new_object_state(data)
    first = hit_piece(data, state, 1, (2, 0, 0), (4, 0, 0))
    assert first.body == 0 and first.result.site == 1 and np.flatnonzero(first.result.broken).tolist() == [0, 2]
    assert first.child_body == 1 and first.child_result.site == 2 and first.split
    assert [p.fragments for p in first.pieces] == [(0,), (2,), (3,), (4, 5), (6,)]
    assert shown_fragments(data, state).tolist() == [True, False, True, True, True, True, True, False, False, False,
                                                     False]
    with pytest.raises(ImpactArgumentError, match="not shown"):
        hit_piece(data, state, 1, (1, 0, 0), (1, 0, 0))
    third = hit_piece(data, state, 5, (1, 1, 0.5), (0, 0, 1))
    assert third.body == 1 and third.child_body == 3 and third.split
    assert [p.fragments for p in third.pieces] == [(4,), (9,), (10,)]


def test_body_view_is_the_documented_slices():
    data = _data("levels_random")
    lvl = data.levels
    for b in range(1, lv.num_bodies(data)):
        view = lv.body_view(data, b)
        s0, s1 = lvl["body_site_ptr"][b: b + 2]
        g0, g1 = lvl["body_child_ptr"][b: b + 2]
        e0, e1 = lvl["body_edge_ptr"][b: b + 2]
        assert np.array_equal(view.sites, lvl["body_sites"][s0:s1])
        assert np.array_equal(view.W, lvl["body_W"][:, g0 - data.p: g1 - data.p])
        assert np.array_equal(view.edges, lvl["body_edges"][e0:e1])
        assert view.fragment_names == data.child_names[g0 - data.p: g1 - data.p]
        assert view.features == ()  # a body's view is a plain file of its own
        parts = view.gameready["collision_fragment_offsets"]
        assert parts[0] == 0 and len(parts) == view.p + 1
        assert lv.body_holding(data, int(g0)) == b and lv.body_holding(data, int(g1) - 1) == b
    assert lv.body_view(data, 0) is data
    with pytest.raises(IndexError):
        lv.body_view(data, lv.num_bodies(data))


def test_states_per_body_and_per_object():
    data = _data("levels_stress")
    state = new_object_state(data)
    assert state.shape == (data.num_edges + len(data.levels["body_edges"]),)
    body_state = new_state(lv.body_view(data, 1))
    result = hit(data, body_state, (2, 0, 0), (4, 0, 0), body=1)
    assert result.groups.shape == (3,) and body_state.shape == (2,)
    dyadic = _data("levels_dyadic")
    with pytest.raises(ImpactArgumentError):
        hit(dyadic, new_state(dyadic), (3, 0, 0), (1, 0, 0), body=2)  # body 0's 3 healths for body 2's 1 bond
    with pytest.raises(ImpactArgumentError):
        check_object_state(data, state[:-1].copy())
    pieces = shown_pieces(data, state)
    assert [p.fragments for p in pieces] == [(0, 1, 2)] and pieces[0].anchored


def test_nearest_fragment_uses_collision_corners():
    data = _data("pillar_levels")
    ready = data.gameready
    j = 3
    corners = ready["collision_vertices"][ready["collision_part_offsets"][ready["collision_fragment_offsets"][j]]]
    assert nearest_fragment(data, range(data.p), corners) == j
    child = data.p + 2
    b = lv.body_holding(data, child)
    view = lv.body_view(data, b)
    local = child - lv.children_range(data, b).start
    corner = view.gameready["collision_vertices"][view.gameready["collision_part_offsets"][
        view.gameready["collision_fragment_offsets"][local]]]
    assert nearest_fragment(data, lv.children_range(data, b), corner) == child


def test_roundtrip_and_refusals(tmp_path):
    data = _data("levels_dyadic")
    header, binary = encode(data, "x.fracture.bin")
    again = decode(header, binary)
    assert again.child_names == data.child_names and again.levels_info == data.levels_info
    assert encode(again, "x.fracture.bin") == (header, binary)
    doc = json.loads(header)
    doc["features"] = ["stress"]  # levels arrays without the feature: ignored, a plain file (with stress: refused)
    with pytest.raises(InputError):
        decode(json.dumps(doc).encode(), binary)
    broken = dataclasses.replace(data, levels={**data.levels, "parent": np.array(data.levels["parent"][::-1])})
    with pytest.raises(ValueError, match="parent"):
        encode(broken, "x.fracture.bin")
