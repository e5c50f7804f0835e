"""Collision parts and mass properties in the GLB: structure per format, the Khronos validator, runtime arrays."""

from __future__ import annotations

import json
import os
import shutil
import subprocess

import numpy as np
import pytest
import trimesh

from fracture_cli.geometry.mass import mass_properties
from fracture_cli.io.gltf import Primitive, glb_bytes, read_glb_chunks
from fracture_cli.io.physics import COLLISION_FORMATS, FragmentPhysics, physics_extender, runtime_arrays
from fracture_cli.stages.collision.convex import collision_shapes
from fracture_cli.types import Material

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VALIDATOR = os.path.join(REPO, "build", "node", "node_modules")


def _fragments():
    """An L-shaped fragment (two parts) next to a box (one part), with centre-of-mass pivots."""
    l_shape = trimesh.boolean.union([trimesh.creation.box(bounds=[[0, 0, 0], [2, 1, 1]]),
                                     trimesh.creation.box(bounds=[[0, 0, 0], [1, 2, 1]])], engine="manifold")
    box = trimesh.creation.box(bounds=[[2, 0, 0], [3, 1, 1]])
    meshes = [(np.asarray(m.vertices), np.asarray(m.faces)) for m in (l_shape, box)]
    shapes = collision_shapes(meshes)
    nodes, physics = [], []
    for k, ((V, F), mesh) in enumerate(zip(meshes, (l_shape, box))):
        mass = mass_properties(V, F)
        physics.append(FragmentPhysics(mass=mass, origin=mass.center, parts=shapes.parts[k]))
        prim = Primitive(V - mass.center, np.asarray(mesh.vertex_normals), None, F, 0)
        nodes.append((f"fragment_{k:03d}", [prim], mass.center))
    return nodes, physics


def _write(tmp_path, collision):
    nodes, physics = _fragments()
    path = tmp_path / f"{collision}.glb"
    path.write_bytes(glb_bytes(nodes, (Material("outer"),), extend=physics_extender(physics, collision, density=2.0)))
    return path, physics


@pytest.mark.parametrize("collision", COLLISION_FORMATS)
def test_every_format_writes_mass_extras_and_its_collision_nodes(tmp_path, collision):
    path, physics = _write(tmp_path, collision)
    doc, _ = read_glb_chunks(str(path))
    assert doc["scenes"][0]["nodes"] == [0, 1]  # collision nodes are children, never roots
    parts = [len(p.parts) for p in physics]
    assert parts[0] >= 2 and parts[1] == 1
    for index, body in enumerate(physics):
        node = doc["nodes"][index]
        extras = node["extras"]["fracture"]
        assert extras["volume"] == pytest.approx(body.mass.volume)
        assert extras["center_of_mass"] == pytest.approx(body.mass.center.tolist())
        assert np.allclose(node["translation"], body.mass.center)
        children = [doc["nodes"][c] for c in node.get("children", [])]
        assert len(children) == (0 if collision == "none" else parts[index])
        for k, child in enumerate(children):
            if collision == "godot":
                assert child["name"] == f"fragment_{index:03d}_{k:02d}-convcolonly" and "mesh" in child
            elif collision == "unreal":
                assert child["name"] == f"UCX_fragment_{index:03d}_{k:02d}"
                assert doc["meshes"][child["mesh"]]["name"] == child["name"]
            elif collision == "omi":
                shape = doc["extensions"]["OMI_physics_shape"]["shapes"][child["extensions"]["OMI_physics_body"]
                                                                           ["collider"]["shape"]]
                assert shape["type"] == "convex" and "mesh" not in child
                assert len(doc["meshes"][shape["convex"]["mesh"]]["primitives"]) == 1
    if collision == "omi":
        assert set(doc["extensionsUsed"]) == {"OMI_physics_body", "OMI_physics_shape"}
        motion = doc["nodes"][0]["extensions"]["OMI_physics_body"]["motion"]
        assert motion["type"] == "dynamic" and "centerOfMass" not in motion  # the pivot is the centre of mass
        assert motion["mass"] == pytest.approx(2.0 * physics[0].mass.volume)
        moments, _ = physics[0].mass.principal()
        assert motion["inertiaDiagonal"] == pytest.approx((2.0 * moments).tolist())
        assert np.linalg.norm(motion["inertiaOrientation"]) == pytest.approx(1.0)
    else:
        assert "extensionsUsed" not in doc


def test_collision_vertices_are_local_to_the_fragment_node(tmp_path):
    path, physics = _write(tmp_path, "godot")
    doc, binary = read_glb_chunks(str(path))
    child = doc["nodes"][doc["nodes"][1]["children"][0]]
    accessor = doc["accessors"][doc["meshes"][child["mesh"]]["primitives"][0]["attributes"]["POSITION"]]
    view = doc["bufferViews"][accessor["bufferView"]]
    local = np.frombuffer(binary, "<f4", accessor["count"] * 3, view["byteOffset"]).reshape(-1, 3)
    world = np.sort(local + np.asarray(doc["nodes"][1]["translation"]), axis=0)
    assert np.allclose(world, np.sort(physics[1].parts[0], axis=0), atol=1e-6)


@pytest.mark.parametrize("collision", COLLISION_FORMATS)
def test_khronos_validator_finds_no_errors_or_warnings(tmp_path, collision):
    if not shutil.which("node") or not os.path.isdir(os.path.join(VALIDATOR, "gltf-validator")):
        pytest.skip("gltf-validator not installed (`make gltf-validator` needs npm)")
    path, _ = _write(tmp_path, collision)
    proc = subprocess.run(["node", os.path.join(REPO, "scripts", "validate_gltf.cjs"), VALIDATOR, str(path)],
                          check=False, capture_output=True, text=True, timeout=120)
    report = json.loads(proc.stdout.splitlines()[0])
    assert report["errors"] == 0 and report["warnings"] == 0, report


def test_runtime_arrays_are_offsets_into_flat_arrays():
    _, physics = _fragments()
    arrays = runtime_arrays(physics)
    p = len(physics)
    assert arrays["fragment_volume"].shape == (p,) and arrays["fragment_inertia"].shape == (p, 6)
    assert arrays["fragment_center_of_mass"].shape == (p, 3)
    parts = arrays["collision_fragment_offsets"]
    vertices = arrays["collision_part_offsets"]
    assert parts.tolist() == [0, len(physics[0].parts), len(physics[0].parts) + len(physics[1].parts)]
    assert vertices[-1] == len(arrays["collision_vertices"])
    k = parts[1]  # the first part of the second fragment
    chunk = arrays["collision_vertices"][vertices[k]:vertices[k + 1]]
    assert np.allclose(chunk, physics[1].parts[0], atol=1e-6)
    assert all(a.dtype.byteorder in "<=|" for a in arrays.values())


def test_unknown_format_is_refused():
    with pytest.raises(ValueError, match="not one of"):
        physics_extender([], "bullet")


def test_fragments_glb_has_centre_of_mass_pivots_and_mass_extras(tmp_path):
    """The bake's GLB writer: node origins at the centre of mass (or the box centre on request), mass in extras."""
    from fracture_cli.io.gltf import read_glb
    from fracture_cli.io.write import write_fragments_glb
    from fracture_cli.types import Fragment, Fragments, Normalization

    wedge = trimesh.creation.cone(radius=1.0, height=2.0, sections=16)  # centre of mass off the box centre
    V, F = np.asarray(wedge.vertices), np.asarray(wedge.faces)
    frag = Fragment(vertices=V, faces=F, uvs=None, normals=np.asarray(wedge.vertex_normals),
                    material_ids=np.zeros(len(F), dtype=np.int32), piece=0)
    norm = Normalization(center=np.array([10.0, 0.0, 0.0]), scale=2.0)
    fragments = Fragments((frag,), (Material("outer"),), norm, 1.0)
    world = mass_properties(norm.to_world(V), F)
    for pivot, expected in (("center_of_mass", world.center),
                            ("bbox", (norm.to_world(V).min(axis=0) + norm.to_world(V).max(axis=0)) / 2)):
        path = tmp_path / f"{pivot}.glb"
        write_fragments_glb(path, fragments, pivot=pivot)
        doc, _ = read_glb_chunks(str(path))
        node = doc["nodes"][0]
        assert np.allclose(node["translation"], expected)
        extras = node["extras"]["fracture"]
        assert extras["volume"] == pytest.approx(world.volume, rel=1e-8)
        assert extras["center_of_mass"] == pytest.approx(world.center.tolist(), rel=1e-8)
        assert extras["inertia"] == pytest.approx(world.inertia6().tolist(), rel=1e-7, abs=1e-12)
        (mesh,), _ = read_glb(str(path))
        assert np.allclose(mesh.primitives[0].positions, norm.to_world(V), atol=1e-5)


def test_runtime_file_carries_the_optional_arrays(tmp_path):
    """Mass and collision arrays round-trip through the runtime file; counts name them; all or none."""
    import dataclasses

    from fracture_cli.runtime.format import RuntimeData, encode, load_runtime, write_runtime

    _, physics = _fragments()
    p = len(physics)
    rng = np.random.default_rng(0)
    data = RuntimeData(sites=rng.random((5, 3), dtype=np.float32), B=rng.random((5, 2, 1), dtype=np.float32),
                       W=rng.random((2, p, 1), dtype=np.float32), edges=np.array([[0, 1]], np.int32),
                       edge_areas=np.ones(1, np.float32), fragment_names=("a_fragment_000", "a_fragment_001"),
                       gameready=runtime_arrays(physics))
    write_runtime(data, tmp_path / "a.fracture.json")
    back = load_runtime(tmp_path / "a.fracture.json")
    for name, array in data.gameready.items():
        np.testing.assert_array_equal(back.gameready[name], array)
    header = json.loads((tmp_path / "a.fracture.json").read_text())
    assert header["version"] == 1 and header["counts"]["collision_parts"] == sum(len(b.parts) for b in physics)
    # A file without them still reads (old bakes), and a header missing one of them is refused.
    plain = dataclasses.replace(data, gameready={})
    write_runtime(plain, tmp_path / "b.fracture.json")
    assert load_runtime(tmp_path / "b.fracture.json").gameready == {}
    partial = dataclasses.replace(data, gameready={k: v for k, v in data.gameready.items() if k != "fragment_inertia"})
    with pytest.raises(ValueError, match="all or none"):
        encode(partial, "c.fracture.bin")
