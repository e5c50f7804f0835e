"""Every file of the malformed-input corpus (tests/data/bad/) gets its expected outcome.

``expected.toml`` lists, per file, either a successful bake whose fragments
are valid (checked here independently of the bake's own report: closed,
volumes summing to the input's, outer faces on the input surface), or exit
code 1 with one error line that names the file and says what is wrong. No
input may crash with a traceback or leave files behind.
"""

from __future__ import annotations

import os
import sys
import tomllib

import numpy as np
import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.io.gltf import read_glb

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from invariants import check_glb  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
CORPUS = os.path.join(HERE, "data", "bad")
with open(os.path.join(CORPUS, "expected.toml"), "rb") as _fh:
    CASES = tomllib.load(_fh)["case"]
SMALL = ["--set", "cage.target_faces=500", "--set", "modes.num_modes=3"]


def bake(path: str, out: str, overrides=()):
    args = ["bake", path, "-o", out, *SMALL]
    for o in overrides:
        args += ["--set", o]
    return CliRunner().invoke(cli, args)


def files_under(folder: str) -> list[str]:
    if not os.path.exists(folder):
        return []
    return [os.path.join(d, f) for d, _, fs in os.walk(folder) for f in fs]


def raw_triangles(path: str) -> np.ndarray:
    """The input's triangles (k, 3, 3) in its own units, read with trimesh (not our loader)."""
    import trimesh

    scene = trimesh.load_scene(path, process=False)
    tris = [g.triangles for g in scene.dump()]
    return np.concatenate(tris).astype(np.float64)


def distance_to_triangles(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    from fracture_cli.geometry.open3d_bridge import open3d

    o3d = open3d()
    origin = tris.reshape(-1, 3).mean(axis=0)  # float32 ray scene: stay near the origin
    scene = o3d.t.geometry.RaycastingScene()
    V = (tris.reshape(-1, 3) - origin).astype(np.float32)
    scene.add_triangles(o3d.core.Tensor(V), o3d.core.Tensor(np.arange(len(V), dtype=np.uint32).reshape(-1, 3)))
    q = o3d.core.Tensor((points - origin).astype(np.float32))
    return scene.compute_distance(q).numpy().astype(np.float64)


def test_corpus_is_complete_and_small():
    names = {c["file"] for c in CASES}
    assert len(CASES) >= 20 and len(names) == len(CASES)
    on_disk = set(os.listdir(CORPUS)) - {"expected.toml"}
    assert names <= on_disk, names - on_disk
    assert sum(os.path.getsize(os.path.join(CORPUS, f)) for f in names) < 2 * 1024 * 1024
    assert {c["outcome"] for c in CASES} == {"ok", "error"}


@pytest.mark.parametrize("entry", CASES, ids=[c["file"] for c in CASES])
def test_corpus_outcome(entry, tmp_path):
    if not entry.get("known_issue"):
        check_outcome(entry, tmp_path)
        return
    try:
        check_outcome(entry, tmp_path)
    except AssertionError:
        pytest.xfail(entry["known_issue"])


def signed_volume_and_bbox(V: np.ndarray, F: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    used = V[np.unique(F)]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0), used.min(axis=0), used.max(axis=0)


def check_loaded(entry):
    """A reader case: the loaded triangles have the known volume and bounding box (no bake: milliseconds)."""
    from fracture_cli.stages.load import load_surface

    surface = load_surface(os.path.join(CORPUS, entry["file"]))
    volume, lo, hi = signed_volume_and_bbox(surface.world_vertices(), surface.faces)
    assert volume == pytest.approx(entry["volume"], rel=1e-6)
    np.testing.assert_allclose(lo, entry["bbox"][0], atol=1e-6)
    np.testing.assert_allclose(hi, entry["bbox"][1], atol=1e-6)


def check_bonds_are_shared_faces(out: str, stem: str, meshes, interior: int, diagonal: float) -> None:
    """The runtime file bonds exactly the written fragments that share fault faces, so every group is connected."""
    from fracture_cli.runtime.format import load_runtime
    from fracture_cli.stages.fragments.interfaces import fragment_graph

    data = load_runtime(os.path.join(out, stem + ".fracture.json"))
    assert list(data.fragment_names) == [m.name for m in meshes]
    solids, fault = [], []
    for mesh in meshes:  # one mesh per fragment, its primitives stacked
        offsets = np.cumsum([0] + [len(p.positions) for p in mesh.primitives])
        solids.append((np.concatenate([p.positions for p in mesh.primitives]),
                       np.concatenate([p.indices + o for p, o in zip(mesh.primitives, offsets)])))
        fault.append(np.concatenate([np.full(len(p.indices), p.material == interior) for p in mesh.primitives]))
    # float32 positions about each fragment's own pivot: the two sides of a fault agree to ~1e-7 of the diagonal.
    edges, _ = fragment_graph(solids, fault, min_area=1e-6 * diagonal**2, tolerance=1e-6 * diagonal)
    bonded = {tuple(e) for e in np.asarray(data.edges).tolist()}
    assert {tuple(e) for e in edges.tolist()} <= bonded
    # Every bond is through shared faces (an area of contact that the meshes show): fault faces, or outer faces of
    # separate bodies touching face to face (kept apart by repair, bonded where they touch; issue 39).
    edges_any, _ = fragment_graph(solids, None, min_area=0.0, tolerance=1e-6 * diagonal)
    assert bonded <= {tuple(e) for e in edges_any.tolist()}


def check_outcome(entry, tmp_path):
    path = os.path.join(CORPUS, entry["file"])
    if entry["outcome"] == "ok" and entry.get("check") == "load":
        check_loaded(entry)
        return
    out = str(tmp_path / "out")
    result = bake(path, out, entry.get("overrides", ()))
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    output = result.output + (result.stderr if result.stderr_bytes is not None else "")
    assert "Traceback" not in output
    assert "internal error" not in output, output
    stem = os.path.splitext(entry["file"])[0]

    if entry["outcome"] == "error":
        assert result.exit_code == 1, output
        errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
        assert len(errors) == 1, result.stderr
        assert entry["file"] in errors[0], errors[0]  # names the file
        assert entry["message"] in errors[0], errors[0]
        assert files_under(out) == [], "a failed bake left files behind"
        return

    assert result.exit_code == 0, output
    for suffix in (".glb", ".fracture.json", ".fracture.bin", ".report.json"):
        assert os.path.exists(os.path.join(out, stem + suffix))
    assert sorted(os.path.basename(f) for f in files_under(out)) == sorted(
        stem + s for s in (".glb", ".fracture.json", ".fracture.bin", ".report.json"))
    import json

    with open(os.path.join(out, stem + ".report.json")) as fh:
        report = json.load(fh)
    checks = report["checks"]
    assert checks["watertight"], checks
    assert checks["volume_error"] < 1e-3, checks
    assert checks["max_outer_distance"] < 1e-4, checks

    # Independent checks on the written GLB (float32, input units).
    meshes, material_names = read_glb(os.path.join(out, stem + ".glb"))
    assert len(meshes) == report["counts"]["fragments"] >= 1
    interior = material_names.index(f"{stem}_interior")
    tris = raw_triangles(os.path.join(CORPUS, entry["reference"]) if entry.get("reference") else path)
    diagonal = float(np.linalg.norm(tris.reshape(-1, 3).max(axis=0) - tris.reshape(-1, 3).min(axis=0)))
    # Every fragment, welded by its exact written position: closed, manifold, oriented, one body, positive volume.
    written = check_glb(os.path.join(out, stem + ".glb"))
    # Every fragment is one body (a fragment that falls apart is split into fragments).
    failing = [f"{f.name}: {f.problems}" for f in written.failing]
    assert not failing, failing
    assert checks["connected"] == all(f.components == 1 for f in written.fragments)
    check_bonds_are_shared_faces(out, stem, meshes, interior, diagonal)
    total = written.total_volume
    outer_points = [p.positions for mesh in meshes for p in mesh.primitives if p.material != interior]
    expected_volume = entry.get("volume", report["checks"]["input_volume"])
    # float32 output positions: volumes good to ~1e-6 relative near the origin.
    tolerance = 1e-3 if entry["file"] != "offset_1e6.glb" else 5e-2
    assert total == pytest.approx(expected_volume, rel=tolerance)
    assert checks["input_volume"] == pytest.approx(expected_volume, rel=tolerance)
    if entry.get("bbox"):
        every = np.concatenate([p.positions for mesh in meshes for p in mesh.primitives])
        np.testing.assert_allclose(every.min(axis=0), entry["bbox"][0], atol=1e-5)
        np.testing.assert_allclose(every.max(axis=0), entry["bbox"][1], atol=1e-5)
    if outer_points:
        d = distance_to_triangles(np.concatenate(outer_points), tris)
        limit = 1e-5 if entry["file"] != "offset_1e6.glb" else 2e-2
        assert d.max() / diagonal < limit, d.max() / diagonal
