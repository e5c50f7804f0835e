"""Fixed costs of a bake (issue 33): start-up to the first stage, and what a pool of forked workers costs.

    python bench/bench_startup.py [--quick]

Start-up: ``fracture -q bake ASSET`` in a fresh process, stopped as its
first stage begins (a hook on the runner, the child below); it prints the
seconds since the process started (``/proc``, as the report's ``startup``),
the CPU seconds of its main thread and of the process so far (the main
thread's less dependent on the shared machine's load than the wall time) and
how many modules are loaded.

Fork cost: :func:`fracture_cli.system.parallel.ordered_map` over 40 items of
negligible cost, forked on 2 workers against run in the process, in a
process holding an array of 50 or 400 MB (a bake's meshes) after a bake's
imports; the difference is what a pool costs before it computes anything,
the break-even that :data:`fracture_cli.system.parallel.FORK_SECONDS` stands
for. Pairs alternate, 7 per size.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
TARGET_STARTUP = 0.3  # issue 33: process start to the first stage, idle machine

_STARTUP_CHILD = r"""
import os, sys, time
from fracture_cli.pipeline import runner
from fracture_cli.system.clock import process_age

def first(self, name):
    print(f"{process_age():.3f} {time.process_time():.3f} {len(sys.modules)} {int('scipy' in sys.modules)} "
          f"{time.thread_time():.3f}",
          flush=True)
    os._exit(0)  # the first step (the first stage) is about to begin

runner.Runner.step = first
from fracture_cli.cli import main
main(sys.argv[1:])
"""

_FORK_CHILD = r"""
import sys, time
import fracture_cli
import numpy as np
from fracture_cli.system import parallel
import fracture_cli.checks, fracture_cli.stages.collision.convex, fracture_cli.stages.fragments

def cheap(shared, item):
    return np.zeros(200) + item

ballast = np.ones(int(sys.argv[1]) * 1024 * 1024 // 8)
items = list(range(40))
t = time.perf_counter(); parallel.ordered_map(cheap, items, ballast, jobs=2); forked = time.perf_counter() - t
t = time.perf_counter(); parallel.ordered_map(cheap, items, ballast, jobs=1); serial = time.perf_counter() - t
print(f"{forked - serial:.4f}")
"""


def run(quick: bool = False) -> str:
    """The section: start-up per sample asset, then the fork cost per process size."""
    reps = 1 if quick else 5
    assets = ("pane.glb",) if quick else ("chair.glb", "pillar.glb", "vase.obj", "pane.glb", "wall.glb")
    load_before = os.getloadavg()
    lines = ["## Fixed costs: start-up and a worker pool (issue 33)", "",
             f"Start-up: `fracture -q bake ASSET` stopped as its first stage begins, {reps} runs per asset (median; "
             "wall from the process's start, as the report's `startup`; CPU of the main thread and of the whole "
             "process so far (the BLAS threads numpy starts add CPU beside the main thread, not wall time); modules "
             "loaded). The 2 cores are shared with other jobs (load average below): on a loaded machine the main "
             "thread's CPU seconds are the better guide to an idle machine's wall time.", "",
             "| asset | wall s | main thread CPU s | process CPU s | modules | scipy loaded |",
             "|---|---:|---:|---:|---:|---|"]
    cpus, walls = [], []
    for asset in assets:
        rows = [_child(_STARTUP_CHILD, "-q", "bake", os.path.join(REPO, "sample_assets", asset), "-o",
                       os.path.join(REPO, "build", "bench-startup")) for _ in range(reps)]
        wall, cpu, main = ([float(r[i]) for r in rows] for i in (0, 1, 4))
        cpus += [statistics.median(main)]
        walls += [statistics.median(wall)]
        lines.append(f"| {asset} | {statistics.median(wall):.2f} | {statistics.median(main):.3f} | "
                     f"{statistics.median(cpu):.3f} | {rows[0][2]} | {'yes' if rows[0][3] == '1' else 'no'} |")
    idle = load_before[0] < 1.0
    worst = max(walls) if idle else max(cpus)
    basis = (f"median wall {min(walls):.2f}-{max(walls):.2f} s (idle: load {load_before[0]:.1f})" if idle else
             f"median main-thread CPU {min(cpus):.3f}-{max(cpus):.3f} s (loaded: load {load_before[0]:.1f})")
    lines += ["", f"- issue 33, start-up at most {TARGET_STARTUP} s on an idle machine: {basis}: "
              f"{'**missed**' if worst > TARGET_STARTUP else '**met**'}.", ""]
    pairs = 3 if quick else 7
    lines += ["Fork cost: `ordered_map` of 40 negligible items on 2 forked workers minus the same in the process "
              f"(seconds, {pairs} alternating runs per size), after a bake's imports:", "",
              "| process holds | smallest | median | largest |", "|---:|---:|---:|---:|"]
    for size in (50, 400):
        costs = [float(_child(_FORK_CHILD, str(size))[0]) for _ in range(pairs)]
        lines.append(f"| {size} MB | {min(costs):.3f} | {statistics.median(costs):.3f} | {max(costs):.3f} |")
    load_after = os.getloadavg()
    lines += ["", f"Load average (1 min) {load_before[0]:.1f} before and {load_after[0]:.1f} after, on "
              f"{os.cpu_count()} cores."]
    return "\n".join(lines) + "\n"


def _child(code: str, *args: str) -> list[str]:
    """Run ``code`` in a fresh interpreter of this venv with ``args``; its one line of output, split."""
    out = subprocess.run([sys.executable, "-c", code, *args], cwd=REPO, check=True, capture_output=True, text=True)
    return out.stdout.split()


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    print(run(parser.parse_args().quick))
