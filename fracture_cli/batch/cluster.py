"""The Dask cluster a batch runs on: a local one by default, or an existing scheduler.

The local cluster has N worker processes of one thread each (a bake is
single-threaded Python and C; separate processes do not share the GIL). Before
any task is submitted every worker is asked for its fracture version and
whether it sees the output folder (through a probe file the client writes), so
a worker on another machine without the shared folder or with another version
fails the batch in seconds with a line naming it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import uuid
from collections.abc import Iterator
from typing import Any

from fracture_cli import __version__
from fracture_cli.errors import FractureError, InputError

log = logging.getLogger(__name__)

INSTALL_HINT = "pip install 'fracture-cli[batch]'"


def require_distributed() -> Any:
    """Import Dask distributed, or say what to install."""
    try:
        import distributed
    except ImportError:
        raise FractureError(f"'fracture batch' needs Dask distributed; install it with {INSTALL_HINT}") from None
    return distributed


@contextlib.contextmanager
def _quiet_dask(verbose: bool) -> Iterator[None]:
    """Keep Dask's own INFO/WARNING chatter (worker restarts ...) out of the user's terminal."""
    logger = logging.getLogger("distributed")
    level = logger.level
    if not verbose:
        logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ignore Ctrl-C while worker processes start (they inherit it) and while the cluster closes.

    A worker interrupted half-way through its imports prints a traceback and
    leaves the cluster in a state its close asserts against; ignored, Ctrl-C
    reaches only this process, which cancels the tasks and closes the cluster.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _open(distributed: Any, scheduler: str | None, workers: int, verbose: bool) -> tuple[Any, Any]:
    """(cluster or None, client)."""
    if not scheduler:
        with _sigint_ignored():
            cluster = distributed.LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                silence_logs=logging.INFO if verbose else logging.ERROR)
        return cluster, distributed.Client(cluster)
    try:
        client = distributed.Client(scheduler, timeout="30s")
    except (OSError, TimeoutError) as exc:
        raise FractureError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    try:
        client.wait_for_workers(1, timeout=60)
    except TimeoutError:
        client.close()
        raise FractureError(f"the Dask scheduler at {scheduler} has no workers (start some with "
                            f"'dask worker {scheduler} --nthreads 1')") from None
    return None, client


@contextlib.contextmanager
def connect(scheduler: str | None, workers: int, verbose: bool = False) -> Iterator[Any]:
    """Yield a ``distributed.Client``: to ``scheduler``, or to a new local cluster of ``workers`` processes.

    Raises
    ------
    FractureError
        Dask missing, the scheduler unreachable, or a scheduler without workers.
    """
    distributed = require_distributed()
    with _quiet_dask(verbose):
        cluster, client = _open(distributed, scheduler, workers, verbose)
        try:
            log.info("batch: Dask scheduler %s, %d worker(s)", client.scheduler.address,
                     len(client.scheduler_info()["workers"]))
            yield client
        finally:
            with _sigint_ignored():
                client.close()
                if cluster is not None:
                    cluster.close()


def _worker_facts(probe: str, manifest: str) -> dict:
    """Run on each worker: its fracture version and whether it sees the probe file and the manifest."""
    import socket

    return {"version": __version__, "host": socket.gethostname(), "sees_output": os.path.exists(probe),
            "sees_inputs": os.path.exists(manifest)}


def check_workers(client: Any, out_root: str, manifest: str) -> None:
    """Refuse workers with another fracture version or without the shared input and output folders.

    Raises
    ------
    FractureError
        Naming the worker.
    """
    os.makedirs(out_root, exist_ok=True)
    probe = os.path.join(out_root, f".fracture-batch-probe-{uuid.uuid4().hex}")
    try:
        with open(probe, "w") as fh:
            fh.write("probe\n")
    except OSError as exc:
        raise InputError(f"output folder is not writable: {exc.strerror}", path=out_root) from None
    try:
        facts = client.run(_worker_facts, probe, os.path.abspath(manifest), on_error="return")
    finally:
        os.remove(probe)
    for address, fact in sorted(facts.items()):
        if isinstance(fact, BaseException):
            raise FractureError(f"Dask worker {address} cannot run fracture ({type(fact).__name__}: {fact}); "
                                f"install the same fracture-cli[batch] on every worker")
        if fact["version"] != __version__:
            raise FractureError(f"Dask worker {address} ({fact['host']}) runs fracture {fact['version']}, this "
                                f"client {__version__}; install the same version on every worker")
        if not fact["sees_output"]:
            raise FractureError(f"Dask worker {address} ({fact['host']}) does not see the output folder "
                                f"{out_root}; it must be a shared folder mounted at the same path on every machine")
        if not fact["sees_inputs"]:
            raise FractureError(f"Dask worker {address} ({fact['host']}) does not see the manifest "
                                f"{os.path.abspath(manifest)}; the assets must be on a shared folder mounted at the "
                                "same path on every machine")
