"""Damage that adds up, anchors and cracks in the Python reader (docs/FORMAT.md section 12)."""

from __future__ import annotations

import dataclasses
import math
import os

import numpy as np
import pytest
from engine_support import CONFORMANCE, bits_to_float, impact_inputs, load_vectors, vector_names

from fracture_cli.errors import ImpactArgumentError, RuntimeFileError
from fracture_cli.runtime.damage import check_state, hit, new_state, state_from_bytes, state_to_bytes
from fracture_cli.runtime.format import decode, encode, load_runtime
from fracture_cli.runtime.impact import project_impact
from fracture_cli.runtime.structure import crack_segments_of

SEQUENCE_FILES = [name for name in vector_names(("anchors", "damage", "stress")) if "sequences" in load_vectors(name)]
HEALTH_TOLERANCE = 1e-9  # docs/FORMAT.md section 12.5


def _data(name: str):
    return load_runtime(os.path.join(CONFORMANCE, f"{name}.fracture.json"))


def test_every_structure_file_has_sequences():
    assert set(SEQUENCE_FILES) == {"structure_dyadic", "damage_stress", "random_structure", "pillar_structure"}


@pytest.mark.parametrize("name", SEQUENCE_FILES)
def test_sequences_of_hits_give_the_expected_states(name):
    data = _data(name)
    problems = []
    for seq in load_vectors(name)["sequences"]:
        state = new_state(data) if seq["start"] is None else np.array([bits_to_float(b) for b in seq["start"]])
        for h in seq["hits"]:
            before = state.copy()
            try:
                result = hit(data, state, *impact_inputs(h))
            except ImpactArgumentError:
                if h["expect"] != "error":
                    problems.append(f"{seq['name']} / {h['name']}: unexpected error")
                if not np.array_equal(state, before):
                    problems.append(f"{seq['name']} / {h['name']}: a refused hit changed the state")
                continue
            if h["expect"] == "error":
                problems.append(f"{seq['name']} / {h['name']}: expected an error")
                continue
            want = np.array([bits_to_float(b) for b in h["health"]])
            got = (result.site, result.groups.tolist(), result.broken.nonzero()[0].tolist(),
                   result.cracked.nonzero()[0].tolist(), result.anchored.astype(int).tolist())
            if got != (h["site"], h["groups"], h["broken"], h["cracked"], h["anchored"]):
                problems.append(f"{seq['name']} / {h['name']}: answers differ")
            if np.max(np.abs(state - want), initial=0.0) > HEALTH_TOLERANCE:
                problems.append(f"{seq['name']} / {h['name']}: health differs by {np.max(np.abs(state - want))}")
    assert not problems, problems


def test_dyadic_healths_are_exact():
    """structure_dyadic's first sequence: bond 2 at load 0.8 loses 0.3 per hit; the fourth hit breaks it."""
    data = _data("structure_dyadic")
    state = new_state(data)
    healths = []
    for _ in range(5):
        result = hit(data, state, (0, 0, 0), (1, 0, 0), 0.78125)
        healths.append(float(state[2]))
    loss = 1.0 * (0.625 / 0.78125 - 0.5)  # q (a / b - c), each step rounded as the spec orders it
    assert healths == [1 - loss, 1 - loss - loss, 1 - loss - loss - loss, 0.0, 0.0]
    assert result.broken.nonzero()[0].tolist() == [2] and not result.cracked.any()
    assert result.num_groups == 1  # bond 2 closes a cycle: nothing comes off


def test_the_top_falls_and_the_foot_stays_anchored():
    data = _data("structure_dyadic")
    result = project_impact(data, (0, 4, 0), (0, 8, 0), 2.0)
    assert result.groups.tolist() == [0, 0, 0, 3, 4]
    assert result.anchored.tolist() == [True, True, True, False, False]


def test_the_stateless_call_is_a_hit_on_a_fresh_state():
    data = _data("random_structure")
    rng = np.random.default_rng(5)
    for _ in range(20):
        point = data.sites[rng.integers(data.num_sites)].astype(float)
        impulse = rng.normal(size=3) * 3
        fresh = project_impact(data, point, impulse)
        state = new_state(data)
        stateful = hit(data, state, point, impulse)
        assert np.array_equal(fresh.broken, stateful.broken) and np.array_equal(fresh.cracked, stateful.cracked)
        assert np.array_equal(fresh.groups, stateful.groups) and np.array_equal(fresh.anchored, stateful.anchored)


def test_repeated_light_hits_break_what_one_strong_hit_breaks():
    """Below the strength a hit only cracks; at most ceil(1 / (q (L - c))) such hits break the bond.

    (pillar_structure is stone-like: c 0.5, r 0.25.)
    """
    data = _data("pillar_structure")
    point, direction = data.sites[500].astype(float), np.array([1.0, 0.0, 0.0])
    assert project_impact(data, point, direction * 1e3).broken.any()
    scale = 1.0
    while not project_impact(data, point, direction * scale * 1.05).broken.any():
        scale *= 1.05
    light = direction * scale * 0.95  # the most loaded bond between 0.95 / 1.05 and 0.95 of its strength
    state = new_state(data)
    first = hit(data, state, point, light)
    assert first.cracked.any() and not first.broken.any()
    hits = 1
    while not hit(data, state, point, light).broken.any():
        hits += 1
        assert hits < 100
    c, r = data.damage["crack_level"], data.damage["damage_rate"]
    least_load = 0.95 / 1.05
    assert 2 <= hits + 1 <= math.ceil(1 / (r / (1 - c) * (least_load - c)))


def test_health_never_comes_back():
    data = _data("random_structure")
    state = new_state(data)
    rng = np.random.default_rng(9)
    previous = state.copy()
    for _ in range(30):
        hit(data, state, data.sites[rng.integers(data.num_sites)].astype(float), rng.normal(size=3) * 2)
        assert np.all(state <= previous)
        previous = state.copy()


def test_states_are_checked_and_round_trip_through_bytes():
    data = _data("structure_dyadic")
    state = new_state(data)
    hit(data, state, (0, 0, 0), (1, 0, 0), 0.78125)
    assert np.array_equal(state_from_bytes(data, state_to_bytes(state)), state)
    for bad in (np.ones(4), np.ones(5, np.float32), np.array([1, 1, np.nan, 1, 1.0]), np.array([1, 1, 1.5, 1, 1.0]),
                np.array([1, 1, -0.5, 1, 1.0])):
        with pytest.raises(ImpactArgumentError):
            check_state(data, bad)
    with pytest.raises(ImpactArgumentError, match="40 bytes"):
        state_from_bytes(data, b"\0" * 8)
    before = state.copy()
    with pytest.raises(ImpactArgumentError):
        hit(data, state, (0, 0, 0), (math.nan, 0, 0))
    assert np.array_equal(state, before)


def test_files_without_damage_keep_their_bytes_and_answers():
    """A version-1 file has no cracks or anchors; a state on it only remembers broken bonds (c = 1, r = 0)."""
    data = _data("pillar")
    assert data.version == 1 and data.features == ()
    result = project_impact(data, data.sites[10].astype(float), (0, 50, 0))
    assert not result.cracked.any() and not result.anchored.any()
    state = new_state(data)
    hit(data, state, data.sites[10].astype(float), (0, 50, 0))
    assert set(np.unique(state)) <= {0.0, 1.0}
    assert np.array_equal(state == 0, result.broken)


def test_structure_fields_round_trip_and_are_validated():
    data = _data("structure_dyadic")
    header, binary = encode(data, "x.fracture.bin")
    again = decode(header, binary)
    assert again.features == ("anchors", "damage") and again.version == 2
    assert again.anchored.tolist() == [1, 0, 0, 0, 0] and again.damage == {"crack_level": 0.5, "damage_rate": 0.5}
    assert crack_segments_of(again.cracks, 0).shape == (2, 2, 3)
    assert crack_segments_of(again.cracks, 1).shape == (0, 2, 3)
    for change, message in ((dict(anchored=np.array([1, 0, 2, 0, 0], np.int32)), "only 0 and 1"),
                            (dict(damage={"crack_level": 0.0, "damage_rate": 1.0}), "crack_level"),
                            (dict(damage={"crack_level": 0.5, "damage_rate": -1.0}), "damage_rate"),
                            (dict(cracks={"crack_ptr": data.cracks["crack_ptr"]}), "come together")):
        with pytest.raises(ValueError, match=message):
            encode(dataclasses.replace(data, **change), "x.fracture.bin")
    with pytest.raises(RuntimeFileError):
        decode(header.replace(b'"damage_rate": 0.5', b'"damage_rate": -0.5'), binary)
