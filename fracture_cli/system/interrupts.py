"""Ctrl-C as the CLI reports it: one handler installed first thing, and the test of whether an error is one.

A SIGINT can surface as something other than a KeyboardInterrupt: while a
native library initialises, the interrupt raised inside its import makes the
import fail (``ImportError: initialization failed``, with the KeyboardInterrupt
as its ``__context__``, or with none when the extension swallowed it). The CLI
asks :func:`caused_by_interrupt` before calling any error a bug, so an
interrupt at any moment ends with exit code 130 and "interrupted".

Only the standard library's cheapest modules are imported here: :func:`install`
runs before the rest of the tool is imported, and whatever loads before it is a
moment in which Ctrl-C still ends the process with Python's own traceback.
"""

from __future__ import annotations

import os
import signal
import time
from types import FrameType

EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for a process stopped by Ctrl-C
#: The line of an interrupted run that wrote nothing (:func:`fracture_cli.io.outputs.interrupt_message`).
NOTHING_WRITTEN = "interrupted; no output was written (previous outputs are unchanged)"

_received: list[int] = []


#: How long a Ctrl-C may wait for an import or a JIT compile to finish before it is raised anyway.
MAX_DEFERRAL_SECONDS = 10.0
#: How soon a deferred Ctrl-C is delivered again (to this process only).
RETRY_SECONDS = 0.05
# Frames in which an exception raised by a signal handler is lost or breaks a module: the import system (a native
# library's initialisation fails with "ImportError: initialization failed", or the interpreter, after a
# KeyboardInterrupt out of code an extension ran while initialising, ends by SIGINT whatever the exit code), and
# numba/llvmlite compiling (a KeyboardInterrupt in llvmlite's ctypes callbacks is printed and dropped), and
# logging (its at-fork hooks run in the parent around every fork of a parallel map: an exception raised in one is
# printed as "Exception ignored in: <function _releaseLock>" and dropped).
_FRAGILE_FILES = ("<frozen importlib.",)
_FRAGILE_PARTS = (f"{os.sep}numba{os.sep}", f"{os.sep}llvmlite{os.sep}", f"{os.sep}logging{os.sep}__init__.py")

_installed_by: list[int] = []  # the pid of the process that installed the handler (a forked child differs)
_deferred_since: list[float] = []  # when the Ctrl-C waiting to be raised came (empty: none is waiting)
_redelivered: list[int] = []  # set by the retry thread just before it sends the SIGINT again


def _fragile(frame: FrameType | None) -> bool:
    """Whether the interrupted code is an import or a JIT compile (any frame of its stack)."""
    while frame is not None:
        name = frame.f_code.co_filename
        if name.startswith(_FRAGILE_FILES) or any(part in name for part in _FRAGILE_PARTS):
            return True
        frame = frame.f_back
    return False


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    """Python's own SIGINT behaviour (raise KeyboardInterrupt), remembering that the signal came.

    In an import or a JIT compile the KeyboardInterrupt would be lost or turned
    into another error, so the signal is sent again a moment later, until that
    code has returned (for at most :data:`MAX_DEFERRAL_SECONDS`). A signal sent
    again after the interrupt was raised meanwhile (by :func:`check`) is dropped:
    one Ctrl-C raises one KeyboardInterrupt.

    A process forked from the one that installed the handler (a parallel
    worker before its initializer ignored SIGINT) ends at once with
    :data:`EXIT_INTERRUPTED`, quietly: the installing process reports the
    interrupt and tears its workers down; a KeyboardInterrupt here would print
    the worker's traceback.
    """
    if _installed_by and os.getpid() != _installed_by[0]:
        os._exit(EXIT_INTERRUPTED)
    if _redelivered:
        _redelivered.clear()
        if not _deferred_since:
            return
    else:
        record(signum)
    now = time.monotonic()
    if _fragile(frame) and now - (_deferred_since or [now])[0] < MAX_DEFERRAL_SECONDS:
        if not _deferred_since:
            _deferred_since.append(now)
        import threading  # here, not at the top: this module loads before anything else (start-up time)

        retry = threading.Timer(RETRY_SECONDS, _redeliver, (os.getpid(),))
        retry.daemon = True
        retry.start()
        return
    _deferred_since.clear()
    raise KeyboardInterrupt


def _redeliver(pid: int) -> None:
    """Send the deferred SIGINT again (from the retry thread), if it is still waiting, to this process only."""
    if os.getpid() == pid and _deferred_since:  # not in a child forked meanwhile
        _redelivered.append(signal.SIGINT)
        try:
            os.kill(pid, signal.SIGINT)
        except OSError:
            pass


def check() -> None:
    """Raise KeyboardInterrupt if a SIGINT came (a checkpoint between steps).

    Some libraries catch and drop whatever their callbacks raise; a Ctrl-C that
    reached the handler still stops the command at the next checkpoint (and a
    deferred one is raised here rather than sent again).
    """
    if _received:
        _deferred_since.clear()
        raise KeyboardInterrupt


def record(signum: int) -> None:
    """Remember that a signal asked the command to stop (SIGINT, or SIGTERM delivered as one)."""
    _received.append(signum)


def install() -> None:
    """Record every SIGINT from now on (call first thing in ``main``).

    Only Python's default handler is replaced: a SIGINT ignored by the parent
    (a background job) stays ignored, and a handler someone else set stays.
    """
    handler = signal.getsignal(signal.SIGINT)
    if handler is signal.default_int_handler or handler is _on_sigint:
        _installed_by[:] = [os.getpid()]  # this process reports a Ctrl-C (a process forked from it does not)
        signal.signal(signal.SIGINT, _on_sigint)


def received() -> bool:
    """Whether a SIGINT (or a SIGTERM taken as one) was recorded since the last :func:`forget`."""
    return bool(_received)


def forget() -> None:
    """Start over (a new command in the same process, e.g. tests calling ``main``)."""
    _received.clear()
    _deferred_since.clear()
    _redelivered.clear()


def caused_by_interrupt(error: BaseException) -> bool:
    """Whether ``error`` is, or was raised while handling, a KeyboardInterrupt, or came after a SIGINT.

    Walks ``__cause__`` and ``__context__`` (the ImportError a native library
    raises when interrupted has the KeyboardInterrupt as its context); when the
    library dropped it, :func:`received` still says a SIGINT came.
    """
    seen: set[int] = set()
    todo: list[BaseException] = [error]
    while todo:
        exc = todo.pop()
        if id(exc) in seen:
            continue
        seen.add(id(exc))
        if isinstance(exc, KeyboardInterrupt):
            return True
        todo += [e for e in (exc.__cause__, exc.__context__) if e is not None]
    return received()
