"""Bake a large generated input (a bumpy sphere, ~1M triangles): per-stage seconds and peak memory.

The input is generated on the fly (never committed) and baked in a
subprocess, so its peak resident memory (``ru_maxrss``) is the bake's alone.
``quick`` uses ~200k triangles.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SETTINGS = ("cage.target_faces=2000", "modes.num_modes=12")

_CHILD = r"""
import json, logging, sys
from fracture_cli.bake import bake
from fracture_cli.recipe import load_recipe
logging.basicConfig(level=logging.WARNING)
result = bake(sys.argv[1], sys.argv[2], load_recipe("default", sys.argv[3:]))
print(json.dumps({"seconds": result.report["seconds"], "counts": result.report["counts"],
                  "checks": result.report["checks"], "triangles": result.report["input"]["triangles"]}))
"""


def bumpy_sphere(path: str, count: int) -> int:
    """Write a bumpy UV sphere with about ``count`` triangles as binary PLY; returns its triangle count."""
    import numpy as np
    import trimesh

    n = max(int(np.sqrt(count / 4.0)), 8)  # a UV sphere of n x n segments has ~4 n^2 triangles
    sphere = trimesh.creation.uv_sphere(radius=1.0, count=[n, n])
    V = np.asarray(sphere.vertices)
    bumps = 1.0 + 0.08 * np.sin(7 * V[:, 0]) * np.sin(5 * V[:, 1]) * np.sin(6 * V[:, 2] + 1.0)
    mesh = trimesh.Trimesh(V * bumps[:, None], sphere.faces, process=True)  # process: merge the pole seams
    mesh.export(path)
    return len(mesh.faces)


def bake_in_subprocess(path: str, out_dir: str, settings=SETTINGS) -> tuple[dict, float, float]:
    """Bake ``path`` in a child process; returns (report extract, wall seconds, peak RSS in MiB)."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _CHILD, path, out_dir, *settings], cwd=REPO, capture_output=True,
                          text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"bake failed ({proc.returncode}): {proc.stderr.strip().splitlines()[-1:]}")
    peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # largest child so far (KiB on Linux)
    return json.loads(proc.stdout.strip().splitlines()[-1]), wall, peak_kib / 1024.0


def run(quick: bool = False) -> str:
    target = 200_000 if quick else 1_000_000
    with tempfile.TemporaryDirectory(prefix="fracture-bench-large-") as tmp:
        path = os.path.join(tmp, "bumpy_sphere.ply")
        triangles = bumpy_sphere(path, target)
        size_mb = os.path.getsize(path) / 1e6
        report, wall, peak = bake_in_subprocess(path, os.path.join(tmp, "out"))
    lines = [
        "## Large input (bench_large)",
        "",
        f"A bumpy UV sphere of {triangles:,} triangles ({size_mb:.1f} MB binary PLY, generated), baked with "
        f"`{' '.join('--set ' + s for s in SETTINGS)}` in a subprocess: {wall:.1f} s wall, peak memory "
        f"{peak:,.0f} MiB (ru_maxrss), {report['counts']['fragments']} fragments, volume error "
        f"{report['checks']['volume_error']:.1e}, watertight {report['checks']['watertight']}.",
        "",
        "| stage | seconds |",
        "| --- | ---: |",
    ]
    for stage, seconds in report["seconds"].items():
        lines.append(f"| {stage} | {seconds:.2f} |")
    lines.append(f"| **total** | **{sum(report['seconds'].values()):.2f}** |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
