"""Crash-safe TetGen: tetrahedralize in a child process.

TetGen does not always raise on bad input: on a self-intersecting or otherwise
invalid surface it can abort or crash the whole process (SIGABRT, SIGSEGV). The
cage search deliberately feeds it surfaces that may be invalid, so every call
goes to a persistent worker process (``python -c`` running :func:`serve` of this module,
talking pickled frames over a pipe). A crash or a timeout kills only the
worker; the caller gets a :class:`TetGenFailure` and the next call starts a
fresh worker. A plain subprocess rather than :mod:`multiprocessing` because
the ``spawn`` method re-imports the caller's ``__main__``, which breaks scripts
without an ``if __name__ == "__main__"`` guard.

TetGen is licensed under the AGPL (through the ``tetgen`` package).
"""

from __future__ import annotations

import atexit
import logging
import os
import pickle
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from typing import IO, Any

import numpy as np

log = logging.getLogger(__name__)

_HEADER = struct.Struct("<Q")


class TetGenFailure(Exception):
    """TetGen produced no tet mesh: it reported an error, crashed or timed out.

    Attributes
    ----------
    reason : str
        One line for logs and error messages.
    """

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def _read_exact(stream: IO[bytes], size: int) -> bytes:
    chunks = []
    while size > 0:
        chunk = stream.read(size)
        if not chunk:
            raise EOFError
        chunks.append(chunk)
        size -= len(chunk)
    return b"".join(chunks)


def _read_frame(stream: IO[bytes]) -> Any:
    (size,) = _HEADER.unpack(_read_exact(stream, _HEADER.size))
    return pickle.loads(_read_exact(stream, size))


def _write_frame(stream: IO[bytes], obj: object) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)) + data)
    stream.flush()


def serve() -> None:
    """Worker loop: read ``(vertices, faces, switches)`` frames, write result frames."""
    # Ctrl-C (SIGINT to the whole process group) is for the parent, which stops the worker itself;
    # dying here would look like a TetGen crash and print a traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # TetGen's C++ code prints to stdout: keep the real stdout for the protocol
    # and send everything else to stderr.
    protocol_out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    protocol_in = sys.stdin.buffer
    import tetgen

    while True:
        try:
            request = _read_frame(protocol_in)
        except EOFError:
            return
        if request is None:
            return
        vertices, faces, switches = request
        try:
            tgen = tetgen.TetGen(vertices, faces)
            nodes, elems, _, _ = tgen.tetrahedralize(switches=switches)
            reply: tuple = ("ok", np.asarray(nodes, dtype=np.float64), np.asarray(elems, dtype=np.int64))
        except Exception as exc:  # reported to the parent, which decides what it means
            reply = ("error", f"{type(exc).__name__}: {exc}", None)
        _write_frame(protocol_out, reply)


_WORKDIR_PREFIX = "fracture-tetgen-"
_WORKDIR_RE = re.compile(re.escape(_WORKDIR_PREFIX) + r"(\d+)-\w+")
_LEGACY_WORKDIR_RE = re.compile(re.escape(_WORKDIR_PREFIX) + r"\w{8}")
_LEGACY_AGE_SECONDS = 24 * 3600


def _pid_running(pid: int) -> bool:
    if os.name == "nt":
        return True  # os.kill(pid, 0) would send a Ctrl-C event there; keep such folders
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def clean_stale_workdirs(folder: str | None = None) -> list[str]:
    """Remove worker folders of fracture processes that no longer run (e.g. killed with SIGKILL).

    Each worker folder is named ``fracture-tetgen-<pid>-<random>`` after the
    process that made it; folders of the older unnumbered form are removed
    once a day old.

    Parameters
    ----------
    folder : str, optional (default the system temporary folder)

    Returns
    -------
    list of str
        The folders removed.
    """
    folder = folder or tempfile.gettempdir()
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    removed = []
    for name in names:
        match = _WORKDIR_RE.fullmatch(name)
        path = os.path.join(folder, name)
        if match:
            stale = int(match.group(1)) != os.getpid() and not _pid_running(int(match.group(1)))
        elif _LEGACY_WORKDIR_RE.fullmatch(name):
            try:
                stale = time.time() - os.stat(path).st_mtime > _LEGACY_AGE_SECONDS
            except OSError:
                stale = False
        else:
            continue
        if stale and os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    if removed:
        log.info("removed %d stale TetGen worker folder(s) from %s", len(removed), folder)
    return removed


class _Worker:
    """One child process running :func:`serve`, restarted after a crash or timeout."""

    def __init__(self) -> None:
        self._process: subprocess.Popen | None = None
        self._workdir: tempfile.TemporaryDirectory | None = None
        self._lock = threading.Lock()

    def _start(self) -> subprocess.Popen:
        # The folder holding fracture_cli/ (this file is fracture_cli/stages/tetra/tetgen.py).
        package_root = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir, os.pardir))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (package_root, env.get("PYTHONPATH", "")) if p)
        # TetGen writes debug files (tetgen-tmpfile_skipped.*) into its working
        # directory on bad input: give it a private one, never the user's.
        clean_stale_workdirs()
        self._workdir = tempfile.TemporaryDirectory(prefix=f"{_WORKDIR_PREFIX}{os.getpid()}-")
        self._process = subprocess.Popen(
            [sys.executable, "-c", "from fracture_cli.stages.tetra.tetgen import serve; serve()"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env,
            cwd=self._workdir.name,
        )
        return self._process

    def _kill(self) -> None:
        process, self._process = self._process, None
        workdir, self._workdir = self._workdir, None
        try:
            if process is None:
                return
            if process.poll() is None:
                process.kill()
            process.wait(timeout=10)
            for stream in (process.stdin, process.stdout):
                try:
                    if stream is not None:
                        stream.close()
                except OSError:
                    pass
        finally:
            if workdir is not None:
                workdir.cleanup()

    def stop(self) -> None:
        """Ask the worker to exit, kill it if it does not within 2 s, and remove its folder.

        Also the ``atexit`` hook: a second Ctrl-C while it waits kills the
        worker at once instead of printing a traceback.
        """
        with self._lock:
            process = self._process
            try:
                if process is not None and process.poll() is None:
                    try:
                        assert process.stdin is not None  # opened with PIPE
                        _write_frame(process.stdin, None)
                        process.wait(timeout=2)
                    except (OSError, subprocess.TimeoutExpired):
                        pass
            except KeyboardInterrupt:
                pass
            finally:
                while True:
                    try:
                        self._kill()
                        break
                    except KeyboardInterrupt:
                        continue

    def _exit_reason(self) -> str:
        if self._process is None:
            return "not running"
        try:
            code = self._process.wait(timeout=2)
        except subprocess.TimeoutExpired:
            return "no exit code"
        return f"signal {-code}" if code < 0 else f"exit code {code}"

    def _running(self) -> subprocess.Popen:
        """The child, started (again) if none is running; the caller holds the lock."""
        if self._process is None or self._process.poll() is not None:
            self._kill()
            return self._start()
        return self._process

    def prestart(self) -> None:
        """Start the child now if none is running, without waiting for it (its imports take ~0.1 s)."""
        with self._lock:
            self._running()

    def run(self, vertices: np.ndarray, faces: np.ndarray, switches: str,
            timeout: float) -> tuple[np.ndarray, np.ndarray | None]:
        with self._lock:
            process = self._running()
            stdin, stdout = process.stdin, process.stdout
            assert stdin is not None and stdout is not None  # opened with PIPE
            try:
                _write_frame(stdin, (vertices, faces, switches))
            except OSError:
                reason = self._exit_reason()
                self._kill()
                raise TetGenFailure(f"TetGen worker died ({reason})") from None
            # A reader thread keeps the timeout portable (no select() on pipes on Windows).
            box: list = []

            def read() -> None:
                try:
                    box.append(_read_frame(stdout))
                except (EOFError, OSError, pickle.UnpicklingError):
                    pass

            reader = threading.Thread(target=read, daemon=True)
            reader.start()
            try:
                reader.join(timeout)
            except BaseException:  # Ctrl-C while TetGen runs: its reply would answer the next request
                self._kill()
                raise
            if reader.is_alive():
                self._kill()
                reader.join(5)
                raise TetGenFailure(f"TetGen timed out after {timeout:g} s")
            if not box:
                reason = self._exit_reason()
                self._kill()
                raise TetGenFailure(f"TetGen crashed ({reason})")
            status, first, second = box[0]
        if status != "ok":
            raise TetGenFailure(f"TetGen failed: {first}")
        return first, second


_worker = _Worker()
atexit.register(_worker.stop)


def tetrahedralize(vertices: np.ndarray, faces: np.ndarray, switches: str,
                   timeout: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    """Tetrahedralize a closed surface with TetGen in a child process.

    Parameters
    ----------
    vertices : (n, 3) float
        Surface vertices.
    faces : (m, 3) int
        Surface triangles.
    switches : str
        TetGen command-line switches, e.g. ``"pYQ"`` (see the TetGen manual).
    timeout : float, optional (default 60)
        Seconds before the worker is killed.

    Returns
    -------
    nodes : (k, 3) float64
        Tet mesh vertices; the first ``n`` are the input vertices.
    tets : (t, 4) int64
        Tetrahedra, as TetGen orients them.

    Raises
    ------
    TetGenFailure
        If TetGen reported an error, crashed, timed out or produced no tets.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int32)
    nodes, tets = _worker.run(vertices, faces, switches, timeout)
    if tets is None or len(tets) == 0:
        raise TetGenFailure("TetGen produced no tetrahedra")
    return nodes, tets


def prestart() -> None:
    """Start the worker process in the background, so that the first :func:`tetrahedralize` does not wait
    for its start-up (Python and TetGen's imports, about 0.1 s). Nothing happens if it is running."""
    _worker.prestart()


def shutdown() -> None:
    """Stop the worker process (it is restarted on the next call)."""
    _worker.stop()


if __name__ == "__main__":
    serve()
