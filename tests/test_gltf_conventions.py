"""Engine naming conventions on glTF input: collision-only nodes skipped, a baked GLB's material prefix removed."""
from __future__ import annotations

import logging

import numpy as np
import trimesh

from fracture_cli.io.gltf import Primitive, glb_bytes
from fracture_cli.io.gltf_conventions import baked_material_prefix, is_collision_only, unprefixed
from fracture_cli.io.gltf_read import read_gltf
from fracture_cli.types import Material


def _box_primitive(offset: float, material: int) -> Primitive:
    box = trimesh.creation.box()
    return Primitive(positions=np.asarray(box.vertices) + offset, normals=np.asarray(box.vertex_normals),
                     uvs=None, indices=np.asarray(box.faces), material=material)


def test_collision_only_names_follow_unreal_and_godot():
    assert is_collision_only("UCX_chair_fragment_000_00")
    assert is_collision_only("UBX_crate") and is_collision_only("USP_ball") and is_collision_only("UCP_pill")
    assert is_collision_only("chair_fragment_000_00-convcolonly") and is_collision_only("wall-colonly")
    assert not is_collision_only("wall-col")  # Godot keeps the visual mesh of a -col node
    assert not is_collision_only("ucx_lowercase") and not is_collision_only(None) and not is_collision_only("")


def test_baked_prefix_needs_fracture_generator_and_one_stem():
    nodes = [{"name": "chair_fragment_000"}, {"name": "chair_fragment_001"}, {"name": "UCX_chair_fragment_000_00"}]
    assert baked_material_prefix({"asset": {"generator": "fracture 0.1.0"}, "nodes": nodes}) == "chair_"
    assert baked_material_prefix({"asset": {"generator": "Blender"}, "nodes": nodes}) == ""
    two = nodes + [{"name": "vase_fragment_000"}]
    assert baked_material_prefix({"asset": {"generator": "fracture 0.1.0"}, "nodes": two}) == ""
    assert unprefixed("chair_interior", "chair_") == "interior"
    assert unprefixed("chair_", "chair_") == "chair_" and unprefixed("wood", "chair_") == "wood"


def test_baked_glb_reads_without_collision_meshes_or_prefix(tmp_path, caplog):
    meshes = [("chair_fragment_000", [_box_primitive(0.0, 0), _box_primitive(0.0, 1)]),
              ("UCX_chair_fragment_000_00", [_box_primitive(5.0, 0)])]
    path = tmp_path / "chair.glb"
    path.write_bytes(glb_bytes(meshes, (Material("chair_wood", base_color=(1, 1, 1, 1)),
                                        Material("chair_interior", base_color=(1, 0, 0, 1)))))
    with caplog.at_level(logging.WARNING, logger="fracture_cli"):
        parts = read_gltf(str(path))
    assert len(parts) == 2  # the UCX_ box at x = 5 is not geometry
    assert max(float(p.vertices[:, 0].max()) for p in parts) < 1.0
    names = {p.material.name for p in parts}
    assert names == {"wood", "interior"}
    assert any("1 collision-only node(s) skipped (UCX_chair_fragment_000_00)" in r.getMessage()
               for r in caplog.records)
