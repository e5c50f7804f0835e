"""The C reader per hit on a piece of a file with levels (docs/FORMAT.md 14.5; issue 34: median < 1 us at level 2).

Each hit strikes a level-2 fragment (a child) of a split level-1 fragment: the state is made
by the Python reader (fracture_cli.runtime.levelstate) hitting the parent hard at one of its
body's sites until it splits, then the bench hits one of the shown children (the one nearest
to a point near a random site of that body, as a game's collider would say) with an impulse
from a tenth to twenty times that level's threshold in a random direction. The state is
copied outside the timed call, so every hit starts from the same split. Beside it, the
same driver on level 1: hits on the intact asset (struck: the fragment nearest the point).
"""

from __future__ import annotations

import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_runtime import CONFORMANCE, ROUNDS, _bits, _build_c_bench, _cell, _run_c_bench  # noqa: E402

from fracture_cli.runtime.format import load_runtime  # noqa: E402
from fracture_cli.runtime.levels import body_threshold, body_view, children_range, num_bodies  # noqa: E402
from fracture_cli.runtime.levelstate import (  # noqa: E402
    hit_piece,
    nearest_fragment,
    new_object_state,
    shown_fragments,
)

FILES = ("pillar_levels", "levels_random")  # the committed conformance files with levels (baked, and synthetic)


def _split_state(data, body: int, rng) -> np.ndarray | None:
    """An object state where body ``body``'s fragment has split (hit hard at its body's sites), or None."""
    view = body_view(data, body)
    parent = int(data.levels["body_fragment"][body])
    for _ in range(50):
        state = new_object_state(data)
        site = view.sites[rng.integers(0, view.num_sites)]
        impulse = rng.normal(size=3)
        impulse *= 40.0 * body_threshold(data, body) / np.linalg.norm(impulse)
        if shown_fragments(data, state)[parent] and hit_piece(data, state, parent, site, impulse).split:
            return state
    return None


def _level2_lines(data, hits: int, rng) -> list[str]:
    lines: list[str] = []
    bodies = list(range(1, num_bodies(data)))
    found = {b: _split_state(data, b, rng) for b in bodies}
    states = {b: state for b, state in found.items() if state is not None}
    bodies = sorted(states)
    while bodies and len(lines) < hits:
        body = bodies[int(rng.integers(0, len(bodies)))]
        view, state = body_view(data, body), states[body]
        shown = shown_fragments(data, state)
        children = [g for g in children_range(data, body) if shown[g]]
        point = view.sites[rng.integers(0, view.num_sites)] + rng.normal(scale=0.01, size=3)
        struck = nearest_fragment(data, children, point)
        impulse = rng.normal(size=3)
        impulse *= body_threshold(data, body) * np.exp(rng.uniform(np.log(0.1), np.log(20.0))) / np.linalg.norm(impulse)
        lines.append(" ".join([str(struck), *(_bits(c) for c in (*point, *impulse)), "-",
                               *(_bits(h) for h in state.tolist())]))
    return lines


def _level1_lines(data, hits: int, rng) -> list[str]:
    state = new_object_state(data)
    lines = []
    for _ in range(hits):
        point = data.sites[rng.integers(0, data.num_sites)] + rng.normal(scale=0.01, size=3)
        struck = nearest_fragment(data, range(data.p), point) if data.gameready else int(rng.integers(0, data.p))
        impulse = rng.normal(size=3)
        impulse *= data.default_threshold * np.exp(rng.uniform(np.log(0.1), np.log(20.0))) / np.linalg.norm(impulse)
        lines.append(" ".join([str(struck), *(_bits(c) for c in (*point, *impulse)), "-",
                               *(_bits(h) for h in state.tolist())]))
    return lines


def run(quick: bool = False) -> str:
    hits = 1000 if quick else 5000
    rng = np.random.default_rng(0)
    rows: list[str] = []
    notes: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        exe = _build_c_bench(tmp, notes)
        if exe is None:
            return "C reader, levels: not measured (no C compiler).\n"
        for name in FILES:
            json_path = os.path.join(CONFORMANCE, f"{name}.fracture.json")
            data = load_runtime(json_path)
            for level, lines in ((1, _level1_lines(data, hits, rng)), (2, _level2_lines(data, hits, rng))):
                hits_file = os.path.join(tmp, f"{name}.{level}.txt")
                with open(hits_file, "w") as fh:
                    fh.write("\n".join(lines) + "\n")
                c = _run_c_bench(exe, json_path, hits_file, "--pieces")
                rows.append(f"| {name} | {data.p} | {len(data.levels['parent'])} | {num_bodies(data)} | {level} | "
                            f"{len(lines)} | {c['groups_median']} | {_cell(c)} | {float(c['cpu_mean_ns']) / 1e3:.2f} |")
    return ("## Levels: the C reader per hit on a piece\n\n"
            "C reader per hit on a piece (`fr_hit_piece`, docs/FORMAT.md section 14.5: the piece's body on a copy "
            "of its healths, the struck fragment's own body, the pieces that replace the struck one; target at "
            f"level 2: median under 1 us), {ROUNDS} rounds, the state copied outside the timed call. Level 2: a "
            "child of a split level-1 fragment; level 1: the intact asset.\n\n"
            "| file | p | p_all | bodies | level | hits | pieces (median) | median / p99 (us) | CPU mean (us) |\n"
            "|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n")


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
