"""Ctrl-C a bake at many moments and check that every one ends as an interrupt (issue 37).

    python scripts/sigint_sweep.py                       # every 0.1 s over the first 5 s
    python scripts/sigint_sweep.py --step 0.5 --until 3  # fewer trials
    python scripts/sigint_sweep.py --old --until 6 -- -j 2  # over an old set, 2 workers

Each trial starts ``fracture bake ASSET -o OUT`` in a session of its own, waits
the trial's delay, sends SIGINT to the whole process group (what Ctrl-C in a
terminal does: the bake, its TetGen worker and any parallel workers get it)
and checks the outcome: exit code 130 with the "interrupted" line, or (when the
bake finished first) exit 0 with a complete output set; never "internal error",
a traceback, an "Exception ignored" note, or a partial set. With ``--old``
the output folder holds a complete set of an earlier bake (other recipe
values, so other bytes) when each trial starts: afterwards it must hold
exactly that set (the report's ``files`` hashes match the files present,
nothing else of the stem is left: no staging folder, no lock) or, after a
finished bake, exactly the new one. A Ctrl-C while the interpreter itself starts
(importing its site module, before the tool's first line runs; the first tenth
of a second on a loaded machine) ends as CPython ends it, exit code 1 and
"Fatal Python error: init_import_site": counted apart, as "interpreter
start-up"; so is one that comes while the tool exits after publishing (Python's
teardown, ~0.7 s with SIGINT ignored: exit code 0 with the new set, "Ctrl-C
while exiting"). The tests run a handful of these moments
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


def trial(asset: str, out: str, delay: float, extra: list[str], old: str | None = None,
          jobs: list[str] | None = None, signum: int = signal.SIGINT) -> tuple[int, str, str]:
    """One bake interrupted after ``delay`` seconds: (exit code, verdict, first stderr line of note).

    ``old``: a folder holding a complete set of ``asset``'s stem, copied to
    ``out`` first; the trial then also checks that ``out`` ends with that set
    or a complete new one. ``jobs``: global flags put before ``bake`` (``-j 2``).
    ``signum``: what is sent (SIGTERM, which the CLI takes as Ctrl-C, to the group too).
    """
    shutil.rmtree(out, ignore_errors=True)
    if old is not None:
        shutil.copytree(old, out)
    # PYTHONFAULTHANDLER: a hung bake is sent SIGABRT before it is killed, which prints every thread's stack.
    env = dict(os.environ, PYTHONPATH=REPO + os.pathsep + os.environ.get("PYTHONPATH", ""), PYTHONFAULTHANDLER="1")
    bake = subprocess.Popen([sys.executable, "-m", "fracture_cli", *(jobs or []), "bake", asset, "-o", out, *extra],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=REPO, env=env,
                            start_new_session=True)
    time.sleep(delay)
    sent = bake.poll() is None  # still running: the Ctrl-C must not be lost
    sent_at = time.time()
    try:
        os.killpg(bake.pid, signum)
    except ProcessLookupError:
        sent = False
    try:
        _, stderr = bake.communicate(timeout=HANG_SECONDS)
    except subprocess.TimeoutExpired:  # e.g. exiting, but waiting forever for a worker nobody told to stop
        tree = subprocess.run(["ps", "-o", "pid,ppid,stat,wchan:20,args", "-g", str(bake.pid)], capture_output=True,
                              text=True).stdout
        os.killpg(bake.pid, signal.SIGABRT)  # the stacks (PYTHONFAULTHANDLER)
        time.sleep(2)
        os.killpg(bake.pid, signal.SIGKILL)
        _, stderr = bake.communicate()
        return bake.returncode, "BROKEN", f"still running {HANG_SECONDS:.0f} s after the Ctrl-C (killed)" + (
            "\n" + tree + stderr if os.environ.get("SWEEP_SHOW") else "")
    code = bake.returncode
    _wait_for_group(bake.pid)  # a worker still running after the bake ended would show in the folder check
    stem = os.path.splitext(os.path.basename(asset))[0]
    show = "\n" + stderr if os.environ.get("SWEEP_SHOW") else ""
    if "Fatal Python error: init_import_site" in stderr:
        # The interpreter's own start-up (its site module, before any of the tool's code runs): CPython ends
        # with exit code 1 and this message; nothing the tool does can change it.
        return code, "interpreter start-up", ""
    frames = [line for line in stderr.splitlines() if line.lstrip().startswith('File "')]
    if frames and all('File "<frozen ' in line for line in frames) and stderr.rstrip().endswith("KeyboardInterrupt"):
        # Python's own module runner (``-m``: runpy finding the package) before the tool's first line: CPython's
        # KeyboardInterrupt traceback, as above.
        return code, "interpreter start-up", ""
    bad = [line for line in stderr.splitlines() if any(word in line for word in BAD_WORDS)]
    if bad:
        return code, "BROKEN", bad[0] + show
    published = code == 0 or (code == 130 and "complete outputs were written" in stderr)
    folder = folder_problem(out, stem, old, finished=published)
    if folder:
        return code, "BROKEN", folder + show
    if code == 130 and "interrupted" in stderr:
        return code, "interrupted" if not published else "interrupted after publishing", ""
    if code == 0:
        if not sent:
            return code, "finished", ""
        # Sent while it ran, yet exit 0: fine only if the set was already published (its report is written
        # last) and the Ctrl-C came while the tool exited (Python's own teardown takes ~0.7 s after the bake's
        # last line, with SIGINT ignored); a set published after the Ctrl-C means the Ctrl-C was lost.
        report = os.path.join(out, stem + ".report.json")
        if os.path.getmtime(report) > sent_at:
            return code, "BROKEN", "the Ctrl-C was lost: the set was published after it, and the exit code is 0"
        return code, "finished (Ctrl-C while exiting)", ""
    last = (stderr.strip().splitlines() or ["(no stderr)"])[-1]
    return code, "BROKEN", last + show


#: Seconds after the Ctrl-C by which an interrupted bake must have ended (a whole bake takes ~15 s).
HANG_SECONDS = 120.0
#: Words that never belong in the stderr of an interrupted bake (CPython's notes of an exception in a
#: worker, an at-fork hook or a finaliser say "Exception ignored"; the CLI's bugs say "internal error").
BAD_WORDS = ("Traceback", "Exception ignored", "internal")


def _wait_for_group(pgid: int, seconds: float = 30.0) -> None:
    """Wait until no process of the bake's process group (its workers) is left, for at most ``seconds``."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return
        except PermissionError:  # a zombie member owned by us still counts; nothing else to do
            return
        time.sleep(0.05)


def set_hashes(folder: str, stem: str) -> dict[str, str] | None:
    """{name: sha256} of every file of ``stem``'s set in ``folder`` (the report included), None if none is there."""
    from fracture_cli.io.inputs import file_sha256
    from fracture_cli.io.outputs import all_names

    found = {n: file_sha256(os.path.join(folder, n)) for n in all_names(stem)
             if os.path.isfile(os.path.join(folder, n))}
    return found or None


def folder_problem(out: str, stem: str, old: str | None, *, finished: bool) -> str:
    """Why ``out`` does not hold one complete set after a trial ("" when it does, or holds none and had none)."""
    from fracture_cli.io.outputs import verify_output_set

    leftovers = sorted(n for n in (os.listdir(out) if os.path.isdir(out) else [])
                       if n.startswith("." + stem + "."))
    if leftovers:
        return f"left behind in the output folder: {', '.join(leftovers)}"
    now = set_hashes(out, stem) if os.path.isdir(out) else None
    if now is None:
        return "no output set after a finished bake" if finished or old is not None else ""
    reason = verify_output_set(out, stem)
    if reason is not None:
        return f"mixed or partial set: {reason}"
    if old is None:
        return ""
    was = set_hashes(old, stem)
    if finished:
        return "" if now != was else "the bake finished but the old set is still there"
    if now == was:
        return ""
    return "interrupted, but the set is not the old one: " + ", ".join(
        sorted(n for n in set(now) | set(was or {}) if now.get(n) != (was or {}).get(n)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--asset", default=os.path.join(REPO, "tests", "data", "bad", "uv_seams.obj"))
    parser.add_argument("--step", type=float, default=0.1, help="seconds between trial moments")
    parser.add_argument("--from", dest="first", type=float, default=None, help="first moment (default: --step)")
    parser.add_argument("--until", type=float, default=5.0, help="last moment, seconds after the start")
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="recipe override")
    parser.add_argument("--old", action="store_true",
                        help="start every trial over a complete set of an earlier bake (baked once, with "
                             "modes.num_modes=8) and check that it is kept or replaced whole")
    parser.add_argument("--signal", dest="signame", choices=("INT", "TERM"), default="INT",
                        help="the signal sent to the process group (TERM: a build tool or timeout stopping it)")
    parser.add_argument("flags", nargs="*", help="global flags put before 'bake' (after --), e.g. -j 2")
    args = parser.parse_args()
    extra = [w for o in args.overrides for w in ("--set", o)]
    first = args.step if args.first is None else args.first
    moments = [round(first + args.step * i, 3) for i in range(int(round((args.until - first) / args.step)) + 1)]
    tally: collections.Counter[str] = collections.Counter()
    codes: collections.Counter[int] = collections.Counter()
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sigint-sweep-") as tmp:
        old = None
        if args.old:
            old = os.path.join(tmp, "old")
            subprocess.run([sys.executable, "-m", "fracture_cli", "-q", *args.flags, "bake", args.asset, "-o", old,
                            *extra, "--set", "modes.num_modes=8"], check=True, cwd=REPO,
                           env=dict(os.environ, PYTHONPATH=REPO + os.pathsep + os.environ.get("PYTHONPATH", "")))
        for delay in moments:
            code, verdict, note = trial(args.asset, os.path.join(tmp, "out"), delay, extra, old, args.flags,
                                        getattr(signal, "SIG" + args.signame))
            tally[verdict] += 1
            codes[code] += 1
            print(f"{delay:5.2f} s  exit {code:4d}  {verdict}{'  ' + note if note else ''}", flush=True)
    print(f"{len(moments)} trials in {time.perf_counter() - start:.0f} s: "
          + ", ".join(f"{n} {v}" for v, n in sorted(tally.items()))
          + "; exit codes " + ", ".join(f"{c}: {n}" for c, n in sorted(codes.items())))
    return 1 if tally["BROKEN"] else 0


if __name__ == "__main__":
    sys.exit(main())
