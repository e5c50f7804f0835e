"""``-j`` default against ``-j 1`` (issue 33), alone and beside one more bake; the report's seconds against the clock.

    python bench/bench_jobs.py [--quick] [--assets chair.glb,vase.obj] [--reps 3]

Every run is a fresh ``fracture -q bake`` process timed from outside (wall,
and CPU of the process and its reaped workers), default recipe. Per
repetition the two kinds run back to back, in alternating order (the one
that goes first changes every repetition), so the shared machine's load
drifts alike for both; the ratios pair the runs of one repetition. Alone: no
other run of this bench meanwhile (whatever else the machine runs: see the
load average). Beside a bake: the same while one more default bake of the
same asset runs in a loop (bench_peer.py's :class:`Competitor`).

The same runs check the report's ``seconds``: ``startup`` + every step
(stages and ``export``) against ``total`` and against the wall time measured
from outside (issue 33: they add up to it within 5%).

Unlike bench_peer.py this needs no Blender, so it measures the ``-j`` target
on its own in minutes rather than the peer section's quarter of an hour.
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from bench_peer import ASSETS, Competitor, bake  # noqa: E402  (bench/ is on the path above)

# Issue 33: -j default never slower than -j 1, alone and beside one more bake; startup + steps within 5% of the wall.
TARGET_JOBS = 1.0
TARGET_ACCOUNTED = 0.05
KINDS = ("default", "j1")


def run(quick: bool = False, assets: tuple[str, ...] | None = None, reps: int | None = None) -> str:
    """The section: both kinds alone, then beside a bake, per asset; the targets."""
    assets = assets or (ASSETS[:1] if quick else ASSETS)
    reps = reps or (1 if quick else 3)
    load_before = os.getloadavg()
    t_start = time.perf_counter()
    alone: dict[str, dict[str, list[dict]]] = {}
    beside: dict[str, dict[str, list[dict]]] = {}
    competing: dict[str, int] = {}
    with tempfile.TemporaryDirectory(prefix="fracture-bench-jobs-") as tmp:
        for asset in assets:
            alone[asset] = alternate(asset, reps, os.path.join(tmp, "alone"))
        for asset in assets:
            with Competitor(asset, os.path.join(tmp, "competitor")) as competitor:
                beside[asset] = alternate(asset, reps, os.path.join(tmp, "beside"))
            competing[asset] = competitor.count
    load_after = os.getloadavg()
    return section(alone, beside, competing, reps, load_before, load_after, time.perf_counter() - t_start)


def alternate(asset: str, reps: int, tmp: str) -> dict[str, list[dict]]:
    """``reps`` repetitions of a default bake and a ``-j 1`` bake of ``asset``, the first of each pair alternating."""
    runs: dict[str, list[dict]] = {kind: [] for kind in KINDS}
    for rep in range(reps):
        for kind in (KINDS if rep % 2 == 0 else KINDS[::-1]):
            runs[kind].append(bake(asset, os.path.join(tmp, kind), jobs=1 if kind == "j1" else None))
        print(f"  jobs: {asset} repetition {rep + 1}/{reps}", file=sys.stderr)
    return runs


def accounted(run: dict) -> tuple[float, float]:
    """(startup + steps) / wall and total / wall of one bake: how much of the measured time its report shows."""
    seconds = run["report"]["seconds"]
    steps = sum(v for k, v in seconds.items() if k != "total")
    return steps / run["wall"], seconds.get("total", float("nan")) / run["wall"]


def ratios(runs: dict[str, list[dict]], key: str = "wall") -> list[float]:
    """Default over ``-j 1`` of each repetition."""
    return [a[key] / b[key] for a, b in zip(runs["default"], runs["j1"])]


def _median(values: list[float], fmt: str = "{:.1f}") -> str:
    return fmt.format(statistics.median(values)) if values else "-"


def _pair(values: list[float]) -> str:
    return f"{min(values):.2f} / {statistics.median(values):.2f}" if values else "-"


def section(alone: dict, beside: dict, competing: dict, reps: int, load_before: tuple, load_after: tuple,
            seconds: float) -> str:
    """The markdown section."""
    lines = ["## `-j` default against `-j 1` (issue 33)", "",
             f"`fracture -q bake ASSET` (default `-j`) and `fracture -q -j 1 bake ASSET`, default recipe, {reps} "
             "repetitions per asset, back to back in alternating order; wall seconds measured from outside (median), "
             "CPU = user + system of the process and its workers (median), ratio = default / `-j 1` of the same "
             "repetition (smallest / median). Beside a bake: while one more default bake of the same asset runs in "
             "a loop (how many of those finished meanwhile). The machine's 2 cores are shared with other jobs "
             "throughout (load average below): 'alone' means no other run of this bench, not an idle machine.", "",
             "| asset | alone: default s | alone: -j 1 s | alone: CPU default / -j 1 s | alone: ratio "
             "| beside: default s | beside: -j 1 s | beside: ratio | other bakes finished |",
             "|---|" + "---:|" * 8]
    for asset in alone:
        a, b = alone[asset], beside[asset]
        wall = {kind: [r["wall"] for r in a[kind]] for kind in KINDS}
        cpu = {kind: [r["cpu"] for r in a[kind]] for kind in KINDS}
        wall_beside = {kind: [r["wall"] for r in b[kind]] for kind in KINDS}
        lines.append(f"| {asset} | {_median(wall['default'])} | {_median(wall['j1'])} "
                     f"| {_median(cpu['default'])} / {_median(cpu['j1'])} | {_pair(ratios(a))} "
                     f"| {_median(wall_beside['default'])} | {_median(wall_beside['j1'])} | {_pair(ratios(b))} "
                     f"| {competing[asset]} |")
    every = [r for runs in (*alone.values(), *beside.values()) for kind in KINDS for r in runs[kind]]
    shown = [accounted(r) for r in every]
    startups = [float(r["report"]["seconds"].get("startup", float("nan"))) for r in every]
    lines += ["", "The report's `seconds` against the wall time measured from outside, over all "
              f"{len(every)} bakes above: (`startup` + stages + `export`) / wall {_spread([s for s, _ in shown])}; "
              f"`total` / wall {_spread([t for _, t in shown])}; `startup` {_spread(startups, 's')}.", ""]
    worst_alone = _worst({a: ratios(r) for a, r in alone.items()})
    worst_beside = _worst({a: ratios(r) for a, r in beside.items()})
    lines += ["Targets (per asset the median of the paired ratios; the worst asset named):", "",
              _verdict("issue 33, `-j` default never slower than `-j 1`, alone", worst_alone, TARGET_JOBS),
              _verdict("issue 33, `-j` default never slower than `-j 1` beside one more bake", worst_beside,
                       TARGET_JOBS),
              _verdict(f"issue 33, `startup` + stages + `export` within {TARGET_ACCOUNTED:.0%} of the wall time "
                       "(largest shortfall 1 - sum / wall of any bake)",
                       ("every bake", max(1 - s for s, _ in shown)) if shown else None, TARGET_ACCOUNTED, ""),
              "", f"Load average (1 min) {load_before[0]:.1f} before and {load_after[0]:.1f} after this section "
              f"({seconds / 60:.0f} min), on {os.cpu_count()} cores."]
    return "\n".join(lines) + "\n"


def _spread(values: list[float], unit: str = "") -> str:
    if not values:
        return "-"
    return (f"min {min(values):.3f}{unit}, median {statistics.median(values):.3f}{unit}, "
            f"max {max(values):.3f}{unit}")


def _worst(per_asset: dict[str, list[float]]) -> tuple[str, float] | None:
    medians = {a: statistics.median(r) for a, r in per_asset.items() if r}
    if not medians:
        return None
    asset = max(medians, key=lambda a: medians[a])
    return asset, medians[asset]


def _verdict(what: str, worst: tuple[str, float] | None, limit: float, unit: str = "x") -> str:
    if worst is None:
        return f"- {what}: not measured."
    where, value = worst
    shown = f"{value:.2f}{unit}" if unit else f"{value:.3f}"
    return f"- {what}: worst {shown} ({where}): {'**missed**' if value > limit else '**met**'}."


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--assets", default="")
    parser.add_argument("--reps", type=int, default=0)
    args = parser.parse_args()
    print(run(args.quick, tuple(a for a in args.assets.split(",") if a) or None, args.reps or None))
