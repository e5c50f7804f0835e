"""``make assets`` serially and with ``make -j2``: does a parallel build of the sample assets pay off?

    python bench/bench_assets.py

Runs ``make assets`` twice from scratch (it removes build/assets/ first): once
serially, once with ``-j2``. Serially each bake uses every core for its own
independent work (``--jobs`` default); under ``-j2`` a bake starts worker
processes only for job slots make's jobserver has free (fracture_cli/system/jobserver.py),
so two bakes at once run on one core each and the last one gets both. BLAS is
limited to one thread either way. Target (issue #16): ``make -j2 assets`` at
most 0.6x the serial time.
"""

from __future__ import annotations

import os
import resource
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
TARGET = 0.6


def make_assets(*flags: str) -> tuple[float, float]:
    """Wall and CPU seconds (children included) of ``make assets`` from an empty build/assets/."""
    shutil.rmtree(os.path.join(REPO, "build", "assets"), ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(["make", "--no-print-directory", *flags, "assets"], cwd=REPO, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def run(quick: bool = False) -> str:
    subprocess.run(["make", "--no-print-directory", "install"], cwd=REPO, check=True, capture_output=True)
    serial = make_assets()
    both = make_assets("-j2")
    ratio = both[0] / serial[0]
    lines = [
        "## make assets: serial and -j2",
        "",
        "`make assets` from an empty build/assets/ (every sample asset with its manifest recipe, one "
        f"`fracture bake` each), then `make -j2 assets`. Target: -j2 at most {TARGET}x the serial wall time.",
        "",
        "| run | wall s | CPU s | CPU % |",
        "|---|---|---|---|",
        f"| make assets | {serial[0]:.1f} | {serial[1]:.1f} | {100 * serial[1] / serial[0]:.0f} |",
        f"| make -j2 assets | {both[0]:.1f} | {both[1]:.1f} | {100 * both[1] / both[0]:.0f} |",
        "",
        f"-j2 / serial: {ratio:.2f}x ({'meets' if ratio <= TARGET else 'misses'} the {TARGET}x target).",
    ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
