"""Material weights eta: grain anisotropy, painted strength, boxes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fracture_cli.errors import RecipeError
from fracture_cli.stages.material import MaterialOptions, material
from fracture_cli.testing import grid_tetmesh


def test_default_is_all_ones():
    mesh = grid_tetmesh((2, 2, 2))
    eta = material(mesh, None, MaterialOptions())
    assert eta.shape == (len(mesh.interior_faces),)
    np.testing.assert_array_equal(eta, 1.0)


def test_grain_makes_cross_grain_faces_expensive():
    mesh = grid_tetmesh((2, 2, 2))
    eta = material(mesh, None, MaterialOptions(grain_axis="z", grain_strength=10.0))
    nz = np.abs(mesh.interior_face_normals[:, 2])
    assert np.all(eta[nz > 0.999] == pytest.approx(10.0))  # faces cutting across z
    assert np.all(eta[nz < 1e-9] == pytest.approx(1.0))  # faces along the grain


def test_boxes_scale_faces_inside_only():
    mesh = grid_tetmesh((4, 1, 1), spacing=1.0)
    box = {"name": "end", "min": [2.5, -1, -1], "max": [5, 2, 2], "strength": 100.0}
    eta = material(mesh, None, MaterialOptions(boxes=[box]))
    centroids = mesh.vertices[mesh.interior_faces].mean(axis=1)
    assert np.all(eta[centroids[:, 0] > 2.5] == 100.0)
    assert np.all(eta[centroids[:, 0] < 2.5] == 1.0)


def test_bad_box_is_a_recipe_error():
    mesh = grid_tetmesh((1, 1, 1))
    with pytest.raises(RecipeError, match="boxes\\[0\\]"):
        material(mesh, None, MaterialOptions(boxes=[{"name": "b", "min": [1, 1, 1], "max": [0, 0, 0], "strength": 2}]))


def test_strength_channel_needs_colours():
    mesh = grid_tetmesh((1, 1, 1))
    with pytest.raises(RecipeError, match="no vertex colours"):
        material(mesh, None, MaterialOptions(strength_channel="r", strength_max=10.0))


def test_strength_channel_interpolates_geometrically():
    from fracture_cli.types import Material, Normalization, SurfaceMesh

    mesh = grid_tetmesh((2, 1, 1), spacing=1.0)
    V = mesh.vertices
    colors = np.zeros((len(V), 4))
    colors[:, 0] = (V[:, 0] > 1.0).astype(float)  # red on the right half
    surface = SurfaceMesh(vertices=V, faces=mesh.boundary_faces, uvs=None, normals=None, colors=colors,
                          material_ids=np.zeros(len(mesh.boundary_faces), np.int32), materials=(Material("m"),),
                          normalization=Normalization.identity())
    opts = dataclasses.replace(MaterialOptions(), strength_channel="r", strength_min=1.0, strength_max=100.0)
    eta = material(mesh, surface, opts)
    assert eta.min() == pytest.approx(1.0) and eta.max() == pytest.approx(100.0)
