"""Bake every real-world corpus file and tabulate what happens (docs/notes/realworld-diagnosis.md).

    .venv/bin/python tests/data/realworld/diagnose.py --recipe default --recipe glass --out build/realworld

For each (file, recipe): the outcome (exit code, the error line), the
independent invariant check of the written GLB (tests/invariants.py), what
report.json claims (watertight, connected, pinched_edges, volume_error), the
repairs it lists (the decision and the kinds of repair), fragment and piece
counts, pieces without a fragment, the fragment volumes relative to the asset,
the modes stage's seconds and the bake's CPU seconds (user + system of the
child process; wall-clock is noisy on a shared machine). ``--compare BEFORE
AFTER`` prints two runs' results.jsonl as a case x recipe matrix (issue 39's
before/after table). ``--extra FILE``
bakes further files (e.g. the sample assets, with ``--recipe``). Results are
appended as JSON lines to ``<out>/results.jsonl`` and printed as a markdown
table.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(os.path.dirname(HERE)))
sys.path.insert(0, os.path.join(REPO, "tests"))

from invariants import check_glb, input_box  # noqa: E402  (after the sys.path line)


def bake_one(path: str, out: str, recipe: str, overrides: list[str], reference: float | None,
             jobs: int | None = None) -> dict:
    """Bake one file with the CLI in a child process and collect what it says and writes."""
    stem = os.path.splitext(os.path.basename(path))[0]
    fracture = os.path.join(REPO, ".venv", "bin", "fracture")
    args = [fracture, "-v", "bake", path, "-o", out, "-r", recipe] + (["-j", str(jobs)] if jobs else [])
    for o in overrides:
        args += ["--set", o]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(args, capture_output=True, text=True, check=False)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    log = proc.stderr.splitlines()
    row: dict = {"file": os.path.basename(path), "recipe": recipe, "overrides": overrides, "exit": proc.returncode,
                 "cpu_s": round(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, 1),
                 "repair": [line.split(": ", 2)[-1] for line in log if line.startswith("repair:")],
                 "warnings": [line for line in log if "warning" in line.lower() or "do not reach" in line]}
    if proc.returncode != 0:
        row["error"] = log[-1] if log else ""
        return row
    report_path = os.path.join(out, f"{stem}.report.json")
    with open(report_path) as fh:
        report = json.load(fh)
    checks = report["checks"]
    row["report"] = {k: checks.get(k) for k in ("watertight", "connected", "pinched_edges", "volume_error",
                                                "fragment_volume_min", "fragment_volume_median",
                                                "fragment_volume_max", "max_outer_distance")}
    repairs = report.get("repairs", [])
    kinds: dict[str, int] = {}
    for r in repairs[1:]:
        kinds[r["what"]] = kinds.get(r["what"], 0) + int(r.get("count", 1))
    row["decision"] = repairs[0]["decision"] if repairs else None
    row["repairs"] = kinds
    counts = report["counts"]
    row["counts"] = {k: counts.get(k) for k in ("fragments", "pieces", "tets", "modes", "cage_faces")}
    row["input_volume"] = checks.get("input_volume")
    row["modes_s"] = report["seconds"].get("modes")
    empty = [line for line in log if "do not reach the input" in line]
    row["empty_pieces"] = int(re.search(r"(\d+) piece", empty[0]).group(1)) if empty else 0
    result = check_glb(os.path.join(out, f"{stem}.glb"), reference_volume=reference, volume_tolerance=1e-2,
                       reference_box=input_box(path))
    row["independent"] = result.summary()
    row["independent"]["problems"] = result.problems[:6]
    return row


def table(rows: list[dict]) -> str:
    """Markdown table of the rows (one per bake)."""
    head = ("| file | recipe | outcome | independent check | report says | repairs (report.json) | fragments / pieces "
            "(no fragment) | volumes min / median / max | CPU s |")
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        if r["exit"] != 0:
            lines.append(f"| {r['file']} | {r['recipe']} | **error**: {r.get('error', '')[-160:]} | | | | | | "
                         f"{r['cpu_s']} |")
            continue
        ind = r["independent"]
        bad = ", ".join(f"{k} {v}" for k, v in ind["fragments_with"].items())
        vol = ind["volume_error"]
        verdict = (f"{ind['failing']}/{ind['fragments']} fail" + (f" ({bad})" if bad else "")
                   + (f"; vol err {vol:.2g}" if vol is not None else "")
                   + (f"; bbox +{ind['bbox_excess']:.2g}" if ind["bbox_excess"] else ""))
        rep = r["report"]
        says = f"watertight {rep['watertight']}, connected {rep['connected']}, pinched {rep['pinched_edges']}"
        repairs = f"**{r['decision']}**: " + ", ".join(f"{k} {v}" for k, v in r["repairs"].items())
        sizes = (f"{rep['fragment_volume_min']:.2%} / {rep['fragment_volume_median']:.2%} / "
                 f"{rep['fragment_volume_max']:.1%}")
        c = r["counts"]
        lines.append(f"| {r['file']} | {r['recipe']} | ok | {verdict} | {says} | {repairs} | "
                     f"{c['fragments']} / {c['pieces']} ({r['empty_pieces']}) | {sizes} | {r['cpu_s']} |")
    return "\n".join(lines)


def _cell(row: dict, case: dict) -> str:
    """One bake as a short table cell: refused (why), or fragments and what an artist or the checker objects to."""
    if row["exit"] != 0:
        error = row.get("error", "")
        for key, label in (("truncated", "truncated GLB"), ("broken mesh", "broken fragment"),
                           ("do not pair", "non-manifold edges"), ("volumes", "volume check")):
            if key in error:
                return f"**refused** ({label})"
        return "**refused**"
    ind = row["independent"]
    notes = []
    if ind["failing"]:
        notes.append(f"{ind['failing']} broken")
    if ind["fragments_with"].get("pinched_vertices"):
        notes.append(f"{ind['fragments_with']['pinched_vertices']} self-touching")
    reference = case.get("volume")
    if reference and ind.get("volume") is not None:
        error = ind["volume"] / reference - 1.0
        if abs(error) > case["volume_tolerance"]:
            notes.append(f"volume {100 * error:+.0f}%")
    if row.get("decision") != case["outcome"]:
        notes.append("filled lump" if row.get("decision") == "solid" else "hollow shell")
    repairs = row.get("repairs", {})
    if "unioned_bodies" in repairs and "kept_bodies_apart" not in repairs and "touching" in case["kind"]:
        notes.append("bodies united")
    return f"ok {row['counts']['fragments']}" + (f" ({'; '.join(notes)})" if notes else "")


def compare(before: str, after: str) -> str:
    """Markdown matrix case x recipe of two results.jsonl files: ``before -> after`` per cell."""
    with open(os.path.join(HERE, "expected.toml"), "rb") as fh:
        cases = {c["file"]: c for c in tomllib.load(fh)["case"]}
    rows: dict[str, dict[tuple[str, str], dict]] = {}
    for label, path in (("before", before), ("after", after)):
        with open(path) as fh:
            rows[label] = {(r["file"], r["recipe"]): r for r in map(json.loads, fh)}
    recipes = list(dict.fromkeys(recipe for _, recipe in rows["after"]))
    files = list(dict.fromkeys(file for file, _ in rows["after"]))
    lines = ["| case | " + " | ".join(recipes) + " |", "|---|" + "---|" * len(recipes)]
    for file in files:
        cells = []
        for recipe in recipes:
            pair = [rows[label].get((file, recipe)) for label in ("before", "after")]
            cells.append(" → ".join(_cell(r, cases[file]) if r else "-" for r in pair))
        lines.append(f"| {file} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recipe", action="append", default=None)
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    parser.add_argument("--only", action="append", default=None, help="file names to bake (default: all)")
    parser.add_argument("--extra", action="append", default=[], help="further files to bake (e.g. sample assets)")
    parser.add_argument("--out", default=os.path.join(REPO, "build", "realworld"))
    parser.add_argument("--jobs", type=int, default=None, help="processes per bake (fracture -j)")
    parser.add_argument("--issue39", action="store_true", help="only the files baked with every recipe")
    parser.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"),
                        help="print the case x recipe matrix of two results.jsonl files and exit")
    args = parser.parse_args()
    if args.compare:
        print(compare(*args.compare))
        return
    with open(os.path.join(HERE, "expected.toml"), "rb") as fh:
        cases = tomllib.load(fh)["case"]
    rows = []
    os.makedirs(args.out, exist_ok=True)
    jobs = [(os.path.join(HERE, c["file"]), c.get("volume")) for c in cases
            if (not args.only or c["file"] in args.only) and (not args.issue39 or c.get("recipes") == "all")]
    jobs += [(os.path.abspath(path), None) for path in args.extra]
    for path, volume in jobs:
        for recipe in args.recipe or ["default"]:
            out = os.path.join(args.out, f"{os.path.splitext(os.path.basename(path))[0]}-{recipe}")
            row = bake_one(path, out, recipe, args.overrides, volume, args.jobs)
            rows.append(row)
            with open(os.path.join(args.out, "results.jsonl"), "a") as fh:
                fh.write(json.dumps(row) + "\n")
            print(table([row]).splitlines()[-1], flush=True)
    print(table(rows))


if __name__ == "__main__":
    main()
