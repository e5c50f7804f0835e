"""Benchmark: the stress criterion against the modes (issue 30): atlas figures, file size, bake time.

Each sample asset is baked twice per recipe (its manifest recipe and the default one) in fresh
processes: ``runtime.criterion = "modes"`` and ``"stress"``; each bake is swept by
its own criterion with :func:`fracture_cli.atlas.run_atlas` (200 hits). Prints a markdown table: the
atlas figures (fracture_cli/atlas/sweep.py), the runtime file's size and growth, the bake's total
seconds and its runtime stage's.

    python bench/bench_stress.py [--quick] [--manifest-only] [--set SECTION.KEY=VALUE ...]

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
COLUMNS = ("hit_detached", "hit_on_largest", "hit_detached_others", "locality_2x", "locality_8x",
           "first_break_splits", "graded_median", "b0_median", "d1_median")


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
    if key in ("hit_detached", "hit_on_largest", "hit_detached_others", "first_break_splits"):
        return f"{100 * value:.0f}%"
    return f"{value:.3g}"


# (label, --set values of the bake, atlas criterion); the stress variants add the command line's --set values.
VARIANTS = (
    ("modes", (), "modes"),
    ("stress", ("runtime.criterion=stress",), "stress"),
    ("stress, no sharing", ("runtime.criterion=stress", "runtime.load_sharing=0"), "stress"),
    ("stress, tets", ("runtime.criterion=stress", "runtime.stress_model=tets"), "stress"),
)
# Manifest rows also get the stress criterion with two levels, the children's bonds at a tenth of the threshold.
LEVELS_VARIANT = ("stress, 2 levels", ("runtime.criterion=stress", "levels.count=2", "levels.threshold_factor=0.1"),
                  "stress")


def _rows(rows: list[tuple[str, str, bool]], overrides: list[str]) -> tuple[list[str], dict[str, list[dict]]]:
    lines: list[str] = []
    figures_by_variant: dict[str, list[dict]] = {}
    for asset, recipe, with_levels in rows:
        base = None
        for label, settings, criterion in VARIANTS + ((LEVELS_VARIANT,) if with_levels else ()):
            with tempfile.TemporaryDirectory() as out:
                extra = [*settings, *overrides] if criterion == "stress" else []
                path, report = _bake(asset, recipe, out, extra)
                size = os.path.getsize(path[: -len(".json")] + ".bin")
                figures = run_atlas(path, criterion=criterion).summary["figures"]
            figures_by_variant.setdefault(label, []).append({"asset": f"{asset} ({recipe})", **figures})
            seconds = report["seconds"]
            total = seconds["total"]  # the bake, to its published outputs (pipeline.bake)
            if base is None:
                base = (size, total, seconds.get("runtime", 0.0))
            stress = criterion == "stress"
            growth = f"{(size - base[0]) / 1e6:+.2f} MB" if stress else ""
            ratio = f"{total:.1f} ({total / base[1]:.2f}x)" if stress else f"{total:.1f}"
            cells = " | ".join(_cell(figures[key], key) for key in COLUMNS)
            lines.append(f"| {asset} | {recipe} | {label} | {cells} | {size} | {growth} | {ratio} | "
                         f"{seconds.get('runtime', 0.0):.2f} |")
    return lines, figures_by_variant


# Issue 30's targets on the atlas figures: (key, at least (True) or at most (False), value).
TARGETS = (("hit_detached", True, 0.95), ("locality_2x", False, 0.3), ("locality_8x", False, 0.5),
           ("first_break_splits", True, 0.5))


def _targets(figures_by_variant: dict[str, list[dict]]) -> list[str]:
    """One line per stress variant: each target's worst row and whether every row meets it."""
    lines = []
    for label, rows in figures_by_variant.items():
        if label == "modes":
            continue
        parts = []
        for key, at_least, value in TARGETS:
            known = [r for r in rows if r[key] is not None]
            if not known:
                continue
            worst = min(known, key=lambda r: r[key]) if at_least else max(known, key=lambda r: r[key])
            met = all(r[key] >= value if at_least else r[key] <= value for r in known)
            shown = f"{100 * worst[key]:.0f}%" if key in ("hit_detached", "first_break_splits") else f"{worst[key]:.2f}"
            parts.append(f"{key} {'>=' if at_least else '<='} {value:g}: worst {shown} ({worst['asset']}), "
                         f"{'met' if met else 'missed'}")
        lines.append(f"- {label} ({len(rows)} rows): " + "; ".join(parts) + ".")
    return lines


def run(quick: bool = False, default_recipe: bool = True, overrides: tuple[str, ...] = ()) -> str:
    """The markdown section (bench/run.py); ``quick``: only the chair with its manifest recipe."""
    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        manifest = dict(tomllib.load(fh)["assets"])
    rows = [(asset, recipe, True) for asset, recipe in manifest.items()]
    if quick:
        rows = [("chair.glb", manifest["chair.glb"], False)]
    elif default_recipe:
        rows += [(asset, "default", False) for asset in manifest]
    head = [
        "## Stress criterion against the modes (issue 30)",
        "",
        "Each sample asset baked per recipe in fresh processes with `runtime.criterion = \"modes\"`, with "
        "`\"stress\"` (the default `stress_model = \"blocks\"`: rigid fragments held by elastic faults, the hit "
        "on the fragment it lands on; and the default `load_sharing = 2`: the struck fragment's bonds share the "
        "load of its broken ones, docs/FORMAT.md section 11.1), the same with `load_sharing = 0` (\"no sharing\"), "
        "with `\"stress\"` and `stress_model = \"tets\"` (elasticity on the tet "
        "mesh), and for the manifest recipes with `\"stress\"` and two levels (`levels.count = 2`, children's "
        "bonds at `levels.threshold_factor = 0.1`; the atlas counts the leaves shown), each swept by its criterion "
        "(`run_atlas`, 200 hits; figures defined in "
        "fracture_cli/atlas/sweep.py). Targets (issue 30, stress criterion): hit fragment detached >= 95%, "
        "locality <= 0.3 at 2 x b0 and <= 0.5 at 8 x b0, first break splits >= 50%, everything / d1 >= 8, "
        "runtime file growth <= 1 MB, stress bake <= 1.5 x the modes bake. `graded_median` is `inf` when the "
        "median hit leaves some bond unbroken at every magnitude (a bond the site does not list, or does not "
        "pull). Bake seconds are wall time on a shared machine; the runtime stage's seconds are the "
        "criterion's own cost.",
        "",
        "| asset | recipe | criterion | " + " | ".join(COLUMNS) + " | .bin bytes | growth | bake s | runtime s |",
        "|" + "---|" * (len(COLUMNS) + 7),
    ]
    lines, figures = _rows(rows, list(overrides))
    return "\n".join(head + lines + ["", "Issue 30's targets per variant (every row):", "", *_targets(figures)]) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--manifest-only", action="store_true", help="without the default-recipe rows")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args()
    print(run(quick=args.quick, default_recipe=not args.manifest_only, overrides=tuple(args.overrides)))


if __name__ == "__main__":
    main()
