"""End-to-end bake of every sample asset with its manifest recipe: seconds per stage and peak memory."""

from __future__ import annotations

import os
import sys
import tempfile
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)


def run(quick: bool = False) -> str:
    sys.path.insert(0, HERE)
    from bench_recipes import bake_child  # one child script for every bench that bakes in a fresh process

    from fracture_cli.pipeline.bake import step_seconds

    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        assets = sorted(tomllib.load(fh)["assets"].items())
    rows = []
    stages = None
    for asset, recipe in assets:
        with tempfile.TemporaryDirectory() as out:
            data = bake_child(os.path.join(REPO, "sample_assets", asset), out, recipe)
        report = data["report"]
        stages = stages or ["startup", *step_seconds(report), "total"]
        c = report["counts"]
        rows.append((asset, recipe, report["input"]["triangles"], c["tets"], c["modes"], c["fragments"],
                     [report["seconds"].get(s, 0.0) for s in stages], data["bake_seconds"], data["peak_mb"],
                     report["checks"]["volume_error"]))
    head = "| asset | recipe | tris | tets | k | fragments | " + " | ".join(stages) + " | wall s | peak MB | vol err |"
    lines = ["## Bake: end to end per sample asset", "",
             "Each sample asset baked with the recipe its manifest names (`make assets`), in a fresh process; "
             "seconds from the process's start to the first stage (startup), per stage, to the published outputs "
             "(total; the report's own figures), the whole process as measured from outside (wall), and peak "
             "resident memory.",
             "", head,
             "|" + "---|" * (head.count("|") - 1)]
    for asset, recipe, tris, tets, k, frags, secs, total, peak, err in rows:
        lines.append(f"| {asset} | {recipe} | {tris} | {tets} | {k} | {frags} | "
                     + " | ".join(f"{s:.2f}" for s in secs) + f" | {total:.1f} | {peak:.0f} | {err:.1e} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run())
