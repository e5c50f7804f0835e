"""Batch building blocks without Dask or bakes: manifest, input hashing, state, plan, impacts, report."""

from __future__ import annotations

import json
import os
import time

import numpy as np
import pytest

from fracture_cli.batch.impacts import asset_impacts
from fracture_cli.batch.inputs import dependency_files, hash_inputs
from fracture_cli.batch.jobs import BAKED, FAILED, UP_TO_DATE, TaskResult
from fracture_cli.batch.manifest import read_manifest, resolve_assets
from fracture_cli.batch.plan import check_no_input_overwritten, plan_batch
from fracture_cli.batch.report import BatchReport, asset_outcome, summary_text, to_markdown
from fracture_cli.batch.state import asset_key, is_up_to_date, read_state, state_path, write_state
from fracture_cli.errors import InputError, OutputError
from fracture_cli.runtime.format import RuntimeData

from conftest import SAMPLE_ASSETS

BOX_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def _tree(root, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def _assets(root, manifest_text: str, out="out", overrides=()):
    (root / "m.toml").write_text(manifest_text)
    return resolve_assets(read_manifest(str(root / "m.toml")), str(root / out), tuple(overrides))


def test_sample_manifest_resolves_as_is(tmp_path):
    assets = resolve_assets(read_manifest(os.path.join(SAMPLE_ASSETS, "manifest.toml")), str(tmp_path))
    assert [(a.name, a.recipe.name, a.out_dir) for a in assets] == [
        ("chair.glb", "wood", str(tmp_path)), ("pillar.glb", "stone", str(tmp_path)),
        ("vase.obj", "ceramic", str(tmp_path))]


def test_globs_tables_overrides_and_mirrored_outputs(tmp_path):
    _tree(tmp_path, {"props/a.obj": BOX_OBJ, "props/b.obj": BOX_OBJ, "props/b.mtl": "", "props/deep/c.obj": BOX_OBJ,
                     "hero.obj": BOX_OBJ, "my.toml": 'extends = "glass"\n[modes]\nnum_modes = 5\n'})
    assets = _assets(tmp_path, '[assets]\n"props/*.obj" = "stone"\n"props/b.obj" = { recipe = "wood", set = '
                               '["modes.num_modes=7"] }\n\n[[batch]]\nglob = "props/**/c.obj"\nrecipe = "stone"\n\n'
                               '[[batch]]\nfile = "hero.obj"\nrecipe = "my.toml"\nset = ["runtime.threshold=9"]\n'
                               'timeout = 60\n',
                     overrides=["cage.target_faces=500"])
    by = {a.name: a for a in assets}
    assert sorted(by) == ["hero.obj", "props/a.obj", "props/b.obj", "props/deep/c.obj"]
    assert by["props/a.obj"].recipe.name == "stone"
    assert (by["props/b.obj"].recipe.name, by["props/b.obj"].recipe["modes"].num_modes) == ("wood", 7)  # explicit wins
    assert by["hero.obj"].recipe.chain == ("my", "glass", "default")
    assert by["hero.obj"].recipe["runtime"].threshold == 9.0
    assert (by["hero.obj"].timeout, by["props/a.obj"].timeout) == (60.0, None)
    assert all(a.recipe["cage"].target_faces == 500 for a in assets)  # --set applies to every asset
    assert by["props/deep/c.obj"].out_dir == str(tmp_path / "out" / "props" / "deep")


@pytest.mark.parametrize("text, message", [
    ('[assets]\n"nope/*.obj" = "stone"\n', '[assets] "nope/*.obj": the glob matches no mesh file'),
    ('[assets]\n"missing.obj" = "stone"\n', '[assets] "missing.obj": no such file'),
    ('[assets]\n"a.obj" = "granite"\n', "[assets] \"a.obj\": unknown recipe 'granite'"),
    ('[assets]\n"a.obj" = { recipe = "stone", set = ["modes.num_modes=-1"] }\n', '[assets] "a.obj": modes.num_modes'),
    ('[assets]\n"a.obj" = { recipe = "stone", sett = [] }\n', "unknown key(s) sett"),
    ('[[batch]]\nglob = "*.obj"\nfile = "a.obj"\n', "[[batch]] #1: give exactly one of 'file' or 'glob'"),
    ('[asset]\n"a.obj" = "stone"\n', "unknown key(s) asset"),
    ('[assets]\n"a.obj" = { recipe = "stone", timeout = -5 }\n', "'timeout' must be a positive number of seconds"),
    ("", "names no assets"),
    ('[assets\n', "is not valid TOML"),
    ('[assets]\n"a.mtl" = "stone"\n', '"a.mtl": not a mesh file'),
    ('[assets]\n"../x.obj" = "stone"\n', "is outside the manifest's folder"),
    ('[assets]\n"*.obj" = "stone"\n"sub/*.obj" = "stone"\n"a.*" = "glass"\n', "with different settings"),
    ('[assets]\n"a.obj" = "stone"\n[[batch]]\nfile = "a.obj"\nrecipe = "glass"\n', "with different settings"),
    ('[assets]\n"a.obj" = "stone"\n"a.ply" = "stone"\n', "would both write a.*"),
])
def test_manifest_errors_name_the_manifest_and_the_entry(tmp_path, text, message):
    root = tmp_path / "root"
    _tree(root, {"a.obj": BOX_OBJ, "a.ply": "ply\n", "a.mtl": "", "sub/b.obj": BOX_OBJ})
    _tree(tmp_path, {"x.obj": BOX_OBJ})
    with pytest.raises(InputError) as exc:
        _assets(root, text)
    line = str(exc.value)
    assert line.startswith(str(root / "m.toml") + ": ") and message in line and "\n" not in line


def test_globs_never_pick_up_baked_outputs(tmp_path):
    _tree(tmp_path, {"a.glb": "x", "out/a.glb": "fragments", "out/a.fracture.json": "{}"})
    assert [a.name for a in _assets(tmp_path, '[assets]\n"**/*.glb" = "stone"\n')] == ["a.glb"]


def test_gltf_and_obj_dependencies_are_part_of_the_key(tmp_path):
    doc = {"asset": {"version": "2.0"}, "buffers": [{"uri": "geo%20data.bin", "byteLength": 4}, {"uri": "data:,x"}],
           "images": [{"uri": "tex/albedo.png"}]}
    _tree(tmp_path, {"m.gltf": json.dumps(doc), "geo data.bin": "abcd", "tex/albedo.png": "png",
                     "v.obj": "mtllib v.mtl\n" + BOX_OBJ, "v.mtl": "newmtl a\nmap_Kd -s 1 1 1 wood.png\n",
                     "wood.png": "w"})
    assert dependency_files(str(tmp_path / "m.gltf")) == [str(tmp_path / "geo data.bin"),
                                                           str(tmp_path / "tex" / "albedo.png")]
    assert dependency_files(str(tmp_path / "v.obj")) == [str(tmp_path / "v.mtl"), str(tmp_path / "wood.png")]
    from fracture_cli.pipeline.recipe import load_recipe

    recipe = load_recipe("stone")
    before = asset_key(hash_inputs(str(tmp_path / "m.gltf")), recipe)
    (tmp_path / "geo data.bin").write_text("abce")  # the external buffer changes: so does the key
    assert asset_key(hash_inputs(str(tmp_path / "m.gltf")), recipe) != before
    assert asset_key(hash_inputs(str(tmp_path / "m.gltf")), load_recipe("stone", ["runtime.threshold=7"])) != \
        asset_key(hash_inputs(str(tmp_path / "m.gltf")), recipe)


def test_special_files_are_never_read(tmp_path):
    _tree(tmp_path, {"v.obj": "mtllib v.mtl\n" + BOX_OBJ})
    os.mkfifo(tmp_path / "v.mtl")  # opening it for reading would block
    names = {f.name: f.sha256 for f in hash_inputs(str(tmp_path / "v.obj"))}
    assert names["v.mtl"] == "not-a-file"


def test_state_and_plan_skip_only_unchanged_assets(tmp_path):
    _tree(tmp_path, {"a.obj": BOX_OBJ, "b.obj": BOX_OBJ})
    assets = _assets(tmp_path, '[assets]\n"*.obj" = "stone"\n')
    plan = plan_batch(assets, impacts=0, cache_dir=None, timeout=10)
    assert [j.name for j in plan.jobs if j.bake] == ["a.obj", "b.obj"]
    job = plan.jobs[0]  # pretend a bake published a's outputs
    os.makedirs(job.out_dir, exist_ok=True)
    outputs = []
    for name in ("a.glb", "a.fracture.json", "a.fracture.bin", "a.report.json"):
        (tmp_path / "out" / name).write_text(json.dumps({"counts": {"fragments": 3}, "files": {"a.glb": "x"}}))
        outputs.append(str(tmp_path / "out" / name))
    ours = {"counts": {"fragments": 3}, "files": {"a.glb": "x"}}
    write_state(state_path(job.out_dir, job.stem), job.key, job.inputs, tuple(outputs), job.hashed_at_ns, ours)
    assert is_up_to_date(read_state(state_path(job.out_dir, "a")), job.key, job.out_dir)
    again = plan_batch(assets, impacts=0, cache_dir=None, timeout=10)
    assert [r.status for r in again.done] == [UP_TO_DATE] and again.done[0].report["counts"]["fragments"] == 3
    assert [j.name for j in again.jobs] == ["b.obj"]
    assert [j.bake for j in plan_batch(assets, impacts=4, cache_dir=None, timeout=10).jobs] == [False, True]
    assert len(plan_batch(assets, impacts=0, cache_dir=None, timeout=10, force=True).jobs) == 2
    time.sleep(0.01)
    (tmp_path / "out" / "a.glb").write_text("replaced by someone")  # an output changed: re-bake
    assert [j.name for j in plan_batch(assets, impacts=0, cache_dir=None, timeout=10).jobs] == ["a.obj", "b.obj"]


def test_state_is_not_written_for_a_set_another_bake_replaced(tmp_path):
    """A concurrent bake of the same stem published after ours: the state must not vouch for its outputs."""
    _tree(tmp_path, {"a.obj": BOX_OBJ})
    assets = _assets(tmp_path, '[assets]\n"*.obj" = "stone"\n')
    job = plan_batch(assets, impacts=0, cache_dir=None, timeout=10).jobs[0]
    os.makedirs(job.out_dir, exist_ok=True)
    outputs = []
    for name in ("a.glb", "a.fracture.json", "a.fracture.bin", "a.report.json"):
        (tmp_path / "out" / name).write_text(json.dumps({"files": {"a.glb": "other"}}))
        outputs.append(str(tmp_path / "out" / name))
    path = state_path(job.out_dir, job.stem)
    (tmp_path / "out" / os.path.basename(path)).write_text("{}")  # an older state
    write_state(path, job.key, job.inputs, tuple(outputs), job.hashed_at_ns, {"files": {"a.glb": "ours"}})
    assert not os.path.exists(path)
    assert [j.name for j in plan_batch(assets, impacts=0, cache_dir=None, timeout=10).jobs] == ["a.obj"]


def test_outputs_that_would_overwrite_inputs_are_refused(tmp_path):
    _tree(tmp_path, {"a.glb": "x", "b.obj": BOX_OBJ})
    manifest = str(tmp_path / "m.toml")
    fine = _assets(tmp_path, '[assets]\n"b.obj" = "stone"\n', out=".")  # b.glb beside b.obj: no input replaced
    check_no_input_overwritten(fine, (), manifest)
    clobber = _assets(tmp_path, '[assets]\n"a.glb" = "stone"\n', out=".")
    with pytest.raises(OutputError, match=r"a\.glb: the output would replace .*a\.glb, which this command reads"):
        check_no_input_overwritten(clobber, (), manifest)
    with pytest.raises(OutputError, match=r"m\.toml: the output would replace .*m\.toml, which this command reads"):
        check_no_input_overwritten(fine, (manifest,), manifest)


def _runtime(seed=0) -> RuntimeData:
    rng = np.random.default_rng(seed)
    s, k, p = 40, 3, 5
    sites = rng.normal(size=(s, 3))
    return RuntimeData(sites=sites.astype(np.float32), B=rng.normal(size=(s, k, 3)).astype(np.float32),
                       W=rng.normal(size=(k, p, 3)).astype(np.float32),
                       edges=np.array([[0, 1], [1, 2], [2, 3], [3, 4], [0, 4]], np.int32),
                       edge_areas=np.ones(5, np.float32), fragment_names=tuple(f"fragment_{j:03d}" for j in range(p)),
                       default_threshold=2.0)


def test_impacts_are_deterministic_and_straddle_the_breaking_impulse():
    import trimesh

    box = trimesh.creation.box(extents=(2, 2, 2))
    V, F = np.asarray(box.vertices, float), np.asarray(box.faces)
    a = asset_impacts(_runtime(), V, F, 40, seed=123)
    b = asset_impacts(_runtime(), V, F, 40, seed=123)
    for field in ("points", "impulses", "breaking", "sites", "broken_bonds", "groups"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not np.array_equal(asset_impacts(_runtime(), V, F, 40, seed=124).points, a.points)
    assert np.allclose(np.abs(a.points).max(axis=1), 1.0)  # on the box's surface
    magnitudes = np.linalg.norm(a.impulses, axis=1)
    np.testing.assert_array_equal(a.broken_bonds > 0, magnitudes > a.breaking)
    assert 0.2 < np.mean(a.broken_bonds > 0) < 0.8  # some hits break, some do not
    assert np.all((a.groups == a.groups.min(axis=1, keepdims=True)) | (a.broken_bonds > 0)[:, None])


def test_report_and_progress_text(tmp_path):
    _tree(tmp_path, {"a.obj": BOX_OBJ, "b|c.obj": BOX_OBJ})
    assets = _assets(tmp_path, '[assets]\n"*.obj" = "stone"\n')
    results = [TaskResult(index=0, status=BAKED, seconds=2.5, worker="tcp://w:1",
                          report={"counts": {"fragments": 7}, "checks": {"watertight": True, "volume_error": 1e-16}}),
               TaskResult(index=1, status=FAILED, seconds=0.1, error="b|c.obj: no triangles")]
    report = BatchReport(manifest="m.toml", out_dir=str(tmp_path / "out"), cluster="local cluster, 2 worker(s)",
                         assets=tuple(asset_outcome(a, r) for a, r in zip(assets, results)), seconds=3.0)
    md = to_markdown(report)
    assert "| a.obj | stone | baked | 2.5 | 7 | ok; volume error 1.0e-16 |  |" in md
    assert "| b\\|c.obj | stone | failed |" in md
    text = summary_text(report)
    assert "failed: b|c.obj: b|c.obj: no triangles" in text
    assert text.splitlines()[-1].startswith("2 asset(s): 1 baked, 0 up to date, 1 failed")
