"""Benchmark: realtime impact projection, Python reference and the engine readers.

Median time per call over random surface hits, for the sample assets (Python
reference, the C reader in engines/c/ and the GDScript reader in engines/godot/
on the same files and hits) and for synthetic runtime files of realistic sizes
(sites ~ a cage's boundary vertices, k modes, p fragments, e graph edges; Python
only). The synthetic threshold is calibrated per file so a typical hit breaks a
few edges (3% of the jumps exceed it), like a game's ordinary hits. Targets:
Python median under 100 microseconds (aim 50; paper: 1-2 ms); C reader median
under 2 microseconds on every sample asset.
"""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from fracture_cli.runtime.format import RuntimeData, load_runtime, write_runtime  # noqa: E402
from fracture_cli.runtime.impact import prepare, project_impact  # noqa: E402

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
C_DIR = os.path.join(REPO, "engines", "c")
C_ROUNDS = 5  # each hit timed this many times by the C driver

SIZES = [  # (sites, k, p, edges, d)
    (1500, 16, 60, 200, 1),
    (1500, 32, 200, 600, 1),
    (1500, 16, 60, 200, 3),
]


def synthetic(s, k, p, e, d, seed=0) -> RuntimeData:
    """Random runtime data: sites on a sphere, a connected random fragment graph."""
    rng = np.random.default_rng(seed)
    sites = rng.normal(size=(s, 3))
    sites /= np.linalg.norm(sites, axis=1, keepdims=True)
    pairs = {(j, j + 1) for j in range(p - 1)}  # a path keeps it connected
    while len(pairs) < e:
        a, b = sorted(rng.integers(0, p, 2).tolist())
        if a != b:
            pairs.add((a, b))
    return RuntimeData(sites=sites.astype(np.float32), B=rng.normal(size=(s, k, d)).astype(np.float32),
                       W=rng.normal(size=(k, p, d)).astype(np.float32), edges=np.array(sorted(pairs), np.int32),
                       edge_areas=np.ones(e, np.float32), fragment_names=tuple(f"fragment_{j:03d}" for j in range(p)))


def run(quick: bool = False) -> str:
    hits = 1000 if quick else 10000
    rows = ["| sites | k | p | edges | d | file (KiB) | load (ms) | median (us) | p90 (us) | broken (median) | groups (median) |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    rng = np.random.default_rng(1)
    for s, k, p, e, d in SIZES:
        with tempfile.TemporaryDirectory() as tmp:
            json_path, bin_path = write_runtime(synthetic(s, k, p, e, d), os.path.join(tmp, "bench.fracture.json"))
            size = (os.path.getsize(json_path) + os.path.getsize(bin_path)) / 1024
            t0 = time.perf_counter()
            data = load_runtime(json_path)
            prepare(data)
            load_ms = (time.perf_counter() - t0) * 1e3
        points = data.sites[rng.integers(0, s, hits)] + rng.normal(scale=0.01, size=(hits, 3))
        impulses = rng.normal(size=(hits, 3))
        prep = prepare(data)
        sample = [np.abs(project_impact(data, points[i], impulses[i], 1e30).alpha @ prep.WdW[:, prep.split:])
                  for i in range(200)]
        threshold = float(np.percentile(np.concatenate(sample), 97))
        times, broken, groups = np.empty(hits), np.empty(hits), np.empty(hits)
        for i in range(hits):
            t = time.perf_counter()
            result = project_impact(data, points[i], impulses[i], threshold)
            times[i] = time.perf_counter() - t
            broken[i] = result.broken.sum()
            groups[i] = result.num_groups
        rows.append(f"| {s} | {k} | {p} | {e} | {d} | {size:.0f} | {load_ms:.1f} | {np.median(times) * 1e6:.0f} | "
                    f"{np.percentile(times, 90) * 1e6:.0f} | {np.median(broken):.0f} | {np.median(groups):.0f} |")
    return ("## Impact projection (runtime)\n\n"
            f"Time per projection over {hits} random surface hits on each sample asset baked with its manifest recipe "
            "(default threshold, impulses of magnitude 4 in random directions), in the Python reference "
            "(`project_impact`), the C reader (engines/c) and the GDScript reader (engines/godot), then the Python "
            "reference on synthetic files of larger sizes. Targets: Python < 100 us (aim 50 us), C < 2 us median; "
            "paper 1-2 ms.\n\n"
            + _sample_assets(hits, rng) + "\n" + "\n".join(rows) + "\n")


def _sample_assets(hits: int, rng) -> str:
    """Rows for the sample assets: bake each, then time the same random surface hits in every reader."""
    import tomllib

    from fracture_cli.bake import bake
    from fracture_cli.io.read import load_surface
    from fracture_cli.recipe import load_recipe

    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        assets = sorted(tomllib.load(fh)["assets"].items())
    rows = [("| asset | recipe | sites | k | fragments | bonds | groups (median) | Python median / p99 (us) | "
             "C median / p99 (us) | GDScript median / p99 (us) |"),
            "|---|---|---|---|---|---|---|---|---|---|"]
    notes: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        c_bench = _build_c_bench(tmp, notes)
        for asset, recipe in assets:
            path = os.path.join(REPO, "sample_assets", asset)
            stem = os.path.splitext(asset)[0]
            out = os.path.join(tmp, stem)
            bake(path, out, load_recipe(recipe))
            json_path = os.path.join(out, f"{stem}.fracture.json")
            data = load_runtime(json_path)
            points, impulses = _surface_hits(load_surface(path), hits, rng)
            prepare(data)
            times, groups = np.empty(hits), np.empty(hits)
            for i in range(hits):
                t = time.perf_counter()
                result = project_impact(data, points[i], impulses[i])
                times[i] = time.perf_counter() - t
                groups[i] = result.num_groups
            hits_file = os.path.join(out, "hits.txt")
            with open(hits_file, "w") as fh:
                fh.writelines(" ".join(_bits(c) for c in (*p, *n)) + " -\n" for p, n in zip(points, impulses))
            c_cell = _run_c_bench(c_bench, json_path, hits_file, notes) if c_bench else "n/a"
            gd_cell = _run_gdscript_bench(os.path.join(tmp, "godot"), json_path, hits_file, notes)
            rows.append(f"| {asset} | {recipe} | {data.num_sites} | {data.k} | {data.p} | {data.num_edges} | "
                        f"{np.median(groups):.0f} | {np.median(times) * 1e6:.0f} / {np.percentile(times, 99) * 1e6:.0f} | "
                        f"{c_cell} | {gd_cell} |")
    text = "\n".join(rows) + "\n"
    return text + ("\n" + "\n".join(sorted(set(notes))) + "\n" if notes else "")


def _surface_hits(surface, hits: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted random points on the input surface and impulses of magnitude 4 in random directions."""
    world = surface.world_vertices()
    tri = world[surface.faces]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    pick = rng.choice(len(tri), size=hits, p=area / area.sum())
    bary = rng.dirichlet(np.ones(3), size=hits)
    points = np.einsum("ij,ijk->ik", bary, tri[pick])
    directions = rng.normal(size=(hits, 3))
    return points, 4.0 * directions / np.linalg.norm(directions, axis=1, keepdims=True)


def _bits(value: float) -> str:
    return struct.pack(">d", float(value)).hex()


def _build_c_bench(tmp: str, notes: list[str]) -> str | None:
    """Compile engines/c with its bench driver (cc -O2, the usual release flags), or None."""
    compiler = shutil.which("cc")
    if compiler is None:
        notes.append("C reader: no C compiler (cc) found, not measured.")
        return None
    exe = os.path.join(tmp, "fracture_bench")
    subprocess.run([compiler, "-std=c99", "-O2", os.path.join(C_DIR, "fracture_runtime.c"),
                    os.path.join(C_DIR, "tools", "fracture_bench.c"), "-o", exe, "-lm"], check=True)
    notes.append(f"C reader: `cc -std=c99 -O2`, every hit timed on its own with CLOCK_MONOTONIC, {C_ROUNDS} rounds "
                 "over all hits, the clock's own cost subtracted.")
    return exe


def _run_c_bench(exe: str, json_path: str, hits_file: str, notes: list[str]) -> str:
    with open(hits_file) as fh:
        out = subprocess.run([exe, json_path, json_path[: -len(".json")] + ".bin", str(C_ROUNDS)], stdin=fh,
                             capture_output=True, text=True, check=True).stdout.split()
    values = dict(zip(out[::2], out[1::2]))
    return f"{float(values['median_ns']) / 1e3:.2f} / {float(values['p99_ns']) / 1e3:.2f}"


def _run_gdscript_bench(project_dir: str, json_path: str, hits_file: str, notes: list[str]) -> str:
    """GDScript reader timed inside headless Godot 3 (OS.get_ticks_usec around each call)."""
    if not any(shutil.which(name) for name in ("godot3-server", "godot3", "godot")) and not os.environ.get("GODOT"):
        notes.append("GDScript reader: Godot 3 not installed (Debian package godot3-server), not measured.")
        return "n/a"
    sys.path.insert(0, os.path.join(REPO, "tests"))
    from godot_harness import GodotProject

    project = GodotProject(project_dir)
    with open(os.path.join(REPO, "engines", "godot", "tests", "bench_project.gd"), encoding="utf-8") as fh:
        run = project.run_script(fh.read(), json_path, hits_file, name="bench_project.gd")
    fields = run.lines("median_us")[0].split()
    notes.append("GDScript reader: Godot 3 headless, `OS.get_ticks_usec()` around each `project()` call.")
    return f"{fields[1]} / {fields[3]}"


if __name__ == "__main__":
    print(run())
