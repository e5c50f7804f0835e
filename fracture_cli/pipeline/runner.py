"""The runner: one stage at a time, logged, timed, cached, with progress (the report's ``seconds``)."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING

from fracture_cli.pipeline import PipelineState, Stage, stage
from fracture_cli.system import interrupts, parallel, progress

if TYPE_CHECKING:  # only for annotations: `fracture --help` imports neither
    from fracture_cli.options import StageOptions
    from fracture_cli.pipeline.cache import StageCache

log = logging.getLogger(__name__)


class Runner:
    """Runs stages one at a time: logs, times, caches and reports progress for each.

    Parameters
    ----------
    label : str
        Prefix of every log line (the input's stem).
    total : int, optional
        Number of steps this run will take, for "[i/n]" (default: unknown).
    cache : StageCache, optional
        Where results of :attr:`Stage.cached` stages are stored and found.
    jobs : int, optional
        How many processes a stage may use for its independent work (``--jobs``; default: every core).
        It never changes a result, so it is not part of the options the report and the cache keys record.
    origin : float, optional
        When the run began on the :func:`time.monotonic` clock (a CLI bake: the process's start); with it,
        the first step also records ``startup``, the time from ``origin`` to that step.

    Attributes
    ----------
    seconds : dict of str -> float
        Wall time of every step run, rounded to ms (the report's ``seconds``), after ``startup`` when
        ``origin`` was given.
    options : dict of str -> options dataclass
        The options each stage ran with (the report's recipe parameters).
    """

    def __init__(self, label: str, total: int | None = None, cache: StageCache | None = None,
                 jobs: int | None = None, origin: float | None = None):
        self.label = label
        self.origin = origin
        self.total = total
        self.cache = cache
        self.jobs = jobs
        self.seconds: dict[str, float] = {}
        self.options: dict[str, StageOptions] = {}
        self._step = 0
        self._key: str | None = None  # cache key of everything run so far
        self._clock: dict[str, float] = {}  # perf_counter at the start of each step still running

    def run(self, name: str, state: PipelineState, options: StageOptions) -> PipelineState:
        """Run stage ``name`` on ``state`` with ``options``; returns the new state."""
        row = stage(name)
        key = self._cache_key(row, state, options)
        with self.step(name):
            cache = self.cache if row.cached and key is not None else None
            result = cache.get(name, key, state) if cache and key else None
            if result is None:
                with parallel.using(self.jobs):
                    result = row.run(state, options)
                if cache and key:
                    cache.put(name, key, result)
        if row.name == "load" and self.cache is not None:
            # The chain of keys starts from the bytes the load read, not from a hash taken before it.
            from fracture_cli.pipeline.cache import cache_key

            self._key = cache_key("load", result.source_sha256, options)
        self.options[name] = options
        # Later stages that make fragments again (levels) make them as these did.
        return dataclasses.replace(result, stage_options={**result.stage_options, name: options})

    def step(self, name: str) -> contextlib.AbstractContextManager[progress.Task]:
        """A context that logs, times and shows progress of one step (a stage or ``export``)."""
        return _timed_step(self, name)

    def stop_clock(self, name: str) -> None:
        """Record the seconds of the running step ``name`` now; its end no longer changes them.

        The export step stops its clock where the report's ``total`` is taken (before the report itself is
        written), so that ``startup`` and the steps never add up to more than ``total``.
        """
        self.seconds[name] = round(time.perf_counter() - self._clock.pop(name), 3)

    def _cache_key(self, row: Stage, state: PipelineState, options: StageOptions) -> str | None:
        if self.cache is None:
            return None
        # on first use: `fracture --help` loads no stage
        from fracture_cli.pipeline.cache import cache_key

        if row.name == "load":
            self._key = None  # set from the bytes read, once the load has run (see run)
        elif self._key is not None:
            self._key = cache_key(row.name, self._key, options)
        return self._key


@contextlib.contextmanager
def _timed_step(runner: Runner, name: str) -> Iterator[progress.Task]:
    interrupts.check()  # a Ctrl-C that a library dropped still stops the run here
    runner._step += 1
    where = f"[{runner._step}/{runner.total}] " if runner.total else ""
    log.info("%s: %s%s ...", runner.label, where, name)
    if runner._step == 1 and runner.origin is not None:
        runner.seconds["startup"] = round(time.monotonic() - runner.origin, 3)
    t0 = runner._clock[name] = time.perf_counter()
    try:
        with progress.task(f"{runner.label}: {where}{name}") as task:
            yield task
    except Exception as exc:
        # Name the stage in a bug's one-line message (the CLI reads these; FractureErrors carry their own).
        if not hasattr(exc, "fracture_stage"):
            exc.fracture_stage = name  # type: ignore[attr-defined]
        raise
    if runner._clock.pop(name, None) is not None:  # not stopped early (Runner.stop_clock)
        runner.seconds[name] = round(time.perf_counter() - t0, 3)
    log.info("%s: %s%s done in %.2f s", runner.label, where, name, runner.seconds[name])
