"""Mass properties of closed meshes against analytic values and trimesh."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from fracture_cli.geometry.mass import mass_properties, principal_axes, quaternion_xyzw


def _box(extents, center=(0.0, 0.0, 0.0)):
    mesh = trimesh.creation.box(extents=extents)
    return np.asarray(mesh.vertices) + np.asarray(center), np.asarray(mesh.faces)


def _rotation(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]


def test_box_matches_analytic_values():
    a, b, c = 2.0, 3.0, 5.0
    props = mass_properties(*_box((a, b, c)))
    m = a * b * c
    assert props.volume == pytest.approx(m, rel=1e-12)
    assert np.allclose(props.center, 0.0, atol=1e-12)
    expected = m / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    assert np.allclose(props.inertia, expected, rtol=1e-12, atol=1e-12)


def test_shifted_rotated_box_transforms_like_a_tensor():
    a, b, c = 1.0, 2.0, 0.5
    R = _rotation([1.0, 2.0, 3.0], 0.7)
    V, F = _box((a, b, c))
    far = np.array([1.0e4, -3.0e4, 2.0e4])  # far from the origin: precision comes from the local origin
    props = mass_properties(V @ R.T + far, F)
    m = a * b * c
    local = m / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    assert props.volume == pytest.approx(m, rel=1e-10)
    assert np.allclose(props.center, far, rtol=0, atol=1e-9)
    assert np.allclose(props.inertia, R @ local @ R.T, rtol=1e-9, atol=1e-10)
    moments, axes = props.principal()
    assert np.allclose(np.sort(moments), np.sort(np.diag(local)), rtol=1e-9)
    assert np.linalg.det(axes) == pytest.approx(1.0)
    assert np.allclose(axes @ np.diag(moments) @ axes.T, props.inertia, atol=1e-10)


def test_sphere_approaches_analytic_and_matches_trimesh():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.5)
    sphere.apply_translation([3.0, -2.0, 1.0])
    props = mass_properties(sphere.vertices, sphere.faces)
    # The polyhedron is slightly smaller than the sphere: compare with trimesh exactly, analytic loosely.
    assert props.volume == pytest.approx(sphere.volume, rel=1e-12)
    assert np.allclose(props.center, sphere.center_mass, atol=1e-12)
    assert np.allclose(props.inertia, sphere.moment_inertia, rtol=1e-10, atol=1e-12)
    r = 1.5
    analytic = 2.0 / 5.0 * (4.0 / 3.0 * np.pi * r ** 3) * r * r
    assert np.allclose(np.diag(props.inertia), analytic, rtol=0.01)


def test_cavity_subtracts():
    outer_v, outer_f = _box((2.0, 2.0, 2.0))
    inner_v, inner_f = _box((1.0, 1.0, 1.0))
    V = np.vstack([outer_v, inner_v])
    F = np.vstack([outer_f, inner_f[:, ::-1] + len(outer_v)])  # the cavity is oriented inward
    props = mass_properties(V, F)
    assert props.volume == pytest.approx(7.0)
    expected = (8.0 / 12.0 * 8.0 - 1.0 / 12.0 * 2.0) * np.eye(3)
    assert np.allclose(props.inertia, expected)


def test_quaternion_round_trip():
    for axis, angle in (([0, 0, 1], 0.0), ([1, 0, 0], np.pi), ([1, 1, 0], 2.5), ([0.3, -1, 2], -1.1)):
        R = _rotation(axis, angle)
        x, y, z, w = quaternion_xyzw(R)
        assert w >= 0
        back = trimesh.transformations.quaternion_matrix([w, x, y, z])[:3, :3]
        assert np.allclose(back, R, atol=1e-12)


def test_principal_axes_follow_the_model_axes():
    """An axis-aligned body gets the identity rotation, whatever the order of its moments."""
    for diagonal in ([3.0, 1.0, 2.0], [1.0, 1.0, 1.0], [2.0, 2.0, 5.0]):
        moments, axes = principal_axes(np.diag(diagonal) + 1e-15)
        assert np.allclose(moments, diagonal) and np.allclose(axes, np.eye(3))
    R = _rotation([0, 0, 1], 0.3)
    tensor = R @ np.diag([3.0, 1.0, 2.0]) @ R.T
    moments, axes = principal_axes(tensor)
    assert np.allclose(axes, R) and np.allclose(moments, [3.0, 1.0, 2.0])
    assert np.linalg.det(axes) == pytest.approx(1.0)


def test_empty_mesh_has_no_mass():
    props = mass_properties(np.zeros((3, 3)), np.zeros((0, 3), dtype=int))
    assert props.volume == 0.0 and not np.any(props.inertia)
