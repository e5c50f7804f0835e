"""The sliding containment check's broad phases find what a plain box broad phase over every pair finds."""

import numpy as np
import pytest
import trimesh

from fracture_cli.geometry import trigeom
from fracture_cli.stages.load.read import surface_from_trimesh
from fracture_cli.stages.smooth import sliding


def _reference_near_input(guard: sliding.Containment, X: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Every box-overlapping pair through the separating-axis test (what the check did before)."""
    boxes = trigeom.triangle_boxes(guard.SV, guard.SF)
    grid = trigeom.BoxGrid(boxes, trigeom.default_cell(boxes))
    qi, j = grid.query(trigeom.triangle_boxes(X, faces), pad=sliding._SLIDE_CLEARANCE)
    hit = trigeom.triangles_intersect(X[faces[qi]], guard.SV[guard.SF[j]], eps=sliding._SLIDE_CLEARANCE)
    return np.unique(qi[hit])


@pytest.mark.parametrize("subdivisions", [1, 4])  # input triangles larger and smaller than the cage's
def test_near_input_matches_all_pairs(subdivisions):
    rng = np.random.default_rng(subdivisions)
    inner = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    surface = surface_from_trimesh(inner)
    cage = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    # The cage in the input's normalized frame, a little outside it.
    V0 = surface.normalization.to_normalized(np.asarray(cage.vertices) * 1.01)
    F = np.asarray(cage.faces, dtype=np.int64)
    guard = sliding.Containment(surface, V0, F)
    found = 0
    for scale in (0.0, 0.003, 0.01, 0.03):
        X = V0 + rng.normal(scale=scale, size=V0.shape)
        faces = F[rng.random(len(F)) < 0.5]
        expected = _reference_near_input(guard, X, faces)
        assert np.array_equal(guard._near_input(X, faces), expected)
        found += len(expected)
    assert found > 0  # the large moves do bring cage triangles to the input
