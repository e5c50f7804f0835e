"""Exact retests of the pairs the floating-point self-intersection test reports."""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import trigeom
from fracture_cli.geometry.exactgeom import real_pairs


def _corner_pair(z: float) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles sharing the origin: one in the plane z = 0, one whose near corner is ``z`` off that plane
    above its interior (the float test counts gaps up to 1e-12 as touching)."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0.25, z], [1, 1, 1]], dtype=float)
    F = np.array([[0, 1, 2], [0, 3, 4]])
    return V, F


def test_a_grazing_corner_pair_is_reported_by_rounding_and_cleared_exactly():
    V, F = _corner_pair(1e-13)
    assert trigeom.self_intersections(V, F).tolist() == [[0, 1]]
    assert len(real_pairs(V, F, trigeom.self_intersections(V, F))) == 0


def test_a_corner_pair_that_crosses_stays_reported():
    V, F = _corner_pair(-1e-13)  # the near corner is under the plane, the far one above: the edge crosses it
    assert real_pairs(V, F, trigeom.self_intersections(V, F)).tolist() == [[0, 1]]


def test_needle_next_to_a_face_is_cleared_exactly():
    """A needle (height 1e-10 on an edge of 1e-2) sharing a corner with a face it only comes near."""
    V = np.array([[0, 0, 0], [1e-2, 0, 0], [5e-3, 1e-10, 0],  # the needle
                  [4e-3, 1e-10 + 5e-13, 0], [4e-3, 1e-2, 0]], dtype=float)  # a face from the needle's corner
    F = np.array([[0, 1, 2], [2, 3, 4]])
    assert len(real_pairs(V, F, np.array([[0, 1]]))) == 0


def test_disjoint_and_coplanar_pairs_are_decided_exactly():
    # Disjoint corners: a triangle through another, and one beside it 1e-13 away.
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],
                  [0.2, 0.2, -1], [0.3, 0.2, 1], [0.2, 0.3, 1],
                  [0.6, 0.6 + 1e-13, 0], [0.6, 2, 0], [2, 0.6 + 1e-13, 0]], dtype=float)
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    assert real_pairs(V, F, np.array([[0, 1], [0, 2]])).tolist() == [[0, 1]]
    # Coplanar triangles sharing a corner: overlapping wedges are a real overlap.
    V2 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0.5, 0], [0.5, 1, 0]], dtype=float)
    assert real_pairs(V2, np.array([[0, 1, 2], [0, 3, 4]]), np.array([[0, 1]])).tolist() == [[0, 1]]


def test_pairs_sharing_an_edge_and_faces_without_area_stay_reported():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, 0.5, 0], [2, 2, 0]], dtype=float)
    # (0, 1, 2) and (0, 2, 1) share an edge (a fold); (0, 3, 4) has no area and meets (0, 1, 2) along a segment.
    F = np.array([[0, 1, 2], [0, 2, 1], [0, 3, 4]])
    assert real_pairs(V, F, np.array([[0, 1], [0, 2]])).tolist() == [[0, 1], [0, 2]]
