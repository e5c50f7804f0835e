"""fracture_cli.geometry.scenes: one surface query (hierarchy) per surface, kept while its arrays live."""

from __future__ import annotations

import gc

import numpy as np
import trimesh

from fracture_cli.geometry import scenes


def test_same_arrays_same_scene_and_forgotten_with_them():
    mesh = trimesh.creation.icosphere(1)
    V, F = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    first = scenes.surface_scene(V, F)
    assert scenes.surface_scene(V, F) is first
    assert scenes.surface_scene(V.copy(), F) is not first  # a copy is other arrays
    V2 = V.copy()
    second = scenes.surface_scene(V2, F)
    assert scenes.surface_scene(V2, F) is second
    del V2
    gc.collect()
    assert scenes._last == {}  # the scene went with its arrays


def test_scene_answers_like_a_new_one():
    mesh = trimesh.creation.icosphere(2)
    V, F = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    from fracture_cli.geometry import surface_query

    points = np.random.default_rng(0).normal(size=(200, 3))
    shared = scenes.surface_scene(V, F)
    surface_query.distances(shared, points)
    fresh = surface_query.build(V, F)
    assert np.array_equal(surface_query.inside(scenes.surface_scene(V, F), points), surface_query.inside(fresh, points))
    assert np.array_equal(surface_query.distances(shared, points), surface_query.distances(fresh, points))
