"""Benchmark: the stress criterion against the modes (issue 30): atlas figures, file size, bake time.

Each sample asset is baked twice per recipe (its manifest recipe, and with --default-recipe also the
default one) in fresh processes: ``runtime.criterion = "modes"`` and ``"stress"``; each bake is swept by
its own criterion with :func:`fracture_cli.atlas.run_atlas` (200 hits). Prints a markdown table: the
atlas figures (fracture_cli/atlas/sweep.py), the runtime file's size and growth, the bake's total
seconds and its runtime stage's.

    python bench/bench_stress.py [--default-recipe] [--set SECTION.KEY=VALUE ...]

``--set`` applies to the stress bakes only (e.g. ``--set runtime.stress_reach=0.1``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import tomllib

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import fracture_cli  # noqa: E402, F401, I001  (first: pins the kernels before numpy loads)

from fracture_cli.atlas import run_atlas  # noqa: E402

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COLUMNS = ("hit_detached", "locality_2x", "locality_8x", "first_break_splits", "graded_median", "b0_median",
           "d1_median")


def _bake(asset: str, recipe: str, out: str, overrides: list[str]) -> tuple[str, dict]:
    """Bake in a fresh process; returns the runtime file and the report."""
    command = [sys.executable, "-m", "fracture_cli", "-q", "bake", os.path.join(REPO, "sample_assets", asset),
               "-o", out, "--recipe", recipe]
    for item in overrides:
        command += ["--set", item]
    subprocess.run(command, check=True, cwd=REPO)
    stem = os.path.splitext(asset)[0]
    with open(os.path.join(out, stem + ".report.json")) as fh:
        report = json.load(fh)
    return os.path.join(out, stem + ".fracture.json"), report


def _cell(value, key: str) -> str:
    if value is None:
        return "inf" if key.startswith("graded") else "-"
    if key in ("hit_detached", "first_break_splits"):
        return f"{100 * value:.0f}%"
    return f"{value:.3g}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--default-recipe", action="store_true")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args()
    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        manifest = dict(tomllib.load(fh)["assets"])
    rows = [(asset, recipe) for asset, recipe in manifest.items()]
    if args.default_recipe:
        rows += [(asset, "default") for asset in manifest]
    print("| asset | recipe | criterion | " + " | ".join(COLUMNS) + " | .bin bytes | growth | bake s | runtime s |")
    print("|" + "---|" * (len(COLUMNS) + 7))
    for asset, recipe in rows:
        base = None
        for criterion in ("modes", "stress"):
            with tempfile.TemporaryDirectory() as out:
                extra = ["runtime.criterion=stress", *args.overrides] if criterion == "stress" else []
                path, report = _bake(asset, recipe, out, extra)
                size = os.path.getsize(path[: -len(".json")] + ".bin")
                figures = run_atlas(path, criterion=criterion).summary["figures"]
            seconds = report["seconds"]
            total = sum(seconds.values())
            if base is None:
                base = (size, total)
            growth = f"{(size - base[0]) / 1e6:+.2f} MB" if criterion == "stress" else ""
            ratio = f"{total:.1f} ({total / base[1]:.2f}x)" if criterion == "stress" else f"{total:.1f}"
            cells = " | ".join(_cell(figures[key], key) for key in COLUMNS)
            print(f"| {asset} | {recipe} | {criterion} | {cells} | {size} | {growth} | {ratio} | "
                  f"{seconds.get('runtime', 0.0):.2f} |", flush=True)


if __name__ == "__main__":
    main()
