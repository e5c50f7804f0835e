"""The atlas on files with levels: its exact analysis of a hit says what the runtime's ``hit_piece`` does."""

from __future__ import annotations

import os

import numpy as np

from fracture_cli.atlas.criterion import criterion_named
from fracture_cli.atlas.hits import rest_groups
from fracture_cli.atlas.layout import fragment_layout
from fracture_cli.atlas.leaves import leaves_at
from fracture_cli.atlas.sweep import atlas_figures, farthest_point_sites, just_above, sweep_hits
from fracture_cli.runtime import levelstate
from fracture_cli.runtime.format import load_runtime
from fracture_cli.runtime.levels import body_view, children_range, num_bodies, num_fragments

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFORMANCE = os.path.join(REPO, "tests", "data", "runtime_conformance")


def _leaf_volumes(data) -> np.ndarray:
    volumes = np.zeros(num_fragments(data))
    volumes[: data.p] = fragment_layout(data).volumes
    for body in range(1, num_bodies(data)):
        span = children_range(data, body)
        volumes[span.start: span.stop] = fragment_layout(body_view(data, body)).volumes
    return volumes


def test_leaves_just_above_d1_are_the_runtime_pieces():
    """Every hit of a sweep on a baked pillar with levels (the conformance file, with collision parts)."""
    data = load_runtime(os.path.join(CONFORMANCE, "pillar_levels.fracture.json"))
    assert data.levels
    layout = fragment_layout(data)
    hits = sweep_hits(data, layout, farthest_point_sites(data.sites, 60), criterion_named("modes"))
    rest = rest_groups(data)
    volumes = _leaf_volumes(data)
    checked = split = 0
    for h in hits:
        if not np.isfinite(h.d1) or h.struck is None:
            continue
        magnitude = just_above(h.d1)
        leaves = leaves_at(data, layout, h, magnitude, rest)
        state = levelstate.new_object_state(data)
        outcome = levelstate.hit_piece(data, state, h.struck, h.hit.point, h.hit.direction * magnitude)
        pieces = levelstate.shown_pieces(data, state)
        assert len(pieces) >= 2  # just above d1 something has come off
        heaviest = max(pieces, key=lambda piece: (float(volumes[list(piece.fragments)].sum()), -piece.fragments[0]))
        shown = [g for piece in pieces for g in piece.fragments]
        expected = {g for g in shown if g not in heaviest.fragments}
        # leaves_at orders the shown leaves as level-1 fragments without the split one, then its children
        order = [g for g in range(data.p) if g in shown] + sorted(g for g in shown if g >= data.p)
        assert {order[i] for i in np.flatnonzero(leaves.detached)} == expected
        assert outcome.split == h.split(magnitude)
        split += outcome.split
        checked += 1
    assert checked >= 20 and split >= 1  # both kinds of first detachment occur


def test_figures_without_children_are_the_level_one_figures():
    data = load_runtime(os.path.join(CONFORMANCE, "pillar_levels.fracture.json"))
    layout = fragment_layout(data)
    hits = sweep_hits(data, layout, farthest_point_sites(data.sites, 40))
    plain = tuple(type(h)(hit=h.hit, struck=h.struck) for h in hits)  # the same hits, children ignored
    with_children, level_one = atlas_figures(data, layout, hits), atlas_figures(data, layout, plain)
    assert level_one.detaching_hits <= with_children.detaching_hits
    assert with_children.b0_median <= level_one.b0_median
