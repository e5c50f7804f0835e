"""How long this process has run: the origin of a bake's ``startup`` and ``total`` seconds.

A bake's report counts from the moment the *process* started, not from the
first line of Python that ran, so the interpreter's own start and every import
before the first stage are in ``startup`` (issue 33: the report once hid
3.7-5.7 s of every bake). Linux gives the start in ``/proc/self/stat`` (field
22, clock ticks since boot), compared with ``/proc/uptime`` read at the same
moment: both have a resolution of 10 ms. Elsewhere the origin is the first
import of this module.
"""

from __future__ import annotations

import os
import time

# Fallback origin where /proc is missing.
_IMPORTED = time.monotonic()


def process_age() -> float | None:
    """Seconds since this process started, from ``/proc`` (None where it cannot be read)."""
    try:
        with open("/proc/self/stat", "rb") as fh:
            stat = fh.read()
        with open("/proc/uptime", "rb") as fh:
            uptime = float(fh.read().split()[0])
        # The command name (field 2) may hold spaces and parentheses: fields are counted after its last ")".
        start_ticks = int(stat[stat.rindex(b")") + 2:].split()[19])
        ticks = os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None
    return max(0.0, uptime - start_ticks / ticks)


def process_origin() -> float:
    """The process's start on the :func:`time.monotonic` clock (this module's import where /proc is missing)."""
    age = process_age()
    now = time.monotonic()
    return now - age if age is not None else _IMPORTED
