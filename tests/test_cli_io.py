"""CLI tests of load/save and of bad input, through click's CliRunner."""

from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from fracture_cli import __version__
from fracture_cli.cli import cli
from fracture_cli.stages.load import load_surface

from conftest import SAMPLE_ASSETS


def run(*args):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def test_version_and_help():
    result = run("--version")
    assert result.exit_code == 0 and __version__ in result.output
    result = run("--help")
    assert result.exit_code == 0
    assert "Examples" in result.output and "fracture bake" in result.output


@pytest.mark.parametrize("name", ["pillar.glb", "chair.glb", "vase.obj"])
@pytest.mark.parametrize("out_ext", [".glb", ".obj"])
def test_round_trip_preserves_geometry_and_uvs(tmp_path, name, out_ext):
    src = os.path.join(SAMPLE_ASSETS, name)
    out = str(tmp_path / f"out{out_ext}")
    result = run("load", src, "save", out)
    assert result.exit_code == 0, result.output
    a, b = load_surface(src), load_surface(out)
    world_a, world_b = a.world_vertices(), b.world_vertices()
    # Same triangles in the same places (vertex order may be compacted per material).
    tri_a = np.sort(np.round(world_a[a.faces], 5).reshape(len(a.faces), -1), axis=0)
    tri_b = np.sort(np.round(world_b[b.faces], 5).reshape(len(b.faces), -1), axis=0)
    assert a.num_faces == b.num_faces
    np.testing.assert_allclose(tri_a, tri_b, atol=2e-5)
    # UVs at each triangle corner survive (float32 precision).
    assert b.uvs is not None
    key_a = np.lexsort(np.round(world_a[a.faces].reshape(len(a.faces), -1), 5).T[::-1])
    key_b = np.lexsort(np.round(world_b[b.faces].reshape(len(b.faces), -1), 5).T[::-1])
    np.testing.assert_allclose(a.uvs[a.faces][key_a], b.uvs[b.faces][key_b], atol=1e-5)


def test_round_trip_keeps_material_names(tmp_path):
    out = str(tmp_path / "p.glb")
    assert run("load", os.path.join(SAMPLE_ASSETS, "pillar.glb"), "save", out).exit_code == 0
    assert [m.name for m in load_surface(out).materials] == ["stone"]


def _write(path, data: bytes):
    with open(path, "wb") as fh:
        fh.write(data)
    return str(path)


@pytest.mark.parametrize(
    "maker, message",
    [
        (lambda d: str(d / "missing.obj"), "no such file"),
        (lambda d: _write(d / "empty.obj", b""), "file is empty"),
        (lambda d: _write(d / "empty.glb", b""), "file is empty"),
        (lambda d: _write(d / "text.glb", b"this is not a binary glTF file at all"), "could not be read"),
        (lambda d: _write(d / "points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"), "contains no triangles"),
        (lambda d: _write(d / "nan.obj", b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n"), "non-finite"),
        (lambda d: _write(d / "inf.obj", b"v 0 0 0\nv inf 0 0\nv 0 1 0\nf 1 2 3\n"), "non-finite"),
        (lambda d: _write(d / "mesh.xyz", b"1 2 3\n"), "unsupported file type"),
    ],
)
def test_bad_input_gives_one_line_and_exit_1(tmp_path, maker, message):
    path = maker(tmp_path)
    out = tmp_path / "out.glb"
    result = CliRunner().invoke(cli, ["load", path, "save", str(out)])
    assert result.exit_code == 1, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1, result.output
    assert message in lines[0] and os.path.basename(path) in lines[0]
    assert "Traceback" not in result.output
    assert not out.exists()
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".out")]  # no temp leftovers


def test_debug_shows_traceback(tmp_path):
    result = CliRunner().invoke(cli, ["--debug", "load", str(tmp_path / "missing.obj")])
    assert result.exit_code == 1
    assert "Traceback" in result.output


def test_save_without_load_is_a_usage_error(tmp_path):
    result = CliRunner().invoke(cli, ["save", str(tmp_path / "x.glb")])
    assert result.exit_code == 2
    assert "put 'load PATH' before it" in result.output


def test_save_does_not_clobber_on_failure(tmp_path):
    out = tmp_path / "keep.glb"
    out.write_bytes(b"previous")
    result = CliRunner().invoke(cli, ["load", str(tmp_path / "missing.obj"), "save", str(out)])
    assert result.exit_code == 1
    assert out.read_bytes() == b"previous"


def test_glb_is_deterministic(tmp_path):
    src = os.path.join(SAMPLE_ASSETS, "chair.glb")
    a, b = tmp_path / "a.glb", tmp_path / "b.glb"
    assert run("load", src, "save", str(a)).exit_code == 0
    assert run("load", src, "save", str(b)).exit_code == 0
    assert a.read_bytes() == b.read_bytes()


def test_normalization_is_unit_diagonal():
    s = load_surface(os.path.join(SAMPLE_ASSETS, "chair.glb"))
    lo, hi = s.vertices.min(0), s.vertices.max(0)
    assert abs(np.linalg.norm(hi - lo) - 1.0) < 1e-9
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-9)
    tm = trimesh.load_scene(os.path.join(SAMPLE_ASSETS, "chair.glb")).to_geometry()
    np.testing.assert_allclose(s.world_vertices().min(0), tm.vertices.min(0), atol=1e-9)


@pytest.mark.parametrize("override, key", [
    ("fragments.interior_color=[nan, 0.5, 0.5, 1.0]", "fragments.interior_color"),
    ("smooth.smoothing=nan", "smooth.smoothing"),
    ("fragments.uv_scale=inf", "fragments.uv_scale"),
    ("runtime.threshold=nan", "runtime.threshold"),
    ("runtime.threshold=inf", "runtime.threshold"),
    ("material.boxes=[{name = \"a\", min = [0, 0, -inf], max = [1, 1, 1], strength = 2.0}]", "material.boxes"),
])
def test_non_finite_options_are_refused_before_any_work(tmp_path, monkeypatch, override, key):
    monkeypatch.setattr("fracture_cli.stages.load.load_surface", lambda *a: pytest.fail("loaded before the check"))
    out = tmp_path / "out"
    result = CliRunner().invoke(cli, ["bake", os.path.join(SAMPLE_ASSETS, "vase.obj"), "-o", str(out),
                                      "--set", override])
    assert result.exit_code == 1, result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and key in errors[0] and "finite" in errors[0], result.stderr
    assert not out.exists()


def test_non_finite_flag_is_a_usage_error(tmp_path):
    result = CliRunner().invoke(cli, ["load", os.path.join(SAMPLE_ASSETS, "vase.obj"), "smooth", "--smoothing", "nan"])
    assert result.exit_code == 2
    assert "--smoothing nan must be a finite number" in result.output


@pytest.mark.parametrize("threshold", ["nan", "-1"])
def test_impact_threshold_must_be_a_number_at_least_zero(tmp_path, threshold):
    from test_runtime import slab_bar

    from fracture_cli.runtime.format import write_runtime
    from fracture_cli.stages.runtime import RuntimeOptions, runtime

    path, _ = write_runtime(runtime(*slab_bar(k=3), RuntimeOptions()), tmp_path / "bar.fracture.json")
    result = CliRunner().invoke(cli, ["impact", str(path), "--point", "0", "0", "0", "--impulse", "1", "0", "0",
                                      "--threshold", threshold])
    assert result.exit_code == 1
    assert result.output.strip().startswith("error:") and "threshold must be a number >= 0" in result.output
    result = CliRunner().invoke(cli, ["impact", str(path), "--point", "0", "0", "0", "--impulse", "1", "0", "0",
                                      "--threshold", "inf"])
    assert result.exit_code == 0 and "0 of" in result.output  # unbreakable: nothing breaks
