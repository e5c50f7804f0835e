"""Atomic pieces and the piece graph (fracture_cli.stages.pieces), checked independently."""

import logging

import numpy as np
import pytest

from fracture_cli.errors import StageError
from fracture_cli.stages.pieces import PiecesOptions, pieces, tet_material_fraction
from fracture_cli.testing import grid_tetmesh
from fracture_cli.types import Modes


def _modes_from_labels(tet_mesh, label_rows):
    """Synthetic modes: mode i is the (scaled) label field i; cut where labels differ."""
    labels = np.asarray(label_rows)
    ft = tet_mesh.interior_face_tets
    cut = labels[:, ft[:, 0]] != labels[:, ft[:, 1]]
    U = (labels.astype(float) + 1.0)[:, :, None]
    return Modes(U=U, labels=labels.astype(np.int32), cut=cut, piece_counts=labels.max(axis=1) + 1,
                 energies=np.zeros(len(labels)), iterations=np.ones(len(labels), np.int32))


@pytest.fixture
def grid():
    return grid_tetmesh((6, 6, 6), spacing=1 / 6, origin=(-0.5, -0.5, -0.5))


def _octant_labels(tm):
    c = tm.tet_centroids
    return [(c[:, 0] > 0.01).astype(int), (c[:, 1] > -0.16).astype(int), (c[:, 2] > 0.17).astype(int)]


def test_octants_give_eight_pieces_with_constant_modes(grid):
    rows = _octant_labels(grid)
    P = pieces(grid, _modes_from_labels(grid, rows))
    assert P.num_pieces == 8
    code = rows[0] + 2 * rows[1] + 4 * rows[2]
    # each piece is exactly one label combination
    for p in range(P.num_pieces):
        assert len(np.unique(code[P.tet_piece == p])) == 1
    assert P.max_deviation < 1e-12
    assert P.W.shape == (3, 8, 1)
    for i in range(3):
        np.testing.assert_allclose(P.W[i, P.tet_piece, 0], rows[i] + 1.0)
    np.testing.assert_allclose(P.volumes.sum(), grid.tet_volumes.sum())


def test_numbering_by_lowest_tet(grid):
    P = pieces(grid, _modes_from_labels(grid, _octant_labels(grid)))
    firsts = [np.flatnonzero(P.tet_piece == p)[0] for p in range(P.num_pieces)]
    assert firsts == sorted(firsts) and P.tet_piece[0] == 0


def test_piece_graph_matches_face_adjacency(grid):
    P = pieces(grid, _modes_from_labels(grid, _octant_labels(grid)))
    ft = grid.interior_face_tets
    a, b = P.tet_piece[ft[:, 0]], P.tet_piece[ft[:, 1]]
    expected = sorted({(min(x, y), max(x, y)) for x, y in zip(a, b) if x != y})
    assert [tuple(e) for e in P.edges.tolist()] == expected
    # Octants of a box: 12 face-sharing pairs (edge- or corner-touching ones are not edges).
    assert len(expected) == 12
    # Total interface area = area of the three cut planes inside the unit cube.
    np.testing.assert_allclose(P.edge_areas.sum(), 3.0, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(P.edge_normals, axis=1), 1.0)
    towards = P.centroids[P.edges[:, 1]] - P.centroids[P.edges[:, 0]]
    assert np.all(np.einsum("ij,ij->i", towards, P.edge_normals) > 0)
    # Interfaces here are planar, so the centroid lies on the plane the normal spans.
    for e in range(len(P.edges)):
        axis = np.argmax(np.abs(P.edge_normals[e]))
        assert abs(P.edge_normals[e][axis]) == pytest.approx(1.0)


def test_merge_small_pieces(grid):
    c = grid.tet_centroids
    small = (c[:, 0] > 0.32) & (c[:, 1] > 0.32) & (c[:, 2] > 0.32)  # one voxel corner
    rows = [small.astype(int)]
    P0 = pieces(grid, _modes_from_labels(grid, rows), PiecesOptions(min_fragment_fraction=0.0))
    assert P0.num_pieces == 2
    P1 = pieces(grid, _modes_from_labels(grid, rows), PiecesOptions(min_fragment_fraction=0.01))
    assert P1.num_pieces == 1
    np.testing.assert_allclose(P1.volumes.sum(), P0.volumes.sum())
    # The deviation check is on the atomic pieces (before merging), where the modes are constant.
    assert P1.max_deviation < 1e-12
    # The merged piece takes the volume-weighted mean of its atomic pieces' modes.
    vol = np.abs(grid.tet_volumes)
    np.testing.assert_allclose(P1.W[0, 0, 0], np.sum(vol * (rows[0] + 1.0)) / vol.sum())


def _box_surface(lo, hi):
    import trimesh

    from fracture_cli.types import Material, Normalization, SurfaceMesh

    box = trimesh.creation.box(bounds=(lo, hi))
    return SurfaceMesh(vertices=np.asarray(box.vertices, float), faces=np.asarray(box.faces, np.int64), uvs=None,
                       normals=None, colors=None, material_ids=np.zeros(len(box.faces), np.int32),
                       materials=(Material("m"),), normalization=Normalization.identity())


def test_pieces_are_measured_in_asset_volume(grid):
    """Piece sizes count the asset they hold, not the cage: an empty piece always merges, and the threshold is a
    fraction of the asset's volume."""
    c = grid.tet_centroids
    # The asset fills x < 0 of the grid; modes cut at x = 1/3 (a piece with no asset) and at y = 0.
    rows = [(c[:, 0] > 1 / 3).astype(int), (c[:, 1] > 0).astype(int)]
    asset = _box_surface((-0.5, -0.5, -0.5), (0.0, 0.5, 0.5))
    modes = _modes_from_labels(grid, rows)
    assert pieces(grid, modes, PiecesOptions(min_fragment_fraction=0.0)).num_pieces == 4
    P = pieces(grid, modes, PiecesOptions(min_fragment_fraction=0.0), surface=asset)
    assert P.num_pieces == 2  # the two pieces beyond x = 1/3 hold nothing of the asset
    material = tet_material_fraction(grid, asset)
    np.testing.assert_allclose((material * np.abs(grid.tet_volumes)).sum(), 0.5, rtol=1e-9)
    # Each of the two remaining pieces holds half the asset (a quarter of the grid): merged above one half.
    assert pieces(grid, modes, PiecesOptions(min_fragment_fraction=0.3), surface=asset).num_pieces == 2
    assert pieces(grid, modes, PiecesOptions(min_fragment_fraction=0.5 + 1e-6), surface=asset).num_pieces == 1


def test_merging_does_not_warn(grid, caplog):
    c = grid.tet_centroids
    rows = [((c[:, 0] > 0.32) & (c[:, 1] > 0.32)).astype(int), (c[:, 2] > 0.0).astype(int)]
    with caplog.at_level(logging.WARNING):
        P = pieces(grid, _modes_from_labels(grid, rows), PiecesOptions(min_fragment_fraction=0.05))
    assert P.num_pieces < 4
    assert not any("deviates" in r.message for r in caplog.records)


def test_deviation_warning(grid, caplog):
    modes = _modes_from_labels(grid, _octant_labels(grid))
    noisy = Modes(U=modes.U + np.random.default_rng(1).normal(0, 0.1, modes.U.shape), labels=modes.labels,
                  cut=modes.cut, piece_counts=modes.piece_counts, energies=modes.energies,
                  iterations=modes.iterations)
    with caplog.at_level(logging.WARNING):
        P = pieces(grid, noisy)
    assert P.max_deviation > 1e-2
    assert any("deviates" in r.message for r in caplog.records)


def test_deterministic(grid):
    modes = _modes_from_labels(grid, _octant_labels(grid))
    A, B = pieces(grid, modes), pieces(grid, modes)
    for name in ("tet_piece", "W", "volumes", "edges", "edge_areas", "edge_centroids", "edge_normals"):
        assert getattr(A, name).tobytes() == getattr(B, name).tobytes()


def test_mismatched_modes_raise(grid):
    other = grid_tetmesh((2, 2, 2))
    with pytest.raises(StageError):
        pieces(grid, _modes_from_labels(other, [np.zeros(other.num_tets, int)]))
