"""modes -> pieces -> smooth -> fragments on two boxes joined by a neck (integration)."""

import numpy as np
import pytest
import trimesh

from fracture_cli.stages.fragments import fragments
from fracture_cli.stages.pieces import pieces
from fracture_cli.stages.smooth import SmoothOptions, smooth
from fracture_cli.testing import two_boxes_with_neck
from fracture_cli.types import Material, Normalization, SurfaceMesh

modes_stage = pytest.importorskip("fracture_cli.stages.modes")


@pytest.mark.parametrize("smoothing", [0.0, 1e-3])
def test_pipeline_from_modes(smoothing):
    tm = two_boxes_with_neck(3)
    M = modes_stage.modes(tm, modes_stage.ModesOptions(num_modes=2))
    P = pieces(tm, M)
    assert P.num_pieces >= 2 and P.max_deviation < 1e-2
    R = smooth(tm, P, SmoothOptions(smoothing=smoothing))
    # input: the tet mesh's own boundary (faces coincide with the regions' outer faces: a hard case)
    V = tm.vertices
    used, F = np.unique(tm.boundary_faces, return_inverse=True)
    surf = SurfaceMesh(vertices=V[used], faces=F.reshape(-1, 3), uvs=None, normals=None, colors=None,
                       material_ids=np.zeros(len(tm.boundary_faces), np.int32), materials=(Material("m"),),
                       normalization=Normalization.identity())
    frags = fragments(surf, R)
    volume = trimesh.Trimesh(surf.vertices, surf.faces).volume
    total = 0.0
    for f in frags.fragments:
        mesh = trimesh.Trimesh(f.vertices, f.faces)
        assert mesh.is_watertight
        total += mesh.volume
    assert total == pytest.approx(volume, rel=1e-3)
    assert len(frags.fragments) >= 2
