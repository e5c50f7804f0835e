"""Repair's fast path (stages/repair/clean.py): it accepts only what the full repair keeps as given."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from fracture_cli.stages.load.read import surface_from_trimesh
from fracture_cli.stages.repair import repair_surface
from fracture_cli.stages.repair import solid as repair_module
from fracture_cli.stages.repair.clean import closed_as_given


def _surface(V, F, name="mesh"):
    return surface_from_trimesh(trimesh.Trimesh(np.asarray(V, float), np.asarray(F), process=False), name)


def _variants():
    m = trimesh.creation.icosphere(2)
    V, F = m.vertices, m.faces
    n = len(V)
    flipped = F.copy()
    flipped[3] = flipped[3, ::-1]
    pinch = np.vstack([V, -V + 2 * V[0]])
    pinch_faces = np.vstack([F, np.where(F[:, ::-1] + n == n, 0, F[:, ::-1] + n)])
    return {
        "clean": (V, F, True),
        "inside_out": (V, F[:, ::-1], False),
        "one_face_flipped": (V, flipped, False),
        "open": (V, F[1:], False),
        "two_bodies": (np.vstack([V, V + 5]), np.vstack([F, F + n]), False),
        "cavity": (np.vstack([V, 0.3 * V]), np.vstack([F, F[:, ::-1] + n]), False),
        "repeated_position": (np.vstack([V, V[:1]]), F, False),
        "pinched_vertex": (pinch, pinch_faces, False),
        "repeated_face": (V, np.vstack([F, F[:1]]), False),
        "unused_vertex": (np.vstack([V, V[:1] + 1e-3]), F, True),
    }


@pytest.mark.parametrize("name", list(_variants()))
def test_fast_path_agrees_with_full_repair(name, monkeypatch):
    V, F, expected = _variants()[name]
    surface = _surface(V, F, name)
    ok, volume = closed_as_given(surface)
    assert ok is expected
    # The full repair, fast path off: it keeps exactly the surfaces the fast path accepts, recording nothing.
    monkeypatch.setattr(repair_module, "closed_as_given", lambda s: (False, 0.0))
    full = repair_surface(surface)
    kept = full.surface is surface and [r.what for r in full.records] == ["decision"]
    if ok:
        assert kept and volume > 0
    monkeypatch.undo()
    fast = repair_surface(surface)
    if ok:
        assert fast.surface is surface and fast.records == full.records


def test_normal_against_its_faces_takes_full_repair():
    m = trimesh.creation.icosphere(2)
    surface = _surface(m.vertices, m.faces)
    normals = surface.normals.copy()
    normals[2] *= -1.0
    assert not closed_as_given(dataclasses.replace(surface, normals=normals))[0]


def _numpy_checks(F):
    """The fast path's numpy checks before it used the compiled ones (closed and wound alike, one fan per
    vertex, one body), as a reference: the verdicts must not change."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n, m = int(F.max()) + 1, len(F)
    a, b = F.reshape(-1), F[:, [1, 2, 0]].reshape(-1)
    lo = np.minimum(a, b)
    key = lo * np.int64(n) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    ordered = key[order]
    first, second = order[0::2], order[1::2]
    if len(first) != len(second) or not np.array_equal(ordered[0::2], ordered[1::2]):
        return False, False, False
    if (ordered[2::2] == ordered[1:-1:2]).any() or ((a[first] == lo[first]) == (a[second] == lo[second])).any():
        return False, False, False
    twin = np.empty(len(a), dtype=np.int64)
    twin[first], twin[second] = second, first
    step = 3 * (twin // 3) + (twin % 3 + 1) % 3
    graph = sp.csr_matrix((np.ones(3 * m, dtype=np.int8), step, np.arange(3 * m + 1)), shape=(3 * m, 3 * m))
    fans = connected_components(graph, directed=True, connection="weak")[0] == len(np.unique(F))
    graph = sp.csr_matrix((np.ones(3 * m, dtype=np.int8), twin // 3, np.arange(0, 3 * m + 1, 3)), shape=(m, m))
    return True, fans, connected_components(graph, directed=True, connection="weak")[0] == 1


def _topology_cases():
    sphere = trimesh.creation.icosphere(2).faces
    n = int(sphere.max()) + 1
    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    fin = np.where(tet == 2, 4, np.where(tet == 3, 5, tet))  # a second tetrahedron on the edge 0-1
    cone = trimesh.creation.cone(1.0, 1.0, sections=12)
    apex = int(np.argmax(cone.vertices[:, 2]))
    other = cone.faces + len(cone.vertices)
    other[other == apex + len(cone.vertices)] = apex  # a second cone sharing only the apex
    flipped = sphere.copy()
    flipped[7] = flipped[7, ::-1]
    return {  # (faces, closed and wound alike, one fan per vertex, one body)
        "closed": (sphere, True, True, True),
        "inside_out": (sphere[:, ::-1], True, True, True),
        "open": (sphere[1:], False, None, None),
        "edge_with_four_faces": (np.vstack([tet, fin]), False, None, None),
        "cones_at_a_vertex": (np.vstack([cone.faces, other]), True, False, False),  # a vertex does not join faces
        "inconsistently_wound": (flipped, False, None, None),
        "two_bodies": (np.vstack([sphere, sphere + n]), True, True, False),
    }


@pytest.mark.parametrize("name", list(_topology_cases()))
def test_compiled_checks_give_the_numpy_verdicts(name):
    from fracture_cli.geometry import trigeom

    F, closed, fans, one_body = _topology_cases()[name]
    F = np.asarray(F, dtype=np.int64)
    reference = _numpy_checks(F)
    assert reference[0] == trigeom.edge_manifold_closed(F) == closed
    if closed:  # the other two tests assume a closed, consistently wound mesh (as the fast path asks them)
        assert reference[1] == trigeom.vertex_manifold(F) == fans
        assert reference[2] == (trigeom.face_components(F) == 1) == one_body
    assert trigeom.face_components(F) == {"two_bodies": 2, "cones_at_a_vertex": 2}.get(name, 1)
