"""Ctrl-C a bake at many moments and check that every one ends as an interrupt (issue 37).

    python scripts/sigint_sweep.py                       # every 0.1 s over the first 5 s
    python scripts/sigint_sweep.py --step 0.5 --until 3  # fewer trials

Each trial starts ``fracture bake ASSET -o OUT`` in a session of its own, waits
the trial's delay, sends SIGINT to the whole process group (what Ctrl-C in a
terminal does: the bake, its TetGen worker and any parallel workers get it)
and checks the outcome: exit code 130 with the "interrupted" line, or (when the
bake finished first) exit 0 with a complete output set; never "internal error",
a traceback, or a partial set. A Ctrl-C while the interpreter itself starts
(importing its site module, before the tool's first line runs; the first tenth
of a second on a loaded machine) ends as CPython ends it, exit code 1 and
"Fatal Python error: init_import_site": counted apart, as "interpreter
start-up". The tests run a handful of these moments
(tests/test_cli_interrupts.py); this is the full sweep. Prints one line per
trial and a summary; exit code 1 if any trial broke the rule. SWEEP_SHOW=1
prints the whole stderr of a broken trial. Run it from a shell with job control
(a terminal): a command started with ``&`` in a script has SIGINT ignored, and
so would every bake it starts.
"""

from __future__ import annotations

import argparse
import collections
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)


def trial(asset: str, out: str, delay: float, extra: list[str]) -> tuple[int, str, str]:
    """One bake interrupted after ``delay`` seconds: (exit code, verdict, first stderr line of note)."""
    from fracture_cli.io.outputs import verify_output_set

    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=REPO + os.pathsep + os.environ.get("PYTHONPATH", ""))
    bake = subprocess.Popen([sys.executable, "-m", "fracture_cli", "bake", asset, "-o", out, *extra],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=REPO, env=env,
                            start_new_session=True)
    time.sleep(delay)
    try:
        os.killpg(bake.pid, signal.SIGINT)
    except ProcessLookupError:
        pass
    _, stderr = bake.communicate(timeout=300)
    code = bake.returncode
    stem = os.path.splitext(os.path.basename(asset))[0]
    if "Fatal Python error: init_import_site" in stderr:
        # The interpreter's own start-up (its site module, before any of the tool's code runs): CPython ends
        # with exit code 1 and this message; nothing the tool does can change it.
        return code, "interpreter start-up", ""
    bad = [line for line in stderr.splitlines() if "internal error" in line or "Traceback" in line]
    if bad:
        return code, "BROKEN", bad[0] + ("\n" + stderr if os.environ.get("SWEEP_SHOW") else "")
    if code == 130 and "interrupted" in stderr:
        written = os.path.isdir(out) and os.listdir(out)
        return code, "interrupted" if not written or verify_output_set(out, stem) is None else "BROKEN", ""
    if code == 0 and verify_output_set(out, stem) is None:
        return code, "finished", ""
    last = (stderr.strip().splitlines() or ["(no stderr)"])[-1]
    return code, "BROKEN", last + ("\n" + stderr if os.environ.get("SWEEP_SHOW") else "")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--asset", default=os.path.join(REPO, "tests", "data", "bad", "uv_seams.obj"))
    parser.add_argument("--step", type=float, default=0.1, help="seconds between trial moments")
    parser.add_argument("--until", type=float, default=5.0, help="last moment, seconds after the start")
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="recipe override")
    args = parser.parse_args()
    extra = [w for o in args.overrides for w in ("--set", o)]
    moments = [round(args.step * i, 3) for i in range(1, int(round(args.until / args.step)) + 1)]
    tally: collections.Counter[str] = collections.Counter()
    codes: collections.Counter[int] = collections.Counter()
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sigint-sweep-") as tmp:
        for delay in moments:
            code, verdict, note = trial(args.asset, os.path.join(tmp, "out"), delay, extra)
            tally[verdict] += 1
            codes[code] += 1
            print(f"{delay:5.2f} s  exit {code:4d}  {verdict}{'  ' + note if note else ''}", flush=True)
    print(f"{len(moments)} trials in {time.perf_counter() - start:.0f} s: "
          + ", ".join(f"{n} {v}" for v, n in sorted(tally.items()))
          + "; exit codes " + ", ".join(f"{c}: {n}" for c, n in sorted(codes.items())))
    return 1 if tally["BROKEN"] else 0


if __name__ == "__main__":
    sys.exit(main())
