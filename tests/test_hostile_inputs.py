"""Issue 38 cases that the committed corpus (tests/data/bad/) cannot hold: FIFOs, files outside the folder,
edits during a batch, old outputs kept; and the readers' new rules checked on attributes, not only volumes."""

from __future__ import annotations

import hashlib
import json
import os
import sys
import threading

import numpy as np
import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.errors import InputError
from fracture_cli.io.inputs import input_files, read_input, recording_reads
from fracture_cli.stages.load import load_surface
from fracture_cli.stages.load.read import size_limits

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "data"))
from make_bad_corpus import Gltf, box, box_primitive, icosphere, obj_text  # noqa: E402

BOX_OBJ = obj_text(*box())
SMALL = ["--set", "cage.target_faces=500", "--set", "modes.num_modes=3"]


def _write(path, data) -> str:
    with open(path, "wb") as fh:
        fh.write(data.encode() if isinstance(data, str) else data)
    return str(path)


def _load_soon(path: str, seconds: float = 60.0):
    """load_surface(path) in a thread: its result or exception, failing the test if it blocks."""
    out: dict = {}

    def run():
        try:
            out["files"] = input_files(path)  # the cache key's listing must not block either
            out["surface"] = load_surface(path)
        except Exception as exc:  # noqa: BLE001 (the test inspects it)
            out["error"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"loading {path} blocked"
    return out


def _textured_gltf(tmp_path, uri: str) -> str:
    g = Gltf()
    g.doc["images"] = [{"uri": uri}]
    g.doc["textures"] = [{"source": 0}]
    g.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    g.node(mesh=g.mesh([box_primitive(g, material=0)]))
    text, binary = g.gltf([0], "box.bin")
    _write(tmp_path / "box.bin", binary)
    return _write(tmp_path / "t.gltf", text)


# ---------------------------------------------------------------- references: regular files in the folder only


@pytest.mark.parametrize("kind", ["gltf image", "gltf buffer", "obj mtllib", "mtl map", "ply texture", "asset"])
def test_a_fifo_is_refused_by_name_without_blocking(tmp_path, kind):
    os.mkfifo(tmp_path / "pipe.png")
    if kind == "gltf image":
        path = _textured_gltf(tmp_path, "pipe.png")
    elif kind == "gltf buffer":
        g = Gltf()
        g.node(mesh=g.mesh([box_primitive(g)]))
        path = _write(tmp_path / "b.gltf", g.gltf([0], "pipe.png")[0])
    elif kind == "obj mtllib":
        path = _write(tmp_path / "m.obj", "mtllib pipe.png\nusemtl a\n" + BOX_OBJ)
    elif kind == "mtl map":
        _write(tmp_path / "m.mtl", "newmtl a\nKd 1 0 0\nmap_Kd pipe.png\n")
        path = _write(tmp_path / "m.obj", "mtllib m.mtl\nusemtl a\n" + BOX_OBJ.replace("\nf", "\nvt 0 0\nf", 1))
    elif kind == "ply texture":
        V, F = box()
        path = _write(tmp_path / "p.ply", "\n".join(
            ["ply", "format ascii 1.0", "comment TextureFile pipe.png", f"element vertex {len(V)}",
             "property float x", "property float y", "property float z", f"element face {len(F)}",
             "property list uchar int vertex_indices", "end_header"]
            + [" ".join(map(str, v)) for v in V] + ["3 " + " ".join(map(str, f)) for f in F]) + "\n")
    else:
        os.mkfifo(tmp_path / "asset.obj")
        path = str(tmp_path / "asset.obj")
    out = _load_soon(path)
    assert isinstance(out.get("error"), InputError), out
    message = str(out["error"])
    assert os.path.basename(path) in message and "FIFO" in message and "\n" not in message


@pytest.mark.parametrize("make, message", [
    (lambda t: _textured_gltf(t, str(t.parent / "secret.png")), "(an absolute path)"),
    (lambda t: _textured_gltf(t, "../secret.png"), "outside the asset's folder"),
    (lambda t: _textured_gltf(t, "sub/%2E%2E/%2E%2E/secret.png"), "outside the asset's folder"),
    (lambda t: _write(t / "m.obj", "mtllib ../secret.mtl\n" + BOX_OBJ), "outside the asset's folder"),
    (lambda t: _write(t / "m.mtl", "newmtl a\nmap_Kd " + str(t.parent / "secret.png") + "\n")
     and _write(t / "m.obj", "mtllib m.mtl\nusemtl a\n" + BOX_OBJ.replace("\nf", "\nvt 0 0\nf", 1)),
     "(an absolute path)"),
])
def test_references_outside_the_folder_are_refused_and_never_read(tmp_path, make, message):
    folder = tmp_path / "asset"
    folder.mkdir()
    from PIL import Image

    Image.new("RGB", (2, 2), (255, 0, 0)).save(tmp_path / "secret.png")
    _write(tmp_path / "secret.mtl", "newmtl a\nKd 1 0 0\n")
    path = make(folder)
    with recording_reads() as reads:
        out = _load_soon(path)
    assert isinstance(out.get("error"), InputError) and message in str(out["error"]), out
    assert os.path.basename(path) in str(out["error"])
    assert not any("secret" in p for p in reads.files), reads.files  # nothing outside the folder was read
    assert not any("secret" in p for p in out["files"])  # nor listed for hashing


def test_an_image_in_a_subfolder_and_a_dot_dot_that_stays_inside_are_read(tmp_path):
    from PIL import Image

    (tmp_path / "tex").mkdir()
    Image.new("RGB", (2, 2), (0, 255, 0)).save(tmp_path / "tex" / "wood.png")
    surface = load_surface(_textured_gltf(tmp_path, "tex/../tex/wood.png"))
    assert surface.materials[0].source.baseColorTexture.getpixel((0, 0)) == (0, 255, 0)


# ---------------------------------------------------------------- the bytes read are the bytes hashed


def test_reads_are_hashed_as_read_and_a_changing_file_is_refused(tmp_path):
    path = _write(tmp_path / "a.obj", BOX_OBJ)
    with recording_reads() as reads:
        load_surface(path)
    (read,) = reads.files.values()
    assert read.sha256 == hashlib.sha256(BOX_OBJ.encode()).hexdigest() and read.size == len(BOX_OBJ)
    with recording_reads():
        read_input(path)
        _write(path, BOX_OBJ + "# edited\n")
        with pytest.raises(InputError, match="changed while it was being read"):
            read_input(path)


def test_batch_state_holds_the_bytes_the_bake_read(tmp_path):
    """An input edited after planning (and the edit undone later) is not reported up to date with other bytes."""
    from fracture_cli.batch import child
    from fracture_cli.batch.manifest import read_manifest, resolve_assets
    from fracture_cli.batch.plan import plan_batch
    from fracture_cli.batch.state import read_state, state_path

    first, second = BOX_OBJ, obj_text(*box((2.0, 1.0, 1.0)))
    _write(tmp_path / "a.obj", first)
    _write(tmp_path / "m.toml", '[assets]\n"a.obj" = "stone"\n')
    assets = resolve_assets(read_manifest(str(tmp_path / "m.toml")), str(tmp_path / "out"),
                            ("cage.target_faces=500", "modes.num_modes=3"))
    (job,) = plan_batch(assets, impacts=0, cache_dir=None, timeout=600).jobs
    _write(tmp_path / "a.obj", second)  # edited after planning, before the bake reads it
    result = child.run(job)
    assert result.status == "baked"
    state = read_state(state_path(job.out_dir, job.stem))
    assert state["inputs"]["a.obj"][2] == hashlib.sha256(second.encode()).hexdigest()
    assert state["key"] != job.key
    assert plan_batch(assets, impacts=0, cache_dir=None, timeout=600).jobs == ()  # the bytes baked: up to date
    _write(tmp_path / "a.obj", first)  # the edit undone: these outputs are not of these bytes
    (again,) = plan_batch(assets, impacts=0, cache_dir=None, timeout=600).jobs
    assert again.bake and again.key == job.key


def test_a_refused_input_keeps_the_old_outputs_and_itself(tmp_path):
    path = _write(tmp_path / "a.obj", BOX_OBJ)
    out = tmp_path / "out"
    assert CliRunner().invoke(cli, ["bake", path, "-o", str(out), *SMALL]).exit_code == 0
    before = {name: (out / name).read_bytes() for name in os.listdir(out)}
    SV, SF = icosphere(1, 1.0e9)
    hostile = obj_text(SV, SF)
    _write(path, hostile)
    result = CliRunner().invoke(cli, ["bake", path, "-o", str(out), *SMALL])
    assert result.exit_code == 1
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "a.obj" in errors[0] and "too large for the outputs" in errors[0], result.stderr
    assert "[3/" not in result.stderr  # refused at the load, before the work
    assert {name: (out / name).read_bytes() for name in os.listdir(out)} == before
    assert (tmp_path / "a.obj").read_text() == hostile


# ---------------------------------------------------------------- sizes the float32 outputs hold


def test_mass_properties_at_the_size_limit_fit_float32():
    from fracture_cli.geometry.mass import mass_properties
    from fracture_cli.types import Normalization

    smallest, largest = size_limits()
    assert 3e-8 < smallest < 1e-7 and 4e7 < largest < 1e8
    for diagonal in (smallest * 1.01, largest * 0.99):
        V, F = box((diagonal / np.sqrt(3),) * 3, (diagonal,) * 3)  # a cube, the most inertia for its diagonal
        norm = Normalization.from_points(V)
        mass = mass_properties(norm.to_normalized(V), F).to_world(norm)
        values = np.concatenate([[mass.volume], mass.center, mass.inertia6()]).astype(np.float32)
        assert np.all(np.isfinite(values)) and np.all(values[[0, 4, 5, 6]] > 0), values


# ---------------------------------------------------------------- glTF: attributes, not only volumes


def _morphed_normals_glb(tmp_path) -> str:
    V, F = box()
    g = Gltf()
    prim = box_primitive(g)
    prim["attributes"]["NORMAL"] = g.accessor(np.tile([0.0, 0.0, 1.0], (8, 1)).astype("<f4"), 5126, "VEC3")
    prim["targets"] = [{"NORMAL": g.accessor(np.tile([2.0, 0.0, -1.0], (8, 1)).astype("<f4"), 5126, "VEC3")}]
    g.doc["meshes"].append({"primitives": [prim], "weights": [0.5]})
    g.node(mesh=0, scale=[0.0, 0.0, 0.0])  # hidden
    g.node(mesh=0, rotation=[0.0, 0.0, 0.7071067811865476, 0.7071067811865476])  # 90 degrees about z
    return _write(tmp_path / "n.glb", g.glb([0, 1]))


def test_morphed_normals_are_unit_and_a_zero_scale_node_leaves_no_nan(tmp_path, caplog):
    surface = load_surface(_morphed_normals_glb(tmp_path))
    assert "degenerate transform" in caplog.text and "node 0" in caplog.text
    assert np.all(np.isfinite(surface.normals)) and len(surface.normals) == 8  # one box: the hidden one skipped
    # (0, 0, 1) + 0.5 * (2, 0, -1) = (1, 0, 0.5), rotated 90 degrees about z: (0, 1, 0.5), normalized
    np.testing.assert_allclose(surface.normals, np.tile(np.array([0.0, 1.0, 0.5]) / np.sqrt(1.25), (8, 1)),
                               atol=1e-7)


def test_skinned_normals_follow_the_joints(tmp_path):
    g = Gltf()
    prim = box_primitive(g)
    prim["attributes"]["NORMAL"] = g.accessor(np.tile([1.0, 0.0, 0.0], (8, 1)).astype("<f4"), 5126, "VEC3")
    prim["attributes"]["JOINTS_0"] = g.accessor(np.zeros((8, 4), "<u1"), 5121, "VEC4")
    prim["attributes"]["WEIGHTS_0"] = g.accessor(np.tile([1.0, 0, 0, 0], (8, 1)).astype("<f4"), 5126, "VEC4")
    g.mesh([prim])
    g.doc["skins"] = [{"joints": [1]}]
    g.node(mesh=0, skin=0, rotation=[0.0, 0.0, 1.0, 0.0])  # ignored (a skinned mesh's node transform)
    g.node(rotation=[0.0, 0.0, 0.7071067811865476, 0.7071067811865476], scale=[1.0, 1.0, -1.0])  # mirrors
    surface = load_surface(_write(tmp_path / "s.glb", g.glb([0, 1])))
    np.testing.assert_allclose(surface.normals, np.tile([0.0, 1.0, 0.0], (8, 1)), atol=1e-7)
    V, F = surface.world_vertices(), surface.faces
    volume = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0
    assert volume == pytest.approx(1.0)  # the mirroring joint flipped the winding back outwards


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["nodes"][0].update(mesh=True), "node 0's mesh is True"),
    (lambda d: d["nodes"][0].update(mesh=0.5), "node 0's mesh is 0.5"),
    (lambda d: d.update(scene=3), "the document's 'scene' is 3"),
    (lambda d: d["scenes"][0].update(nodes=[-1]), "scene 0's node is -1"),
    (lambda d: d["accessors"][1].update(componentType=5122), "are SCALAR short"),
    (lambda d: d["accessors"][1].update(type="VEC2"), "are VEC2"),
    (lambda d: d["accessors"][0].update(type="VEC2"), "POSITION (accessor 0) is VEC2"),
    (lambda d: d["meshes"][0]["primitives"][0].update(material=-1), "material is -1"),
    (lambda d: d["nodes"].append({"children": [0]}) or d["nodes"].append({"children": [0]}), "has two parents"),
])
def test_invalid_indices_and_types_are_refused_by_name(tmp_path, edit, message):
    g = Gltf()
    g.node(mesh=g.mesh([box_primitive(g)]))
    text, binary = g.gltf([0], "b.bin")
    _write(tmp_path / "b.bin", binary)
    doc = json.loads(text)
    edit(doc)
    with pytest.raises(InputError) as info:
        load_surface(_write(tmp_path / "bad.gltf", json.dumps(doc)))
    assert message in str(info.value) and "bad.gltf" in str(info.value) and "\n" not in str(info.value)
