"""``run_batch``: a manifest in, baked outputs, a report and (optionally) an impacts dataset out.

Order of work: read and check the manifest and every recipe, refuse outputs
that would overwrite inputs, check the output folder, plan (hash inputs, skip
what is up to date): all before a worker starts. Then one Dask task per asset;
then the dataset and the report, written atomically.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from fracture_cli.batch.cluster import check_workers, connect, require_distributed
from fracture_cli.batch.dataset import require_pyarrow, write_impacts
from fracture_cli.batch.execute import execute
from fracture_cli.batch.jobs import BakeJob, TaskResult
from fracture_cli.batch.manifest import read_manifest, resolve_assets
from fracture_cli.batch.plan import check_no_input_overwritten, plan_batch
from fracture_cli.batch.report import BatchReport, asset_outcome, write_report
from fracture_cli.batch.task import run_job
from fracture_cli.errors import FractureError, InputError, UsageError

MAX_IMPACTS = 1_000_000


class BatchInterrupted(FractureError):
    """Ctrl-C during a batch: finished assets keep their outputs; exit code 130 like any interrupted tool."""

    exit_code = 130


@dataclass(frozen=True)
class BatchOptions:
    """How to run a batch (the ``fracture batch`` options).

    Attributes
    ----------
    out_dir : str
        OUTDIR; each asset's outputs go to the asset's folder below the manifest's, mirrored here.
    scheduler : str or None
        Address of an existing Dask scheduler (``tcp://host:8786``); None: a local cluster.
    workers : int
        Worker processes of the local cluster.
    timeout : float
        Seconds before one asset's bake is killed.
    impacts : int
        Dataset impacts per asset (0: no dataset).
    cache_dir : str or None
        Shared stage cache (``bake --cache``).
    overrides : tuple of str
        ``--set`` overrides applied to every asset, after the manifest's.
    force : bool
        Bake everything, even what is up to date.
    verbose : bool
        Let Dask log at INFO.
    recipes_dir : str or None
        The user's recipe folder (``--recipes``), searched first for recipe names.
    """

    out_dir: str
    scheduler: str | None = None
    workers: int = field(default_factory=lambda: os.cpu_count() or 1)
    timeout: float = 1800.0
    impacts: int = 0
    cache_dir: str | None = None
    overrides: tuple[str, ...] = ()
    force: bool = False
    verbose: bool = False
    recipes_dir: str | None = None


def _check_options(options: BatchOptions) -> None:
    if not options.out_dir:
        raise UsageError("-o/--out must name a folder")
    if not 1 <= options.workers <= 1024:
        raise UsageError(f"--workers {options.workers} is out of range (1..1024)")
    if not (math.isfinite(options.timeout) and options.timeout > 0):
        raise UsageError(f"--timeout {options.timeout} must be a positive number of seconds")
    if not 0 <= options.impacts <= MAX_IMPACTS:
        raise UsageError(f"--impacts {options.impacts} is out of range (0..{MAX_IMPACTS})")


def _check_writable(folder: str) -> None:
    # on first use: the batch driver starts light; workers load the stages
    from fracture_cli.io.preflight import check_folder_path

    check_folder_path(folder)  # a dangling link or a link loop: one clear line, not makedirs' "File exists"
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output folder: {exc.strerror}", path=folder) from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError("output folder is not writable", path=folder)


def batch_files(manifest: str, out_root: str) -> tuple[str, str, str]:
    """Paths of the report (JSON, Markdown) and the impacts dataset of a batch."""
    stem = os.path.join(os.path.abspath(out_root), os.path.splitext(os.path.basename(manifest))[0])
    return f"{stem}.batch.json", f"{stem}.batch.md", f"{stem}.impacts.parquet"


def _run_jobs(jobs: tuple[BakeJob, ...], options: BatchOptions, manifest: str, out_root: str,
              collect: Callable[[TaskResult], None], task: Callable[[BakeJob], TaskResult]) -> tuple[str, bool]:
    """Run the jobs on a cluster; returns (cluster description, interrupted)."""
    with connect(options.scheduler, options.workers, options.verbose) as client:
        workers = len(client.scheduler_info()["workers"])
        where = f"scheduler {options.scheduler}" if options.scheduler else "local cluster"
        check_workers(client, out_root, manifest)
        try:
            execute(client, jobs, collect, task)
        except KeyboardInterrupt:
            return f"{where}, {workers} worker(s)", True
    return f"{where}, {workers} worker(s)", False


def run_batch(manifest_path: str, options: BatchOptions,
              task: Callable[[BakeJob], TaskResult] = run_job) -> BatchReport:
    """Bake every asset of a manifest on Dask; see the module docstring.

    Parameters
    ----------
    manifest_path : str
    options : BatchOptions
    task : callable, optional (default :func:`~fracture_cli.batch.task.run_job`)
        The per-asset task (a seam for tests).

    Returns
    -------
    BatchReport
        Also written as ``<manifest stem>.batch.json`` / ``.batch.md`` in OUTDIR.
        Progress goes to :mod:`fracture_cli.system.progress` (one item per task), a
        failed asset's line to the log as it happens.

    Raises
    ------
    FractureError
        A bad manifest, recipe or option, outputs that would overwrite inputs,
        an unusable cluster: before any bake. Failed assets do not raise;
        they are in the report. :class:`BatchInterrupted` on Ctrl-C.
    """
    _check_options(options)
    start = time.perf_counter()
    manifest = read_manifest(manifest_path)
    out_root = os.path.abspath(options.out_dir)
    assets = resolve_assets(manifest, out_root, options.overrides, options.recipes_dir)
    json_path, md_path, data_path = batch_files(manifest.path, out_root)
    check_no_input_overwritten(assets, (json_path, md_path, data_path), manifest.path)
    _check_writable(out_root)
    if options.impacts:
        require_pyarrow()
    cache_dir = os.path.abspath(options.cache_dir) if options.cache_dir else None
    plan = plan_batch(assets, impacts=options.impacts, cache_dir=cache_dir, timeout=options.timeout,
                      force=options.force)
    results = {r.index: r for r in plan.done}

    def collect(result: TaskResult) -> None:
        results[result.index] = result

    cluster, interrupted = "no cluster (everything up to date)", False
    if plan.jobs:
        require_distributed()
        cluster, interrupted = _run_jobs(plan.jobs, options, manifest.path, out_root, collect, task)
    outcomes = tuple(asset_outcome(a, results.get(i)) for i, a in enumerate(assets))
    dataset, rows = None, 0
    if options.impacts:
        impacts = [(a.name, a.recipe.name, found) for i, a in enumerate(assets)
                   if (found := getattr(results.get(i), "impacts", None)) is not None]
        dataset, rows = data_path, write_impacts(data_path, impacts, options.impacts)
    report = BatchReport(manifest=manifest.path, out_dir=out_root, cluster=cluster, assets=outcomes,
                         seconds=time.perf_counter() - start, dataset=dataset, dataset_rows=rows,
                         interrupted=interrupted)
    write_report(report, json_path, md_path)
    if interrupted:
        raise BatchInterrupted(f"batch interrupted after {len(results)} of {len(assets)} assets; finished outputs "
                               f"are kept, re-run to bake the rest (report: {md_path})")
    return report
