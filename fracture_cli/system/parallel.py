"""How many cores a bake may use (``--jobs``), an ordered parallel map, and BLAS thread limits.

Stages with independent work items (one boolean per piece, one check per
fragment) call :func:`ordered_map`. With more than one job it runs the items
on forked worker processes (manifold3d keeps the GIL during a boolean, so
threads would not run them at the same time) and returns the results in the
items' order: what a worker computes depends only on its item and on the data
shared at fork time, never on which worker ran it or when, so the outputs are
byte-identical to a serial run (tests/test_parallel.py bakes both ways).

:func:`using` sets the number of jobs for everything run inside it (the
pipeline's :class:`~fracture_cli.pipeline.runner.Runner` does this per stage) and
limits BLAS (OpenBLAS, MKL) to one thread meanwhile: the bake's own workers
use the cores, a BLAS worker thread on top would only oversubscribe them
(``make -j2 assets``, several bakes at once), and a reduction split over a
varying number of threads would round differently on machines with a
different core count.

A pool pays for itself only when the work is large (issue 33: 24 forks cost
a small bake 1.1 s, and beside a second bake on 2 cores the default ``-j``
was 1.2-1.3x slower than ``-j 1``): a bake's map therefore starts its items
in this process and forks only for the items left when their estimated cost
is above the break-even (:func:`fork_pays`, :data:`FORK_SECONDS`), on the
cores that no other task is running on at that moment (:func:`idle_cores`).

Under a parallel ``make`` (``make -j2 assets``) make already runs several
bakes at once; a bake's own workers would only add fork and pickle overhead
and fight for the same cores. Unless ``--jobs`` is given, a map then asks
make's jobserver (:mod:`fracture_cli.system.jobserver`) for free job slots and starts
only that many workers (none when every slot is busy), or runs serially when
make has no jobserver this process can use. Outside make nothing changes.

Forking a process whose native thread pools are busy is unsafe: a TBB worker
of manifold3d that holds a task-pool lock at the moment of ``fork()`` leaves
that lock held forever in the child, whose next boolean then sleeps in
``tbb::detail::r1::wait_on_address`` (seen: 2 of 300 forks right after a
boolean, and the bench's ~59 s collision-stage stalls). :func:`using` and
:func:`ordered_map` therefore size manifold3d's TBB scheduler to one thread
before its first use (:func:`single_threaded_tbb`): the parent then has no
TBB worker thread that a fork could cut off mid-operation. The parent loses
nothing it needs: ``--jobs`` gives the cores to the forked workers.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextvars import ContextVar
from typing import Any, TypeVar

from fracture_cli.system import jobserver

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
    """The most jobs for the work being run: :func:`using`'s, else the default (1 inside a worker).

    The default is every core, or 1 under a parallel ``make`` whose jobserver
    is not usable here (:func:`fracture_cli.system.jobserver.default_jobs`); with a
    usable jobserver it is every core, of which :func:`ordered_map` uses as
    many as make has free slots for.
    """
    if _IN_WORKER:
        return 1
    value = _JOBS.get()
    return jobserver.default_jobs(available_cores()) if value is None else max(int(value), 1)


@contextlib.contextmanager
def using(jobs: int | None) -> Iterator[None]:
    """Run the body with ``jobs`` jobs (None: the default of :func:`current_jobs`) and BLAS limited to one thread."""
    single_threaded_tbb()
    token = _JOBS.set(jobs)
    try:
        with blas_threads(1):
            yield
    finally:
        _JOBS.reset(token)


_TBB_SIZED = False


def single_threaded_tbb() -> None:
    """Make manifold3d's TBB scheduler run without worker threads (once per process, before its first use).

    TBB sizes its pool once, from the CPU affinity of the thread that first
    uses it, and manifold3d offers no setting for it: the first manifold3d
    operation therefore runs with this thread limited to one core, which is
    restored at once. Afterwards every manifold3d operation runs on the
    calling thread only, so a forked worker never inherits a TBB lock held by
    a thread that does not exist in it (see the module notes). Does nothing
    where the affinity cannot be set (not Linux) or after the pool exists.
    """
    global _TBB_SIZED
    if _TBB_SIZED or _IN_WORKER or not hasattr(os, "sched_setaffinity"):
        return
    _TBB_SIZED = True
    import manifold3d

    cores = os.sched_getaffinity(0)
    if len(cores) <= 1:
        return  # TBB starts no worker thread on one core anyway
    os.sched_setaffinity(0, {min(cores)})
    try:
        # Any manifold3d construction makes TBB read the affinity (0.4 ms); later changes are not looked at.
        manifold3d.Manifold.cube((1.0, 1.0, 1.0)).volume()
    finally:
        os.sched_setaffinity(0, cores)


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
        a worker process or a platform without ``fork`` runs serially here. Given
        here, the items run on that many workers. Otherwise (a bake: its
        ``--jobs`` or every core) the items run in this process, one after
        another, until the ones left would take longer here than forked
        (:func:`fork_pays`); only those go to workers, so a map of small items
        never forks. Then, when neither this nor :func:`using` gives a number,
        the workers are as many as the cores no other task runs on
        (:func:`idle_cores`), or, when make's jobserver is usable, 1 + (the
        tokens it gets from make without waiting): the bake's own job slot and
        one per token, which go back when the map ends.

    Returns
    -------
    list
        The results, in the order of ``items`` (each pickled back from its worker).
    """
    count = min(jobs if jobs is not None else current_jobs(), len(items))
    if count <= 1 or _IN_WORKER or not hasattr(os, "fork"):
        return [function(shared, item) for item in items]
    if jobs is not None:  # the caller's explicit number: workers, whatever the work costs
        return _run_locked(function, shared, items, count)
    # The bake's jobs: the items run here, one after another, until the ones left are worth forking for.
    done: list[R] = []
    started = time.process_time()
    for item in items:
        if done and fork_pays(time.process_time() - started, len(done), len(items) - len(done), count):
            break
        done.append(function(shared, item))
    else:
        return done
    rest = items[len(done):]
    count = min(count, len(rest))
    make = jobserver.client() if _JOBS.get() is None else None  # an explicit number wins
    if make is None and _JOBS.get() is None:
        # No --jobs and no make: only the cores nothing else runs on now (another bake beside this one).
        count = min(count, idle_cores(available_cores()))
    if count <= 1:
        return done + [function(shared, item) for item in rest]
    if make is None:
        return done + _run_locked(function, shared, rest, count)
    # This process holds make's implicit slot; each further worker needs a token.
    with make.tokens(count - 1) as extra:
        if extra == 0:
            return done + [function(shared, item) for item in rest]
        return done + _run_locked(function, shared, rest, 1 + extra)


#: What a pool of forked workers costs before it computes anything, seconds: forking a process of 50-400 MB after
#: a bake's imports, starting two workers, pickling the results back and the copy-on-write faults of the children.
#: Measured on 2 shared cores: 0.07-0.26 s (smallest of 7) and 0.12-0.31 s (median) at load 5.5-7, 0.23-0.26 s and
#: 0.31 s at load 10-11 (bench/RESULTS.md, "Fixed costs: start-up and a worker pool"). The smaller figures count: on
#: a busy machine :func:`idle_cores` forks nothing, and no idle machine was at hand to measure.
#: A map forks only when it saves more than this.
FORK_SECONDS = 0.15


def fork_pays(spent: float, done: int, left: int, workers: int) -> bool:
    """Whether forking ``workers`` processes for the ``left`` items finishes them sooner than this process would.

    Parameters
    ----------
    spent : float
        CPU seconds this process spent on the items done so far.
    done : int
        How many items that was (the rest is estimated at the same cost per item).
    left : int
        Items still to do.
    workers : int
        Processes they would be shared among (this process waits meanwhile).

    Returns
    -------
    bool
        True when the rest's estimated cost less its share per worker is more
        than :data:`FORK_SECONDS`.
    """
    rest = spent / max(done, 1) * left
    return rest - rest / max(workers, 1) > FORK_SECONDS


def idle_cores(cores: int) -> int:
    """How many of ``cores`` no other task is running on now (at least 1: this process's own).

    Parameters
    ----------
    cores : int
        The cores this process may use (:func:`available_cores`).

    Returns
    -------
    int
        ``cores`` less the other runnable tasks, between 1 and ``cores``;
        ``cores`` where ``/proc/loadavg`` cannot be read (not Linux).

    Notes
    -----
    Linux's count of runnable tasks (``/proc/loadavg``'s fourth field, this
    process included; threads count one each), the smallest of three looks a
    millisecond apart, so a task that only just woke does not count. Beside
    another CPU-bound job on a 2-core machine this is 1: its own workers would
    only take turns with it (issue 33: forking there made a bake 1.2-1.3x
    slower than ``-j 1``).
    """
    running = []
    for attempt in range(3):
        try:
            with open("/proc/loadavg", encoding="ascii") as fh:
                running.append(int(fh.read().split()[3].split("/")[0]))
        except (OSError, ValueError, IndexError):
            return cores
        if attempt < 2:
            time.sleep(0.001)
    return max(1, min(cores, cores - (min(running) - 1)))


def _run_locked(function: Callable[[Any, T], R], shared: Any, items: Sequence[T], count: int) -> list[R]:
    """:func:`_run_forked` with the work published for the workers to inherit (one map at a time)."""
    single_threaded_tbb()  # no-op in a bake (using() did it); library callers may come here first
    global _WORK
    with _WORK_LOCK:
        _WORK = (function, shared, items)
        try:
            return _run_forked(function, shared, items, count)
        finally:
            _WORK = None


def _run_forked(function: Callable[[Any, T], R], shared: Any, items: Sequence[T], count: int) -> list[R]:
    """The items on ``count`` forked workers, in chunks; finished in this process if the workers stall.

    Forking a process that has used threaded native libraries (manifold3d's TBB
    scheduler before :func:`single_threaded_tbb`, a library's pool this module
    does not size) can, rarely, leave a lock held in the child: the worker then
    sleeps forever. This watchdog stays as the safety net. A worker never waits for anything while it has work, so
    when no chunk finishes and no worker uses any CPU time for
    :data:`STALL_SECONDS`, the pool is killed and the remaining items are
    computed here, one after another (the same results: each depends only on
    its item and ``shared``).
    """
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    # Interleaved small chunks balance items of very different cost (a big fragment next to slivers).
    size = max(1, len(items) // (8 * count))
    chunks = [range(i, min(i + size, len(items))) for i in range(0, len(items), size)]
    results: list[Any] = [None] * len(items)
    others = set(multiprocessing.active_children())
    pool = ProcessPoolExecutor(max_workers=count, mp_context=multiprocessing.get_context("fork"),
                               initializer=_start_worker)
    stalled = False
    try:
        pending = {pool.submit(_run_chunk, chunk): chunk for chunk in chunks}
        last_cpu, quiet_since = -1, time.monotonic()
        while pending:
            # Polled often, so a stall costs STALL_SECONDS, not up to twice that.
            done, _ = wait(pending, timeout=min(_STALL_POLL, STALL_SECONDS), return_when=FIRST_COMPLETED)
            for future in done:
                chunk = pending.pop(future)
                results[chunk.start:chunk.stop] = future.result()
            cpu = None if done else _workers_cpu_ticks(pool)
            if done or cpu is None or cpu != last_cpu:
                last_cpu, quiet_since = (-1 if cpu is None else cpu), time.monotonic()
                continue
            if time.monotonic() - quiet_since >= STALL_SECONDS:
                stalled = True
                break
        if stalled:
            log.warning("parallel workers stopped making progress (no CPU time for %g s); finishing %d item(s) in "
                        "this process", STALL_SECONDS, sum(len(c) for c in pending.values()))
            _kill_workers(pool, others)
            for chunk in pending.values():
                results[chunk.start:chunk.stop] = [function(shared, items[i]) for i in chunk]
    except BaseException:
        # Ctrl-C (the workers ignore SIGINT: this process handles it) or a worker's error: the workers would
        # finish their chunks before shutdown() returned, so they are killed; the exception goes on as it is.
        _kill_workers(pool, others)
        raise
    finally:
        try:
            pool.shutdown(wait=not stalled, cancel_futures=True)
        except BaseException:  # a Ctrl-C while shutdown() waits for the workers to stop (seen once in the sweep)
            _kill_workers(pool, others)
            raise
    return results


def _kill_workers(pool: Any, others: set[Any]) -> None:
    """Kill the pool's workers so that nothing waits for them: neither shutdown() nor the interpreter's exit.

    Also a worker forked but not yet registered in the pool (Ctrl-C in the
    middle of ``submit()``): with no manager thread to stop it, the exit would
    wait for it forever. And a worker killed while it sends a result leaves
    part of a message in the result pipe, whose rest the pool's manager thread
    would wait for forever (shutdown() and the exit join that thread; seen in
    9 of 10 Ctrl-Cs of a map with 20 MB results): this process holds the
    pipe's write end too (it never writes to it), so that copy is closed and
    the reader sees the end of the pipe once the workers are gone.
    ``others``: the processes this one had started before the pool.
    """
    import multiprocessing

    workers = set((getattr(pool, "_processes", None) or {}).values())
    for process in workers | (set(multiprocessing.active_children()) - others):
        process.kill()
    writer = getattr(getattr(pool, "_result_queue", None), "_writer", None)
    if writer is not None:
        with contextlib.suppress(OSError):
            writer.close()


#: Seconds without a finished chunk and without any worker CPU time after which forked workers count as stalled
#: (a worker with work never waits: it always uses CPU time; the bench saw workers asleep after forking from a
#: process that had run manifold3d booleans).
STALL_SECONDS = 10.0
# How often the workers' progress is looked at.
_STALL_POLL = 1.0


def _workers_cpu_ticks(pool: Any) -> int | None:
    """User + system CPU ticks of the pool's worker processes (Linux ``/proc``), None where unknown."""
    total = 0
    for pid in list(getattr(pool, "_processes", {}) or {}):
        try:
            with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            return None
        total += int(fields[11]) + int(fields[12])  # utime, stime (fields 14 and 15 of stat(5))
    return total


def _start_worker() -> None:
    global _IN_WORKER
    _IN_WORKER = True
    import signal

    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # the parent's SIGTERM-as-Ctrl-C (cli.main) is not for workers
    # Ctrl-C reaches the whole process group: the parent reports it and kills the pool (_run_forked); a worker
    # raising KeyboardInterrupt would print multiprocessing's traceback (and its siblings an EOFError).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # on first use: start-up
    from fracture_cli.system import progress

    progress.configure(None)  # the parent process owns the terminal
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


def _run_chunk(indices: range) -> list[Any]:
    assert _WORK is not None, "worker started without work"  # internal invariant: set before the fork
    function, shared, items = _WORK
    return [function(shared, items[i]) for i in indices]
