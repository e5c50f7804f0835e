"""Bake a large generated input (a bumpy sphere, ~1M triangles): per-stage seconds and peak memory.

The input is generated on the fly (never committed) and baked in a
subprocess, so its peak resident memory (``VmHWM``) is the bake's alone.
``quick`` uses ~200k triangles.
"""

from __future__ import annotations

import os
import sys
import tempfile

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SETTINGS = ("cage.target_faces=2000", "modes.num_modes=12")


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


def bake_in_subprocess(path: str, out_dir: str, settings=SETTINGS) -> dict:
    """Bake ``path`` in a child process: its report, wall and CPU seconds (per stage too), peaks (MiB)."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from bench_recipes import bake_child

    return bake_child(path, out_dir, "default", *settings)


def run(quick: bool = False) -> str:
    target = 200_000 if quick else 1_000_000
    with tempfile.TemporaryDirectory(prefix="fracture-bench-large-") as tmp:
        path = os.path.join(tmp, "bumpy_sphere.ply")
        triangles = bumpy_sphere(path, target)
        size_mb = os.path.getsize(path) / 1e6
        data = bake_in_subprocess(path, os.path.join(tmp, "out"))
    report, wall, cpu = data["report"], data["wall"], data["cpu"]
    lines = [
        "## Large input (bench_large)",
        "",
        f"A bumpy UV sphere of {triangles:,} triangles ({size_mb:.1f} MB binary PLY, generated), baked with "
        f"`{' '.join('--set ' + s for s in SETTINGS)}` in a subprocess: {wall:.1f} s wall, peak memory "
        f"{data['peak_mb']:,.0f} MiB (VmHWM; largest worker {data['worker_peak_mb']:,.0f} MiB), "
        f"{cpu:.1f} s CPU ({100 * cpu / wall:.0f} %), {report['counts']['fragments']} fragments, volume error "
        f"{report['checks']['volume_error']:.1e}, watertight {report['checks']['watertight']}. "
        "Target: under 60 s wall, peak under 2 GB.",
        "",
        "| stage | seconds | CPU s |",
        "| --- | ---: | ---: |",
    ]
    seconds = report["seconds"]
    lines.append(f"| start-up (process start to the first stage) | {seconds['startup']:.2f} | |")
    for stage, value in seconds.items():
        if stage not in ("startup", "total"):
            lines.append(f"| {stage} | {value:.2f} | {data['cpu_stages'].get(stage, 0.0):.2f} |")
    lines.append(f"| **total** (to the published outputs) | **{seconds['total']:.2f}** | **{cpu:.2f}** |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
