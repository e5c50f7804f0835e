"""The output-set protocol: a bake replaces its files as one set, or not at all.

A bake of ``<stem>`` writes four files into the output folder::

    <stem>.fracture.bin  <stem>.fracture.json  <stem>.glb  <stem>.report.json

and the report is the set's *manifest*: it is written and published last and
lists the SHA-256 and size of the other three (``report["files"]``). How a
set is replaced:

1. **Preflight** (:mod:`.preflight`, before any long work): the output folder name is usable
   (not ``""``, the stem is UTF-8), the folder exists or can be created and
   accepts a new file, the output names are free or regular files, no output
   path is an input of the batch nor a file of another published set
   (:func:`~fracture_cli.io.preflight.guard_outputs`, the guard of every
   command that writes: resolved paths, symlinks and hard links included), and
   the free space covers an estimate of the outputs. Each failure is one
   :class:`OutputError` line.
2. **Lock** (:mod:`.stemlock`). ``.<stem>.fracture-lock`` is created with ``O_CREAT | O_EXCL``
   (atomic on local disks and on NFSv3+ and SMB shares, unlike ``fcntl``
   locks, which NFS honours only with a working lock daemon). It holds the
   owner's host, pid, process start time and boot id and a random token; the
   owner touches it every :data:`HEARTBEAT_SECONDS`. A lock is stale when its
   owner is on this host and no longer running (pid gone, or reused: another
   start time), never while it runs; a lock of another host when its
   modification time has not changed for :data:`STALE_SECONDS` while we
   watched it (the owner's machine died; only our own monotonic clock is used,
   so machines need not agree on the time).
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
import threading
from collections.abc import Iterator
from dataclasses import dataclass

from fracture_cli.errors import OutputError, StageError, printable
from fracture_cli.io.inputs import file_sha256
from fracture_cli.io.stemlock import LOCK_TIMEOUT_SECONDS, StemLock
from fracture_cli.system import interrupts
from fracture_cli.system.interrupts import NOTHING_WRITTEN

log = logging.getLogger(__name__)

#: The suffixes of one output set, in publish order: the report (the manifest) last.
SUFFIXES = (".fracture.bin", ".fracture.json", ".glb", ".report.json")
REPORT_SUFFIX = ".report.json"
#: Outputs a bake writes only when asked (``--preview``). They belong to the set all the same: published
#: before the report and listed in it when written, removed in the same step when not (an older one
#: would show other fragments than the files beside it).
#: The aligned-fracture companion pair (docs/FORMAT.md section 13) is written only with ``aligned.enabled``.
OPTIONAL_SUFFIXES = (".preview.png", ".aligned.bin", ".aligned.json")
_JOURNAL = "PUBLISHING"
_BACKUP = "previous"
_TOKEN_RE = "[0-9a-f]{32}"

# Output sets this process published, for a truthful message on Ctrl-C (see :func:`interrupt_message`).
_published: list[str] = []


def output_names(stem: str) -> tuple[str, ...]:
    """The file names every output set of ``stem`` has, in publish order (report last)."""
    return tuple(stem + s for s in SUFFIXES)


def optional_names(stem: str) -> tuple[str, ...]:
    """The file names of ``stem``'s optional outputs (:data:`OPTIONAL_SUFFIXES`)."""
    return tuple(stem + s for s in OPTIONAL_SUFFIXES)


def all_names(stem: str) -> tuple[str, ...]:
    """Every file name an output set of ``stem`` may have (what preflight and the input check guard)."""
    return output_names(stem) + optional_names(stem)


def _set_names(stem: str, written: tuple[str, ...]) -> tuple[str, ...]:
    """Publish order of a set with the optional outputs ``written``: the required files, the optional, the report."""
    required = output_names(stem)
    return required[:-1] + tuple(n for n in optional_names(stem) if n in written) + required[-1:]


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """Mode of every published file: ``0666`` minus the umask (``0644`` with the usual umask)."""
    return 0o666 & ~_umask()


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
        lines = _read_journal(os.path.join(staging, _JOURNAL))
        names = tuple(n for n in lines or () if not n.startswith("-"))
        removed = [n[1:] for n in lines or () if n.startswith("-") and n[1:] in optional_names(stem)]
        if lines and names == _set_names(stem, names):
            for name in names:
                src = os.path.join(staging, name)
                if os.path.exists(src):
                    os.replace(src, os.path.join(out_dir, name))
            for name in removed:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(os.path.join(out_dir, name))
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
        """Path in the staging folder of output ``name`` (one of :func:`all_names`)."""
        if name not in all_names(self.stem):
            raise ValueError(f"{name} is not an output of {self.stem}")
        return os.path.join(self.path, name)

    def names(self) -> tuple[str, ...]:
        """The outputs of this set in publish order: the required ones and the optional ones written here."""
        return _set_names(self.stem, tuple(n for n in optional_names(self.stem) if os.path.isfile(self.file(n))))

    def write_report(self, report: dict) -> str:
        """Write ``report`` as ``<stem>.report.json``, the manifest: ``report["files"]`` gets the other files' hashes.

        Raises
        ------
        StageError
            If the report holds NaN or infinity (JSON has no such numbers: a bug upstream).
        """
        files = {}
        for name in self.names()[:-1]:
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
            raise write_error(exc, out_dir) from None
        try:
            try:
                yield staging
                _finish_files(staging)
                interrupts.check()  # a Ctrl-C dropped while writing: the previous set stays
                with _sigint_deferred():
                    publish(staging)  # raises OutputError itself once a rename has happened
                    _published.append(os.path.join(out_dir, stem))
            except OSError as exc:
                raise write_error(exc, out_dir) from None
        finally:
            shutil.rmtree(staging.path, ignore_errors=True)


def write_error(exc: OSError, out_dir: str) -> OutputError:
    """One line for an OSError while writing into ``out_dir`` (nothing of the previous set was replaced)."""
    # on first use: reading or writing one format loads only what it needs
    from fracture_cli.io.diskspace import free_bytes, human_size

    where = printable(out_dir)
    if exc.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
        with contextlib.suppress(OSError):
            where += f" ({human_size(free_bytes(out_dir))} free)"
        return OutputError("disk full while writing the outputs; the previous outputs are unchanged", path=where)
    return OutputError(f"could not write the outputs ({exc.strerror or exc}); the previous outputs are unchanged",
                       path=where)


def _finish_files(staging: Staging) -> None:
    """Every output present, mode ``0666 & ~umask`` (mkstemp makes 0600), and synced to disk."""
    mode = file_mode()
    for name in staging.names():
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
    out_dir, names = staging.out_dir, staging.names()
    # Optional outputs of an older set that this one does not have: removed in the same step.
    stale = [n for n in optional_names(staging.stem) if n not in names and os.path.isfile(os.path.join(out_dir, n))]
    backup = os.path.join(staging.path, _BACKUP)
    os.mkdir(backup)
    previous = []
    for name in names + tuple(stale):
        target = os.path.join(out_dir, name)
        if os.path.isfile(target):
            _link_or_copy(target, os.path.join(backup, name))
            previous.append(name)
    journal = os.path.join(staging.path, _JOURNAL)
    with open(journal, "w", encoding="utf-8") as fh:
        fh.write("".join(n + "\n" for n in names) + "".join("-" + n + "\n" for n in stale))
        fh.flush()
        os.fsync(fh.fileno())
    _sync_dir(staging.path)
    done: list[str] = []
    try:
        for name in names:
            os.replace(staging.file(name), os.path.join(out_dir, name))
            done.append(name)
        for name in stale:
            os.unlink(os.path.join(out_dir, name))
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
                with contextlib.suppress(FileNotFoundError):
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
        return NOTHING_WRITTEN
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
    if not isinstance(files, dict):
        return f"{stem}{REPORT_SUFFIX} is not a manifest (no 'files' object)"
    listed = [n for n in optional_names(stem) if n in files]
    for name in output_names(stem)[:-1] + tuple(listed):
        entry = files.get(name)
        path = os.path.join(out_dir, name)
        if not isinstance(entry, dict):
            return f"the report does not list {name}"
        if not os.path.isfile(path):
            return f"{name} is missing"
        if os.path.getsize(path) != entry.get("bytes") or file_sha256(path) != entry.get("sha256"):
            return f"{name} is not the file the report lists (from another bake)"
    return None
