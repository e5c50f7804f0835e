"""The Dask task: run one asset's bake process with a timeout.

The task itself never raises for a bad asset: a bake error, a crash, a timeout
all become a failed :class:`~fracture_cli.batch.jobs.TaskResult` with one
line. The bake runs in its own process group, so a timeout kills it together
with any helper it started (the TetGen worker), and single-threaded BLAS, so
parallel bakes do not oversubscribe the cores.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import time

from fracture_cli.batch.jobs import FAILED, BakeJob, TaskResult

# One BLAS/OpenMP thread per bake: the parallelism is one bake per worker.
SINGLE_THREADED = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                          "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")}


def _kill_group(proc: subprocess.Popen) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def _last_line(log_file: str) -> str:
    try:
        with open(log_file, "rb") as fh:
            fh.seek(max(0, os.path.getsize(log_file) - 4096))
            lines = [ln.strip() for ln in fh.read().decode("utf-8", "replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:300] if lines else ""


def _crash_message(job: BakeJob, returncode: int, log_file: str) -> str:
    if returncode < 0:
        try:
            what = f"killed by signal {signal.Signals(-returncode).name}"
        except ValueError:
            what = f"killed by signal {-returncode}"
    else:
        what = f"exited with code {returncode}"
    tail = _last_line(log_file)
    return f"{job.input_path}: the bake process {what}" + (f" ({tail})" if tail else "")


def _worker_address() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return ""


def run_job(job: BakeJob) -> TaskResult:
    """Bake one asset in a subprocess; see the module docstring.

    Parameters
    ----------
    job : BakeJob

    Returns
    -------
    TaskResult
        ``seconds`` is the wall-clock time of the bake process.
    """
    worker = _worker_address()
    with tempfile.TemporaryDirectory(prefix="fracture-batch-") as tmp:
        job_file, result_file, log_file = (os.path.join(tmp, n) for n in ("job.pkl", "result.pkl", "bake.log"))
        with open(job_file, "wb") as fh:
            pickle.dump(job, fh)
        env = {**os.environ, **SINGLE_THREADED}
        t0 = time.perf_counter()
        with open(log_file, "wb") as log:
            proc = subprocess.Popen(
                [sys.executable, "-m", "fracture_cli.batch.child", job_file, result_file, str(os.getpid())],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
            try:
                returncode = proc.wait(timeout=job.timeout)
            except subprocess.TimeoutExpired:
                return TaskResult(index=job.index, status=FAILED, seconds=round(time.perf_counter() - t0, 3),
                                  worker=worker, error=f"{job.input_path}: timed out after {job.timeout:g} s and "
                                                       "was killed (raise --timeout if it needs longer)")
            finally:
                _kill_group(proc)  # also reaps helpers the bake left behind
        seconds = round(time.perf_counter() - t0, 3)
        if not os.path.exists(result_file):
            return TaskResult(index=job.index, status=FAILED, seconds=seconds, worker=worker,
                              error=_crash_message(job, returncode, log_file))
        with open(result_file, "rb") as fh:
            result: TaskResult = pickle.load(fh)
    return dataclasses.replace(result, seconds=seconds, worker=worker)
