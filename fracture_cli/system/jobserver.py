"""GNU make's jobserver: how many worker processes a bake may add when make runs it.

Under ``make -jN`` make already runs up to N recipes at once, and shares those
N job slots with every program it starts that knows its *jobserver*: a pipe
holding N - 1 one-byte tokens (the program make started holds one slot
implicitly). A bake that wants more than one worker process for a parallel
section (:func:`fracture_cli.system.parallel.ordered_map`) takes extra tokens from
that pipe without waiting, runs on 1 + (tokens taken) processes, and writes
exactly the bytes it read back when the section ends, on an error or Ctrl-C
too. Two bakes of ``make -j2`` thus run one process each, and a bake left alone
at the end of the build gets the free slot for its next section.

``MAKEFLAGS`` says where the jobserver is:

- ``--jobserver-auth=R,W`` (make 4.3; ``--jobserver-fds`` before 4.2): two
  inherited file descriptors of a pipe. make 4.3 keeps them open only for
  recipe lines it treats as recursive (a ``+`` prefix or ``$(MAKE)``); for any
  other line it closes them at ``exec`` but leaves ``MAKEFLAGS`` as it is, so
  the numbers may name files this process opened since. They count as the
  jobserver only if both are the two ends of one pipe and inheritable (Python
  opens its own files non-inheritable, PEP 446, make passes the jobserver
  inheritable). Tokens are read through a separate non-blocking open of the
  read end (``/proc/self/fd/R``), because setting ``O_NONBLOCK`` on the
  inherited descriptor would change it for make and every other job sharing it.
- ``--jobserver-auth=fifo:PATH`` (make 4.4): a named pipe, opened here.

When ``MAKEFLAGS`` says make runs jobs in parallel (``-jN`` with N > 1, or
``-j``) but no jobserver is usable, the default is one job: make already keeps
the cores busy with other recipes. Outside make, or under a serial make, a bake
uses every core as before. An explicit ``--jobs`` always wins (the caller does
not ask this module then); the number of workers never changes a result.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import logging
import os
import select
import stat
import threading
from collections.abc import Iterator, Mapping

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class MakeFlags:
    """What ``MAKEFLAGS`` says about parallel jobs.

    Attributes
    ----------
    parallel : bool
        make runs several recipes at once (``-jN`` with N > 1, or ``-j`` without a number).
    auth : str or None
        The last ``--jobserver-auth`` (or older ``--jobserver-fds``) value: ``"R,W"`` or ``"fifo:PATH"``.
    """

    parallel: bool = False
    auth: str | None = None


def parse_makeflags(text: str) -> MakeFlags:
    """The job flags of a ``MAKEFLAGS`` value (``"s -j2 --jobserver-auth=3,4 -- VAR=x"``).

    The first word holds single-letter flags without a dash (``s``, ``k``), so
    ``-j`` always comes as its own word; variable assignments after ``--`` are
    not flags.
    """
    parallel, auth = False, None
    for word in text.split():
        if word == "--":
            break
        if word == "-j" or word == "--jobs":
            parallel = True
        elif word.startswith("-j") and word[2:].isdigit():
            parallel = int(word[2:]) > 1
        elif word.startswith("--jobs=") and word[7:].isdigit():
            parallel = int(word[7:]) > 1
        elif word.startswith(("--jobserver-auth=", "--jobserver-fds=")):
            auth = word.split("=", 1)[1]
    return MakeFlags(parallel=parallel, auth=auth)


class Jobserver:
    """A client of make's jobserver: takes tokens without waiting and gives them back.

    Parameters
    ----------
    read_fd : int
        A non-blocking descriptor of the token pipe, opened for this client (closed by :meth:`close`).
    write_fd : int
        Where tokens go back: make's write end, or ``read_fd`` for a FIFO opened read-write.
    """

    def __init__(self, read_fd: int, write_fd: int):
        self.read_fd = read_fd
        self.write_fd = write_fd
        # Threads of one process must not interleave a take and a give-back on the shared descriptors' state.
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def tokens(self, wanted: int) -> Iterator[int]:
        """Take up to ``wanted`` tokens that are free now for the body; yields how many it got.

        The bytes read are written back when the body ends, however it ends
        (exception, ``KeyboardInterrupt``): a lost token would leave make with
        one job slot less until the build ends.
        """
        taken = bytearray()
        try:
            with self._lock:
                while len(taken) < wanted:
                    token = self._take()
                    if not token:
                        break
                    taken += token
            if taken:
                log.debug("jobserver: %d extra job slot(s) taken", len(taken))
            yield len(taken)
        finally:
            if taken:
                self._give_back(bytes(taken))

    def _take(self) -> bytes:
        """One token, or b"" when none is free (or every writer is gone)."""
        try:
            return os.read(self.read_fd, 1)
        except BlockingIOError:
            return b""

    def _give_back(self, tokens: bytes) -> None:
        view = memoryview(tokens)
        while view:
            try:
                view = view[os.write(self.write_fd, view):]
            except BlockingIOError:  # a full pipe (64 KiB of tokens): never in practice, wait for room
                select.select([], [self.write_fd], [])

    def close(self) -> None:
        """Close the descriptors this client opened (never make's own)."""
        os.close(self.read_fd)


# The client of this process, looked for once (the inherited descriptors must be checked before they could be
# mistaken for files opened later), keyed by the MAKEFLAGS it was built from.
_CLIENT: tuple[str, Jobserver | None, bool] | None = None
_CLIENT_LOCK = threading.Lock()


def default_jobs(cores: int, environ: Mapping[str, str] | None = None) -> int:
    """The number of jobs a bake should plan for when ``--jobs`` is not given.

    ``cores`` outside a parallel make and with a usable jobserver (then the
    upper bound: :func:`client` says how many slots are free), 1 under a
    parallel make without one.
    """
    _, parallel = _lookup(environ)
    return 1 if parallel and client(environ) is None else cores


def client(environ: Mapping[str, str] | None = None) -> Jobserver | None:
    """The jobserver of the make that started this process, None if there is none or it is not usable here."""
    found, _ = _lookup(environ)
    return found


def forget() -> None:
    """Drop the client looked up before (for tests, which set ``MAKEFLAGS`` and fake a jobserver)."""
    global _CLIENT
    with _CLIENT_LOCK:
        if _CLIENT is not None and _CLIENT[1] is not None:
            _CLIENT[1].close()
        _CLIENT = None


def _lookup(environ: Mapping[str, str] | None) -> tuple[Jobserver | None, bool]:
    """(client or None, whether make runs jobs in parallel), computed once per ``MAKEFLAGS`` value."""
    global _CLIENT
    text = (os.environ if environ is None else environ).get("MAKEFLAGS", "")
    with _CLIENT_LOCK:
        if _CLIENT is None or _CLIENT[0] != text:
            if _CLIENT is not None and _CLIENT[1] is not None:
                _CLIENT[1].close()
            flags = parse_makeflags(text)
            found = _open(flags.auth) if flags.auth else None
            if flags.parallel and found is None:
                log.debug("make runs jobs in parallel (MAKEFLAGS %r) and its jobserver is not usable here: "
                          "1 job per bake unless --jobs is given", text)
            _CLIENT = (text, found, flags.parallel)
        return _CLIENT[1], _CLIENT[2]


def _open(auth: str) -> Jobserver | None:
    """A client for the ``--jobserver-auth`` value ``auth``, None if it does not name a usable jobserver."""
    try:
        if auth.startswith("fifo:"):
            return _open_fifo(auth[len("fifo:"):])
        read_text, write_text = auth.split(",")
        return _open_pipe(int(read_text), int(write_text))
    except (ValueError, OSError) as exc:
        log.debug("jobserver %r not usable: %s", auth, exc)
        return None


def _open_fifo(path: str) -> Jobserver | None:
    """make 4.4's named pipe, opened read-write (so reading never sees end-of-file) and non-blocking."""
    fd = os.open(path, os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)
    if not stat.S_ISFIFO(os.fstat(fd).st_mode):
        os.close(fd)
        log.debug("jobserver %r is not a FIFO", path)
        return None
    return Jobserver(fd, fd)


def _open_pipe(read_fd: int, write_fd: int) -> Jobserver | None:
    """make 4.3's inherited pipe ends, if that is what the descriptors still are (see the module notes)."""
    if read_fd < 0 or write_fd < 0 or read_fd == write_fd:
        return None
    ends = []
    for fd, mode in ((read_fd, os.O_RDONLY), (write_fd, os.O_WRONLY)):
        try:
            info = os.fstat(fd)
            access = fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE
            inheritable = os.get_inheritable(fd)
        except OSError as exc:
            if exc.errno != errno.EBADF:
                raise
            log.debug("jobserver descriptor %d is closed (make starts non-recursive recipes without it)", fd)
            return None
        if not (stat.S_ISFIFO(info.st_mode) and access in (mode, os.O_RDWR) and inheritable):
            log.debug("descriptor %d is not make's jobserver pipe (opened by this process since)", fd)
            return None
        ends.append((info.st_dev, info.st_ino))
    if ends[0] != ends[1]:
        log.debug("descriptors %d and %d are not the two ends of one pipe", read_fd, write_fd)
        return None
    # A private open file description of the read end: O_NONBLOCK on it leaves make's descriptor blocking.
    own = os.open(f"/proc/self/fd/{read_fd}", os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    return Jobserver(own, write_fd)
