"""Run a batch's jobs on a Dask client: one task per asset, results as they finish.

A task that raises (a bug in the task itself) fails its asset only. A worker
lost mid-task is Dask's business: the scheduler gives the task to another
worker, up to ``distributed.scheduler.allowed-failures`` times (3 by default),
then reports ``KilledWorker``, which fails that asset only. The bake process
of the lost worker dies with it (see :mod:`fracture_cli.batch.child`), and a
bake publishes its outputs as a set, so the retry never meets half a set.
"""

from __future__ import annotations

import logging
import traceback
import uuid
from collections.abc import Callable
from typing import Any

from fracture_cli.batch.cluster import require_distributed
from fracture_cli.batch.jobs import FAILED, BakeJob, TaskResult
from fracture_cli.batch.task import run_job
from fracture_cli.system import progress

log = logging.getLogger(__name__)


def _outcome(future: Any, job: BakeJob, killed_worker: type[BaseException]) -> TaskResult:
    try:
        return future.result()
    except killed_worker:
        error = (f"{job.input_path}: the Dask workers running it died repeatedly (out of memory, or killed); "
                 "gave up on this asset")
    except Exception as exc:  # the task itself raised: this asset fails, the batch goes on
        first = str(exc).splitlines()[0] if str(exc) else ""
        error = f"{job.input_path}: task failed ({type(exc).__name__}: {first[:300]})"
        return TaskResult(index=job.index, status=FAILED, error=error, detail="".join(
            traceback.format_exception(type(exc), exc, exc.__traceback__)))
    return TaskResult(index=job.index, status=FAILED, error=error)


def execute(client: Any, jobs: tuple[BakeJob, ...], on_result: Callable[[TaskResult], None],
            task: Callable[[BakeJob], TaskResult] = run_job) -> list[TaskResult]:
    """Submit one task per job and collect the results in completion order.

    Parameters
    ----------
    client : distributed.Client
    jobs : tuple of BakeJob
    on_result : callable
        Called with each result as it arrives. Progress goes to
        :mod:`fracture_cli.system.progress`, a failure's line to the log at once.
    task : callable, optional (default :func:`~fracture_cli.batch.task.run_job`)
        The function run on a worker for each job.

    Returns
    -------
    list of TaskResult
        One per job. On KeyboardInterrupt the pending tasks are cancelled and
        the interrupt propagates.
    """
    distributed = require_distributed()
    run_id = uuid.uuid4().hex[:12]  # keys unique per run: two batches on one scheduler never share a task
    pending = {client.submit(task, job, key=f"fracture-bake-{run_id}-{job.index:06d}", pure=False): job
               for job in jobs}
    results = []
    with progress.task("batch", total=len(jobs)) as bar:
        try:
            for future in distributed.as_completed(list(pending)):
                job = pending.pop(future)
                result = _outcome(future, job, distributed.KilledWorker)
                future.release()
                if result.status == FAILED:
                    log.error("failed: %s: %s", job.name, result.error)
                results.append(result)
                on_result(result)
                bar.advance()
        except BaseException:
            client.cancel(list(pending))
            raise
    return results
