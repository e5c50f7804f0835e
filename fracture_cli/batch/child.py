"""The bake process: ``python -m fracture_cli.batch.child JOB RESULT PARENT_PID``.

A Dask worker runs every bake in one of these, so a bake that hangs inside a C
extension can be killed at its timeout without taking the worker down, and a
crash (SIGSEGV in a native library) fails one asset instead of the worker. On
Linux the process asks the kernel to kill it when its worker dies, so a lost
worker never leaves a bake running that could publish after the retry.

The job is a pickled :class:`~fracture_cli.batch.jobs.BakeJob`; the result, a
pickled :class:`~fracture_cli.batch.jobs.TaskResult`, is written atomically.
Every error ends up as the result's one-line ``error`` (an unexpected one
also with its traceback in ``detail``, for ``--debug`` and bug reports).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import pickle
import signal
import sys
import traceback

from fracture_cli.batch.adapter import bake_asset
from fracture_cli.batch.inputs import InputFile, as_read
from fracture_cli.batch.jobs import BAKED, FAILED, UP_TO_DATE, BakeJob, TaskResult
from fracture_cli.batch.state import asset_key, content_seed, state_path, write_state
from fracture_cli.errors import FractureError, InputError
from fracture_cli.io.atomic import write_bytes_atomic
from fracture_cli.pipeline.bake import describe_error

log = logging.getLogger("fracture_cli")

_PR_SET_PDEATHSIG = 1


def _die_with_parent(parent_pid: int) -> None:
    """Be killed when the worker dies (Linux); exit at once if it is already gone."""
    if sys.platform.startswith("linux"):
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent_pid:
        os._exit(1)


class _Collect(logging.Handler):
    """Keeps the bake's warnings for the batch report."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def _impacts(job: BakeJob, inputs: tuple[InputFile, ...], seed: int):
    """The dataset rows of an asset, from the input read again: refused if it is not the input baked."""
    # on first use: the batch driver starts light; workers load the stages
    from fracture_cli.batch.impacts import asset_impacts
    from fracture_cli.io.inputs import input_files, recording_reads
    from fracture_cli.runtime.format import load_runtime
    from fracture_cli.stages.load import LoadOptions, load_surface

    data = load_runtime(os.path.join(job.out_dir, f"{job.stem}.fracture.json"))
    with recording_reads() as reads:
        surface = load_surface(job.input_path, job.recipe.section("load", LoadOptions))
    now = {f.name: f.sha256 for f in as_read(job.input_path, reads.as_read(input_files(job.input_path)))}
    baked = {f.name: f.sha256 for f in inputs}
    # Files on one side only mean another listing, hence another asset file: its own hash differs then.
    if any(now[name] != baked[name] for name in now.keys() & baked.keys()):
        raise InputError("changed while the batch ran (its bytes now are not the ones its outputs were baked "
                         "from); run the batch again", path=job.input_path)
    return asset_impacts(data, surface.world_vertices(), surface.faces, job.impacts, seed)


def _read_report(job: BakeJob) -> dict:
    import json

    with open(os.path.join(job.out_dir, f"{job.stem}.report.json"), encoding="utf-8") as fh:
        return json.load(fh)


def run(job: BakeJob) -> TaskResult:
    """Bake (unless up to date), record the state, and compute the impacts asked for.

    The state is keyed on the hashes the bake took of the bytes it read (not
    the planner's, taken earlier): an input edited after planning is recorded
    as the bytes baked, so undoing the edit later makes the asset stale again.
    """
    inputs, seed = job.inputs, job.seed
    if job.bake:
        outcome = bake_asset(job.input_path, job.out_dir, job.recipe, job.cache_dir)
        inputs = as_read(job.input_path, outcome.inputs)
        key = asset_key(inputs, job.recipe)
        if key != job.key:
            log.warning("%s: changed after the batch was planned; the outputs and the state are of the bytes the "
                        "bake read", job.input_path)
        hashed_at = min(r.started_ns for r in outcome.inputs)
        write_state(state_path(job.out_dir, job.stem), key, inputs, outcome.outputs, hashed_at, outcome.report)
        report, status, seed = outcome.report, BAKED, content_seed(inputs)
    else:
        report, status = _read_report(job), UP_TO_DATE
    rows = _impacts(job, inputs, seed) if job.impacts else None
    return TaskResult(index=job.index, status=status, report=report, impacts=rows, inputs=inputs)


def main(argv: list[str]) -> int:
    job_file, result_file, parent = argv
    _die_with_parent(int(parent))
    with open(job_file, "rb") as fh:
        job: BakeJob = pickle.load(fh)
    collect = _Collect()
    log.addHandler(collect)
    log.addHandler(logging.StreamHandler(sys.stderr))
    log.setLevel(logging.WARNING)
    try:
        result = run(job)
    except FractureError as exc:
        result = TaskResult(index=job.index, status=FAILED, error=str(exc))
    except Exception as exc:  # a bug in a stage: one line in the summary, the traceback in the report
        result = TaskResult(index=job.index, status=FAILED, detail=traceback.format_exc(),
                            error=describe_error(exc, job.input_path))
    result = dataclasses.replace(result, warnings=tuple(collect.messages))
    write_bytes_atomic(result_file, pickle.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
