"""The output-set protocol: a bake replaces its files as one set, or not at all.

A bake of ``<stem>`` writes four files into the output folder::

    <stem>.fracture.bin  <stem>.fracture.json  <stem>.glb  <stem>.report.json

and the report is the set's *manifest*: it is written and published last and
lists the SHA-256 and size of the other three (``report["files"]``). How a
set is replaced:

1. **Preflight** (before any long work): the output folder name is usable
   (not ``""``, the stem is UTF-8), the folder exists or can be created and
   accepts a new file, the output names are free or regular files, no output
   path is an input of the batch (compared by real path, symlinks and hard
   links included, via :func:`os.path.samefile`), and the free space covers
   an estimate of the outputs. Each failure is one :class:`OutputError` line.
2. **Lock.** ``.<stem>.fracture-lock`` is created with ``O_CREAT | O_EXCL``
   (atomic on local disks and on NFSv3+ and SMB shares, unlike ``fcntl``
   locks, which NFS honours only with a working lock daemon). It holds the
   owner's host, pid and a random token; the owner touches it every
   :data:`HEARTBEAT_SECONDS`. A lock is stale when its owner is on this host
   and no longer running, or when its modification time has not changed for
   :data:`STALE_SECONDS` while we watched it (the owner's machine died; only
   our own monotonic clock is used, so machines need not agree on the time).
   A stale lock is removed under a second exclusive file,
   ``.<stem>.fracture-lock.break``, after checking that its token is still
   the stale one, so two waiters never remove a fresh lock. A live lock is
   waited for (another bake of the same stem is writing its files; that
   takes seconds), at most ``lock_timeout`` seconds.
3. **Recover** (under the lock): staging folders ``.<stem>.staging-<token>``
   left by a killed bake are removed; one killed *while publishing* (it has
   a ``PUBLISHING`` journal) is rolled forward first, because its new files
   were complete and synced before the journal was written.
4. **Stage**: every file is written into a fresh staging folder inside the
   output folder (same file system, so renames are atomic), then given mode
   ``0666 & ~umask`` and synced.
5. **Publish**: the journal is written, the old files are hard-linked into
   the staging folder as a backup, and the new files are renamed over the old
   ones, report last; then the folder is synced and the staging folder
   removed. Ctrl-C is held back for these milliseconds and delivered after
   them. If a rename fails, the old files are restored from the backup.

What a reader may rely on:

* After a bake exits (with any code, or is interrupted by Ctrl-C), the four
  files are either all from the previous bake or all from the new one.
* After ``SIGKILL`` or a power loss *during the publish step* (a window of a
  few renames), the folder can hold a mix until the next bake of that stem
  into that folder, which completes the interrupted set before anything else.
  Such a mix is always detectable: the report lists the hash of every other
  file, and ``.fracture.json`` holds the CRC-32 of its ``.bin``.
  :func:`verify_output_set` does the check.
* While another bake is publishing, a reader can see the files change one by
  one (the window is the same few renames); checking the report's hashes
  (and retrying) guards against it.
* An input file is never written, renamed or replaced.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import math
import os
import re
import secrets
import shutil
import signal
import socket
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from fracture_cli.errors import OutputError, StageError
from fracture_cli.io.inputs import file_sha256

log = logging.getLogger(__name__)

#: The suffixes of one output set, in publish order: the report (the manifest) last.
SUFFIXES = (".fracture.bin", ".fracture.json", ".glb", ".report.json")
REPORT_SUFFIX = ".report.json"
HEARTBEAT_SECONDS = 5.0
STALE_SECONDS = 60.0
LOCK_TIMEOUT_SECONDS = 600.0
_POLL_SECONDS = 0.1
_JOURNAL = "PUBLISHING"
_BACKUP = "previous"
_TOKEN_RE = "[0-9a-f]{32}"

# Output sets this process published, for a truthful message on Ctrl-C (see :func:`interrupt_message`).
_published: list[str] = []


def output_names(stem: str) -> tuple[str, ...]:
    """The file names of ``stem``'s output set, in publish order (report last)."""
    return tuple(stem + s for s in SUFFIXES)


def printable(path: str | os.PathLike) -> str:
    """``path`` for a message: bytes that are not UTF-8 shown as ``\\xNN`` escapes."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """Mode of every published file: ``0666`` minus the umask (``0644`` with the usual umask)."""
    return 0o666 & ~_umask()


# ----------------------------------------------------------------------------
# Preflight


def preflight(out_dir: str, stem: str, inputs: Iterable[str] = (), estimate_bytes: int = 0) -> None:
    """Check, before any long work, that ``stem``'s outputs can be written into ``out_dir``.

    Parameters
    ----------
    out_dir : str
        Output folder; if missing, its nearest existing parent is checked
        instead and the folder is made by :func:`output_set`, so a bake that
        fails before writing leaves no empty folder behind.
    stem : str
        The outputs' base name.
    inputs : iterable of str, optional
        Every file the batch reads (assets and their companion files): none
        may be an output path.
    estimate_bytes : int, optional (default 0)
        Expected size of the outputs; refused when the folder has less free space.

    Raises
    ------
    OutputError
        One line naming the folder or file and the problem.
    """
    if not out_dir:
        raise OutputError('the output folder is "" (empty); give one, e.g. -o build/out')
    try:
        os.fsencode(stem).decode("utf-8")
    except UnicodeDecodeError:
        raise OutputError(f"the file name is not valid UTF-8 ({printable(stem)}): the outputs and the runtime "
                          "file's reference to its .bin need a UTF-8 name; rename the input") from None
    if not os.path.isdir(out_dir):
        # Created only when the outputs are written, so a bake that fails leaves no empty folder behind.
        ancestor = _existing_ancestor(out_dir)
        _check_writable(ancestor, for_new_folder=True)
        _check_free_space(ancestor, stem, estimate_bytes, out_dir)
        return
    for name in output_names(stem):
        target = os.path.join(out_dir, name)
        if os.path.lexists(target) and not os.path.isfile(target):
            raise OutputError("is in the way of an output (not a regular file); remove or rename it",
                              path=printable(target))
    check_inputs_untouched(out_dir, [stem], inputs)
    _check_writable(out_dir)
    _check_free_space(out_dir, stem, estimate_bytes, out_dir)
    # Complete or clear what a killed bake left now, so the folder holds one set even if this bake fails.
    lock = StemLock(out_dir, stem)
    if lock.acquire(timeout=0):
        try:
            recover(out_dir, stem)
        except OSError as exc:
            raise _write_error(exc, out_dir) from None
        finally:
            lock.release()


def _existing_ancestor(out_dir: str) -> str:
    """The nearest existing folder above a missing ``out_dir`` (refused if a file is in the way)."""
    path = os.path.abspath(out_dir)
    while not os.path.exists(path):
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    if not os.path.isdir(path):
        what = "the output folder is a file, not a folder" if path == os.path.abspath(out_dir) else \
            f"cannot create the output folder: {printable(path)} is a file"
        raise OutputError(what, path=printable(out_dir))
    return path


def _check_writable(folder: str, *, for_new_folder: bool = False) -> None:
    """Create and remove a probe in ``folder`` (a file, or a folder when the output folder is still to be made)."""
    probe = os.path.join(folder, f".fracture-probe-{secrets.token_hex(8)}")
    try:
        if for_new_folder:
            os.mkdir(probe, 0o700)
            os.rmdir(probe)
        else:
            os.close(os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
            os.unlink(probe)
    except OSError as exc:
        what = "cannot create the output folder" if for_new_folder else "the output folder is not writable"
        raise OutputError(f"{what} ({exc.strerror})", path=printable(folder)) from None


def free_bytes(out_dir: str) -> int:
    """Bytes available to this user in ``out_dir``'s file system."""
    return shutil.disk_usage(out_dir).free


def _check_free_space(folder: str, stem: str, estimate_bytes: int, out_dir: str) -> None:
    free = free_bytes(folder)
    if estimate_bytes > free:
        raise OutputError(f"only {_size(free)} free in the output folder; the outputs of {printable(stem)} need "
                          f"about {_size(estimate_bytes)}", path=printable(out_dir))


def _size(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"  # pragma: no cover


def check_inputs_untouched(out_dir: str, stems: Iterable[str], inputs: Iterable[str]) -> None:
    """Refuse if an output path of any of ``stems`` in ``out_dir`` is one of ``inputs``.

    Raises
    ------
    OutputError
        See :func:`refuse_replacing_inputs`.
    """
    refuse_replacing_inputs([os.path.join(out_dir, name) for stem in stems for name in output_names(stem)], inputs)


def refuse_replacing_inputs(targets: Iterable[str], inputs: Iterable[str]) -> None:
    """Refuse if a file about to be written (``targets``) is one of ``inputs``.

    Real paths are compared (:func:`os.path.samefile`: the same device and
    inode), so an input reached through a symlink, a symlinked folder or a
    hard link is found too. Targets that do not exist yet are fine.

    Raises
    ------
    OutputError
        Naming the input and the output that would replace it.
    """
    existing = []
    for path in inputs:
        with contextlib.suppress(OSError):
            existing.append((path, os.stat(path)))
    for target in targets:
        try:
            st = os.stat(target)
        except OSError:
            continue
        for path, ist in existing:
            if (st.st_dev, st.st_ino) == (ist.st_dev, ist.st_ino):
                raise OutputError(f"is an input of this bake and the output {printable(target)} would replace "
                                  "it; write into another folder", path=printable(path))


def refuse_inputs_as_outputs(out_dir: str, inputs: Iterable[str]) -> None:
    """Refuse a batch in which an output path of one input is another input (or a companion file of one).

    Raises
    ------
    OutputError
        See :func:`check_inputs_untouched`.
    """
    from fracture_cli.io.inputs import input_files

    if not out_dir:
        return  # preflight() says what is wrong with it
    inputs = list(inputs)
    stems = [os.path.splitext(os.path.basename(p))[0] for p in inputs]
    check_inputs_untouched(out_dir, stems, [f for p in inputs for f in input_files(p)])


# ----------------------------------------------------------------------------
# The stem lock


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


# ----------------------------------------------------------------------------
# Staging and publishing


def _staging_dirs(out_dir: str, stem: str) -> list[str]:
    pattern = re.compile(re.escape(f".{stem}.staging-") + _TOKEN_RE + r"|" + re.escape(f".{stem}.bake-") + r"\w{8}")
    try:
        names = os.listdir(out_dir)
    except OSError:
        return []
    return sorted(os.path.join(out_dir, n) for n in names if pattern.fullmatch(n))


def recover(out_dir: str, stem: str) -> None:
    """Finish or remove what killed bakes of ``stem`` left in ``out_dir``; call with the stem lock held.

    A staging folder with a publish journal is rolled forward (its files are
    complete); every other staging folder is removed.
    """
    for staging in _staging_dirs(out_dir, stem):
        names = _read_journal(os.path.join(staging, _JOURNAL))
        if names == output_names(stem):
            for name in names:
                src = os.path.join(staging, name)
                if os.path.exists(src):
                    os.replace(src, os.path.join(out_dir, name))
            _sync_dir(out_dir)
            log.warning("%s: completed the output set of %s that a killed bake was publishing",
                        printable(out_dir), printable(stem))
        else:
            log.info("%s: removing %s left by a killed bake", printable(out_dir), os.path.basename(staging))
        shutil.rmtree(staging, ignore_errors=True)


def _read_journal(path: str) -> tuple[str, ...] | None:
    """The names in a publish journal, None if there is none; a journal cut short lists fewer names.

    The journal is written and synced before the first rename, so a partial
    one means no rename happened and the staging folder is simply discarded.
    """
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            text = fh.read()
    except OSError:
        return None
    return tuple(text.splitlines()) if text.endswith("\n") else ()


@dataclass
class Staging:
    """The staging folder of one output set; files are written here, then :func:`publish`-ed."""

    out_dir: str
    stem: str
    path: str

    def file(self, name: str) -> str:
        """Path in the staging folder of output ``name`` (one of :func:`output_names`)."""
        if name not in output_names(self.stem):
            raise ValueError(f"{name} is not an output of {self.stem}")
        return os.path.join(self.path, name)

    def write_report(self, report: dict) -> str:
        """Write ``report`` as ``<stem>.report.json``, the manifest: ``report["files"]`` gets the other files' hashes.

        Raises
        ------
        StageError
            If the report holds NaN or infinity (JSON has no such numbers: a bug upstream).
        """
        files = {}
        for name in output_names(self.stem)[:-1]:
            path = self.file(name)
            files[name] = {"sha256": file_sha256(path), "bytes": os.path.getsize(path)}
        report["files"] = files
        bad = _nonfinite(report)
        if bad:
            raise StageError(f"the report has non-finite numbers at {', '.join(bad[:5])}", stage="export")
        target = self.file(self.stem + REPORT_SUFFIX)
        with open(target, "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=2, sort_keys=True, allow_nan=False)
            fh.write("\n")
        return target


def _nonfinite(value, where: str = "") -> list[str]:
    if isinstance(value, float):
        return [] if math.isfinite(value) else [where or "(top)"]
    if isinstance(value, dict):
        return [p for k, v in value.items() for p in _nonfinite(v, f"{where}.{k}" if where else str(k))]
    if isinstance(value, (list, tuple)):
        return [p for i, v in enumerate(value) for p in _nonfinite(v, f"{where}[{i}]")]
    return []


@contextlib.contextmanager
def output_set(out_dir: str, stem: str, *, lock_timeout: float = LOCK_TIMEOUT_SECONDS) -> Iterator[Staging]:
    """Write ``stem``'s outputs into a staging folder and publish them as a set when the block ends.

    Parameters
    ----------
    out_dir : str
        The output folder (checked by :func:`preflight` beforehand).
    stem : str
    lock_timeout : float, optional
        Seconds to wait for another bake of the same stem holding the lock.

    Yields
    ------
    Staging
        Write every output to ``staging.file(name)``, the report last with
        :meth:`Staging.write_report`.

    Raises
    ------
    OutputError
        The folder is locked, full, read-only, or a file could not be
        replaced; the message says which outputs are in place.

    Notes
    -----
    If the block raises (or Ctrl-C arrives before the publish step), nothing
    in ``out_dir`` changes. A Ctrl-C during the publish step is delivered
    after it, so the set is complete when the KeyboardInterrupt propagates.
    """
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the output folder ({exc.strerror})", path=printable(out_dir)) from None
    with StemLock(out_dir, stem, timeout=lock_timeout):
        staging = Staging(out_dir, stem, os.path.join(out_dir, f".{stem}.staging-{secrets.token_hex(16)}"))
        try:
            recover(out_dir, stem)
            os.mkdir(staging.path, 0o700)
        except OSError as exc:
            raise _write_error(exc, out_dir) from None
        try:
            try:
                yield staging
                _finish_files(staging)
                with _sigint_deferred():
                    publish(staging)  # raises OutputError itself once a rename has happened
                    _published.append(os.path.join(out_dir, stem))
            except OSError as exc:
                raise _write_error(exc, out_dir) from None
        finally:
            shutil.rmtree(staging.path, ignore_errors=True)


def _write_error(exc: OSError, out_dir: str) -> OutputError:
    where = printable(out_dir)
    if exc.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
        with contextlib.suppress(OSError):
            where += f" ({_size(free_bytes(out_dir))} free)"
        return OutputError("disk full while writing the outputs; the previous outputs are unchanged", path=where)
    return OutputError(f"could not write the outputs ({exc.strerror or exc}); the previous outputs are unchanged",
                       path=where)


def _finish_files(staging: Staging) -> None:
    """Every output present, mode ``0666 & ~umask`` (mkstemp makes 0600), and synced to disk."""
    mode = file_mode()
    for name in output_names(staging.stem):
        path = staging.file(name)
        if not os.path.isfile(path):
            raise StageError(f"{name} was not written", stage="export")
        os.chmod(path, mode)
        with open(path, "rb") as fh:
            os.fsync(fh.fileno())


def publish(staging: Staging) -> None:
    """Rename the staged files over the outputs, report last; on a failure restore the previous files.

    Raises
    ------
    OutputError
        A rename failed; says whether the previous set was restored.
    """
    out_dir, names = staging.out_dir, output_names(staging.stem)
    backup = os.path.join(staging.path, _BACKUP)
    os.mkdir(backup)
    previous = []
    for name in names:
        target = os.path.join(out_dir, name)
        if os.path.isfile(target):
            _link_or_copy(target, os.path.join(backup, name))
            previous.append(name)
    journal = os.path.join(staging.path, _JOURNAL)
    with open(journal, "w", encoding="utf-8") as fh:
        fh.write("\n".join(names) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    _sync_dir(staging.path)
    done: list[str] = []
    try:
        for name in names:
            os.replace(staging.file(name), os.path.join(out_dir, name))
            done.append(name)
    except BaseException as exc:
        os.unlink(journal)  # from here on the staging folder is not a set to roll forward
        _restore(out_dir, backup, done, previous, exc)
        raise
    _sync_dir(out_dir)
    os.unlink(journal)


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:  # no hard links on this file system (FAT, some shares): a copy
        shutil.copy2(src, dst)


def _restore(out_dir: str, backup: str, done: list[str], previous: list[str], cause: BaseException) -> None:
    """Undo the renames in ``done``: previous files back from ``backup``, new ones removed."""
    try:
        for name in done:
            target = os.path.join(out_dir, name)
            if name in previous:
                os.replace(os.path.join(backup, name), target)
            else:
                os.unlink(target)
    except OSError as exc:
        raise OutputError(f"publishing failed ({_reason(cause)}) and restoring the previous outputs failed too "
                          f"({exc.strerror}): the files of {printable(os.path.basename(backup))} are mixed; check "
                          "them against the report's hashes and bake again", path=printable(out_dir)) from cause
    if isinstance(cause, OSError):
        raise OutputError(f"could not replace the outputs ({_reason(cause)}); the previous outputs were restored",
                          path=printable(out_dir)) from cause


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return f"{exc.strerror}: {os.path.basename(exc.filename2 or exc.filename or '')}".rstrip(": ")
    return type(exc).__name__


def _sync_dir(path: str) -> None:
    """fsync a folder so renames in it survive a power loss (where the OS supports it)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _in_main_thread() -> bool:
    """Whether signal handlers can be set here (Python delivers signals to the main thread only)."""
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[None]:
    """Hold a Ctrl-C back until the block ends, then raise KeyboardInterrupt (main thread only)."""
    if not _in_main_thread():
        yield
        return
    received: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if received and previous is not signal.SIG_IGN:
        raise KeyboardInterrupt


def published_sets() -> tuple[str, ...]:
    """``<out_dir>/<stem>`` of every output set this process published, in order."""
    return tuple(_published)


def forget_published() -> None:
    """Start a new run: :func:`interrupt_message` lists only sets published after this call."""
    _published.clear()


def interrupt_message() -> str:
    """One truthful line for an interrupted run: which output sets are complete, and that nothing else changed."""
    if not _published:
        return "interrupted; no output was written (previous outputs are unchanged)"
    names = ", ".join(printable(p) for p in _published)
    return f"interrupted; complete outputs were written for {names}; no other output was changed"


# ----------------------------------------------------------------------------
# Readers


def verify_output_set(out_dir: str, stem: str) -> str | None:
    """Why ``stem``'s outputs in ``out_dir`` are not one complete set, or None if they are.

    Checks that every file the report lists exists with the listed size and
    SHA-256. A reader that gets a problem while a bake may be running should
    retry after a moment; otherwise the folder is damaged (rebake).
    """
    report_path = os.path.join(out_dir, stem + REPORT_SUFFIX)
    try:
        with open(report_path, encoding="utf-8") as fh:
            files = json.load(fh)["files"]
    except FileNotFoundError:
        return f"{stem}{REPORT_SUFFIX} is missing"
    except (ValueError, KeyError, TypeError) as exc:
        return f"{stem}{REPORT_SUFFIX} is not a manifest ({exc})"
    for name in output_names(stem)[:-1]:
        entry = files.get(name) if isinstance(files, dict) else None
        path = os.path.join(out_dir, name)
        if not isinstance(entry, dict):
            return f"the report does not list {name}"
        if not os.path.isfile(path):
            return f"{name} is missing"
        if os.path.getsize(path) != entry.get("bytes") or file_sha256(path) != entry.get("sha256"):
            return f"{name} is not the file the report lists (from another bake)"
    return None
