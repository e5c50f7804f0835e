"""Cache keys cover every byte an input depends on: glTF buffers and images, OBJ materials and textures."""

from __future__ import annotations

import hashlib
import json
import os
import sys

import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.io.inputs import input_files
from fracture_cli.pipeline.cache import input_digest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "data"))
from make_bad_corpus import Gltf, box, box_primitive, obj_text

SMALL = ["--set", "cage.target_faces=500", "--set", "modes.num_modes=3"]


def gltf_box(folder, extents=(1.0, 1.0, 1.0)) -> str:
    g = Gltf()
    g.node(mesh=g.mesh([box_primitive(g, extents)]))
    g.doc["images"] = [{"uri": "wood%20grain.png"}]
    text, binary = g.gltf([0], "box.bin")
    (folder / "box.gltf").write_text(text)
    (folder / "box.bin").write_bytes(binary)
    return str(folder / "box.gltf")


def test_companion_files_are_listed(tmp_path):
    path = gltf_box(tmp_path)
    assert input_files(path) == [path, str(tmp_path / "box.bin"), str(tmp_path / "wood grain.png")]
    V, F = box()
    (tmp_path / "m.obj").write_text("mtllib m.mtl\n" + obj_text(V, F))
    (tmp_path / "m.mtl").write_text("newmtl wood\nKd 1 0 0\nmap_Kd -s 1 1 1 tex/wood.png\n")
    assert input_files(str(tmp_path / "m.obj")) == [str(tmp_path / n) for n in ("m.obj", "m.mtl", "tex/wood.png")]
    (tmp_path / "p.ply").write_text("ply\nformat ascii 1.0\ncomment TextureFile skin.jpg\nelement vertex 0\n"
                                    "end_header\n")
    assert input_files(str(tmp_path / "p.ply")) == [str(tmp_path / "p.ply"), str(tmp_path / "skin.jpg")]


def test_digest_changes_with_every_companion(tmp_path):
    path = gltf_box(tmp_path)
    single = tmp_path / "single.obj"
    single.write_text("v 0 0 0\n")
    assert input_digest([str(single)]) == hashlib.sha256(single.read_bytes()).hexdigest()  # what sha256sum says
    first = input_digest(input_files(path))
    (tmp_path / "wood grain.png").write_bytes(b"an image appears")
    with_image = input_digest(input_files(path))
    raw = bytearray((tmp_path / "box.bin").read_bytes())
    raw[0] ^= 1
    (tmp_path / "box.bin").write_bytes(bytes(raw))
    edited = input_digest(input_files(path))
    assert len({first, with_image, edited}) == 3


def test_editing_the_bin_of_a_gltf_invalidates_the_cache(tmp_path):
    cache, out = str(tmp_path / "cache"), str(tmp_path / "out")
    path = gltf_box(tmp_path, (1.0, 1.0, 1.0))
    doc = json.loads((tmp_path / "box.gltf").read_text())
    del doc["images"]
    (tmp_path / "box.gltf").write_text(json.dumps(doc))
    first = CliRunner().invoke(cli, ["bake", path, "-o", out, "--cache", cache, "--json", *SMALL])
    assert first.exit_code == 0, first.output
    # Same .gltf, a .bin whose positions now describe a box twice as long (x from -1 to 1).
    g = Gltf()
    g.node(mesh=g.mesh([box_primitive(g, (2.0, 1.0, 1.0))]))
    _, binary = g.gltf([0], "box.bin")
    assert len(binary) == len((tmp_path / "box.bin").read_bytes())
    (tmp_path / "box.bin").write_bytes(binary)
    second = CliRunner().invoke(cli, ["bake", path, "-o", out, "--cache", cache, "--json", *SMALL])
    assert second.exit_code == 0, second.output
    a, b = json.loads(first.stdout), json.loads(second.stdout)
    assert set(a["cache"].values()) == {"miss"} and set(b["cache"].values()) == {"miss"}  # nothing reused
    assert {"cage", "modes"} <= set(b["cache"])
    assert a["input"]["sha256"] != b["input"]["sha256"]
    assert b["checks"]["input_volume"] == pytest.approx(2.0)
    assert sum(f["volume"] for f in b["fragments"]) == pytest.approx(2.0, rel=1e-6)
