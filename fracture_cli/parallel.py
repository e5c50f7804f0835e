"""How many cores a bake may use (``--jobs``), an ordered parallel map, and BLAS thread limits.

Stages with independent work items (one boolean per piece, one check per
fragment) call :func:`ordered_map`. With more than one job it runs the items
on forked worker processes (manifold3d keeps the GIL during a boolean, so
threads would not run them at the same time) and returns the results in the
items' order: what a worker computes depends only on its item and on the data
shared at fork time, never on which worker ran it or when, so the outputs are
byte-identical to a serial run (tests/test_parallel.py bakes both ways).

:func:`using` sets the number of jobs for everything run inside it (the
pipeline's :class:`~fracture_cli.pipeline.Runner` does this per stage) and
limits BLAS (OpenBLAS, MKL) to one thread meanwhile: the bake's own workers
use the cores, a BLAS worker thread on top would only oversubscribe them
(``make -j2 assets``, several bakes at once), and a reduction split over a
varying number of threads would round differently on machines with a
different core count.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from collections.abc import Callable, Iterator, Sequence
from contextvars import ContextVar
from typing import Any, TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")

# The jobs of the current bake (None: every core), set by :func:`using`.
_JOBS: ContextVar[int | None] = ContextVar("fracture_jobs", default=None)
# What forked workers read: set before the pool forks, so they inherit it (nothing is pickled but results).
_WORK: tuple[Callable[[Any, Any], Any], Any, Sequence[Any]] | None = None
_WORK_LOCK = threading.Lock()
_IN_WORKER = False


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity, else ``os.cpu_count()``)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return max(os.cpu_count() or 1, 1)


def current_jobs() -> int:
    """The number of jobs for the work being run: :func:`using`'s, else every core (1 inside a worker)."""
    if _IN_WORKER:
        return 1
    value = _JOBS.get()
    return available_cores() if value is None else max(int(value), 1)


@contextlib.contextmanager
def using(jobs: int | None) -> Iterator[None]:
    """Run the body with ``jobs`` jobs (None: every core) and BLAS limited to one thread."""
    token = _JOBS.set(jobs)
    try:
        with blas_threads(1):
            yield
    finally:
        _JOBS.reset(token)


@contextlib.contextmanager
def blas_threads(count: int) -> Iterator[None]:
    """Limit the BLAS libraries numpy and scipy use to ``count`` threads in the body (threadpoolctl)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=count, user_api="blas"):
        yield


def ordered_map(function: Callable[[Any, T], R], items: Sequence[T], shared: Any = None, *,
                jobs: int | None = None) -> list[R]:
    """``[function(shared, item) for item in items]``, on up to ``jobs`` worker processes.

    Parameters
    ----------
    function : callable
        A module-level function ``function(shared, item)``; it must not depend
        on global state that a previous call changed (workers run any subset).
    items : sequence
        The work items; results come back in this order.
    shared : object, optional
        Read-only data every call needs (a manifold3d solid, meshes): workers
        inherit it when they fork, it is never pickled.
    jobs : int, optional
        At most this many processes (default :func:`current_jobs`). One job, one item,
        a worker process or a platform without ``fork`` runs serially here.

    Returns
    -------
    list
        The results, in the order of ``items`` (each pickled back from its worker).
    """
    count = min(jobs if jobs is not None else current_jobs(), len(items))
    if count <= 1 or _IN_WORKER or not hasattr(os, "fork"):
        return [function(shared, item) for item in items]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    global _WORK
    with _WORK_LOCK:
        _WORK = (function, shared, items)
        try:
            with ProcessPoolExecutor(max_workers=count, mp_context=multiprocessing.get_context("fork"),
                                     initializer=_start_worker) as pool:
                # Interleaved small chunks balance items of very different cost (a big fragment next to slivers).
                return list(pool.map(_run_item, range(len(items)), chunksize=max(1, len(items) // (8 * count))))
        finally:
            _WORK = None


def _start_worker() -> None:
    global _IN_WORKER
    _IN_WORKER = True
    from fracture_cli import progress

    progress.configure(None)  # the parent process owns the terminal
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


def _run_item(index: int) -> Any:
    assert _WORK is not None, "worker started without work"  # internal invariant: set before the fork
    function, shared, items = _WORK
    return function(shared, items[index])
