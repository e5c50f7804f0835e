"""Progress of long work: a bar on a terminal, a line every 10 s elsewhere, nothing when quiet.

Stages report progress without knowing where it goes::

    with progress.task("modes", total=k) as t:
        for i in range(k):
            ...
            t.advance()

A stage whose step the pipeline already shows as a task can instead count
items on that innermost task, without opening its own::

    progress.items(k, "mode")      # "modes [6/11]: mode 3/12, ... left"
    ...
    progress.advance()

The command line chooses the sink once (:func:`configure`); the library default
is silent, so tests and library users see nothing. Tasks nest (the bake's
stage, then the modes inside it); on a terminal each open task is one tqdm bar
(with "i/k" and an ETA once it counts items; a background thread keeps the
clocks ticking), elsewhere that thread writes one line for the innermost task
whenever 10 s pass without one. Call
:meth:`Task.advance` from the thread that opened the task.
"""

from __future__ import annotations

import contextlib
import shutil
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, TextIO

_BAR_WITH_TOTAL = "{desc} {n_fmt}/{total_fmt} {bar} [{elapsed}<{remaining}]"
# At least this often (seconds) a line is written for a running task when the output is not a terminal.
HEARTBEAT_SECONDS = 10.0


@dataclass
class Task:
    """One unit of work with an optional count of items; see :func:`task`."""

    description: str
    total: int | None = None
    done: int = 0
    noun: str = ""  # what is counted, when the count was added later (:func:`items`)
    started: float = field(default_factory=time.monotonic)
    _bar: object | None = None

    def advance(self, items: int = 1) -> None:
        """Mark ``items`` more items done."""
        self.done += items
        if self._bar is not None:
            self._bar.update(items)  # type: ignore[attr-defined]

    @property
    def label(self) -> str:
        return f"{self.description}: {self.noun}" if self.noun else self.description

    def status(self, now: float) -> str:
        """One line: description, i/k, elapsed and (with a total) the remaining time estimated from the rate."""
        elapsed = now - self.started
        text = self.label
        if self.total:
            text += f" {self.done}/{self.total}"
        text += f", {_duration(elapsed)} elapsed"
        if self.total and self.done:
            text += f", about {_duration(elapsed / self.done * (self.total - self.done))} left"
        return text


@dataclass
class _Sink:
    stream: TextIO | None = None  # None: silent
    bars: bool = False
    stack: list[Task] = field(default_factory=list)
    last_line: float = 0.0
    lock: threading.Lock = field(default_factory=threading.Lock)
    wake: threading.Event = field(default_factory=threading.Event)
    thread: threading.Thread | None = None


_sink = _Sink()


def configure(stream: TextIO | None, bars: bool | None = None) -> None:
    """Send progress to ``stream`` (None: nowhere), as bars when ``bars`` (default: when it is a terminal)."""
    _sink.stream = stream
    _sink.bars = bool(stream is not None and (stream.isatty() if bars is None else bars))


def write(line: str) -> None:
    """Write one line to the progress stream (above any bars), or to stderr when progress is off."""
    stream = _sink.stream or sys.stderr
    if _sink.bars and _sink.stack:
        from tqdm import tqdm

        tqdm.write(line, file=stream)
    else:
        stream.write(line + "\n")
        stream.flush()


@contextlib.contextmanager
def task(description: str, total: int | None = None) -> Iterator[Task]:
    """Open a task for the duration of a ``with`` block; yields the :class:`Task` to advance."""
    current = Task(description, total)
    if _sink.stream is None:
        yield current
        return
    if _sink.bars:
        from tqdm import tqdm

        bar_format = _BAR_WITH_TOTAL if total else "{desc} [{elapsed}]"
        # A terminal that reports no size (0 x 0) would make tqdm hide every bar: fall back to 100 x 24.
        size = shutil.get_terminal_size((100, 24))
        current._bar = tqdm(total=total, desc=description, file=_sink.stream, position=len(_sink.stack),
                            leave=False, bar_format=bar_format, ncols=min(size.columns, 120),
                            nrows=max(size.lines, 4))
    with _sink.lock:
        _sink.stack.append(current)
    _start_heartbeat()
    try:
        yield current
    finally:
        with _sink.lock:
            _sink.stack.remove(current)
        if current._bar is not None:
            current._bar.close()  # type: ignore[attr-defined]


def items(total: int, noun: str = "") -> None:
    """Give the innermost open task a count of ``total`` items (named ``noun``), starting at 0."""
    if not _sink.stack:
        return
    current = _sink.stack[-1]
    current.total, current.done, current.noun = int(total), 0, noun
    if current._bar is not None:
        bar: Any = current._bar
        bar.bar_format = _BAR_WITH_TOTAL
        bar.set_description_str(current.label, refresh=False)
        bar.reset(total=int(total))


def advance(count: int = 1) -> None:
    """Mark ``count`` more items of the innermost open task done."""
    if _sink.stack:
        _sink.stack[-1].advance(count)


def _start_heartbeat() -> None:
    if _sink.thread is not None and _sink.thread.is_alive():
        return
    _sink.last_line = time.monotonic()
    _sink.thread = threading.Thread(target=_heartbeat, name="fracture-progress", daemon=True)
    _sink.thread.start()


def _heartbeat() -> None:
    """Redraw the bars every second (their clocks tick between items); without bars, write the innermost
    task's status whenever HEARTBEAT_SECONDS pass without a line."""
    while True:
        _sink.wake.wait(1.0)
        now = time.monotonic()
        with _sink.lock:
            stream = _sink.stream
            if _sink.bars:
                for t in _sink.stack:
                    if t._bar is not None:
                        t._bar.refresh()  # type: ignore[attr-defined]
            if not _sink.stack or stream is None or _sink.bars:
                _sink.last_line = now
                continue
            if now - _sink.last_line < HEARTBEAT_SECONDS:
                continue
            line = "progress: " + " > ".join(t.status(now) if t is _sink.stack[-1] else t.label
                                             for t in _sink.stack)
            _sink.last_line = now
            # under the lock: :func:`configure` cannot swap or close the stream between the check and the write
            stream.write(line + "\n")
            stream.flush()


def _duration(seconds: float) -> str:
    seconds = max(0.0, seconds)
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"
