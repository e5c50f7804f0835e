"""A per-stem lock file in an output folder that works across processes and machines.

``.<stem>.fracture-lock`` is created with ``O_CREAT | O_EXCL``, which is
atomic on local disks and on NFSv3+ and SMB shares (unlike ``fcntl`` locks,
which NFS honours only with a working lock daemon). It holds the owner's host,
pid and a random token; the owner touches it every :data:`HEARTBEAT_SECONDS`.
A lock is stale when its owner is on this host and no longer running, or when
its modification time has not changed for :data:`STALE_SECONDS` while a
waiter watched it (the owner's machine died; only the waiter's monotonic clock
is used, so machines need not agree on the time). A stale lock is removed
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
import socket
import threading
import time
from dataclasses import dataclass, field

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
        while True:
            if self._try_create():
                self._beat = threading.Thread(target=self._heartbeat, name="fracture-lock", daemon=True)
                self._beat.start()
                return True
            holder = _read_lock(self.path)
            if holder is None:
                continue  # released between our attempt and the read
            mtime, info = holder
            if seen is None or seen != (mtime, info.get("token", "")):
                seen, seen_since = (mtime, info.get("token", "")), time.monotonic()
            if _owner_dead(info) or time.monotonic() - seen_since > STALE_SECONDS:
                log.warning("output lock %s of pid %s on %s is stale; removing it", printable(self.path),
                            info.get("pid"), info.get("host"))
                self._break(info.get("token", ""))
                continue
            if time.monotonic() >= deadline:
                if timeout == 0:
                    return False
                raise OutputError(f"another bake (pid {info.get('pid')} on {info.get('host')}, since "
                                  f"{info.get('started')}) is writing {printable(self.stem)}.* here; waited "
                                  f"{timeout:.0f} s (remove the lock if no bake is running)",
                                  path=printable(self.path))
            time.sleep(_POLL_SECONDS)

    def _try_create(self) -> bool:
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            return False
        except OSError as exc:
            raise OutputError(f"cannot create the output lock ({exc.strerror})", path=printable(self.path)) from None
        info = {"host": socket.gethostname(), "pid": os.getpid(), "token": self.token,
                "started": time.strftime("%Y-%m-%d %H:%M:%S")}
        with os.fdopen(fd, "w") as fh:
            json.dump(info, fh)
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
        """Stop the heartbeat and remove the lock file if it is still ours."""
        self._stop.set()
        if self._beat is not None:
            self._beat.join()
            self._beat = None
        holder = _read_lock(self.path)
        if holder is not None and holder[1].get("token") == self.token:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.path)


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


def _owner_dead(info: dict) -> bool:
    """True if the lock's owner ran on this host and no longer runs (unknown: False)."""
    pid = info.get("pid")
    if info.get("host") != socket.gethostname() or not isinstance(pid, int) or pid <= 0 or os.name == "nt":
        return False  # on Windows os.kill(pid, 0) would send a Ctrl-C event
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:
        return False  # EPERM: alive, another user's
    return False
