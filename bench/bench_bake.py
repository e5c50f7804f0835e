"""End-to-end bake of every sample asset with its manifest recipe: seconds per stage and peak memory."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)

_CHILD = r"""
import json, resource, sys, time
from fracture_cli.bake import bake
from fracture_cli.recipe import load_recipe
t0 = time.perf_counter()
result = bake(sys.argv[1], sys.argv[2], load_recipe(sys.argv[3]))
total = time.perf_counter() - t0
# VmHWM, this process's own peak (ru_maxrss would carry the parent's across fork and exec).
with open("/proc/self/status") as fh:
    peak = next((int(line.split()[1]) / 1024.0 for line in fh if line.startswith("VmHWM:")),
                resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
print(json.dumps({"report": result.report, "total": total, "peak_mb": peak}))
"""


def run(quick: bool = False) -> str:
    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        assets = sorted(tomllib.load(fh)["assets"].items())
    rows = []
    stages = None
    for asset, recipe in assets:
        with tempfile.TemporaryDirectory() as out:
            proc = subprocess.run(
                [sys.executable, "-c", _CHILD, os.path.join(REPO, "sample_assets", asset), out, recipe],
                capture_output=True, text=True, cwd=REPO, check=True)
        data = json.loads(proc.stdout.strip().splitlines()[-1])
        report = data["report"]
        stages = stages or list(report["seconds"])
        c = report["counts"]
        rows.append((asset, recipe, report["input"]["triangles"], c["tets"], c["modes"], c["fragments"],
                     [report["seconds"].get(s, 0.0) for s in stages], data["total"], data["peak_mb"],
                     report["checks"]["volume_error"]))
    head = "| asset | recipe | tris | tets | k | fragments | " + " | ".join(stages) + " | total s | peak MB | vol err |"
    lines = ["## Bake: end to end per sample asset", "",
             "Each sample asset baked with the recipe its manifest names (`make assets`), in a fresh process; "
             "seconds per stage, total, and peak resident memory.", "", head,
             "|" + "---|" * (head.count("|") - 1)]
    for asset, recipe, tris, tets, k, frags, secs, total, peak, err in rows:
        lines.append(f"| {asset} | {recipe} | {tris} | {tets} | {k} | {frags} | "
                     + " | ".join(f"{s:.2f}" for s in secs) + f" | {total:.1f} | {peak:.0f} | {err:.1e} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run())
