"""The readers follow their formats' specifications (glTF 2.0, OBJ, PLY, STL); checked on the loaded mesh.

Each test builds a tiny file in code and compares what :func:`load_surface`
returns with the geometry the file means (volume, bounding box, attribute
values), so it runs in milliseconds. The corpus in tests/data/bad/ holds the
cases issue 13 reported; these cover the rest of each rule.
"""

from __future__ import annotations

import base64
import json
import os
import struct
import sys

import numpy as np
import pytest

from fracture_cli.errors import InputError
from fracture_cli.stages.load import load_surface
from fracture_cli.stages.load.read import double_sided_back_faces

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "data"))
from make_bad_corpus import Gltf, box, box_primitive, concat, obj_text, stl_binary

CORPUS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "bad")


def volume_bbox(surface):
    V, F = surface.world_vertices(), surface.faces
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    used = V[np.unique(F)]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0), used.min(axis=0), used.max(axis=0)


def write(path, data) -> str:
    with open(path, "wb") as fh:
        fh.write(data.encode() if isinstance(data, str) else data)
    return str(path)


# ---------------------------------------------------------------- glTF


def test_shared_material_name_stays_two_materials():
    surface = load_surface(os.path.join(CORPUS, "shared_material_name.glb"))
    assert [m.name for m in surface.materials] == ["paint", "paint"]
    assert [m.base_color for m in surface.materials] == [(1.0, 0.0, 0.0, 1.0), (0.0, 0.0, 1.0, 1.0)]
    # each box keeps its own colour: the red box at x = 0, the blue one at x = 2
    centres = [surface.world_vertices()[np.unique(surface.faces[surface.material_ids == i])].mean(axis=0)[0]
               for i in range(2)]
    assert centres == pytest.approx([0.0, 2.0])


def test_quantized_normals_are_normalized_and_unit():
    surface = load_surface(os.path.join(CORPUS, "quantized.glb"))
    # normalized int8 normals of a box's corners, through the node's non-uniform scale (inverse transpose)
    assert np.allclose(np.linalg.norm(surface.normals, axis=1), 1.0)
    corner = surface.world_vertices()
    assert np.all(np.sign(surface.normals) == np.sign(corner))


def test_sparse_accessor_without_buffer_view_starts_from_zeros(tmp_path):
    V, F = box()
    g = Gltf()
    everything = np.arange(len(V))
    pos = g.accessor(V.astype("<f4"), 5126, "VEC3", view=False, sparse={
        "count": len(V), "indices": {"bufferView": g.view(everything.astype("<u4").tobytes()), "componentType": 5125},
        "values": {"bufferView": g.view(V.astype("<f4").tobytes())}})
    g.node(mesh=g.mesh([{"attributes": {"POSITION": pos},
                         "indices": g.accessor(F.reshape(-1).astype("<u2"), 5123, "SCALAR")}]))
    volume, lo, hi = volume_bbox(load_surface(write(tmp_path / "s.glb", g.glb([0]))))
    assert volume == pytest.approx(1.0) and lo == pytest.approx([-0.5] * 3) and hi == pytest.approx([0.5] * 3)


def test_interleaved_buffer_view_with_byte_stride(tmp_path):
    V, F = box((2.0, 1.0, 1.0))
    uv = np.stack([V[:, 0] / 2 + 0.5, V[:, 1] + 0.5], axis=1)
    interleaved = np.zeros(len(V), dtype=[("p", "<f4", 3), ("uv", "<f4", 2), ("pad", "<f4", 1)])
    interleaved["p"], interleaved["uv"] = V, uv
    g = Gltf()
    view = g.view(interleaved.tobytes(), stride=interleaved.dtype.itemsize)
    g.doc["accessors"] += [{"bufferView": view, "byteOffset": 0, "componentType": 5126, "count": 8, "type": "VEC3"},
                           {"bufferView": view, "byteOffset": 12, "componentType": 5126, "count": 8, "type": "VEC2"}]
    g.node(mesh=g.mesh([{"attributes": {"POSITION": 0, "TEXCOORD_0": 1},
                         "indices": g.accessor(F.reshape(-1).astype("<u2"), 5123, "SCALAR")}]))
    surface = load_surface(write(tmp_path / "i.glb", g.glb([0])))
    assert volume_bbox(surface)[0] == pytest.approx(2.0)
    order = np.argsort(surface.world_vertices() @ [100.0, 10.0, 1.0])
    np.testing.assert_allclose(surface.uvs[order][:, 0], uv[np.argsort(V @ [100.0, 10.0, 1.0])][:, 0], atol=1e-7)
    np.testing.assert_allclose(surface.uvs[order][:, 1], 1 - uv[np.argsort(V @ [100.0, 10.0, 1.0])][:, 1], atol=1e-7)


@pytest.mark.parametrize("component, scale, lo", [(5121, 255, 0), (5123, 65535, 0), (5120, 127, -127),
                                                   (5122, 32767, -32767)])
def test_normalized_texture_coordinates(tmp_path, component, scale, lo):
    raw = np.array([[lo, 0], [scale, scale], [0, scale], [scale, 0]] * 2)
    dtype = {5121: "u1", 5123: "<u2", 5120: "i1", 5122: "<i2"}[component]
    g = Gltf()
    prim = box_primitive(g)
    prim["attributes"]["TEXCOORD_0"] = g.accessor(raw.astype(dtype), component, "VEC2", normalized=True)
    g.node(mesh=g.mesh([prim]))
    surface = load_surface(write(tmp_path / "n.glb", g.glb([0])))
    expected = np.maximum(raw / scale, -1.0)
    expected[:, 1] = 1.0 - expected[:, 1]
    np.testing.assert_allclose(surface.uvs, expected)


def test_texture_transform_follows_the_extension(tmp_path):
    g = Gltf()
    prim = box_primitive(g, material=0)
    uv = np.tile([[1.0, 0.0]], (8, 1))
    prim["attributes"]["TEXCOORD_0"] = g.accessor(uv.astype("<f4"), 5126, "VEC2")
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0, "extensions": {
        "KHR_texture_transform": {"offset": [0.5, 0.25], "rotation": np.pi / 2, "scale": [2.0, 1.0]}}}}}]
    g.doc["textures"] = [{"source": 0}]
    g.doc["images"] = [{"uri": "missing.png"}]  # the image is not needed for the UVs (and costs only a warning)
    g.node(mesh=g.mesh([prim]))
    surface = load_surface(write(tmp_path / "t.glb", g.glb([0])))
    # (1, 0) scaled to (2, 0), rotated by 90 degrees to (0, 2) (the extension's matrix), offset to (0.5, 2.25)
    np.testing.assert_allclose(surface.uvs, np.tile([[0.5, 1.0 - 2.25]], (8, 1)), atol=1e-12)


@pytest.mark.parametrize("mode", [5, 6])
def test_triangle_strips_and_fans(tmp_path, mode):
    # A square pyramid's base as a strip or fan, its four sides as a list: volume 1/3 * 4 * 1.
    base = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [0, 0, 1]], dtype=np.float64)
    order = [0, 3, 1, 2] if mode == 5 else [0, 3, 2, 1]  # both draw the base facing down
    g = Gltf()
    pos = g.accessor(base.astype("<f4"), 5126, "VEC3")
    sides = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]).reshape(-1)
    g.node(mesh=g.mesh([
        {"attributes": {"POSITION": pos}, "indices": g.accessor(np.array(order, "<u2"), 5123, "SCALAR"),
         "mode": mode},
        {"attributes": {"POSITION": pos}, "indices": g.accessor(sides.astype("<u2"), 5123, "SCALAR")},
        {"attributes": {"POSITION": pos}, "mode": 1},  # lines: skipped
    ]))
    assert volume_bbox(load_surface(write(tmp_path / "p.glb", g.glb([0]))))[0] == pytest.approx(4.0 / 3.0)


def test_data_uri_buffer_and_gltf_without_scenes(tmp_path):
    g = Gltf()
    g.node(mesh=g.mesh([box_primitive(g)]))
    text, _ = g.gltf([0], "data:application/octet-stream;base64," + base64.b64encode(bytes(g.binary)).decode())
    doc = json.loads(text)
    del doc["scenes"], doc["scene"]
    assert volume_bbox(load_surface(write(tmp_path / "d.gltf", json.dumps(doc))))[0] == pytest.approx(1.0)


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["nodes"].append({"children": [0]}) or d["nodes"][0].update(children=[1]), "cycle"),
    (lambda d: d["accessors"][0].update(count=400), "reads past the end"),
    (lambda d: d["bufferViews"][0].update(byteLength=10**6), "lies outside its buffer"),
    (lambda d: d["accessors"][0].update(count=4), "missing vertices"),
    (lambda d: d["buffers"][0].update(uri="https://example.com/box.bin"), "a URL, not a file name"),
    (lambda d: d.update(extensionsRequired=["EXT_meshopt_compression"]), "EXT_meshopt_compression"),
])
def test_malformed_gltf_is_one_line(tmp_path, edit, message):
    g = Gltf()
    g.node(mesh=g.mesh([box_primitive(g)]))
    text, binary = g.gltf([0], "b.bin")
    write(tmp_path / "b.bin", binary)
    doc = json.loads(text)
    edit(doc)
    if message == "cycle":
        doc["scenes"][0]["nodes"] = [1]
    with pytest.raises(InputError, match=message) as info:
        load_surface(write(tmp_path / "bad.gltf", json.dumps(doc)))
    assert "bad.gltf" in str(info.value) and "\n" not in str(info.value)


# ---------------------------------------------------------------- OBJ, PLY, STL


def test_obj_relative_indices_mix_with_absolute_and_uv_normal_slots(tmp_path):
    V, F = box()
    lines = ["v " + " ".join(map(str, v)) for v in V] + ["vt 0 0", "vt 1 0", "vt 1 1", "vn 0 0 1"]
    # each face: absolute vertex index, relative texture and normal indices
    lines += [f"f {a + 1}/-3/-1 {b + 1}/-2/-1 {c + 1}/-1/-1" for a, b, c in F]
    surface = load_surface(write(tmp_path / "m.obj", "\n".join(lines) + "\n"))
    assert volume_bbox(surface)[0] == pytest.approx(1.0)
    assert {tuple(np.round(uv, 6)) for uv in surface.uvs} <= {(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)}


def test_obj_corpus_relative_boxes_are_two_boxes():
    surface = load_surface(os.path.join(CORPUS, "obj_relative.obj"))
    volume, lo, hi = volume_bbox(surface)
    assert volume == pytest.approx(2.0) and lo == pytest.approx([-0.5] * 3) and hi == pytest.approx([3.5, 0.5, 0.5])


def test_ply_ascii_mixed_polygons_and_colors(tmp_path):
    V, _ = box()
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6]]
    tris = [[0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    header = ["ply", "format ascii 1.0", "element vertex 8", "property float x", "property float y",
              "property float z", "property uchar red", "property uchar green", "property uchar blue",
              f"element face {len(quads) + len(tris)}", "property list uchar int vertex_indices",
              "element edge 1", "property int vertex1", "property int vertex2", "end_header"]
    rows = [" ".join(map(str, v)) + " 255 0 51" for v in V]
    rows += [f"{len(p)} " + " ".join(map(str, p)) for p in quads + tris] + ["0 1"]
    surface = load_surface(write(tmp_path / "m.ply", "\n".join(header + rows) + "\n"))
    assert volume_bbox(surface)[0] == pytest.approx(1.0)
    np.testing.assert_allclose(surface.colors[0], [1.0, 0.0, 0.2, 1.0])


def test_ply_big_endian_and_face_texcoords(tmp_path):
    V, F = box()
    header = (b"ply\nformat binary_big_endian 1.0\nelement vertex 8\nproperty double x\nproperty double y\n"
              b"property double z\nelement face 12\nproperty list uchar uint vertex_indices\n"
              b"property list uchar float texcoord\nend_header\n")
    body = V.astype(">f8").tobytes()
    for k, f in enumerate(F):
        body += struct.pack(">B3I", 3, *f) + struct.pack(">B6f", 6, *([k / 12, 0.5] * 3))
    surface = load_surface(write(tmp_path / "b.ply", header + body))
    assert volume_bbox(surface)[0] == pytest.approx(1.0)
    assert surface.uvs is not None and len(np.unique(np.round(surface.uvs[:, 0], 6))) == 12


def test_ply_short_data_is_one_line(tmp_path):
    V, _ = box()
    header = (b"ply\nformat binary_little_endian 1.0\nelement vertex 8\nproperty float x\nproperty float y\n"
              b"property float z\nelement face 12\nproperty list uchar int vertex_indices\nend_header\n")
    with pytest.raises(InputError, match="does not match the header"):
        load_surface(write(tmp_path / "s.ply", header + V.astype("<f4").tobytes() + b"\x03\x00"))


def test_ascii_stl_and_binary_stl_named_solid(tmp_path):
    V, F = box()
    facets = "".join("facet normal 0 0 0\n outer loop\n" + "".join(f"  vertex {x} {y} {z}\n" for x, y, z in V[f])
                     + " endloop\nendfacet\n" for f in F)
    ascii_stl = load_surface(write(tmp_path / "a.stl", f"solid box\n{facets}endsolid box\n"))
    assert volume_bbox(ascii_stl)[0] == pytest.approx(1.0)
    binary = stl_binary(V, F)  # a correct count and a header starting with "solid": binary by its size
    binary_stl = load_surface(write(tmp_path / "b.stl", b"solid but binary".ljust(80) + binary[80:]))
    assert volume_bbox(binary_stl)[0] == pytest.approx(1.0)


# ---------------------------------------------------------------- double-sided geometry


def test_double_sided_parts_keep_one_side_and_touching_solids_keep_both():
    V, F = box()
    sphere_like = concat((V, F), (V, F[:, ::-1]))
    assert double_sided_back_faces(*sphere_like).sum() == 12
    stacked = concat(box(), box((1, 1, 1), (0, 0, 1)))  # the shared square is a coincident opposite pair
    assert not double_sided_back_faces(*stacked).any()
    both = concat(sphere_like, box((1, 1, 1), (5, 0, 0)))
    assert double_sided_back_faces(*both).sum() == 12


def test_double_sided_sphere_loads_as_one_sphere():
    surface = load_surface(os.path.join(CORPUS, "double_sided_sphere.obj"))
    assert surface.num_faces == 320 and volume_bbox(surface)[0] > 4.0


def test_obj_with_faces_written_twice_per_side_text(tmp_path):
    # The same through the OBJ text path: the file's second copy has its own vertices (unwelded).
    V, F = box()
    surface = load_surface(write(tmp_path / "two.obj", obj_text(*concat((V, F), (V.copy(), F[:, ::-1])))))
    assert surface.num_faces == 12 and volume_bbox(surface)[0] == pytest.approx(1.0)
