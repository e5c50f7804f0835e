"""The README's performance table, generated from bench/RESULTS.md so that it cannot go stale.

    python bench/perf_table.py [--results bench/RESULTS.md] [--readme README.md] [--check]

Reads the sections of RESULTS.md (markdown tables), picks the headline
figures and rewrites the block between ``<!-- perf-table:begin -->`` and
``<!-- perf-table:end -->`` in README.md. ``make bench`` runs it after the
benchmarks; ``--check`` exits 1 when the README's block differs (for CI or a
review). A section missing from RESULTS.md, or whose format changed, gives no
row (its figures stay in RESULTS.md).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from collections.abc import Callable

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
BEGIN, END = "<!-- perf-table:begin -->", "<!-- perf-table:end -->"

Table = list[dict[str, str]]


def sections(text: str) -> dict[str, str]:
    """Top-level sections of RESULTS.md by their ``## `` title."""
    out: dict[str, str] = {}
    title = None
    for line in text.splitlines():
        if line.startswith("## "):
            title = line[3:].strip()
            out[title] = ""
        elif title is not None:
            out[title] += line + "\n"
    return out


def tables(section: str) -> list[Table]:
    """Every markdown table of a section, as rows of {column: cell}."""
    found: list[Table] = []
    lines = section.splitlines()
    i = 0
    while i < len(lines):
        if lines[i].startswith("|") and i + 1 < len(lines) and re.match(r"^\|[\s:|-]+\|$", lines[i + 1].strip()):
            head = [c.strip() for c in lines[i].strip().strip("|").split("|")]
            rows = []
            i += 2
            while i < len(lines) and lines[i].startswith("|"):
                cells = [c.strip() for c in lines[i].strip().strip("|").split("|")]
                rows.append(dict(zip(head, cells)))
                i += 1
            found.append(rows)
        else:
            i += 1
    return found


def _number(cell: str) -> float:
    return float(re.sub(r"[^0-9.eE+-]", "", cell.split("/")[0]))


def _span(values: list[float], fmt: str = "{:.0f}") -> str:
    lo, hi = min(values), max(values)
    return fmt.format(lo) if fmt.format(lo) == fmt.format(hi) else f"{fmt.format(lo)}-{fmt.format(hi)}"


def _find(secs: dict[str, str], prefix: str) -> str | None:
    return next((body for title, body in secs.items() if title.startswith(prefix)), None)


def _bake_rows(secs: dict[str, str]) -> list[tuple[str, str]]:
    body = _find(secs, "Bake: end to end")
    rows = tables(body)[0] if body else []
    if not rows:
        return []
    totals = [_number(r["total s"]) for r in rows]
    peaks = [_number(r["peak MB"]) for r in rows]
    return [("bake of each sample asset with its manifest recipe",
             f"{_span(totals, '{:.1f}')} s, peak {_span(peaks)} MB")]


def _recipe_rows(secs: dict[str, str]) -> list[tuple[str, str]]:
    body = _find(secs, "Recipes:")
    rows = tables(body)[0] if body else []
    if not rows:
        return []
    walls = [_number(r["wall s"]) for r in rows]
    cpu = [_number(r["CPU %"]) for r in rows]
    peaks = [_number(r["peak MB"]) for r in rows]
    worst = max(rows, key=lambda r: _number(r["wall s"]))
    out = [(f"every built-in recipe on every sample asset ({len(rows)} bakes)",
            f"{_span(walls, '{:.1f}')} s (slowest: {worst['recipe']} on {worst['asset']}), CPU {_span(cpu)} %, "
            f"peak {_span(peaks)} MB")]
    default = [r for r in rows if r["recipe"] == "default"]
    if default:
        def span(column: str, fmt: str) -> str:
            return _span([_number(r[column]) for r in default], fmt)

        out.append(("default bake / plain Voronoi shatter (same asset, same fragment count)",
                    f"{span('ratio', '{:.1f}')}x (bake {span('wall s', '{:.1f}')} s, of which start-up "
                    f"{span('start-up s', '{:.1f}')} s; shatter {span('baseline s', '{:.2f}')} s)"))
    return out


def _large_rows(secs: dict[str, str]) -> list[tuple[str, str]]:
    body = _find(secs, "Large input")
    if not body:
        return []
    match = re.search(r"([\d,]+) triangles.*?: ([\d.]+) s wall, peak memory ([\d,]+) MiB", body, re.S)
    if not match:
        return []
    tris, wall, peak = match.groups()
    return [(f"bake of a {tris}-triangle input", f"{wall} s, peak {peak} MB")]


def _assets_rows(secs: dict[str, str]) -> list[tuple[str, str]]:
    body = _find(secs, "make assets")
    rows = tables(body)[0] if body else []
    if len(rows) < 2:
        return []
    wall = {r["run"]: _number(r["wall s"]) for r in rows}
    serial, both = wall.get("make assets"), wall.get("make -j2 assets")
    if not serial or not both:
        return []
    return [("`make -j2 assets` / `make assets`", f"{both:.1f} s / {serial:.1f} s = {both / serial:.2f}x")]


def _cage_rows(secs: dict[str, str]) -> list[tuple[str, str]]:
    body = _find(secs, "Cage")
    rows = tables(body)[0] if body else []
    row = next((r for r in rows if r.get("input", "").startswith("torus") and r.get("target") == "2,000"), None)
    if row is None:
        return []
    return [(f"nested cage, 2,000 faces, {row['triangles']}-triangle input", f"{_number(row['total s']):.1f} s")]


def _modes_rows(secs: dict[str, str]) -> list[tuple[str, str]]:
    body = _find(secs, "Fracture modes")
    rows = [r for t in (tables(body) if body else []) for r in t]
    fast = [r for r in rows if r.get("solver") == "fast" and r.get("s/mode") and r.get("tets")
            and r.get("max-flow", "kernel") in ("kernel", "ortools", "")]
    if not fast:
        return []
    seen: dict[str, str] = {}
    for r in fast:
        seen.setdefault(r["tets"], r["s/mode"])
    return [("fracture modes, exact solver (s/mode by tets)", ", ".join(f"{v} at {k}" for k, v in seen.items()))]


def _peer_rows(secs: dict[str, str]) -> list[tuple[str, str]]:
    """Blender's Cell Fracture beside the bake (bench_peer.py): median ratios per asset, their span."""
    body = _find(secs, "Peer:")
    found = tables(body) if body else []
    if len(found) < 2 or not found[0] or not found[1]:
        return []

    def medians(rows: Table, column: str) -> list[float]:  # cells "min / median"; "-" where not measured
        return [float(r[column].split("/")[-1]) for r in rows if r[column] != "-"]

    default, voronoi = found[0], found[1]
    out = []
    walls, cpus = medians(default, "bake / Blender (min / median)"), medians(default, "CPU ratio")
    if walls and cpus:
        out.append((f"default bake / Blender's Cell Fracture, same piece count, hulls and GLB (whole process, "
                    f"{len(walls)} assets)", f"{_span(walls, '{:.1f}')}x wall, {_span(cpus, '{:.1f}')}x CPU"))
    peer, plain = medians(voronoi, "bake / Blender"), medians(voronoi, "bake / shatter")
    if peer and plain:
        out.append((f"voronoi bake of 100 cells / Cell Fracture's 100 pieces with hulls ({len(peer)} assets) / "
                    f"plain Voronoi shatter ({len(plain)})",
                    f"{_span(peer, '{:.1f}')}x / {_span(plain, '{:.0f}')}x wall"))
    return out


ROWS: tuple[Callable[[dict[str, str]], list[tuple[str, str]]], ...] = (
    _bake_rows, _recipe_rows, _peer_rows, _assets_rows, _large_rows, _cage_rows, _modes_rows)


def perf_table(results: str) -> str:
    """The README block (markers included) for the text of RESULTS.md."""
    secs = sections(results)
    date = re.search(r"- date: (\S+)", results)
    lines = [BEGIN, f"<!-- generated by bench/perf_table.py from bench/RESULTS.md"
             f"{' of ' + date.group(1) if date else ''}; do not edit by hand -->", "",
             "| what | measured |", "|---|---|"]
    for make_rows in ROWS:
        try:
            rows = make_rows(secs)
        except (KeyError, ValueError, IndexError):  # a section's format changed: no row rather than a wrong one
            rows = []
        lines += [f"| {what} | {value} |" for what, value in rows]
    return "\n".join(lines + [END])


def update_readme(readme: str, block: str) -> str:
    """``readme`` with its perf-table block replaced by ``block``."""
    start, end = readme.find(BEGIN), readme.find(END)
    if start < 0 or end < start:
        raise SystemExit(f"README has no {BEGIN} ... {END} block")
    return readme[:start] + block + readme[end + len(END):]


def main_update(results: str = os.path.join(HERE, "RESULTS.md"), readme: str = os.path.join(REPO, "README.md")) -> None:
    """Rewrite the README's block from ``results`` (what ``make bench`` does after the benchmarks)."""
    with open(results) as fh:
        block = perf_table(fh.read())
    with open(readme) as fh:
        text = fh.read()
    updated = update_readme(text, block)
    if updated != text:
        with open(readme, "w") as fh:
            fh.write(updated)
        print(f"updated the performance table in {readme}", file=sys.stderr)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", default=os.path.join(HERE, "RESULTS.md"))
    parser.add_argument("--readme", default=os.path.join(REPO, "README.md"))
    parser.add_argument("--check", action="store_true", help="exit 1 if the README's table is not up to date")
    args = parser.parse_args()
    with open(args.results) as fh:
        block = perf_table(fh.read())
    with open(args.readme) as fh:
        readme = fh.read()
    updated = update_readme(readme, block)
    if args.check:
        if updated != readme:
            print(f"{args.readme}: the performance table is not generated from {args.results}; run "
                  "`python bench/perf_table.py`", file=sys.stderr)
            return 1
        return 0
    main_update(args.results, args.readme)
    return 0


if __name__ == "__main__":
    sys.exit(main())
