"""A per-stem lock file in an output folder that works across processes and machines.

``.<stem>.fracture-lock`` is created with ``O_CREAT | O_EXCL``, which is
atomic on local disks and on NFSv3+ and SMB shares (unlike ``fcntl`` locks,
which NFS honours only with a working lock daemon). It holds the owner's host,
pid, the process's start time (``/proc/<pid>/stat`` field 22) and boot id, and
a random token; the owner touches it every :data:`HEARTBEAT_SECONDS`. A lock
whose owner ran on this host is stale only when that process no longer runs:
its pid is gone, or now belongs to a process that started at another time (a
pid reused), or the machine has rebooted since; a live owner's lock is never
broken, however long its heartbeat pauses (a stopped or busy bake). A lock of
another host (or without an owner to check) is stale when its modification
time has not changed for :data:`STALE_SECONDS` while a waiter watched it (the
owner's machine died; only the waiter's monotonic clock is used, so machines
need not agree on the time). A stale lock is removed
under a second exclusive file, ``<lock>.break``, after checking that its token
is still the stale one, so two waiters never remove a fresh lock. See
docs/OUTPUTS.md.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import secrets
import signal
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from types import FrameType

from fracture_cli.errors import OutputError, printable

log = logging.getLogger(__name__)

HEARTBEAT_SECONDS = 5.0
STALE_SECONDS = 60.0
LOCK_TIMEOUT_SECONDS = 600.0
_POLL_SECONDS = 0.1


@dataclass
class StemLock:
    """``.<stem>.fracture-lock`` in the output folder; see the module docstring.

    Use as a context manager, or :meth:`acquire` / :meth:`release`.
    """

    out_dir: str
    stem: str
    timeout: float = LOCK_TIMEOUT_SECONDS
    token: str = field(default_factory=lambda: secrets.token_hex(16))
    _stop: threading.Event = field(default_factory=threading.Event, repr=False)
    _beat: threading.Thread | None = field(default=None, repr=False)

    @property
    def path(self) -> str:
        return os.path.join(self.out_dir, f".{self.stem}.fracture-lock")

    def __enter__(self) -> StemLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def acquire(self, timeout: float | None = None) -> bool:
        """Take the lock, waiting up to ``timeout`` s (default ``self.timeout``) for a live owner.

        Returns
        -------
        bool
            True when taken; False only if ``timeout`` is 0 and a live bake holds it.

        Raises
        ------
        OutputError
            The lock is still held by a live bake after ``timeout`` seconds, or
            cannot be created.
        """
        timeout = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        seen: tuple[float, str] | None = None  # (mtime, token) of the holder's lock when first seen
        seen_since = time.monotonic()
        told: str | None = None  # the token of the live owner the "waiting" line was logged for
        while True:
            try:
                with _sigint_held():  # a Ctrl-C while the lock is made and filled in comes right after
                    created = self._try_create()
                if created:
                    self._beat = threading.Thread(target=self._heartbeat, name="fracture-lock", daemon=True)
                    self._beat.start()
            except BaseException:
                self.release()  # the lock just made goes with the interrupt (release removes only our own)
                raise
            if created:
                return True
            holder = _read_lock(self.path)
            if holder is None:
                continue  # released between our attempt and the read
            mtime, info = holder
            if seen is None or seen != (mtime, info.get("token", "")):
                seen, seen_since = (mtime, info.get("token", "")), time.monotonic()
            owner = owner_state(info)
            if owner == "dead" or (owner == "unknown" and time.monotonic() - seen_since > STALE_SECONDS):
                why = "its process no longer runs" if owner == "dead" else \
                    f"unchanged for {STALE_SECONDS:.0f} s (its host stopped)"
                log.warning("%s: removing the stale output lock of pid %s on %s (%s)", printable(self.path),
                            info.get("pid"), info.get("host"), why)
                self._break(info.get("token", ""))
                continue
            if time.monotonic() >= deadline:
                if timeout == 0:
                    return False
                raise OutputError(f"{_holder(info, self.stem)}; waited {timeout:.0f} s (remove the lock if no "
                                  "bake is running)", path=printable(self.path))
            if told != info.get("token", ""):
                told = info.get("token", "")
                log.warning("%s: %s; waiting for it (at most %.0f s)", printable(self.path),
                            _holder(info, self.stem), max(deadline - time.monotonic(), 0.0))
            time.sleep(_POLL_SECONDS)

    def _try_create(self) -> bool:
        info = {"host": socket.gethostname(), "pid": os.getpid(), "token": self.token,
                "started": time.strftime("%Y-%m-%d %H:%M:%S"), "start_ticks": process_start(os.getpid()),
                "boot_id": boot_id()}
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            return False
        except OSError as exc:
            raise OutputError(f"cannot create the output lock ({exc.strerror})", path=printable(self.path)) from None
        try:
            with os.fdopen(fd, "w") as fh:
                json.dump(info, fh)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(self.path)
            raise
        return True

    def _break(self, stale_token: str) -> None:
        """Remove the lock if it still holds ``stale_token``, under ``<lock>.break`` so only one waiter does."""
        breaker = self.path + ".break"
        try:
            fd = os.open(breaker, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            # Another waiter is breaking it; a breaker file older than STALE_SECONDS was left by a killed one.
            with contextlib.suppress(OSError):
                if time.time() - os.stat(breaker).st_mtime > STALE_SECONDS:
                    os.unlink(breaker)
            time.sleep(_POLL_SECONDS)
            return
        os.close(fd)
        try:
            holder = _read_lock(self.path)
            if holder is not None and holder[1].get("token", "") == stale_token:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self.path)
        finally:
            with contextlib.suppress(OSError):
                os.unlink(breaker)

    def _heartbeat(self) -> None:
        while not self._stop.wait(HEARTBEAT_SECONDS):
            with contextlib.suppress(OSError):
                os.utime(self.path)

    def release(self) -> None:
        """Stop the heartbeat and remove the lock file if it is still ours (a Ctrl-C meanwhile comes after)."""
        with _sigint_held():
            self._stop.set()
            if self._beat is not None:
                self._beat.join()
                self._beat = None
            holder = _read_lock(self.path)
            if holder is not None and holder[1].get("token") == self.token:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self.path)


@contextlib.contextmanager
def _sigint_held() -> Iterator[None]:
    """Hold a Ctrl-C back while the block runs, then give it to the handler in place (main thread only).

    A lock file must not be left behind by an interrupt between its creation
    and its owner record, or between the heartbeat's end and its removal: a
    next bake would take it for a live bake's (or, empty, wait
    :data:`STALE_SECONDS` before breaking it).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[FrameType | None] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(frame))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if held and callable(previous):
        previous(signal.SIGINT, held[0])


def _read_lock(path: str) -> tuple[float, dict] | None:
    """(mtime, owner info) of a lock file, None if it does not exist; unreadable content counts as no owner info."""
    try:
        with open(path, "rb") as fh:
            mtime = os.fstat(fh.fileno()).st_mtime
            raw = fh.read(4096)
    except FileNotFoundError:
        return None
    try:
        info = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        info = {}
    return mtime, info if isinstance(info, dict) else {}


def _holder(info: dict, stem: str) -> str:
    """The live owner of a lock, for a message: 'another bake (pid 123 on host, since ...) is writing stem.* here'."""
    return (f"another bake (pid {info.get('pid')} on {info.get('host')}, since {info.get('started')}) is writing "
            f"{printable(stem)}.* here")


def process_start(pid: int) -> int | None:
    """When process ``pid`` started, in clock ticks after boot (``/proc/<pid>/stat`` field 22); None where unknown.

    With the pid it names one process for the life of the machine: a pid the
    kernel gave to a new process after the owner died has another start time.
    """
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()  # the command name (field 2) may hold spaces and ")"
        return int(fields[19])  # field 22: fields[0] is field 3
    except (OSError, IndexError, ValueError):
        return None


def boot_id() -> str | None:
    """This boot of the machine (``/proc/sys/kernel/random/boot_id``), None where unknown."""
    try:
        with open("/proc/sys/kernel/random/boot_id", encoding="ascii") as fh:
            return fh.read().strip() or None
    except OSError:
        return None


def owner_state(info: dict) -> str:
    """Whether a lock's owner still runs: "alive", "dead", or "unknown" (another host, no pid to check).

    An owner on this host is "dead" when its pid is gone, when the process
    with that pid started at another time than the one the lock records (the
    pid was reused), or when the lock was written before the machine last
    booted; otherwise "alive" (also when the process is another user's).
    """
    pid = info.get("pid")
    if info.get("host") != socket.gethostname() or not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return "unknown"
    recorded_boot, now_boot = info.get("boot_id"), boot_id()
    if isinstance(recorded_boot, str) and now_boot is not None and recorded_boot != now_boot:
        return "dead"  # the machine rebooted since: no process of the old boot runs
    if os.name == "nt":
        return "unknown"  # os.kill(pid, 0) would send a Ctrl-C event there
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return "dead"
    except OSError:
        pass  # EPERM: it runs, as another user
    recorded, now = info.get("start_ticks"), process_start(pid)
    if isinstance(recorded, int) and now is not None and recorded != now:
        return "dead"  # the pid now belongs to another process
    return "alive"
