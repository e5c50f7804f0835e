"""Batch progress on a stream: a bar on a terminal, periodic lines in a log.

A failure is always written at once (a build log should show it where it
happened, not only in the final table).
"""

from __future__ import annotations

import time
from typing import TextIO

from fracture_cli.batch.jobs import BAKED, FAILED, UP_TO_DATE, TaskResult


class Progress:
    """Counts results and shows them.

    Parameters
    ----------
    total : int
        Number of tasks.
    stream : text stream
        Usually stderr.
    tty : bool
        Redraw one bar line in place (a terminal) or print a line every ``interval`` seconds.
    names : dict of int -> str
        Asset name by job index, for failure lines.
    interval : float, optional (default 30)
    """

    def __init__(self, total: int, stream: TextIO, tty: bool, names: dict[int, str], interval: float = 30.0):
        self.total, self.stream, self.tty, self.names, self.interval = total, stream, tty, names, interval
        self.counts = {BAKED: 0, UP_TO_DATE: 0, FAILED: 0}
        self.start = self.last_line = time.monotonic()
        if total and not tty:
            self._write(f"batch: {total} task(s) submitted")

    def _write(self, line: str) -> None:
        self.stream.write(line + "\n")
        self.stream.flush()

    def _status(self) -> str:
        done = sum(self.counts.values())
        elapsed = time.monotonic() - self.start
        text = (f"{done}/{self.total} done ({self.counts[BAKED]} baked, {self.counts[UP_TO_DATE]} up to date, "
                f"{self.counts[FAILED]} failed)")
        if done and elapsed > 0:
            eta = (self.total - done) * elapsed / done
            text += f", {done / elapsed * 60:.1f}/min, {eta:.0f} s left"
        return text

    def update(self, result: TaskResult) -> None:
        """Record one finished task."""
        self.counts[result.status] = self.counts.get(result.status, 0) + 1
        if result.status == FAILED:
            if self.tty:
                self.stream.write("\r\033[K")
            self._write(f"failed: {self.names.get(result.index, result.index)}: {result.error}")
        if self.tty:
            done = sum(self.counts.values())
            width = 30
            filled = int(width * done / max(self.total, 1))
            self.stream.write(f"\r\033[K[{'#' * filled}{'.' * (width - filled)}] {self._status()}")
            self.stream.flush()
        elif time.monotonic() - self.last_line >= self.interval or sum(self.counts.values()) == self.total:
            self.last_line = time.monotonic()
            self._write(f"batch: {self._status()}")

    def close(self) -> None:
        """End the bar line."""
        if self.tty and self.total:
            self.stream.write("\n")
            self.stream.flush()
