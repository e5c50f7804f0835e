"""Run every bench/bench_*.py and write their sections to one markdown file.

    python bench/run.py --out bench/RESULTS.md [--quick] [--only cage,modes]

Each benchmark module exposes ``run(quick: bool = False) -> str`` returning a
markdown section. Speed and memory targets live here, never in tests. With
``--only``, the other sections of an existing output file are kept (so one
section can be rerun). Writing bench/RESULTS.md also regenerates the README's
performance table from it (bench/perf_table.py).
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import os
import platform
import re
import sys
import time
import traceback

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

# Before any benchmark imports numpy: the pinned kernels every bake runs with (fracture_cli/system/numeric_env.py).
import fracture_cli  # noqa: E402, F401, I001


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(HERE, "RESULTS.md"))
    parser.add_argument("--quick", action="store_true", help="smaller sizes, for a smoke run")
    parser.add_argument("--only", default="", help="comma-separated benchmark names (e.g. cage,modes)")
    args = parser.parse_args()
    only = {s.strip() for s in args.only.split(",") if s.strip()}
    names = sorted(f[len("bench_"):-3] for f in os.listdir(HERE) if f.startswith("bench_") and f.endswith(".py"))
    if only:
        names = [n for n in names if n in only]
    import numpy

    header = [
        "# Benchmark results",
        "",
        f"- date: {datetime.date.today().isoformat()}",
        f"- machine: {os.cpu_count()} cores, {platform.machine()}, {platform.system()}",
        f"- python {platform.python_version()}, numpy {numpy.__version__}",
        f"- mode: {'quick' if args.quick else 'full'}",
        "",
        "Regenerate with `make bench`. Each section says what it measures and the target.",
        "",
    ]
    sections: dict[str, str] = {}
    failed = 0
    for name in names:
        spec = importlib.util.spec_from_file_location(f"bench_{name}", os.path.join(HERE, f"bench_{name}.py"))
        module = importlib.util.module_from_spec(spec)
        t0 = time.perf_counter()
        try:
            spec.loader.exec_module(module)
            section = module.run(quick=args.quick)
        except Exception:  # a benchmark failure is reported in the results, then the run fails
            failed += 1
            section = f"## {name}\n\nFAILED:\n\n```\n{traceback.format_exc()}\n```\n"
        sections[name] = (f"<!-- bench:{name} -->\n" + section.rstrip()
                          + f"\n\n_(section took {time.perf_counter() - t0:.1f} s)_\n")
        print(f"bench {name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    if only and os.path.exists(args.out):
        with open(args.out) as fh:
            kept = previous_sections(fh.read())
        # A kept section ends where the next begins: without its trailing blank lines, so a rerun adds none.
        sections = {**{k: v.rstrip() + "\n" for k, v in kept.items() if k not in sections}, **sections}
    body = [sections[k] for k in sorted(sections)]
    with open(args.out, "w") as fh:
        fh.write("\n".join(header) + "\n" + "\n".join(body))
    print(f"wrote {args.out}", file=sys.stderr)
    if os.path.abspath(args.out) == os.path.join(HERE, "RESULTS.md"):
        import perf_table

        perf_table.main_update()
    return 1 if failed else 0


# Titles of the sections written before they carried a ``<!-- bench:NAME -->`` marker.
_LEGACY_TITLES = {"bake": "Bake: end to end", "cage": "Cage", "fragments": "Pieces, fault smoothing",
                  "large": "Large input", "modes": "Fracture modes", "preview": "Preview",
                  "runtime": "Impact projection"}


def previous_sections(text: str) -> dict[str, str]:
    """The sections of an earlier results file by benchmark name (markers, else known titles)."""
    out: dict[str, str] = {}
    name = None
    marker = None
    for line in text.splitlines(keepends=True):
        found = re.match(r"<!-- bench:(\w+) -->", line)
        if found:
            marker = found.group(1)
            continue
        if line.startswith("## "):
            name = marker or next((k for k, t in _LEGACY_TITLES.items() if line[3:].startswith(t)), None)
            marker = None
            if name is not None:
                out[name] = f"<!-- bench:{name} -->\n"
        if name is not None:
            out[name] += line
    return out


if __name__ == "__main__":
    sys.exit(main())
