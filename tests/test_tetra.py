"""Tests of the tetra stage and of cage / tet mesh files."""

from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh

from fracture_cli.errors import InputError, StageError
from fracture_cli.geometry import tetgeom
from fracture_cli.io.cage_io import load_tetmesh, save_cage, save_tetmesh
from fracture_cli.stages.cage import CageOptions, cage
from fracture_cli.stages.tetra import TetraOptions, tetra
from fracture_cli.types import Cage, Material, Normalization, SurfaceMesh

SAMPLE_ASSETS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "sample_assets")


def _surface(mesh: trimesh.Trimesh) -> SurfaceMesh:
    world = mesh.vertices * 4.0 + [10.0, -2.0, 3.0]  # a non-trivial map back to world units
    norm = Normalization.from_points(world)
    return SurfaceMesh(vertices=norm.to_normalized(world), faces=np.asarray(mesh.faces),
                       uvs=None, normals=None, colors=None, material_ids=np.zeros(len(mesh.faces), np.int32),
                       materials=(Material("m"),), normalization=norm, name="test")


@pytest.fixture(scope="module")
def sphere_cage() -> Cage:
    return cage(_surface(trimesh.creation.icosphere(3)), CageOptions(target_faces=500))


@pytest.fixture(scope="module")
def chair_cage() -> Cage:
    path = os.path.join(SAMPLE_ASSETS, "chair.glb")
    if not os.path.exists(path):
        pytest.skip("chair.glb not generated yet")
    from fracture_cli.stages.load import load_surface

    return cage(load_surface(path), CageOptions(target_faces=500))


def canonical_triangles(F):
    F = np.asarray(F, dtype=np.int64)
    k = np.argmin(F, axis=1)
    r = np.arange(len(F))
    rotated = np.stack([F[r, k], F[r, (k + 1) % 3], F[r, (k + 2) % 3]], axis=1)
    return rotated[np.lexsort(rotated.T[::-1])]


@pytest.mark.parametrize("which", ["sphere_cage", "chair_cage"])
def test_tet_mesh_is_valid_and_bounded_by_the_cage(which, request):
    cage_ = request.getfixturevalue(which)
    mesh = tetra(cage_, TetraOptions())
    assert mesh.vertices.dtype == np.float64 and mesh.tets.dtype == np.int64
    assert np.all(tetgeom.tet_volumes(mesh.vertices, mesh.tets) > 0)
    # The cage's vertices come first, unmoved; the boundary is exactly the cage, same orientation.
    assert np.array_equal(mesh.vertices[:len(cage_.vertices)], cage_.vertices)
    assert np.array_equal(canonical_triangles(mesh.boundary_faces), canonical_triangles(cage_.faces))
    # Volumes add up to the cage volume.
    cage_volume = trimesh.Trimesh(cage_.vertices, cage_.faces, process=False).volume
    assert np.isclose(mesh.tet_volumes.sum(), cage_volume, rtol=1e-9)
    assert mesh.normalization is cage_.normalization
    # Every vertex is used.
    assert len(np.unique(mesh.tets)) == mesh.num_vertices


def test_tetra_is_deterministic(sphere_cage):
    first = tetra(sphere_cage, TetraOptions())
    second = tetra(sphere_cage, TetraOptions())
    assert first.tets.tobytes() == second.tets.tobytes()
    assert first.vertices.tobytes() == second.vertices.tobytes()


def test_volume_bound_refines(sphere_cage):
    coarse = tetra(sphere_cage, TetraOptions())
    fine = tetra(sphere_cage, TetraOptions(max_volume=2e-4))
    assert fine.num_tets > 2 * coarse.num_tets
    cage_volume = trimesh.Trimesh(sphere_cage.vertices, sphere_cage.faces, process=False).volume
    # A target, not a hard bound: keeping the boundary exactly (TetGen -Y) stops
    # refinement near the surface, so only the bulk of the tets obey it.
    assert np.median(fine.tet_volumes) <= 2e-4 * cage_volume


def test_tetra_rejects_an_inside_out_cage(sphere_cage):
    flipped = Cage(vertices=sphere_cage.vertices, faces=sphere_cage.faces[:, ::-1].copy(), offset=0.01)
    with pytest.raises(StageError, match="no volume"):
        tetra(flipped)


def test_tetra_reports_tetgen_failure():
    sphere = trimesh.creation.icosphere(1)
    V = np.vstack([sphere.vertices, sphere.vertices + [0.5, 0, 0]])
    F = np.vstack([sphere.faces, sphere.faces + len(sphere.vertices)])  # overlapping shells
    with pytest.raises(StageError, match="tetra"):
        tetra(Cage(vertices=V, faces=F, offset=0.01))


def test_tetmesh_round_trip(tmp_path, sphere_cage):
    mesh = tetra(sphere_cage)
    path = tmp_path / "sub" / "mesh.npz"
    save_tetmesh(path, mesh)
    loaded = load_tetmesh(path)
    assert loaded.vertices.tobytes() == mesh.vertices.tobytes()
    assert loaded.tets.tobytes() == mesh.tets.tobytes()
    assert np.array_equal(loaded.normalization.center, mesh.normalization.center)
    assert loaded.normalization.scale == mesh.normalization.scale
    with np.load(path) as data:
        assert set(data.files) == {"format", "vertices", "tets", "center", "scale"}
    assert [p.name for p in path.parent.iterdir()] == ["mesh.npz"]  # no temporary left behind


def test_load_tetmesh_errors(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_tetmesh(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an archive")
    with pytest.raises(InputError):
        load_tetmesh(bad)
    partial = tmp_path / "partial.npz"
    np.savez(partial, vertices=np.zeros((4, 3)))
    with pytest.raises(InputError, match="missing"):
        load_tetmesh(partial)


@pytest.mark.parametrize("ext", [".obj", ".ply", ".stl", ".off"])
def test_save_cage_in_world_units(tmp_path, sphere_cage, ext):
    path = tmp_path / f"cage{ext}"
    save_cage(path, sphere_cage)
    loaded = trimesh.load(path, process=ext == ".stl", force="mesh")  # STL stores corners per face: merge them
    assert len(loaded.faces) == len(sphere_cage.faces)
    world = sphere_cage.normalization.to_world(sphere_cage.vertices)
    atol = (1e-5 if ext == ".stl" else 1e-6) * sphere_cage.normalization.scale  # STL is float32
    if ext != ".stl":
        assert np.allclose(loaded.vertices, world, atol=atol)
        assert np.array_equal(np.asarray(loaded.faces), sphere_cage.faces)
    else:
        assert np.allclose(np.sort(loaded.vertices, axis=0), np.sort(world, axis=0), atol=atol)
    assert loaded.is_watertight and loaded.volume > 0


def test_save_cage_rejects_unknown_format(tmp_path, sphere_cage):
    with pytest.raises(InputError, match="pick one of"):
        save_cage(tmp_path / "cage.xyz", sphere_cage)


def test_cage_with_a_needle_face_still_tetrahedralizes(caplog):
    """A box whose 400-face cage has a needle triangle: TetGen puts a point on it. The boundary is then a
    refinement of the cage (same area, same volume), which is accepted; anything else is refused."""
    import logging

    import trimesh

    from fracture_cli.stages.cage import CageOptions, cage
    from fracture_cli.stages.load.read import surface_from_trimesh
    from fracture_cli.stages.tetra import TetraOptions, tetra

    box = trimesh.creation.box(extents=(0.5773, 0.3, 0.3))
    box.apply_translation((0.6868, 0.0, 0.5345))
    cage_result = cage(surface_from_trimesh(box), CageOptions(target_faces=400))
    with caplog.at_level(logging.INFO, logger="fracture_cli"):
        mesh = tetra(cage_result, TetraOptions())
    assert np.all(mesh.tet_volumes > 0)
    V, F = cage_result.vertices, cage_result.faces
    cage_volume = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0
    assert mesh.tet_volumes.sum() == pytest.approx(cage_volume, rel=1e-9)
    B = mesh.boundary_faces
    area = 0.5 * np.linalg.norm(np.cross(mesh.vertices[B[:, 1]] - mesh.vertices[B[:, 0]],
                                         mesh.vertices[B[:, 2]] - mesh.vertices[B[:, 0]]), axis=1).sum()
    cage_area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
    assert area == pytest.approx(cage_area, rel=1e-9)


def test_flat_tets_on_the_cage_surface_are_removed(caplog):
    import logging

    from fracture_cli.stages.load import load_surface
    from fracture_cli.stages.repair import repair

    # A cube's 800-face cage: TetGen joins four coplanar points of a flat side into a flat tet.
    path = os.path.join(os.path.dirname(__file__), "data", "bad", "micro.off")
    cage_ = cage(repair(load_surface(path)), CageOptions(target_faces=800))
    with caplog.at_level(logging.INFO, logger="fracture_cli.stages.tetra"):
        mesh = tetra(cage_, TetraOptions())
    assert "removed 1 flat tet" in caplog.text
    edges = mesh.vertices[mesh.tets[:, [0, 0, 0, 1, 1, 2]]] - mesh.vertices[mesh.tets[:, [1, 2, 3, 2, 3, 3]]]
    shape = mesh.tet_volumes / np.linalg.norm(edges, axis=2).max(axis=1) ** 3
    assert shape.min() > 1e-9
    # The boundary is a different triangulation of the same surface: closed, same area, same volume.
    boundary = trimesh.Trimesh(mesh.vertices, mesh.boundary_faces, process=False)
    surface = trimesh.Trimesh(cage_.vertices, cage_.faces, process=False)
    assert boundary.is_watertight and boundary.is_winding_consistent
    assert np.isclose(boundary.area, surface.area, rtol=1e-12)
    assert np.isclose(mesh.tet_volumes.sum(), surface.volume, rtol=1e-9)
    assert len(np.unique(mesh.tets)) == mesh.num_vertices
