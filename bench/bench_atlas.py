"""Benchmark: the break atlas of every sample asset (issue 30): does breaking follow the hit?

Each sample asset is baked with the recipe its manifest names (sample_assets/manifest.toml) in a
temporary folder, in a fresh process (`python -m fracture_cli bake`), then swept by
:func:`fracture_cli.atlas.run_atlas` (200 hits by farthest-point sampling, impulse towards the
asset's centre; every figure is defined in fracture_cli/atlas/sweep.py). Targets (issue 30, for
the stress criterion to come): hit fragment detached >= 95%, locality <= 0.3 at 2 x b0 and
<= 0.5 at 8 x b0, first break splits >= 50%, everything / d1 >= 8.

    python bench/bench_atlas.py [--quick] [--no-bake] [--default-recipe]

--no-bake (and --quick) sweeps the manifest bakes committed under tests/data/runtime_conformance/
instead of baking (minutes); --default-recipe adds a row per asset baked with the default recipe.
Baking, the authored patterns of issue 32 get rows too (:data:`PATTERN_BAKES`): a voronoi pattern on the
pillar and the chair, the radial glass_pane recipe on the pane, the bricks of brick_wall on the wall; and
stress bakes with two levels of fracture (:data:`LEVEL_BAKES`).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import tomllib

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import fracture_cli  # noqa: E402, F401, I001  (first: pins the kernels before numpy loads)

from fracture_cli.atlas import run_atlas  # noqa: E402

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFORMANCE = os.path.join(REPO, "tests", "data", "runtime_conformance")
# Issue 32's pattern bakes: (asset, recipe, --set values, label).
PATTERN_BAKES = (
    ("pillar.glb", "stone", ("pattern.kind=voronoi", "pattern.count=24"), "stone, voronoi 24"),
    ("chair.glb", "wood", ("pattern.kind=voronoi", "pattern.count=24"), "wood, voronoi 24"),
    ("pane.glb", "glass_pane", (), "glass_pane: radial"),
    ("wall.glb", "brick_wall", (), "brick_wall: bricks"),
)
# Levels (issue 34) swept as the runtime's hit_piece answers them (fracture_cli/atlas/leaves.py): the fragment hit
# breaks into its children too; with the stress criterion, the children's default threshold as baked and at 0.1x.
LEVEL_BAKES = tuple(
    (asset, recipe, ("runtime.criterion=stress", "levels.count=2", *extra), f"{recipe}, stress, 2 levels{label}")
    for asset, recipe in (("chair.glb", "wood"), ("pillar.glb", "stone"), ("vase.obj", "ceramic"))
    for extra, label in (((), ""), (("levels.threshold_factor=0.1",), ", children at 0.1 T")))
COLUMNS = ("hit_detached", "hit_on_largest", "hit_detached_others", "locality_2x", "locality_8x",
           "first_break_splits", "graded_median", "graded_p10",
           "b0_median", "d1_median")


def _manifest() -> dict[str, str]:
    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        return dict(tomllib.load(fh)["assets"])


def _bake(asset: str, recipe: str, out: str, settings: tuple[str, ...] = ()) -> str:
    """Bake one sample asset in a fresh process (``settings``: ``--set`` values); returns its runtime file."""
    sets = [arg for value in settings for arg in ("--set", value)]
    subprocess.run([sys.executable, "-m", "fracture_cli", "-q", "bake", os.path.join(REPO, "sample_assets", asset),
                    "-o", out, "--recipe", recipe, *sets], check=True, cwd=REPO)
    return os.path.join(out, os.path.splitext(asset)[0] + ".fracture.json")


def _cell(figures: dict, key: str) -> str:
    value = figures[key]
    if value is None:
        return "-"
    if key in ("hit_detached", "hit_on_largest", "hit_detached_others", "first_break_splits"):
        return f"{100 * value:.0f}%"
    if key.startswith("locality"):
        return f"{value:.2f} / {figures[key + '_median']:.2f} ({figures[key + '_hits']})"
    return f"{value:.3g}"


def _row(label: str, json_path: str, criterion: str = "modes") -> str:
    t0 = time.perf_counter()
    result = run_atlas(json_path, criterion=criterion)
    seconds = time.perf_counter() - t0
    summary = result.summary
    figures = summary["figures"]
    cells = [label, summary["criterion"], str(summary["counts"]["fragments"]), str(summary["counts"]["edges"]),
             *(_cell(figures, key) for key in COLUMNS), f"{seconds:.2f}"]
    return "| " + " | ".join(cells) + " |"


def run(quick: bool = False, bake: bool = True, default_recipe: bool = False) -> str:
    bake = bake and not quick
    lines = [
        "## Break atlas",
        "",
        ("Each sample asset " + ("baked with its manifest recipe in a fresh process" if bake else
                                 "from its committed manifest bake (tests/data/runtime_conformance/)")
         + ", then `run_atlas` (fracture_cli/atlas/): 200 hits spread over the contact sites by farthest-point "
           "sampling, impulse towards the asset's centre of mass, the file's default threshold T. Exact per hit "
           "(no magnitude sampling): b0 = first bond breaks, d1 = first detachment, everything = every bond "
           "broken. Columns: hit fragment (the one whose collision parts are nearest the hit) detached just above "
           "d1; hits on the largest fragment; hit fragment detached over the other hits "
           "(docs/notes/breaking-analysis.md); locality (mean / median over the hits that "
           "detach something (their number)) = mean distance hit-detached fragments over mean distance "
           "hit-all fragments, at 2 x b0 and 8 x b0; share of first breaks that split (d1 = b0); median and "
           "10th percentile of everything / d1; medians of b0 / T and d1 / T. Issue 30's targets (stress "
           "criterion): hit detached >= 95%, locality <= 0.3 (2x) and <= 0.5 (8x), splits >= 50%, "
           "everything / d1 >= 8."),
        "",
        "| asset (recipe) | criterion | fragments | bonds | hit detached | hit on largest | hit detached (others) "
        "| locality 2x | locality 8x | first break splits | everything / d1 median | everything / d1 p10 | b0 / T "
        "| d1 / T | atlas (s) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    recipes = [("manifest", None)] + ([("default", "default")] if default_recipe and bake else [])
    with tempfile.TemporaryDirectory() as tmp:
        for which, forced in recipes:
            for asset, recipe in _manifest().items():
                stem = os.path.splitext(asset)[0]
                recipe = forced or recipe
                if bake:
                    json_path = _bake(asset, recipe, os.path.join(tmp, f"{stem}-{which}"))
                else:
                    json_path = os.path.join(CONFORMANCE, f"{stem}.fracture.json")
                lines.append(_row(f"{asset} ({recipe})", json_path))
        if bake:
            for asset, recipe, settings, label in PATTERN_BAKES:
                out = os.path.join(tmp, f"{os.path.splitext(asset)[0]}-pattern-{recipe}")
                lines.append(_row(f"{asset} ({label})", _bake(asset, recipe, out, settings)))
            for asset, recipe, settings, label in LEVEL_BAKES:
                out = os.path.join(tmp, f"{os.path.splitext(asset)[0]}-levels-{len(lines)}")
                lines.append(_row(f"{asset} ({label})", _bake(asset, recipe, out, settings), "stress"))
    if bake:
        lines += ["", "The pattern rows (issue 32): the cells of an authored pattern are the pieces and the modes are "
                  "solved on them (docs/ALGORITHM.md section 9), so the same figures say whether a pattern breaks "
                  "by the hit.",
                  "",
                  "The level rows (issues 30, 34): with `levels.count = 2` a hit on a fragment with children breaks "
                  "it too (docs/FORMAT.md section 14.5) and the figures count the leaves shown "
                  "(fracture_cli/atlas/leaves.py): the fragment hit is the child the hit lands on once its parent "
                  "has split. `levels.threshold_factor = 0.1` makes the children's bonds ten times weaker than the "
                  "level-1 bonds (as Chaos's damage thresholds per level)."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--no-bake", action="store_true")
    parser.add_argument("--default-recipe", action="store_true")
    args = parser.parse_args()
    print(run(quick=args.quick, bake=not args.no_bake, default_recipe=args.default_recipe))
