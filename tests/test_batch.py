"""`fracture batch` end to end on a local Dask cluster of 2 workers.

Small settings (a 300-600 face cage, 4 modes) keep each bake at a few seconds.
Checks: the outputs are byte-identical to serial `fracture bake`; a second run
bakes nothing; editing one recipe re-bakes only its assets; a bake that raises
or hangs fails alone; a worker killed mid-batch loses and corrupts nothing.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import threading
import time

import numpy as np
import pytest
from click.testing import CliRunner

pytest.importorskip("distributed", reason="fracture batch needs the 'batch' extra (dask[distributed])")
pytest.importorskip("pyarrow", reason="the impacts dataset needs the 'batch' extra (pyarrow)")

from fracture_cli.batch.jobs import BAKED, FAILED, UP_TO_DATE, BakeJob, TaskResult
from fracture_cli.batch.runner import BatchOptions, run_batch
from fracture_cli.cli import cli

from conftest import SAMPLE_ASSETS

FAST = ("cage.target_faces=600", "modes.num_modes=4")
TINY = ("cage.target_faces=300", "modes.num_modes=4")
DATA_SUFFIXES = (".glb", ".fracture.json", ".fracture.bin")


def _set_args(overrides) -> list[str]:
    return [arg for o in overrides for arg in ("--set", o)]


def _serial_bake(asset: str, out: str, recipe: str, overrides) -> None:
    result = CliRunner().invoke(cli, ["bake", asset, "-o", out, "-r", recipe, "-q", *_set_args(overrides)])
    assert result.exit_code == 0, result.output


def _same_bytes(a_dir: str, b_dir: str, stem: str) -> None:
    for suffix in DATA_SUFFIXES:
        with open(os.path.join(a_dir, stem + suffix), "rb") as a, open(os.path.join(b_dir, stem + suffix), "rb") as b:
            assert a.read() == b.read(), f"{stem}{suffix} differs from the serial bake"


def _write_box(path, extents=(1.0, 0.6, 0.4), sphere=False) -> None:
    import trimesh

    os.makedirs(os.path.dirname(path), exist_ok=True)
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.5) if sphere else trimesh.creation.box(extents=extents)
    mesh.export(path)


def _complete_set(out_dir: str, stem: str) -> dict:
    """Every output exists and parses; returns the report."""
    from fracture_cli.runtime.format import load_runtime

    for suffix in DATA_SUFFIXES + (".report.json",):
        assert os.path.isfile(os.path.join(out_dir, stem + suffix)), f"{stem}{suffix} missing"
    data = load_runtime(os.path.join(out_dir, f"{stem}.fracture.json"))
    with open(os.path.join(out_dir, f"{stem}.glb"), "rb") as fh:
        assert fh.read(4) == b"glTF"
    with open(os.path.join(out_dir, f"{stem}.report.json")) as fh:
        report = json.load(fh)
    assert report["counts"]["fragments"] == len(data.fragment_names)
    return report


def _statuses(report) -> dict[str, str]:
    return {a.name: a.status for a in report.assets}


def test_sample_manifest_as_is_matches_serial_bake_then_skips(tmp_path):
    manifest = os.path.join(SAMPLE_ASSETS, "manifest.toml")
    out, serial = str(tmp_path / "out"), str(tmp_path / "serial")
    args = ["batch", manifest, "-o", out, "--workers", "2", *_set_args(FAST)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "3 baked, 0 up to date, 0 failed" in result.output
    import tomllib

    with open(manifest, "rb") as fh:
        entries = tomllib.load(fh)["assets"]
    for name, recipe in entries.items():
        _serial_bake(os.path.join(SAMPLE_ASSETS, name), serial, recipe, FAST)
        _same_bytes(out, serial, os.path.splitext(name)[0])
    report = json.loads((tmp_path / "out" / "manifest.batch.json").read_text())
    assert {a["status"] for a in report["assets"]} == {BAKED}
    assert all(a["fragments"] > 1 and a["checks"]["watertight"] for a in report["assets"])
    assert "| chair.glb | wood | baked |" in (tmp_path / "out" / "manifest.batch.md").read_text()

    again = CliRunner().invoke(cli, args + ["--json"])
    assert again.exit_code == 0, again.output
    second = json.loads(again.stdout)
    assert second["counts"] == {BAKED: 0, UP_TO_DATE: 3, FAILED: 0}
    assert second["cluster"].startswith("no cluster")  # nothing to do: no workers started


def _generated_manifest(root) -> str:
    """boxes/a.obj, boxes/b.obj (recipe crate.toml, by glob) and ball.obj (rock.toml, table form)."""
    _write_box(str(root / "boxes" / "a.obj"))
    _write_box(str(root / "boxes" / "b.obj"), extents=(0.5, 1.0, 0.7))
    _write_box(str(root / "ball.obj"), sphere=True)
    (root / "recipes").mkdir()
    for name in ("crate", "rock"):  # TINY as recipes
        (root / "recipes" / f"{name}.toml").write_text('extends = "stone"\n[cage]\ntarget_faces = 300\n'
                                                       '[modes]\nnum_modes = 4\n')
    (root / "props.toml").write_text(
        '[assets]\n"ball.obj" = { recipe = "recipes/rock.toml", set = ["runtime.threshold=5.0"] }\n\n'
        '[[batch]]\nglob = "boxes/*.obj"\nrecipe = "recipes/crate.toml"\n')
    return str(root / "props.toml")


def test_generated_batch_is_incremental_and_writes_an_impacts_dataset(tmp_path):
    import pyarrow.parquet as pq

    manifest = _generated_manifest(tmp_path / "assets")
    out = tmp_path / "out"
    options = BatchOptions(out_dir=str(out), workers=2, cache_dir=str(tmp_path / "cache"))
    first = run_batch(manifest, options)
    assert _statuses(first) == {"ball.obj": BAKED, "boxes/a.obj": BAKED, "boxes/b.obj": BAKED}
    for folder, stem in ((out, "ball"), (out / "boxes", "a"), (out / "boxes", "b")):
        _complete_set(str(folder), stem)
    assert _complete_set(str(out), "ball")["recipe"]["parameters"]["runtime"]["threshold"] == 5.0

    # Editing one recipe re-bakes only the assets that use it.
    crate = tmp_path / "assets" / "recipes" / "crate.toml"
    crate.write_text(crate.read_text() + "\n[smooth]\nsmoothing = 0.002\n")
    second = run_batch(manifest, options)
    assert _statuses(second) == {"ball.obj": UP_TO_DATE, "boxes/a.obj": BAKED, "boxes/b.obj": BAKED}
    # Only smoothing changed: the workers reused the shared cache's cages and modes.
    assert set(_complete_set(str(out / "boxes"), "a")["cache"].values()) == {"hit"}

    # Impacts only: nothing is re-baked; rows are deterministic and some hits break, some do not.
    third = run_batch(manifest, BatchOptions(out_dir=str(out), workers=2, impacts=6))
    assert set(_statuses(third).values()) == {UP_TO_DATE}
    table = pq.read_table(str(out / "props.impacts.parquet"))
    assert table.num_rows == 18
    assert table.column_names[:3] == ["asset", "recipe", "impact"]
    rows = table.to_pylist()
    assert [r["asset"] for r in rows] == ["ball.obj"] * 6 + ["boxes/a.obj"] * 6 + ["boxes/b.obj"] * 6
    broke = [r["broken_bonds"] > 0 for r in rows]
    assert any(broke) and not all(broke)
    for r in rows:
        magnitude = float(np.linalg.norm(r["impulse"]))
        assert (r["broken_bonds"] > 0) == (magnitude > r["breaking_impulse"] * (1 - 1e-9))
    _check_rows_recomputed(rows[6:12], out / "boxes", "a", tmp_path / "assets" / "boxes" / "a.obj")


def _check_rows_recomputed(rows, out_dir, stem, asset) -> None:
    """The dataset rows equal a direct computation with the asset's content seed."""
    from fracture_cli.batch.impacts import asset_impacts
    from fracture_cli.batch.inputs import hash_inputs
    from fracture_cli.batch.state import content_seed
    from fracture_cli.runtime.format import load_runtime
    from fracture_cli.stages.load import load_surface

    surface = load_surface(str(asset))
    data = load_runtime(str(out_dir / f"{stem}.fracture.json"))
    seed = content_seed(hash_inputs(str(asset)))
    expect = asset_impacts(data, surface.world_vertices(), surface.faces, len(rows), seed)
    np.testing.assert_array_equal(np.array([r["point"] for r in rows]), expect.points)
    np.testing.assert_array_equal(np.array([r["groups"] for r in rows]), expect.groups)


def test_a_bake_that_raises_or_hangs_fails_alone(tmp_path):
    root = tmp_path / "assets"
    _write_box(str(root / "good.obj"))
    (root / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 9\n")
    # A material file that is a FIFO nobody writes: reading it would block forever (like a hung network
    # mount); the reader refuses it by name instead of opening it in a way that waits.
    _write_box(str(root / "fifo.obj"), extents=(0.8, 0.8, 0.3))
    (root / "fifo.obj").write_text("mtllib fifo.mtl\n" + (root / "fifo.obj").read_text())
    os.mkfifo(root / "fifo.mtl")
    # A bake that cannot finish in its time (1 s: less than the bake process takes to start) is killed.
    _write_box(str(root / "slow.obj"), sphere=True)
    # Only the slow asset gets a short timeout: the others may be slow on a busy machine.
    (root / "m.toml").write_text('[assets]\n"*.obj" = "stone"\n"slow.obj" = { recipe = "stone", timeout = 1 }\n')
    out = tmp_path / "out"
    result = CliRunner().invoke(cli, ["batch", str(root / "m.toml"), "-o", str(out), "--workers", "2",
                                      *_set_args(TINY)])
    assert result.exit_code == 1
    assert "error: 3 of 4 asset(s) failed" in result.output
    assert "Traceback" not in result.output
    report = json.loads((out / "m.batch.json").read_text())
    by_name = {a["name"]: a for a in report["assets"]}
    assert by_name["good.obj"]["status"] == BAKED
    assert by_name["broken.obj"]["status"] == FAILED and "broken.obj" in by_name["broken.obj"]["error"]
    assert "fifo.obj: references 'fifo.mtl', which is a FIFO" in by_name["fifo.obj"]["error"]
    assert "timed out after 1 s" in by_name["slow.obj"]["error"]
    _complete_set(str(out), "good")
    for stem in ("fifo", "slow"):
        assert not any(os.path.exists(out / f"{stem}{s}") for s in DATA_SUFFIXES)
    # Nobody ever opened the FIFO for reading (a writer would find a reader).
    with pytest.raises(OSError) as exc:
        os.open(root / "fifo.mtl", os.O_WRONLY | os.O_NONBLOCK)
    assert exc.value.errno == errno.ENXIO


def _raising_task(job: BakeJob) -> TaskResult:
    if job.name == "b.obj":
        raise RuntimeError("simulated bug in the task")
    return TaskResult(index=job.index, status=BAKED, seconds=0.0)


def test_a_task_that_raises_fails_its_asset_only(tmp_path):
    root = tmp_path / "assets"
    for name in ("a", "b", "c"):
        _write_box(str(root / f"{name}.obj"))
    (root / "m.toml").write_text('[assets]\n"*.obj" = "default"\n')
    report = run_batch(str(root / "m.toml"), BatchOptions(out_dir=str(tmp_path / "out"), workers=2),
                       task=_raising_task)
    assert _statuses(report) == {"a.obj": BAKED, "b.obj": FAILED, "c.obj": BAKED}
    assert "RuntimeError: simulated bug in the task" in report.failed[0].error


def _kill_a_worker_mid_bake(worker_pids: list[int], killed: dict, stop: threading.Event) -> None:
    """Kill the first worker whose bake process has run for a second (SIGKILL, like the OOM killer)."""
    import psutil

    while not stop.is_set():
        for pid in worker_pids:
            try:
                children = psutil.Process(pid).children()
            except psutil.NoSuchProcess:
                continue
            bakes = [c for c in children if "fracture_cli.batch.child" in " ".join(c.cmdline())]
            if bakes and time.time() - bakes[0].create_time() > 1.0:
                killed["bake"] = bakes[0].pid
                os.kill(pid, signal.SIGKILL)
                killed["worker"] = pid
                return
        time.sleep(0.1)


def test_a_worker_killed_mid_batch_loses_nothing(tmp_path):
    import psutil
    from distributed import Client, LocalCluster

    root = tmp_path / "assets"
    _write_box(str(root / "a.obj"))
    _write_box(str(root / "b.obj"), sphere=True)
    (root / "m.toml").write_text('[assets]\n"*.obj" = "stone"\n')
    out = tmp_path / "out"
    killed: dict = {}
    stop = threading.Event()
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None, silence_logs=50) as cluster, \
            Client(cluster) as client:
        pids = list(client.run(os.getpid).values())
        killer = threading.Thread(target=_kill_a_worker_mid_bake, args=(pids, killed, stop), daemon=True)
        killer.start()
        try:
            report = run_batch(str(root / "m.toml"), BatchOptions(out_dir=str(out), scheduler=cluster.scheduler_address,
                                                                  overrides=TINY))
        finally:
            stop.set()
    assert killed.get("worker"), "the test never saw a bake running to kill its worker"
    assert not psutil.pid_exists(killed["bake"]) or psutil.Process(killed["bake"]).status() == psutil.STATUS_ZOMBIE
    assert _statuses(report) == {"a.obj": BAKED, "b.obj": BAKED}
    serial = str(tmp_path / "serial")
    for stem in ("a", "b"):
        _complete_set(str(out), stem)
        _serial_bake(str(root / f"{stem}.obj"), serial, "stone", TINY)
        _same_bytes(str(out), serial, stem)
    leftovers = [n for n in os.listdir(out) if ".tmp" in n or ".bake-" in n]
    assert not leftovers, leftovers


def test_missing_dask_is_one_line(tmp_path, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_dask(name, *args, **kwargs):
        if name == "distributed" or name.startswith("distributed."):
            raise ImportError("No module named 'distributed'")
        return real_import(name, *args, **kwargs)

    root = tmp_path / "assets"
    _write_box(str(root / "a.obj"))
    (root / "m.toml").write_text('[assets]\n"a.obj" = "stone"\n')
    monkeypatch.setattr(builtins, "__import__", no_dask)
    result = CliRunner().invoke(cli, ["batch", str(root / "m.toml"), "-o", str(tmp_path / "out")])
    assert result.exit_code == 1
    assert "pip install 'fracture-cli[batch]'" in result.output
    assert len(result.output.strip().splitlines()) == 1
