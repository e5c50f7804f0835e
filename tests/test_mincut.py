"""The exact min-cut of the modes' pricing (fracture_cli.discontinuity.mincut) against brute force.

``MinCut.source_side`` returns the minimal set S minimising ``w(boundary of S) - supply(S)``.
OR-Tools solves it in a one-arc form (each face one arc of twice its weight, its weight shifted
onto the terminal arcs: every cut changes by the same constant) or, when those shifted
capacities could overflow, in the two-arc form; scipy in the two-arc form. All three must give
the brute-force answer: the intersection of all minimisers (they are closed under intersection).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from fracture_cli.discontinuity.mincut import MinCut

pytest.importorskip("ortools", reason="OR-Tools is not installed: only the scipy max-flow can be checked")


def _brute_force(faces, omega, supply, t):
    """The minimal minimiser of w(boundary of S) - supply(S) over all node sets S (sorted ids)."""
    best, minimisers = None, []
    for bits in itertools.product([False, True], repeat=t):
        inside = np.array(bits)
        value = omega[inside[faces[:, 0]] != inside[faces[:, 1]]].sum() - supply[inside].sum()
        if best is None or value < best - 1e-9:
            best, minimisers = value, [inside]
        elif abs(value - best) <= 1e-9:
            minimisers.append(inside)
    return np.flatnonzero(np.logical_and.reduce(minimisers))


@pytest.mark.parametrize("seed", range(40))
def test_small_graphs_with_ties_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    t = int(rng.integers(3, 11))
    pairs = np.array([(a, b) for a in range(t) for b in range(a + 1, t)])
    faces = pairs[rng.random(len(pairs)) < 0.5]
    if len(faces) == 0:
        faces = pairs[:1]
    # Small integer weights and supplies (many ties), the positive supply a power of two so that
    # every backend's integer scaling is exact.
    omega = rng.integers(1, 4, len(faces)).astype(np.float64)
    supply = rng.integers(-3, 4, t).astype(np.float64)
    positive = supply > 0
    if not positive.any():
        supply[0], positive[0] = 1.0, True
    supply[np.flatnonzero(positive)[0]] += 2.0 ** np.ceil(np.log2(supply[positive].sum())) - supply[positive].sum()
    expected = _brute_force(faces, omega, supply, t)
    for backend in ("ortools", "scipy"):
        side = MinCut(faces, omega, t, backend=backend).source_side(supply)
        np.testing.assert_array_equal(side, expected, err_msg=backend)


def test_unbreakable_faces_take_the_two_arc_form(monkeypatch):
    # A star of 200 faces of weight 1e12 (their shifted terminal capacities would overflow int64)
    # and one breakable face to leaf 200, which alone has enough supply to leave.
    leaves = 201
    faces = np.column_stack([np.zeros(leaves - 1, dtype=np.int64), np.arange(1, leaves)])
    omega = np.full(leaves - 1, 1e12)
    omega[-1] = 1.0
    supply = np.zeros(leaves)
    supply[0], supply[-1] = -2.0, 3.0
    calls = []
    two_arc = MinCut._two_arc_side
    monkeypatch.setattr(MinCut, "_two_arc_side", lambda self, *a: calls.append(1) or two_arc(self, *a))
    for backend in ("ortools", "scipy"):
        side = MinCut(faces, omega, leaves, backend=backend).source_side(supply)
        np.testing.assert_array_equal(side, [leaves - 1], err_msg=backend)
    assert calls == [1]  # OR-Tools fell back to the two-arc form; scipy always uses it
