"""Fault simplification prototype: shared faults stay identical, fragments stay closed and valid."""

from __future__ import annotations

import manifold3d
import numpy as np
import pytest

from fracture_cli.gameready.mass import mass_properties
from fracture_cli.gameready.simplify import _valid, simplify_faults
from fracture_cli.types import Fragment, Fragments, Material, Normalization

OUTER, INTERIOR = 0, 1


def _fault_x(y: np.ndarray, bend: float) -> np.ndarray:
    return 1.0 + bend * np.sin(np.pi * y)


def _fragment(solid: manifold3d.Manifold, piece: int, bend: float) -> Fragment:
    mesh = solid.to_mesh64()
    V = np.array(mesh.vert_properties, dtype=float)[:, :3].copy()
    F = np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)
    T = V[F]
    on_fault = np.all(np.abs(T[:, :, 0] - _fault_x(T[:, :, 1], bend)) < 1e-9, axis=1)
    material = np.where(on_fault, INTERIOR, OUTER).astype(np.int32)
    return Fragment(vertices=V, faces=F, uvs=np.zeros((len(V), 2)), normals=np.zeros_like(V),
                    material_ids=material, piece=piece)


def _pair(bend: float = 0.0) -> Fragments:
    """Two cubes sharing the face x = 1 (finely triangulated, alike on both sides); ``bend`` curves it.

    The right cube is the mirror image of the left one, so their shared face has the same triangles;
    the bend moves points by ``bend sin(pi y)`` along x, fading to nothing at x = 0 and x = 2.
    """
    left = manifold3d.Manifold.cube([1.0, 1.0, 1.0]).refine(4)
    right = left.mirror([1.0, 0.0, 0.0]).translate([2.0, 0.0, 0.0])

    def warp(p):
        return [p[0] + bend * np.sin(np.pi * p[1]) * (1.0 - abs(p[0] - 1.0)), p[1], p[2]]

    frags = tuple(_fragment(solid.warp(warp) if bend else solid, k, bend) for k, solid in enumerate((left, right)))
    volume = sum(mass_properties(f.vertices, f.faces).volume for f in frags)
    return Fragments(fragments=frags, materials=(Material("outer"), Material("interior")),
                     normalization=Normalization.identity(), input_volume=volume)


def _fault(frag: Fragment) -> set:
    """The fault triangles as sets of corner positions (orientation-free)."""
    T = np.round(frag.vertices[frag.faces[frag.material_ids == INTERIOR]], 12)
    return {frozenset(map(tuple, t)) for t in T}


def _outer(frag: Fragment) -> np.ndarray:
    """The outer triangles' corners, rows sorted (order-free)."""
    return np.sort(np.round(frag.vertices[frag.faces[frag.material_ids == OUTER]], 12).reshape(-1, 9), axis=0)


def test_flat_fault_collapses_to_its_boundary():
    fragments = _pair()
    result, report = simplify_faults(fragments, tolerance=1e-3)
    assert report.fault_before == 64 and report.unmatched == 0 and report.patches == 1
    # 16 locked boundary vertices and 9 free ones: most of the free ones go (collinear boundary points
    # keep a few, since no collapse may leave a flat triangle).
    assert report.fault_after <= 40
    assert all(_valid(f) for f in result.fragments)
    assert _fault(result.fragments[0]) == _fault(result.fragments[1])
    for before, after in zip(fragments.fragments, result.fragments):
        assert mass_properties(after.vertices, after.faces).volume == pytest.approx(
            mass_properties(before.vertices, before.faces).volume, rel=1e-12)
        assert np.array_equal(_outer(before), _outer(after))  # outer faces untouched


def test_curved_fault_keeps_its_shape_within_the_tolerance():
    fragments = _pair(bend=0.2)
    tight, _ = simplify_faults(fragments, tolerance=1e-6)
    loose, report = simplify_faults(fragments, tolerance=0.05)
    assert report.fault_after < report.fault_before
    assert len(_fault(tight.fragments[0])) >= len(_fault(loose.fragments[0]))
    assert all(_valid(f) for f in loose.fragments)
    assert _fault(loose.fragments[0]) == _fault(loose.fragments[1])
    total = sum(mass_properties(f.vertices, f.faces).volume for f in loose.fragments)
    assert total == pytest.approx(fragments.input_volume, rel=1e-12)  # the partition is kept exactly


def test_zero_tolerance_changes_nothing():
    fragments = _pair(bend=0.2)
    result, report = simplify_faults(fragments, tolerance=0.0)
    assert report.fault_after == report.fault_before
    for before, after in zip(fragments.fragments, result.fragments):
        assert _fault(before) == _fault(after)
