"""Fault simplification: shared faults stay identical, fragments closed and valid, the outer surface the input's."""

from __future__ import annotations

import dataclasses
import json
import os

import manifold3d
import numpy as np
import pytest

from fracture_cli.geometry.mass import mass_properties
from fracture_cli.geometry.trigeom import point_triangle_distance
from fracture_cli.pipeline import STAGE_NAMES
from fracture_cli.pipeline.recipe import load_recipe
from fracture_cli.stages.simplify import SimplifyOptions, triangle_budget
from fracture_cli.stages.simplify.budget import Limits, shares
from fracture_cli.stages.simplify.faultmatch import bad_faces, pinched_positions
from fracture_cli.stages.simplify.faults import simplify_faults, valid
from fracture_cli.types import Fragment, Fragments, Material, Normalization, SurfaceMesh

from conftest import SAMPLE_ASSETS

OUTER, INTERIOR = 0, 1


def _uv(P: np.ndarray) -> np.ndarray:
    """The input's UVs: a linear function of position, so any point of the surface has a known UV."""
    return np.column_stack([P[:, 0] + 0.5 * P[:, 1], P[:, 2] - 0.25 * P[:, 0]])


def _fault_x(y: np.ndarray, z: np.ndarray, bend: float) -> np.ndarray:
    return 1.0 + bend * np.sin(np.pi * y) * np.sin(np.pi * z)


def _fragment(solid: manifold3d.Manifold, piece: int, bend: float) -> Fragment:
    mesh = solid.to_mesh64()
    V = np.array(mesh.vert_properties, dtype=float)[:, :3].copy()
    F = np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)
    T = V[F]
    on_fault = np.all(np.abs(T[:, :, 0] - _fault_x(T[:, :, 1], T[:, :, 2], bend)) < 1e-9, axis=1)
    material = np.where(on_fault, INTERIOR, OUTER).astype(np.int32)
    return Fragment(vertices=V, faces=F, uvs=_uv(V), normals=np.zeros_like(V), material_ids=material, piece=piece)


def _pair(bend: float = 0.0) -> tuple[Fragments, SurfaceMesh]:
    """Two cubes sharing the face x = 1 (finely triangulated, alike on both sides); ``bend`` curves it.

    The right cube is the mirror image of the left one, so their shared face has the same triangles;
    the bend moves points by ``bend sin(pi y) sin(pi z)`` along x, fading to nothing at x = 0 and x = 2. The input
    is the box [0, 2] x [0, 1] x [0, 1] (12 triangles).
    """
    left = manifold3d.Manifold.cube([1.0, 1.0, 1.0]).refine(8)
    right = left.mirror([1.0, 0.0, 0.0]).translate([2.0, 0.0, 0.0])

    def warp(p):
        return [p[0] + bend * np.sin(np.pi * p[1]) * np.sin(np.pi * p[2]) * (1.0 - abs(p[0] - 1.0)), p[1], p[2]]

    frags = tuple(_fragment(solid.warp(warp) if bend else solid, k, bend) for k, solid in enumerate((left, right)))
    volume = sum(mass_properties(f.vertices, f.faces).volume for f in frags)
    box = manifold3d.Manifold.cube([2.0, 1.0, 1.0]).to_mesh64()
    V = np.array(box.vert_properties, dtype=float)[:, :3].copy()
    F = np.array(box.tri_verts, dtype=np.int64).reshape(-1, 3)
    surface = SurfaceMesh(vertices=V, faces=F, uvs=_uv(V), normals=None, colors=None,
                          material_ids=np.zeros(len(F), dtype=np.int32), materials=(Material("outer"),),
                          normalization=Normalization.identity())
    fragments = Fragments(fragments=frags, materials=(Material("outer"), Material("interior")),
                          normalization=Normalization.identity(), input_volume=volume)
    return fragments, surface


def _fault(frag: Fragment) -> set:
    """The fault triangles as sets of corner positions (orientation-free)."""
    T = np.round(frag.vertices[frag.faces[frag.material_ids == INTERIOR]], 12)
    return {frozenset(map(tuple, t)) for t in T}


def _check_outer(before: Fragments, after: Fragments) -> None:
    """Outer faces on the input box with its UVs, and covering what they covered."""
    for old, new in zip(before.fragments, after.fragments):
        outer = new.faces[new.material_ids == OUTER]
        P = new.vertices[np.unique(outer)]
        on_box = np.min(np.column_stack([P, 1.0 - P[:, 1:], 2.0 - P[:, :1]]), axis=1)
        assert np.abs(on_box).max() < 1e-12
        np.testing.assert_allclose(new.uvs[np.unique(outer)], _uv(P), atol=1e-12)

        def area(f: Fragment) -> float:
            T = f.vertices[f.faces[f.material_ids == OUTER]]
            return float(np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1).sum() / 2)

        assert area(new) == pytest.approx(area(old), rel=1e-12)


def test_flat_fault_collapses_to_a_few_triangles():
    fragments, surface = _pair()
    result, report = simplify_faults(fragments, surface, tolerance=1e-3)
    assert report.fault_before == 256 and report.unmatched == 0 and report.patches == 1
    assert report.fault_after <= 8  # a flat square: a few triangles per side once its edges are straight
    assert report.triangles_after < report.triangles_before / 4
    assert all(valid(f) for f in result.fragments)
    assert _fault(result.fragments[0]) == _fault(result.fragments[1])
    for before, after in zip(fragments.fragments, result.fragments):
        assert mass_properties(after.vertices, after.faces).volume == pytest.approx(
            mass_properties(before.vertices, before.faces).volume, rel=1e-12)
    _check_outer(fragments, result)


def test_curved_fault_keeps_its_shape_within_the_tolerance():
    fragments, surface = _pair(bend=0.2)
    tight, _ = simplify_faults(fragments, surface, tolerance=1e-6)
    loose, report = simplify_faults(fragments, surface, tolerance=0.02)
    assert report.fault_after < report.fault_before
    assert len(_fault(tight.fragments[0])) >= len(_fault(loose.fragments[0]))
    assert all(valid(f) for f in loose.fragments)
    assert _fault(loose.fragments[0]) == _fault(loose.fragments[1])
    total = sum(mass_properties(f.vertices, f.faces).volume for f in loose.fragments)
    assert total == pytest.approx(fragments.input_volume, rel=1e-12)  # the partition is kept exactly
    # Every vertex of the cut fault lies within the tolerance of the simplified one.
    old = fragments.fragments[0]
    points = np.unique(old.vertices[old.faces[old.material_ids == INTERIOR]].reshape(-1, 3), axis=0)
    new = loose.fragments[0]
    T = new.vertices[new.faces[new.material_ids == INTERIOR]]
    distance = np.min([point_triangle_distance(points, np.broadcast_to(t, (len(points), 3, 3))) for t in T], axis=0)
    assert distance.max() <= 0.02 + 1e-12
    _check_outer(fragments, loose)


def test_budget_simplifies_further():
    fragments, surface = _pair(bend=0.2)
    free, _ = simplify_faults(fragments, surface, tolerance=1e-4)
    capped, report = simplify_faults(fragments, surface, tolerance=1e-4, max_triangles=60)
    assert max(len(f.faces) for f in capped.fragments) < max(len(f.faces) for f in free.fragments)
    assert all(valid(f) for f in capped.fragments)
    assert report.over_budget == sum(len(f.faces) > 60 for f in capped.fragments)


def test_fit_budget_brings_the_asset_within_its_budget():
    """Issue 20: at default settings (fit_budget) the asset keeps to twice the input's triangles + 64 per fragment."""
    fragments, surface = _pair(bend=0.2)
    budget = triangle_budget(len(surface.faces), len(fragments.fragments))
    free, _ = simplify_faults(fragments, surface, tolerance=2e-3)
    fitted, report = simplify_faults(fragments, surface, tolerance=2e-3, fit_budget=True)
    assert sum(len(f.faces) for f in free.fragments) > budget >= report.triangles_after
    assert report.triangles_after == sum(len(f.faces) for f in fitted.fragments)
    assert all(valid(f) for f in fitted.fragments)
    assert _fault(fitted.fragments[0]) == _fault(fitted.fragments[1])
    total = sum(mass_properties(f.vertices, f.faces).volume for f in fitted.fragments)
    assert total == pytest.approx(fragments.input_volume, rel=1e-12)
    _check_outer(fragments, fitted)


def test_budget_shares_what_stuck_fragments_leave():
    share = shares(100, np.array([1.0, 1.0, 2.0]))
    assert share.sum() == pytest.approx(triangle_budget(100, 3))
    limits = Limits(budget=triangle_budget(100, 3), share=share)
    # Within the budget: nothing to do, however uneven.
    assert limits.over(np.array([300, 10, 10]), np.zeros(3, dtype=bool)).tolist() == []
    # Above it: the fragments above their shares (114, 114, 164 of 392).
    assert limits.over(np.array([200, 100, 200]), np.zeros(3, dtype=bool)).tolist() == [0, 2]
    # Fragment 0 cannot go further: the others share what it leaves (192 for 1 and 2: 64 and 128, about).
    assert limits.over(np.array([200, 100, 100]), np.array([True, False, False])).tolist() == [1]
    assert Limits(max_triangles=150).over(np.array([200, 100, 160]), np.array([False, False, True])).tolist() == [0]


def test_a_fragment_touching_itself_at_a_vertex_may_go_on_doing_so_there():
    """Two tetrahedra meeting at one apex, each with its own copy of it (as the booleans cut such a body): the
    apex is the one pinch, allowed where it was and nowhere else."""
    apex = np.zeros(3)
    base = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    V = np.vstack([apex, base, apex, -base])
    tet = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 3], [1, 2, 3]])
    F = np.vstack([tet, tet[:, ::-1] + 4])  # the second mirrored through the apex: its faces turn
    fragment = Fragment(vertices=V, faces=F, uvs=_uv(V), normals=np.zeros_like(V),
                        material_ids=np.zeros(len(F), dtype=np.int32), piece=0)
    pinches = pinched_positions(fragment)
    assert pinches is not None and pinches.tolist() == [[0.0, 0.0, 0.0]]
    assert len(bad_faces(fragment)) == len(F)
    assert bad_faces(fragment, pinches=pinches) is None
    assert len(bad_faces(fragment, pinches=np.array([[1.0, 0.0, 0.0]]))) == len(F)
    # Not closed (a face gone): nothing to allow.
    assert pinched_positions(dataclasses.replace(fragment, faces=F[1:], material_ids=fragment.material_ids[1:])) is None


def test_zero_tolerance_changes_nothing():
    fragments, surface = _pair(bend=0.2)
    result, report = simplify_faults(fragments, surface, tolerance=0.0)
    assert report.fault_after == report.fault_before
    for before, after in zip(fragments.fragments, result.fragments):
        assert _fault(before) == _fault(after)


def test_stage_runs_after_fragments_with_recipe_keys():
    assert STAGE_NAMES.index("simplify") == STAGE_NAMES.index("fragments") + 1
    recipe = load_recipe("default")
    assert isinstance(recipe["simplify"], SimplifyOptions)
    assert recipe["simplify"].tolerance > 0 and recipe["simplify"].max_triangles == 0
    assert recipe["simplify"].fit_budget


def test_chair_bake_within_the_triangle_budget(tmp_path):
    """Issue 20: at default settings, at most twice the input's triangles plus 64 per fragment."""
    from fracture_cli.pipeline.bake import bake

    bake(os.path.join(SAMPLE_ASSETS, "chair.glb"), str(tmp_path), load_recipe("wood"))
    with open(tmp_path / "chair.report.json") as fh:
        report = json.load(fh)
    checks = report["checks"]
    triangles = sum(f["triangles"] for f in report["fragments"])
    assert checks["triangles"] == triangles
    assert checks["triangle_budget"] == triangle_budget(report["input"]["triangles"], len(report["fragments"]))
    assert triangles <= checks["triangle_budget"] < checks["triangles_cut"]
    assert checks["watertight"] and checks["volume_error"] <= 1e-9 and checks["max_outer_distance"] <= 1e-9


def test_self_intersections_among_matches_the_full_check():
    # Random triangles, many crossing: the pairs involving the chosen faces are the full check's.
    from fracture_cli.geometry.trigeom import self_intersections, self_intersections_among

    rng = np.random.default_rng(3)
    V = rng.random((60, 3))
    F = np.array([rng.choice(60, 3, replace=False) for _ in range(80)])
    full = np.unique(self_intersections(V, F), axis=0)  # (the full check's order is the grid's)
    assert len(full) > 0
    assert np.array_equal(self_intersections_among(V, F, np.arange(len(F))), full)
    some = np.arange(0, len(F), 3)
    expected = full[np.isin(full, some).any(axis=1)]
    assert np.array_equal(self_intersections_among(V, F, some), expected)


def test_nearest_input_triangle_by_grid_is_the_brute_force_one():
    from fracture_cli.stages.simplify.faultmatch import _nearest_within

    rng = np.random.default_rng(5)
    S = rng.random((300, 3, 3)) * 0.2 + rng.random((300, 1, 3))
    points = S[:40].mean(axis=1) + rng.normal(scale=1e-9, size=(40, 3))
    best, distance = _nearest_within(S, points, 1e-7)
    for i, p in enumerate(points):
        d = point_triangle_distance(np.broadcast_to(p, (len(S), 3)), S)
        if d.min() <= 1e-7:
            assert best[i] == int(np.argmin(d)) and distance[i] == d.min()
        else:
            assert best[i] == -1 or distance[i] > 1e-7



def test_cap_needles_are_flipped_away_without_moving_the_surface():
    """A needle (apex 1e-12 off its long edge) and the face across that edge become two well-shaped faces."""
    from fracture_cli.stages.simplify.decimate import MIN_SHAPE, SurfaceComplex

    b, c, d, a, e = range(5)
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, -1, 0], [0.5, 1e-12, 0], [0.5, 1, 0]], dtype=float)
    faces = np.array([[b, d, c], [b, c, a], [b, a, e], [a, c, e]])

    def complex_() -> SurfaceComplex:
        return SurfaceComplex(V, faces, np.full(4, -1), [(0, 1)] * 4, np.ones(4, dtype=bool), set())

    flipped = complex_()
    assert flipped.flip_needles(set()) == 1
    ids, F = flipped.face_arrays()
    T = V[F]
    normal = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    longest = np.max(np.sum((T - np.roll(T, 1, axis=1)) ** 2, axis=2), axis=1)
    assert np.all(normal[:, 2] > MIN_SHAPE * longest)  # none is a needle; all still face +z
    assert normal[:, 2].sum() == pytest.approx(2.0)  # the same area (twice it: 1 below the edge, 1 above)
    assert {frozenset(f) for f in F.tolist()} >= {frozenset((a, b, d)), frozenset((a, d, c))}
    assert complex_().flip_needles({0}) == 0  # faces of a fragment kept as cut stay as they are
