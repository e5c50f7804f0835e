"""The one output guard (issue 37): no command overwrites what it reads or a published bake set's files.

Every command that writes is tried with the outputs a user mistypes: the input
itself, a symlink or a hard link to it, a companion file the input references,
the runtime file's ``.bin``, the GLB read beside it, a file of a published bake
set. Each must end with exit code 1 and one error line naming the output and
the file it would replace, before any work, and leave every input byte-identical.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys

import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.errors import OutputError
from fracture_cli.io.preflight import guard_outputs, published_sets

HERE = os.path.dirname(os.path.abspath(__file__))
SMALL = ["--set", "cage.target_faces=500", "--set", "modes.num_modes=3"]
HIT = ["--point", "0", "0", "0", "--impulse", "0", "-50", "0"]


def digest(*folders) -> dict[str, str]:
    """SHA-256 of every file under ``folders`` (symlinks by their target's bytes)."""
    out = {}
    for folder in folders:
        for root, _, files in os.walk(folder):
            for name in files:
                path = os.path.join(root, name)
                with open(path, "rb") as fh:
                    out[path] = hashlib.sha256(fh.read()).hexdigest()
    return out


def refused(args: list[str], *paths, folders=()) -> str:
    """Run ``fracture ARGS``; assert exit 1, one error line naming every path, every file in ``folders`` intact."""
    before = digest(*folders)
    result = CliRunner().invoke(cli, [str(a) for a in args])
    output = result.output + result.stderr
    assert result.exit_code == 1, output
    assert "Traceback" not in output and "internal error" not in output, output
    lines = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, result.stderr
    for path in paths:
        assert str(path) in lines[0], lines[0]
    assert digest(*folders) == before
    return lines[0]


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if any stage starts: the guard refuses before any work."""
    monkeypatch.setattr("fracture_cli.pipeline.runner.Runner.run", lambda *a, **k: pytest.fail("a stage ran"))


@pytest.fixture
def source(tmp_path):
    """A folder with ``s.obj`` (a box with UVs); the folder's every file is an input."""
    folder = tmp_path / "src"
    folder.mkdir()
    shutil.copy(os.path.join(HERE, "data", "bad", "uv_seams.obj"), folder / "s.obj")
    return folder


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """``OUT/small.*``: a published bake set (module scope: baked once)."""
    folder = tmp_path_factory.mktemp("baked")
    asset = folder / "small.obj"
    shutil.copy(os.path.join(HERE, "data", "bad", "uv_seams.obj"), asset)
    out = folder / "OUT"
    result = CliRunner().invoke(cli, ["bake", str(asset), "-o", str(out), *SMALL])
    assert result.exit_code == 0, result.output + result.stderr
    return out


@pytest.fixture
def bake_copy(baked, tmp_path):
    """A private copy of the baked set (tests may make links in it)."""
    out = tmp_path / "OUT"
    shutil.copytree(baked, out)
    return out


# ---------------------------------------------------------------- the chain: save, save-cage, save-tets, export


def test_save_cage_over_the_source_asset(source, no_work):
    s = source / "s.obj"
    line = refused(["load", s, "repair", "cage", "save-cage", s], s, folders=[source])
    assert "which this command reads" in line


def test_save_over_the_input_a_symlink_and_a_hard_link(source, tmp_path, no_work):
    s = source / "s.obj"
    link = tmp_path / "link.obj"
    link.symlink_to(s)
    hard = tmp_path / "hard.obj"
    os.link(s, hard)
    (tmp_path / "folder_link").symlink_to(source)
    refused(["load", s, "save", s], s, folders=[source])
    assert "symbolic link" in refused(["load", s, "save", link], link, s, folders=[source])
    assert "hard link" in refused(["load", s, "save", hard], hard, s, folders=[source])
    refused(["load", s, "save", tmp_path / "folder_link" / "s.obj"], s, folders=[source])  # a symlinked folder


def test_save_tets_and_load_tets_on_the_same_file(source, tmp_path, no_work):
    s = source / "s.obj"
    refused(["load", s, "save-tets", s], s, folders=[source])
    tets = tmp_path / "t.npz"
    tets.write_bytes(b"not really")
    refused(["load-tets", tets, "save-tets", tets], tets, folders=[tmp_path])


def test_save_obj_would_replace_the_inputs_material_library(tmp_path, no_work):
    """``save b.obj`` writes ``b.mtl`` too: an input's material library of that name is refused."""
    text = open(os.path.join(HERE, "data", "bad", "uv_seams.obj")).read()
    (tmp_path / "a.obj").write_text("mtllib b.mtl\n" + text)
    (tmp_path / "b.mtl").write_text("newmtl m\nKd 1 0 0\n")
    refused(["load", tmp_path / "a.obj", "save", tmp_path / "b.obj"], tmp_path / "b.mtl", folders=[tmp_path])


def test_save_over_a_gltf_buffer(tmp_path, no_work):
    sys.path.insert(0, os.path.join(HERE, "data"))
    from make_bad_corpus import Gltf, box_primitive

    g = Gltf()
    g.node(mesh=g.mesh([box_primitive(g)]))
    text, binary = g.gltf([0], "x.obj")  # the buffer has a name `save` could write
    (tmp_path / "x.gltf").write_text(text)
    (tmp_path / "x.obj").write_bytes(binary)
    refused(["load", tmp_path / "x.gltf", "save", tmp_path / "x.obj"], tmp_path / "x.obj", folders=[tmp_path])


def test_export_into_the_inputs_folder(tmp_path, no_work):
    glb = tmp_path / "prop.glb"
    shutil.copy(os.path.join(HERE, "data", "bad", "two_materials.glb"), glb)
    refused(["load", glb, "repair", "cage", "tetra", "export", tmp_path], glb, folders=[tmp_path])


def test_save_over_a_file_of_a_published_set(bake_copy, source, no_work):
    line = refused(["load", source / "s.obj", "save", bake_copy / "small.glb"], bake_copy / "small.glb",
                   bake_copy / "small.report.json", folders=[bake_copy, source])
    assert "only a bake of small into that folder" in line


def test_two_outputs_of_one_chain_are_one_file(source, tmp_path, no_work):
    out = tmp_path / "o.obj"
    refused(["load", source / "s.obj", "save", out, "cage", "save-cage", out], out, folders=[source])


# ---------------------------------------------------------------- impact and preview: they read a bake


def test_impact_outputs_over_the_files_it_reads(bake_copy):
    rt = bake_copy / "small.fracture.json"
    for out in ("small.glb", "small.fracture.json", "small.fracture.bin"):
        refused(["impact", rt, *HIT, "-o", bake_copy / out], bake_copy / out, folders=[bake_copy])
    refused(["impact", rt, *HIT, "--png", bake_copy / "small.report.json"], bake_copy / "small.report.json",
            folders=[bake_copy])


def test_impact_output_linked_to_what_it_reads(bake_copy, tmp_path):
    rt = bake_copy / "small.fracture.json"
    os.link(bake_copy / "small.glb", tmp_path / "hard.glb")
    (tmp_path / "soft.glb").symlink_to(bake_copy / "small.fracture.bin")
    assert "hard link" in refused(["impact", rt, *HIT, "-o", tmp_path / "hard.glb"], tmp_path / "hard.glb",
                                  bake_copy / "small.glb", folders=[bake_copy])
    assert "symbolic link" in refused(["impact", rt, *HIT, "-o", tmp_path / "soft.glb"], tmp_path / "soft.glb",
                                      "small.fracture.bin", folders=[bake_copy])


def test_impact_over_another_published_set(baked, bake_copy):
    """Reading one bake, writing over a file of another published set (not an input) is refused too."""
    refused(["impact", baked / "small.fracture.json", *HIT, "-o", bake_copy / "small.glb"], bake_copy / "small.glb",
            bake_copy / "small.report.json", folders=[baked, bake_copy])


def test_impact_glb_and_png_are_one_file(bake_copy, tmp_path):
    out = tmp_path / "x.glb"
    refused(["impact", bake_copy / "small.fracture.json", *HIT, "-o", out, "--png", out], out, folders=[bake_copy])


def test_impact_writes_beside_the_set_when_the_name_is_free(bake_copy):
    before = digest(bake_copy)
    result = CliRunner().invoke(cli, ["impact", str(bake_copy / "small.fracture.json"), *HIT,
                                      "-o", str(bake_copy / "broken.glb")])
    assert result.exit_code == 0, result.output + result.stderr
    assert (bake_copy / "broken.glb").stat().st_size > 0
    assert {k: v for k, v in digest(bake_copy).items() if not k.endswith("broken.glb")} == before


def test_preview_over_the_files_it_reads(bake_copy, tmp_path):
    rt = bake_copy / "small.fracture.json"
    for out in ("small.report.json", "small.glb", "small.fracture.bin"):
        refused(["preview", rt, "-o", bake_copy / out], bake_copy / out, folders=[bake_copy])
    (tmp_path / "p.png").symlink_to(bake_copy / "small.report.json")
    refused(["preview", rt, "-o", tmp_path / "p.png"], tmp_path / "p.png", "small.report.json", folders=[bake_copy])


# ---------------------------------------------------------------- bake and batch


def test_bake_over_a_file_another_set_lists(source, tmp_path, no_work):
    """A bake republishes its own set only: a name another set's report lists is refused."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "s.glb").write_text("someone else's")
    (out / "other.report.json").write_text(json.dumps({"files": {"s.glb": {"sha256": "x", "bytes": 14}}}))
    refused(["bake", source / "s.obj", "-o", out], out / "s.glb", out / "other.report.json", folders=[source, out])


def test_bake_over_a_hard_link_to_its_input(source, tmp_path, no_work):
    out = tmp_path / "out"
    out.mkdir()
    os.link(source / "s.obj", out / "s.glb")
    refused(["bake", source / "s.obj", "-o", out], out / "s.glb", source / "s.obj", folders=[source])


def test_batch_over_an_input_and_a_published_set(source, bake_copy, tmp_path):
    pytest.importorskip("distributed")
    manifest = source / "m.toml"
    manifest.write_text('[assets]\n"s.obj" = "stone"\n')
    os.link(source / "s.obj", bake_copy / "m.batch.json")  # the batch report's name: a hard link to the asset
    refused(["batch", manifest, "-o", bake_copy], bake_copy / "m.batch.json", source / "s.obj",
            folders=[source, bake_copy])
    os.unlink(bake_copy / "m.batch.json")
    report = json.loads((bake_copy / "small.report.json").read_text())
    report["files"]["s.glb"] = report["files"]["small.glb"]  # set `small` now lists the asset's output name
    (bake_copy / "small.report.json").write_text(json.dumps(report))
    refused(["batch", manifest, "-o", bake_copy], bake_copy / "s.glb", bake_copy / "small.report.json",
            folders=[source, bake_copy])


# ---------------------------------------------------------------- the guard itself


def test_republishing_a_set_is_allowed_and_nothing_else(bake_copy):
    assert [s.stem for s in published_sets(str(bake_copy))] == ["small"]
    guard_outputs(sets=[(str(bake_copy), "small")])  # a bake of small into OUT
    guard_outputs([str(bake_copy / "small.preview.png")])  # not listed: not a file of the set
    for name in ("small.glb", "small.fracture.json", "small.fracture.bin", "small.report.json"):
        with pytest.raises(OutputError, match="a file of the bake set"):
            guard_outputs([str(bake_copy / name)])
        with pytest.raises(OutputError, match="a file of the bake set"):
            guard_outputs([str(bake_copy / name)], sets=[(str(bake_copy), "other")])


def test_reports_that_are_not_manifests_are_not_sets(tmp_path):
    (tmp_path / "a.report.json").write_text("not json")
    (tmp_path / "b.report.json").write_text('{"files": []}')
    (tmp_path / "c.report.json").write_text("[1, 2]")
    assert published_sets(str(tmp_path)) == ()
    assert published_sets(str(tmp_path / "missing")) == ()
    guard_outputs([str(tmp_path / "a.report.json")])


# ---------------------------------------------------------------- an output folder that cannot be one (issue 38)


def _broken_folder(tmp_path, kind: str):
    """An ``-o`` that no folder can be made at: (the path, the line's words)."""
    os.symlink(tmp_path / "missing", tmp_path / "dangling")
    os.symlink(tmp_path / "loop", tmp_path / "loop")
    (tmp_path / "a file").write_text("not a folder\n")
    return {"a dangling link": (tmp_path / "dangling", "is a dangling symbolic link"),
            "a link loop": (tmp_path / "loop", "is a symbolic link loop"),
            "inside a dangling link": (tmp_path / "dangling" / "out", "dangling symbolic link"),
            "inside a link loop": (tmp_path / "loop" / "out", "is a symbolic link loop"),
            "inside a file": (tmp_path / "a file" / "out", "is a file")}[kind]


KINDS = ["a dangling link", "a link loop", "inside a dangling link", "inside a link loop", "inside a file"]


@pytest.mark.parametrize("kind", KINDS)
def test_bake_into_an_output_folder_that_cannot_be_made(kind, source, tmp_path, no_work):
    """Refused by the preflight, before any stage, with one line (it used to fail after the whole bake)."""
    out, words = _broken_folder(tmp_path, kind)
    line = refused(["bake", source / "s.obj", "-o", out], out, folders=[source])
    assert words in line
    assert not os.path.exists(tmp_path / "missing") and (tmp_path / "a file").read_text() == "not a folder\n"


@pytest.mark.parametrize("kind", ["a dangling link", "inside a file"])
def test_chain_export_into_an_output_folder_that_cannot_be_made(kind, source, tmp_path, no_work):
    out, words = _broken_folder(tmp_path, kind)
    chain = ["load", source / "s.obj", "repair", "cage", "tetra", "material", "modes", "pieces", "smooth",
             "fragments", "simplify", "collision", "runtime", "export", out]
    assert words in refused(chain, out, folders=[source])


@pytest.mark.parametrize("kind", ["a dangling link", "inside a link loop"])
def test_batch_into_an_output_folder_that_cannot_be_made(kind, source, tmp_path, no_work):
    out, words = _broken_folder(tmp_path, kind)
    (source / "m.toml").write_text('[assets]\n"s.obj" = "default"\n')
    assert words in refused(["batch", source / "m.toml", "-o", out, "--workers", "1"], out, folders=[source])
