"""--jobs: the ordered parallel map and byte-identical bakes with one job and with several."""

from __future__ import annotations

import json
import logging
import os
import time

import numpy as np
import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.cli.options import hoist_global_flags
from fracture_cli.errors import StageError
from fracture_cli.system import parallel

from conftest import SAMPLE_ASSETS

# A small bake (seconds) that still has several fragments and uses the field smoothing.
FAST = ["--set", "cage.target_faces=600", "--set", "modes.num_modes=4", "--set", "smooth.refine=1"]


# Every test starts outside make, with no jobserver client kept (see conftest).
pytestmark = pytest.mark.usefixtures("outside_make")


def _square_plus(shared, item):
    return shared["offset"] + item * item, os.getpid()


def _fail_on_three(shared, item):
    if item == 3:
        raise StageError(f"item {item} failed", stage="test")
    return item


def test_ordered_map_keeps_order_and_uses_workers():
    items = list(range(40))
    serial = parallel.ordered_map(_square_plus, items, {"offset": 7}, jobs=1)
    forked = parallel.ordered_map(_square_plus, items, {"offset": 7}, jobs=2)
    assert [r for r, _ in forked] == [r for r, _ in serial] == [7 + i * i for i in items]
    assert {pid for _, pid in serial} == {os.getpid()}
    if hasattr(os, "fork"):
        assert os.getpid() not in {pid for _, pid in forked}


def test_worker_errors_reach_the_caller():
    with pytest.raises(StageError, match="item 3 failed"):
        parallel.ordered_map(_fail_on_three, list(range(6)), jobs=2)


def test_using_sets_jobs_and_limits_blas():
    from threadpoolctl import threadpool_info

    with parallel.using(3):
        assert parallel.current_jobs() == 3
        assert all(pool["num_threads"] == 1 for pool in threadpool_info() if pool["user_api"] == "blas")
    assert parallel.current_jobs() == parallel.available_cores()


def test_tbb_has_no_worker_threads_to_fork_from():
    # A fresh process: the first manifold3d use after single_threaded_tbb() leaves only the main thread (a TBB
    # worker would be a thread whose locks a forked worker could inherit held; tbb wait_on_address forever).
    import subprocess
    import sys

    code = ("import os, manifold3d\n"
            "from fracture_cli.system import parallel\n"
            "parallel.single_threaded_tbb()\n"
            "big = manifold3d.Manifold.sphere(1.0, 400)\n"
            "(big ^ manifold3d.Manifold.cube((1, 1, 1))).volume()\n"
            "print(len(os.listdir('/proc/self/task')), len(os.sched_getaffinity(0)))\n")
    if not hasattr(os, "sched_setaffinity"):
        pytest.skip("CPU affinity cannot be set here")
    threads, cores = map(int, subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                             check=True).stdout.split())
    assert threads == 1
    assert cores == parallel.available_cores()  # the affinity is restored


def test_jobs_flag_is_global():
    assert hoist_global_flags(["bake", "a.glb", "-o", "out", "-j", "1", "-q"])[:3] == ["-j", "1", "-q"]
    assert hoist_global_flags(["bake", "a.glb", "--jobs=2"])[0] == "--jobs=2"


@pytest.mark.slow
def test_bake_with_one_job_and_two_is_byte_identical(tmp_path, monkeypatch):
    monkeypatch.setattr(parallel, "FORK_SECONDS", -1.0)  # every map forks after its first item, however small
    chair = os.path.join(SAMPLE_ASSETS, "chair.glb")
    outs = []
    for jobs in ("1", "2"):
        out = tmp_path / f"jobs{jobs}"
        result = CliRunner().invoke(cli, ["bake", chair, "-o", str(out), "-r", "wood", *FAST, "-j", jobs, "-q"])
        assert result.exit_code == 0, result.output
        outs.append(out)
    for name in ("chair.glb", "chair.fracture.json", "chair.fracture.bin"):
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name
    reports = [json.loads((o / "chair.report.json").read_text()) for o in outs]
    for r in reports:
        r.pop("seconds")
    assert reports[0] == reports[1]
    assert reports[0]["counts"]["fragments"] > 1
    assert np.isfinite(reports[0]["checks"]["max_overlap"])


def test_large_input_crop_gives_the_same_fragments(monkeypatch):
    """Above _CROP_TRIANGLES pieces are cut from crops of the input: same fragments, same volumes."""
    from test_fragments import cage_tets, octant_pieces, uv_sphere

    import fracture_cli.stages.fragments.cut as fr
    from fracture_cli.geometry.trigeom import signed_volume
    from fracture_cli.stages.fragments import fragments
    from fracture_cli.stages.smooth import SmoothOptions, smooth

    surf = uv_sphere()
    tm = cage_tets()
    regions = smooth(tm, octant_pieces(tm), SmoothOptions(smoothing=0.0))
    whole = fragments(surf, regions)
    monkeypatch.setattr(fr, "_CROP_TRIANGLES", 0)
    monkeypatch.setattr(fr, "_CROP_GROUPS", 3)
    cropped = fragments(surf, regions)
    assert [f.piece for f in cropped.fragments] == [f.piece for f in whole.fragments]
    for a, b in zip(cropped.fragments, whole.fragments):
        assert np.isclose(signed_volume(a.vertices, a.faces), signed_volume(b.vertices, b.faces), rtol=1e-9)
        np.testing.assert_allclose(a.vertices.min(axis=0), b.vertices.min(axis=0), atol=1e-12)
    assert fr._piece_groups(regions.meshes, 3) == fr._piece_groups(regions.meshes, 3)
    assert sorted(p for g in fr._piece_groups(regions.meshes, 3) for p in g) == list(range(len(regions.meshes)))


def _sleeps_in_workers(shared, item):
    """Sleeps (no CPU time) when run in a forked worker: what a worker stuck on an inherited lock looks like."""
    import time

    if parallel._IN_WORKER:
        time.sleep(3600)
    return item * shared


def test_stalled_workers_are_abandoned_and_the_items_finished_here(monkeypatch, caplog):
    monkeypatch.setattr(parallel, "STALL_SECONDS", 0.5)
    with caplog.at_level(logging.WARNING, logger="fracture_cli"):
        assert parallel.ordered_map(_sleeps_in_workers, list(range(7)), 3, jobs=2) == [3 * i for i in range(7)]
    assert any("stopped making progress" in r.message for r in caplog.records)


def _costly(shared, item):
    """About ``shared`` CPU seconds of work, and the process that did it."""
    start = time.process_time()
    while time.process_time() - start < shared:
        pass
    return item, os.getpid()


def test_a_bake_map_forks_only_for_work_that_pays():
    # Cheap items stay in this process whatever --jobs says; costly ones go to workers after the first.
    with parallel.using(2):
        cheap = parallel.ordered_map(_costly, list(range(30)), 0.0)
        costly = parallel.ordered_map(_costly, list(range(8)), 2 * parallel.FORK_SECONDS / 5)
    assert [i for i, _ in cheap] == list(range(30))
    assert {pid for _, pid in cheap} == {os.getpid()}
    assert [i for i, _ in costly] == list(range(8))
    assert costly[0][1] == os.getpid()
    if hasattr(os, "fork"):
        assert os.getpid() not in {pid for _, pid in costly[1:]}


def test_fork_pays_above_the_break_even():
    per_item = parallel.FORK_SECONDS / 10
    assert not parallel.fork_pays(per_item, 1, 10, 2)  # half of 10 items saved = the fork's cost: no gain
    assert parallel.fork_pays(per_item, 1, 30, 2)
    assert not parallel.fork_pays(per_item, 1, 1000, 1)
    assert 1 <= parallel.idle_cores(parallel.available_cores()) <= parallel.available_cores()
