"""The meshfix modules chained as round two's repair would chain them, on every real-world corpus file.

This is the input side of issue 15 without the stage code: weld by position,
keep one copy of repeated faces, orient, cut off fins hinged on a solid
(issue 39), split non-manifold edges and
vertices, fill what closes into a solid, thicken what is a sheet, turn closed
bodies outward and unite them (manifold3d). Each corpus file must give the
solid its ``expected.toml`` entry describes: every body closed before the
union, the union's volume the reference volume, a thickened sheet inside the
input's bounding box.
"""

from __future__ import annotations

import os
import tomllib

import manifold3d
import numpy as np
import pytest

from fracture_cli.geometry.edges import edge_table, face_bodies, signed_volume, weld_by_position
from fracture_cli.geometry.weld_check import check_mesh
from fracture_cli.stages.load import LoadOptions, load_surface
from fracture_cli.stages.repair.faces import orient_consistently, unique_faces
from fracture_cli.stages.repair.fins import hinged_sheets
from fracture_cli.stages.repair.holes import fill_holes, plan_fill
from fracture_cli.stages.repair.nonmanifold import split_nonmanifold
from fracture_cli.stages.repair.thicken import thicken_inward

CORPUS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "realworld")
with open(os.path.join(CORPUS, "expected.toml"), "rb") as _fh:
    CASES = {c["file"]: c for c in tomllib.load(_fh)["case"]}
SHELL_THICKNESS = 0.01  # of the bounding-box diagonal, as repair.shell_thickness


def meshfix_bodies(V: np.ndarray, F: np.ndarray, box: np.ndarray) -> tuple[list[tuple[np.ndarray, np.ndarray]], list]:
    """Closed outward bodies (V, F) made from a welded mesh, and every repair record."""
    records: list = []
    W = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])]
    unique = unique_faces(W)
    W = W[unique.keep]
    flip, flipped = orient_consistently(W)
    W[flip] = W[flip][:, ::-1]
    hinged = hinged_sheets(W)
    if hinged.any():
        # Fins hinged on a solid (issue 39): cut off along the hinge (own vertex copies), thickened below as sheets.
        used = np.unique(W[hinged])
        copy = np.full(len(V), -1, dtype=np.int64)
        copy[used] = len(V) + np.arange(len(used))
        V = np.vstack([V, V[used]])
        W[hinged] = copy[W[hinged]]
    split = split_nonmanifold(V, W)
    plan = plan_fill(split.vertices, split.faces)
    filled = fill_holes(split.vertices, split.faces, plan)
    records += unique.records + flipped + split.records + plan.records + filled.records
    P, G = filled.vertices, filled.faces
    bodies = []
    body = face_bodies(edge_table(G))
    for b in range(int(body.max()) + 1):
        faces = G[body == b]
        if check_mesh(P, faces).open_edges:
            sheet = thicken_inward(P, faces, SHELL_THICKNESS, box=box)
            records += sheet.records
            bodies.append((sheet.vertices, sheet.faces))
        else:
            bodies.append((P, faces if signed_volume(P, faces) > 0 else faces[:, ::-1]))
    return bodies, records


def union_volume(bodies: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, np.ndarray]:
    """Volume and vertices of the union of closed bodies (manifold3d)."""
    parts = []
    for V, F in bodies:
        used, local = np.unique(F, return_inverse=True)
        P, index = weld_by_position(V[used])
        parts.append(manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(P),
                                                           tri_verts=np.ascontiguousarray(
                                                               index[local.reshape(-1, 3)], dtype=np.uint64))))
        assert parts[-1].status() == manifold3d.Error.NoError, parts[-1].status()
    union = manifold3d.Manifold.batch_boolean(parts, manifold3d.OpType.Add)
    return float(union.volume()), np.asarray(union.to_mesh64().vert_properties)[:, :3]


@pytest.mark.parametrize("name", sorted(CASES))
def test_meshfix_makes_the_expected_solid(name):
    case = CASES[name]
    surface = load_surface(os.path.join(CORPUS, name), LoadOptions())
    V, index = weld_by_position(surface.vertices)
    box = np.stack([surface.vertices.min(axis=0), surface.vertices.max(axis=0)])
    bodies, records = meshfix_bodies(V, index[surface.faces], box)
    for P, F in bodies:
        check = check_mesh(P, F)
        assert check.open_edges == check.pinched_edges == check.misoriented_edges == 0 and check.volume > 0, (
            f"{name}: a body is not closed: {check.problems()}")
    volume, points = union_volume(bodies)
    scale = surface.normalization.scale
    kinds = {r.what for r in records}
    if case["outcome"] == "solid":
        assert volume * scale**3 == pytest.approx(case["volume"], rel=case["volume_tolerance"]), sorted(kinds)
        assert "thickened_sheet" not in kinds
    else:
        assert "thickened_sheet" in kinds and volume > 0
        excess = max(float(np.max(box[0] - points.min(axis=0))), float(np.max(points.max(axis=0) - box[1])), 0.0)
        assert excess <= 1e-6 * np.linalg.norm(box[1] - box[0])
    assert all(r.to_dict()["what"] for r in records)
