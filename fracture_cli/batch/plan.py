"""Plan a batch: hash the inputs, refuse outputs that would overwrite inputs, skip what is up to date.

Runs on the client before any worker is started, so a bad manifest or an
output folder that would clobber an asset fails in a second, not after an hour.
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass

from fracture_cli.batch.inputs import InputFile, dependency_files, hash_inputs
from fracture_cli.batch.jobs import UP_TO_DATE, BakeJob, TaskResult
from fracture_cli.batch.manifest import Asset
from fracture_cli.batch.state import asset_key, content_seed, is_up_to_date, read_state, reusable_hashes, state_path
from fracture_cli.io.preflight import guard_outputs

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Plan:
    """Jobs for the workers and the results known without running anything.

    Attributes
    ----------
    jobs : tuple of BakeJob
        Assets to bake, or (with impacts) up-to-date assets whose impacts are wanted.
    done : tuple of TaskResult
        Up-to-date assets that need no task.
    """

    jobs: tuple[BakeJob, ...]
    done: tuple[TaskResult, ...]


def check_no_input_overwritten(assets: list[Asset], extra_outputs: tuple[str, ...], manifest: str) -> None:
    """Refuse a batch whose outputs (including its report files) would replace any input.

    The output guard of every command (:func:`~fracture_cli.io.preflight.guard_outputs`):
    paths are compared resolved and existing files by inode, so a symlink or a hard
    link to an asset in the output folder is caught too; each asset republishes its
    own bake set, and any other published set's files are refused.

    Raises
    ------
    OutputError
        Naming the output and the input (or set) it would replace.
    """
    inputs = [manifest] + [p for asset in assets for p in [asset.path] + dependency_files(asset.path)]
    states = [state_path(asset.out_dir, asset.stem) for asset in assets]
    guard_outputs(states + list(extra_outputs), inputs, sets=[(asset.out_dir, asset.stem) for asset in assets])


def _report_on_disk(asset: Asset) -> dict | None:
    try:
        with open(os.path.join(asset.out_dir, f"{asset.stem}.report.json"), encoding="utf-8") as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


def plan_batch(assets: list[Asset], *, impacts: int, cache_dir: str | None, timeout: float,
               force: bool = False) -> Plan:
    """Decide, per asset, whether to bake, only compute impacts, or do nothing.

    Parameters
    ----------
    assets : list of Asset
    impacts : int
        Dataset impacts per asset (0: none); up-to-date assets then still get a task.
    cache_dir : str or None
    timeout : float
        Seconds per bake, for assets whose manifest entry sets none.
    force : bool, optional (default False)
        Bake everything, ignoring the state files.

    Returns
    -------
    Plan
    """
    jobs, done = [], []
    for index, asset in enumerate(assets):
        state = read_state(state_path(asset.out_dir, asset.stem))
        hashed_at = time.time_ns()
        # Over the files the last bake read too (its state's names), so its key is comparable with this one.
        read_before = tuple((state or {}).get("inputs") or ()) if isinstance((state or {}).get("inputs"), dict) else ()
        inputs: tuple[InputFile, ...] = hash_inputs(asset.path, reusable_hashes(state), also=read_before)
        key = asset_key(inputs, asset.recipe)
        fresh = not force and is_up_to_date(state, key, asset.out_dir)
        report = _report_on_disk(asset) if fresh else None
        if fresh and report is not None and not impacts:
            done.append(TaskResult(index=index, status=UP_TO_DATE, report=report))
            continue
        jobs.append(BakeJob(index=index, name=asset.name, input_path=asset.path, out_dir=asset.out_dir,
                            stem=asset.stem, recipe=asset.recipe, key=key, inputs=inputs, hashed_at_ns=hashed_at,
                            bake=not (fresh and report is not None), impacts=impacts, seed=content_seed(inputs),
                            cache_dir=cache_dir, timeout=asset.timeout or timeout))
    log.info("batch: %d asset(s): %d to bake, %d up to date", len(assets), sum(j.bake for j in jobs),
             len(assets) - sum(j.bake for j in jobs))
    return Plan(jobs=tuple(jobs), done=tuple(done))
