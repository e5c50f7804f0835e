"""What the machine-independent numerics cost (issue 29): pinned kernels against the machine's own, per stage.

    python bench/bench_numerics.py [--quick]

Each sample asset is baked with its manifest recipe in fresh processes,
alternately with the pinned kernels (the default: OpenBLAS's ``Prescott`` set,
numpy at its ``X86_V2`` baseline) and with ``FRACTURE_NUMERICS=host`` (the
kernels this CPU would pick), ``-j 1`` so the cores do not compete; the table
gives the median wall seconds of every stage from the reports. The second
table times the libm replacements of :mod:`fracture_cli.system.detmath` against
numpy's own functions on a million values (the only bake path that calls one
per element in bulk is the smoothing's solid-angle test).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)

import fracture_cli  # noqa: E402, F401, I001  (first: pins the kernels before numpy loads)

import numpy as np  # noqa: E402

from fracture_cli.system import detmath  # noqa: E402
from fracture_cli.pipeline import STEPS  # noqa: E402


def _bake(asset: str, recipe: str, out: str, host: bool) -> dict[str, float]:
    env = dict(os.environ)
    env.pop("FRACTURE_NUMERICS", None)
    if host:
        env["FRACTURE_NUMERICS"] = "host"
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "fracture_cli", "-q", "bake", os.path.join(REPO, "sample_assets", asset),
                    "-o", out, "--recipe", recipe, "-j", "1"], check=True, env=env)
    wall = time.perf_counter() - t0
    with open(os.path.join(out, os.path.splitext(asset)[0] + ".report.json")) as fh:
        seconds = json.load(fh)["seconds"]
    return {**{k: float(v) for k, v in seconds.items() if isinstance(v, (int, float))}, "process": wall}


def _stage_table(repeats: int) -> list[str]:
    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        manifest = tomllib.load(fh)["assets"]
    columns = list(STEPS) + ["process"]
    lines = ["| asset (recipe) | kernels | " + " | ".join(columns) + " |",
             "|---|---|" + "---:|" * len(columns)]
    with tempfile.TemporaryDirectory() as tmp:
        for asset, recipe in manifest.items():
            runs: dict[bool, list[dict[str, float]]] = {False: [], True: []}
            for _ in range(repeats):
                for host in (False, True):  # alternating: the machine's load drifts alike for both
                    runs[host].append(_bake(asset, recipe, os.path.join(tmp, "host" if host else "pinned"), host))
            medians = {host: {c: statistics.median(r.get(c, 0.0) for r in runs[host]) for c in columns}
                       for host in runs}
            for host, label in ((False, "pinned"), (True, "host")):
                cells = [f"{medians[host][c]:.2f}" for c in columns]
                lines.append(f"| {asset} ({recipe}) | {label} | " + " | ".join(cells) + " |")
            ratio = medians[False]["process"] / max(medians[True]["process"], 1e-9)
            lines.append(f"| {asset} ({recipe}) | pinned / host | " + " | ".join(
                f"{medians[False][c] / medians[True][c]:.2f}" if medians[True][c] > 0.05 else "-" for c in columns[:-1])
                + f" | **{ratio:.2f}** |")
    return lines


def _function_table() -> list[str]:
    rng = np.random.default_rng(0)
    x = rng.uniform(-1.0, 1.0, 1_000_000)
    y = rng.uniform(-1.0, 1.0, 1_000_000)
    positive = np.abs(x) + 1e-3
    cases = [("atan2", lambda: detmath.atan2(y, x), lambda: np.arctan2(y, x)),
             ("acos", lambda: detmath.acos(x), lambda: np.arccos(x)),
             ("exp", lambda: detmath.exp(x), lambda: np.exp(x)),
             ("log", lambda: detmath.log(positive), lambda: np.log(positive)),
             ("sin_cos", lambda: detmath.sin_cos(x), lambda: (np.sin(x), np.cos(x)))]
    lines = ["| function (1M values) | detmath ms | numpy ms | ratio |", "|---|---:|---:|---:|"]
    for name, ours, theirs in cases:
        times = []
        for fn in (ours, theirs):
            best = float("inf")
            for _ in range(5):
                t0 = time.perf_counter()
                fn()
                best = min(best, time.perf_counter() - t0)
            times.append(best * 1e3)
        lines.append(f"| {name} | {times[0]:.1f} | {times[1]:.1f} | {times[0] / times[1]:.1f}x |")
    return lines


def run(quick: bool = False) -> str:
    lines = ["## Numerics: the cost of the same bytes on every CPU (issue 29)", "",
             __doc__.split("\n\n", 2)[2].strip(), "",
             "Target: no stage measurably slower with the pinned kernels (ratios within this machine's 10-18% "
             "run-to-run noise).", ""]
    lines += _stage_table(1 if quick else 3)
    lines += ["", "### libm replacements (best of 5)", ""]
    lines += _function_table()
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
