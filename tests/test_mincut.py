"""The exact min-cut of the modes' pricing (fracture_cli.stages.modes.solver.mincut) against brute force.

``MinCut.source_side`` returns the minimal set S minimising ``w(boundary of S) - supply(S)``.
The compiled kernel (fracture_cli.stages.modes.solver.maxflow_kernel) solves it in the two-arc form;
OR-Tools in a one-arc form (each face one arc of twice its weight, its weight shifted onto the
terminal arcs: every cut changes by the same constant) or, when those shifted capacities could
overflow, in the two-arc form; scipy in the two-arc form. All must give the brute-force answer:
the intersection of all minimisers (they are closed under intersection).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from fracture_cli.stages.modes.solver import maxflow_kernel
from fracture_cli.stages.modes.solver.mincut import MinCut

pytest.importorskip("ortools", reason="OR-Tools is not installed: only the scipy max-flow can be checked")


def _brute_force(faces, omega, supply, t):
    """The minimal minimiser of w(boundary of S) - supply(S) over all node sets S (sorted ids).

    Exact in Python integers when ``omega`` and ``supply`` are integer arrays (ties then exact).
    """
    exact = omega.dtype.kind == "i" and supply.dtype.kind == "i"
    omega_list, supply_list = [int(x) for x in omega], [int(x) for x in supply]
    best, minimisers = None, []
    for bits in itertools.product([False, True], repeat=t):
        inside = np.array(bits)
        cut = np.flatnonzero(inside[faces[:, 0]] != inside[faces[:, 1]])
        if exact:
            value = sum(omega_list[f] for f in cut) - sum(supply_list[v] for v in np.flatnonzero(inside))
        else:
            value = omega[cut].sum() - supply[inside].sum()
        tol = 0 if exact else 1e-9
        if best is None or value < best - tol:
            best, minimisers = value, [inside]
        elif abs(value - best) <= tol:
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
    for backend in ("kernel", "ortools", "scipy"):
        side = MinCut(faces, omega, t, backend=backend).source_side(supply)
        np.testing.assert_array_equal(side, expected, err_msg=backend)


def test_auto_prefers_the_kernel():
    faces = np.array([[0, 1]])
    assert MinCut(faces, np.ones(1), 2).backend == "kernel"


def _kernel_side(faces, capacity, supply, t):
    """The compiled kernel's cut, straight (no scaling, no node order): sorted ids, certified."""
    first, head, sister, face = maxflow_kernel.arc_structure(faces[:, 0].astype(np.int32),
                                                             faces[:, 1].astype(np.int32), t)
    side, certified = maxflow_kernel.source_side(first, head, sister, face, capacity.astype(np.int64),
                                                 supply.astype(np.int64))
    assert certified
    return side


@pytest.mark.parametrize("seed", range(60))
def test_kernel_matches_brute_force_on_awkward_graphs(seed):
    # Random graphs on up to 11 nodes with the awkward cases of the pricing and beyond: faces in either
    # order (lo > hi), zero capacities, nodes without terminal arcs or without faces, several components,
    # many ties (small integers), or capacities and supplies near 2**53 (exact integer arithmetic).
    rng = np.random.default_rng(1000 + seed)
    t = int(rng.integers(1, 12))
    pairs = np.array([(a, b) for a in range(t) for b in range(t) if a != b], dtype=np.int64).reshape(-1, 2)
    faces = pairs[rng.random(len(pairs)) < rng.uniform(0.05, 0.4)]
    if seed % 3 == 0:  # no faces at all on the last node(s)
        faces = faces[(faces < t - 2).all(axis=1)] if t > 3 else faces
    big = seed % 4 == 3
    scale = 2**53 if big else 4
    capacity = rng.integers(0, scale, len(faces), dtype=np.int64)
    capacity[rng.random(len(faces)) < 0.2] = 0
    supply = rng.integers(-scale, scale, t, dtype=np.int64)
    supply[rng.random(t) < 0.3] = 0
    if big:
        supply = supply // 4  # every cut, and the flow, stays below 2**62
        capacity[rng.random(len(faces)) < 0.3] = 2**53
    np.testing.assert_array_equal(_kernel_side(faces, capacity, supply, t),
                                  _brute_force(faces, capacity, supply, t))


def test_kernel_edge_cases():
    # No faces, no supply: empty; all supply, no sink: everything with a path from a source; a lone sink.
    no_faces = np.zeros((0, 2), dtype=np.int64)
    assert len(_kernel_side(no_faces, np.zeros(0), np.zeros(3), 3)) == 0
    np.testing.assert_array_equal(_kernel_side(no_faces, np.zeros(0), np.array([1, 0, -1]), 3), [0])
    path = np.array([[0, 1], [1, 2], [3, 4]])
    np.testing.assert_array_equal(_kernel_side(path, np.array([5, 5, 5]), np.array([1, 0, 0, 0, 2]), 5),
                                  [0, 1, 2, 3, 4])
    # A tie: the source side {0} and {0, 1} both cost 1; the minimal one is returned.
    np.testing.assert_array_equal(_kernel_side(np.array([[0, 1], [1, 2]]), np.array([1, 1]),
                                               np.array([2, 0, -2]), 3), [0])
    maxflow_kernel.warm_kernels()


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
    # The kernel has no terminal shifts to overflow: the same cut, in its own form.
    side = MinCut(faces, omega, leaves, backend="kernel").source_side(supply)
    np.testing.assert_array_equal(side, [leaves - 1])
