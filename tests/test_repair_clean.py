"""Repair's fast path (stages/repair/clean.py): it accepts only what the full repair keeps as given."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from fracture_cli.io.read import surface_from_trimesh
from fracture_cli.stages import repair as repair_module
from fracture_cli.stages.repair import repair_surface
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
