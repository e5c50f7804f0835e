"""Connected bodies, tiny-body merging and the fragment graph on small meshes built in code."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from fracture_cli.geometry.mass import mass_properties
from fracture_cli.geometry.trigeom import edge_manifold_closed, vertex_manifold
from fracture_cli.stages.fragments.bodies import body_faces, split_fragments
from fracture_cli.stages.fragments.interfaces import fragment_graph, interface_areas
from fracture_cli.types import Fragment, Fragments, Material, Normalization

OUTER, INTERIOR = 0, 1
MATERIALS = (Material("outer"), Material("interior"))


def _box(lo, hi, subdivisions=0):
    mesh = trimesh.creation.box(bounds=[lo, hi])
    for _ in range(subdivisions):
        mesh = mesh.subdivide()
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)


def _concat(*meshes):
    """One mesh (V, F) of several, faces renumbered."""
    starts = np.cumsum([0] + [len(v) for v, _ in meshes])
    return np.vstack([v for v, _ in meshes]), np.vstack([f + s for (_, f), s in zip(meshes, starts)])


def _fragment(mesh, piece, interior_planes=()):
    """A Fragment of a mesh; faces on the planes ``(axis, value)`` get the interior material."""
    V, F = mesh
    centroid = V[F].mean(axis=1)
    material = np.full(len(F), OUTER, dtype=np.int32)
    for axis, value in interior_planes:
        on = np.all(np.isclose(V[F][:, :, axis], value), axis=1)
        material[on] = INTERIOR
    assert centroid.shape == (len(F), 3)
    return Fragment(vertices=V, faces=F, uvs=np.zeros((len(V), 2)), normals=np.zeros_like(V),
                    material_ids=material, piece=piece)


def _closed(frag):
    """Closed, edge- and vertex-manifold once vertices at one position are welded."""
    _, weld = np.unique(frag.vertices, axis=0, return_inverse=True)
    W = weld.reshape(-1)[frag.faces]
    return edge_manifold_closed(W) and vertex_manifold(W)


def _fragments(frags):
    volume = sum(mass_properties(f.vertices, f.faces).volume for f in frags)
    return Fragments(fragments=tuple(frags), materials=MATERIALS, normalization=Normalization.identity(),
                     input_volume=volume)


def test_two_boxes_in_one_fragment_are_two_bodies():
    V, F = _concat(_box([0, 0, 0], [1, 1, 1]), _box([3, 0, 0], [4, 2, 1]))
    bodies = body_faces(V, F)
    assert [len(b) for b in bodies] == [12, 12]
    assert mass_properties(V, F[bodies[0]]).volume == pytest.approx(2.0)  # largest first
    result, report = split_fragments(_fragments([_fragment((V, F), piece=7)]))
    assert report.bodies == (2,) and report.merged == 0
    assert len(result.fragments) == 2
    assert all(f.piece == 7 for f in result.fragments)
    assert all(_closed(f) for f in result.fragments)
    volumes = sorted(mass_properties(f.vertices, f.faces).volume for f in result.fragments)
    assert volumes == pytest.approx([1.0, 2.0])


@pytest.mark.parametrize("second", [([1, 1, 0], [2, 2, 1]), ([1, 1, 1], [2, 2, 2])], ids=["edge", "vertex"])
def test_pinched_contact_splits_bodies(second):
    """Boxes sharing an edge or a vertex (welded) are separate bodies with their own copies of it."""
    V, F = _concat(_box([0, 0, 0], [1, 1, 1]), _box(*second))
    V, weld = np.unique(V, axis=0, return_inverse=True)  # one vertex per position, as after a boolean
    F = weld.reshape(-1)[F]
    assert not (edge_manifold_closed(F) and vertex_manifold(F))
    bodies = body_faces(V, F)
    assert len(bodies) == 2
    result, _ = split_fragments(_fragments([_fragment((V, F), piece=0)]))
    for frag in result.fragments:
        assert _closed(frag)
        assert mass_properties(frag.vertices, frag.faces).volume == pytest.approx(1.0)


def test_cavity_stays_with_its_body():
    outer = _box([0, 0, 0], [4, 4, 4])
    inner_v, inner_f = _box([1, 1, 1], [2, 2, 2])
    V, F = _concat(outer, (inner_v, inner_f[:, ::-1]), _box([10, 0, 0], [11, 1, 1]))
    bodies = body_faces(V, F)
    assert [len(b) for b in bodies] == [24, 12]
    assert mass_properties(V, F[bodies[0]]).volume == pytest.approx(63.0)


def test_interface_area_does_not_need_matching_triangulations():
    left = _box([0, 0, 0], [1, 1, 1])
    right = _box([1, 0, 0], [2, 1, 1], subdivisions=2)
    far = _box([5, 0, 0], [6, 1, 1])
    pairs, areas = interface_areas([left, right, far])
    assert pairs.tolist() == [[0, 1]]
    assert areas[0] == pytest.approx(1.0)


def test_fragment_graph_ignores_contact_along_an_edge_and_respects_candidates():
    a = _box([0, 0, 0], [1, 1, 1])
    b = _box([1, 0, 0], [2, 1, 1])
    c = _box([2, 0, 0], [3, 0.5, 1])   # half of b's right face
    d = _box([-1, 1, 0], [0, 2, 1])    # touches a along an edge only
    edges, areas = fragment_graph([a, b, c, d])
    assert edges.tolist() == [[0, 1], [1, 2]]
    assert areas == pytest.approx([1.0, 0.5])
    edges, _ = fragment_graph([a, b, c, d], min_area=0.75)
    assert edges.tolist() == [[0, 1]]
    only_x1 = [np.all(np.isclose(V[F][:, :, 0], 1.0), axis=1) for V, F in (a, b, c, d)]
    edges, _ = fragment_graph([a, b, c, d], candidates=only_x1)
    assert edges.tolist() == [[0, 1]]


def test_tiny_chip_merges_into_the_neighbour_it_touches():
    """A fragment with a detached chip: the chip is glued to the fragment it shares its fault with."""
    main = _box([0, 0, 0], [1, 1, 1])
    chip = _box([2, 0, 0], [2.05, 0.05, 0.05])
    a = _fragment(_concat(main, chip), piece=3, interior_planes=[(0, 1.0), (0, 2.0)])
    b = _fragment(_box([1, 0, 0], [2, 1, 1], subdivisions=1), piece=5, interior_planes=[(0, 1.0), (0, 2.0)])
    result, report = split_fragments(_fragments([a, b]), min_volume_fraction=1e-4)
    assert report.bodies == (2, 1) and report.merged == 1 and report.isolated == 0
    assert len(result.fragments) == 2
    by_piece = {f.piece: f for f in result.fragments}
    assert set(by_piece) == {3, 5}
    grown = by_piece[5]
    assert _closed(grown)
    assert mass_properties(grown.vertices, grown.faces).volume == pytest.approx(1.0 + 0.05 ** 3, rel=1e-9)
    assert len(body_faces(grown.vertices, grown.faces)) == 1
    assert set(np.unique(grown.material_ids)) <= {OUTER, INTERIOR}
    # The same chip above the threshold stays a fragment of its own (with the first fragment's piece).
    result, report = split_fragments(_fragments([a, b]), min_volume_fraction=1e-6)
    assert report.merged == 0 and len(result.fragments) == 3
    assert sorted(f.piece for f in result.fragments) == [3, 3, 5]


def test_isolated_tiny_body_is_kept():
    a = _fragment(_concat(_box([0, 0, 0], [1, 1, 1]), _box([5, 5, 5], [5.01, 5.01, 5.01])), piece=0)
    result, report = split_fragments(_fragments([a]), min_volume_fraction=1e-3)
    assert report.isolated == 1 and len(result.fragments) == 2


def test_runtime_repeats_a_split_piece_and_takes_bonds_from_the_meshes():
    """Two fragments of one piece get its column of W; bonds come from the fragment graph, not the piece graph."""
    from fracture_cli.errors import StageError
    from fracture_cli.stages.runtime.build import _restrict_to_fragments
    from fracture_cli.types import Pieces

    W = np.arange(6, dtype=np.float64).reshape(2, 3, 1)
    pieces = Pieces(tet_piece=np.zeros(1, np.int32), W=W, volumes=np.ones(3), centroids=np.zeros((3, 3)),
                    edges=np.array([[0, 1], [1, 2]], np.int32), edge_areas=np.ones(2),
                    edge_centroids=np.zeros((2, 3)), edge_normals=np.zeros((2, 3)))
    graph = (np.array([[1, 2], [0, 2]]), np.array([0.5, 0.25]))
    W2, edges, areas = _restrict_to_fragments(W, pieces, [1, 1, 2], graph)
    np.testing.assert_array_equal(W2[:, 0], W[:, 1])
    np.testing.assert_array_equal(W2[:, 1], W[:, 1])
    assert edges.tolist() == [[0, 2], [1, 2]] and areas.tolist() == [0.25, 0.5]
    with pytest.raises(StageError, match="share a piece"):
        _restrict_to_fragments(W, pieces, [1, 1, 2])
