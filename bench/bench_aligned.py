"""Benchmark: aligned fracture at runtime (issue 35): C and JavaScript cost per hit on the sample assets.

Each sample asset is baked with its manifest recipe up to the collision stage once; the aligned stage
then makes the companion file for several pattern sizes (sites per pattern; the default 50, on the
chair also 20 and 100). The C reader (``cc -std=c99 -O2``) and the JavaScript reader (Node.js) answer
the same random surface hits (a random direction, the file's default scale times 0.5 to 1.5): per hit
the median of repeated calls, in CPU time of the calling thread (C) or process (Node.js). Goal: under
1 ms per hit in C for a 50-site pattern on the chair.

    python bench/bench_aligned.py [--quick]     # or: python bench/run.py --only aligned
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import tempfile
import time
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)
sys.path.insert(0, os.path.join(REPO, "tests"))

import fracture_cli  # noqa: E402, F401, I001  (first: pins the kernels before numpy loads)

from aligned_support import JS_DRIVER, NODE, compile_c_driver, random_hits, run_driver  # noqa: E402
from fracture_cli.pipeline import STAGE_NAMES, PipelineState, stage  # noqa: E402
from fracture_cli.pipeline.runner import Runner  # noqa: E402
from fracture_cli.pipeline.recipe import load_recipe  # noqa: E402
from fracture_cli.runtime.aligned_data import write_aligned  # noqa: E402
from fracture_cli.stages.aligned.options import AlignedOptions  # noqa: E402

FAST = ["cage.target_faces=600", "modes.num_modes=4"]


def _state(asset: str, recipe: str, quick: bool) -> PipelineState:
    """The pipeline state after the collision stage (the aligned stage's inputs)."""
    options = load_recipe(recipe, FAST if quick else ())
    runner = Runner(f"bench {asset}")
    state = PipelineState(source=os.path.join(REPO, "sample_assets", asset))
    for name in STAGE_NAMES:
        if name not in ("runtime", "aligned"):
            state = runner.run(name, state, options[name])
    return state


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def _measure(command: list[str], path: str, hits, repeat: int) -> dict:
    answers = run_driver(command, path, hits, "--time", str(repeat))
    us = [a["us"] for a in answers if a["status"] == "ok"]
    return {"p50": statistics.median(us), "p90": _percentile(us, 0.9), "max": max(us),
            "fragments": statistics.median(a["fragments"] for a in answers),
            "parts": statistics.median(a["parts"] for a in answers),
            "triangles": statistics.median(a["triangles"] for a in answers),
            "arena": max(a.get("arena_used", 0) for a in answers)}


def run(quick: bool = False) -> str:
    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        manifest = tomllib.load(fh)["assets"]
    hits_per_asset = 20 if quick else 100
    rows_c, rows_js, rows_stage = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        driver = compile_c_driver(os.path.join(tmp, "fracture_aligned_check"))
        for asset, recipe in sorted(manifest.items(), key=lambda kv: kv[0] != "chair.glb"):
            state = _state(asset, recipe, quick)
            stem = os.path.splitext(asset)[0]
            for sites in ((20, 50, 100) if asset == "chair.glb" and not quick else (50,)):
                options = dataclasses.replace(AlignedOptions(), enabled=True, sites=sites, patterns=1)
                t0 = time.process_time()
                data = stage("aligned").run(state, options).aligned
                seconds = time.process_time() - t0
                path = os.path.join(tmp, f"{stem}_{sites}.aligned.json")
                write_aligned(data, path)
                size = os.path.getsize(path[:-5] + ".bin")
                hits = random_hits(data, hits_per_asset, seed=35)
                c = _measure([driver], path, hits, 21)
                label = f"{asset} ({recipe})"
                rows_c.append(f"| {label} | {sites} | {data.num_pieces} | {len(data['triangle_materials'])} | "
                              f"{c['fragments']:.0f} | {c['parts']:.0f} | {c['triangles']:.0f} | "
                              f"{c['p50']:.0f} / {c['p90']:.0f} / {c['max']:.0f} | {c['arena'] / 2**20:.1f} |")
                rows_stage.append(f"| {label} | {sites} | {seconds:.2f} | {size / 1024:.0f} |")
                if NODE is not None and sites == 50:
                    js = _measure([NODE, JS_DRIVER], path, hits[: hits_per_asset // 2], 5)
                    rows_js.append(f"| {label} | {sites} | {js['p50']:.0f} / {js['p90']:.0f} / {js['max']:.0f} | "
                                   f"{js['p50'] / c['p50']:.1f} |")
    lines = [
        "## Aligned fracture (seed 001, issue 35)",
        "",
        f"Cost per hit of `fra_fracture` (engines/c, `cc -std=c99 -O2`) and `alignedFracture` (engines/web, Node.js"
        f"{'' if NODE else ': not installed'}) on {hits_per_asset} random surface hits per asset "
        "(tests/aligned_support.py `random_hits`: a random direction, 0.5 to 1.5 times the file's default "
        "scale, which is 0.25 of the bounding-box diagonal), one pattern; each hit repeated (C 21 times, JS "
        "5) and its median CPU time taken; then the median, 90th percentile and maximum over the hits, in "
        "microseconds. Goal: under 1 ms (1000 us) in C for a 50-site pattern on the chair."
        + (" Quick mode: fast bakes (small cage, 4 modes)." if quick else ""),
        "",
        "| asset | sites | pieces | stored triangles | fragments | parts | new triangles | C us p50 / p90 / max "
        "| arena MiB |",
        "|---|---|---|---|---|---|---|---|---|",
        *rows_c,
        "",
        "JavaScript (same files, half the hits):",
        "",
        "| asset | sites | JS us p50 / p90 / max | JS / C (p50) |",
        "|---|---|---|---|",
        *rows_js,
        "",
        "Bake: the aligned stage's CPU seconds (convex pieces, triangle assignment, patterns) and the "
        "companion file's size.",
        "",
        "| asset | sites | stage s | .aligned.bin KiB |",
        "|---|---|---|---|",
        *rows_stage,
    ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    print(run(quick=parser.parse_args().quick))
