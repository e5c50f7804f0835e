"""Benchmark: realtime impact projection, Python reference and the engine readers.

Median and p99 time per call over random surface hits, for the sample assets (the
Python reference and the C, C#, JavaScript and GDScript readers under engines/ on the
same files and hits) and for synthetic runtime files of realistic sizes (sites ~ a
cage's boundary vertices, k modes, p fragments, e graph edges; Python only). The
synthetic threshold is calibrated per file so a typical hit breaks a few edges (3% of
the jumps exceed it), like a game's ordinary hits. Targets: Python median under 100
microseconds (aim 50; paper: 1-2 ms); C reader median under 2 microseconds on every
sample asset, also per hit on a damage state (docs/FORMAT.md section 12).

    python bench/bench_runtime.py [--quick] [--no-bake]

--no-bake times the sample assets' runtime files committed under
tests/data/runtime_conformance/ instead of baking them (minutes) first.
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
CS_DIR = os.path.join(REPO, "engines", "csharp")
JS_CHECK = os.path.join(REPO, "engines", "web", "fracture_check.mjs")
CONFORMANCE = os.path.join(REPO, "tests", "data", "runtime_conformance")
ROUNDS = 5  # each hit timed this many times by the C, C# and JavaScript drivers

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


def run(quick: bool = False, bake: bool = True) -> str:
    hits = 1000 if quick else 10000
    rows = [("| sites | k | p | edges | d | file (KiB) | load (ms) | median (us) | p90 (us) | broken (median) "
             "| groups (median) |"),
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
            "(default threshold, impulses of magnitude 4 in random directions), median / p99 in microseconds: the "
            "Python reference (`project_impact`), the C reader (engines/c; default: with its d = 1 jump table; "
            "compact: `FR_LOAD_COMPACT`), the C# reader (engines/csharp, Mono), the JavaScript reader (engines/web, "
            "Node.js, with `jumpTable: true`) and the GDScript reader (engines/godot, Godot 3 headless); the engine "
            "readers compute the groups and broken edges only (no displacements, as a game that only spawns bodies), "
            "the Python reference everything; \"C with state\": `fr_hit` on a damage state (docs/FORMAT.md section "
            "12), also answering the cracked bonds and anchored fragments, each hit on a fresh state (a version-1 "
            "file's state only remembers broken bonds). Then the Python reference on synthetic files of larger sizes. "
            "Targets: Python < 100 us (aim 50 us), C < 2 us median (also with state); paper 1-2 ms.\n\n"
            + _sample_assets(hits, rng, bake) + "\n" + _stress_rows(hits, rng) + "\n" + _damage_rows(hits, rng)
            + "\n" + "\n".join(rows) + "\n")


STRESS_FILES = (("chair.glb", "chair_stress"),)  # (sample asset, conformance runtime file with criterion "stress")
DAMAGE_FILES = (("pillar.glb", "pillar_structure"),)  # (sample asset, conformance file with "anchors" and "damage")


def _damage_rows(hits: int, rng) -> str:
    """The C reader per hit on a damage state (docs/FORMAT.md section 12) of the committed structure files."""
    from fracture_cli.stages.load import load_surface

    rows = ["| asset | runtime file | features | crack level, rate | sites | fragments | bonds | impulse | "
            "groups (median) | C median / p99 (us) | C with state median / p99 (us) | C with state mean CPU (us) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        c_bench = _build_c_bench(tmp, [])
        if c_bench is None:
            return "C reader, damage state: not measured (no C compiler).\n"
        for asset, name in DAMAGE_FILES:
            points, impulses = _surface_hits(load_surface(os.path.join(REPO, "sample_assets", asset)), hits, rng)
            json_path = os.path.join(CONFORMANCE, f"{name}.fracture.json")
            data = load_runtime(json_path)
            for magnitude in (4, 40):
                hits_file = os.path.join(tmp, f"{name}.{magnitude}.hits.txt")
                with open(hits_file, "w") as fh:
                    fh.writelines(" ".join(_bits(c) for c in (*p, *(n * magnitude / 4))) + " -\n"
                                  for p, n in zip(points, impulses))
                c = _run_c_bench(c_bench, json_path, hits_file)
                state = _run_c_bench(c_bench, json_path, hits_file, "--state")
                rows.append(f"| {asset} | {name} | {', '.join(data.features)} | {data.damage['crack_level']:g}, "
                            f"{data.damage['damage_rate']:g} | {data.num_sites} | {data.p} | {data.num_edges} | "
                            f"{magnitude} | {state['groups_median']} | {_cell(c)} | {_cell(state)} | "
                            f"{float(state['cpu_mean_ns']) / 1e3:.2f} |")
    return ("C reader per hit on a damage state (docs/FORMAT.md section 12, `fr_hit`: cracks, health, anchored "
            f"groups) beside the stateless call on the same committed file: {hits} random surface hits of magnitude "
            f"4 and 40 in random directions, the file's default threshold, groups, cracked bonds and anchored "
            f"fragments, each hit on a fresh state, {ROUNDS} rounds (the stateless call on a \"damage\" file is a hit "
            "on a fresh state too).\n\n" + "\n".join(rows) + "\n")


def _stress_rows(hits: int, rng) -> str:
    """The C reader per hit with the stress criterion (docs/FORMAT.md section 11) on the committed files."""
    from fracture_cli.stages.load import load_surface

    rows = ["| asset | runtime file | criterion | sites | fragments | bonds | site_bonds (max per site) | impulse | "
            "groups (median) | C median / p99 (us) | C mean CPU (us) | C memory (MiB) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    notes: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        c_bench = _build_c_bench(tmp, notes)
        if c_bench is None:
            return "C reader, stress criterion: not measured (no C compiler).\n"
        for asset, stem in STRESS_FILES:
            points, impulses = _surface_hits(load_surface(os.path.join(REPO, "sample_assets", asset)), hits, rng)
            for magnitude, name in ((4, stem.replace("_stress", "")), (4, stem), (40, stem)):
                hits_file = os.path.join(tmp, f"{stem}.{magnitude}.hits.txt")
                with open(hits_file, "w") as fh:
                    fh.writelines(" ".join(_bits(c) for c in (*p, *(n * magnitude / 4))) + " -\n"
                                  for p, n in zip(points, impulses))
                data = load_runtime(os.path.join(CONFORMANCE, f"{name}.fracture.json"))
                ptr = data.stress["site_bonds_ptr"] if data.criterion == "stress" else None
                lists = f"{len(data.stress['site_bonds'])} ({int(np.diff(ptr).max())})" if ptr is not None else "-"
                c = _run_c_bench(c_bench, os.path.join(CONFORMANCE, f"{name}.fracture.json"), hits_file)
                rows.append(f"| {asset} | {name} | {data.criterion} | {data.num_sites} | {data.p} | {data.num_edges} | "
                            f"{lists} | {magnitude} | {c['groups_median']} | {_cell(c)} | "
                            f"{float(c['cpu_mean_ns']) / 1e3:.2f} | {float(c['memory_kib']) / 1024:.2f} |")
    return ("C reader per hit with the stress criterion (docs/FORMAT.md section 11; target <= 5 us median) beside "
            f"the modes on the same asset: the committed conformance runtime files, {hits} random surface hits of "
            "magnitude 4 (and 40, where the stress criterion breaks more bonds) in random directions, the file's "
            f"default threshold, groups only, {ROUNDS} rounds (the modes file uses the d = 1 jump table; the stress "
            "file has none).\n\n"
            + "\n".join(rows) + "\n")


def _sample_assets(hits: int, rng, bake: bool = True) -> str:
    """Rows for the sample assets: bake each (or take the committed file), then time the same hits in every reader."""
    import tomllib

    from fracture_cli.pipeline.bake import bake as bake_asset
    from fracture_cli.pipeline.recipe import load_recipe
    from fracture_cli.stages.load import load_surface

    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        assets = sorted(tomllib.load(fh)["assets"].items())
    rows = [("| asset | recipe | sites | k | fragments | bonds | groups (median) | Python | C | C compact | "
             "C with state | C# | JavaScript | GDScript | C jump table (MiB, load ms) |"),
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    notes: list[str] = []
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        c_bench = _build_c_bench(tmp, notes)
        cs_bench = _build_csharp_bench(tmp, notes)
        for asset, recipe in assets:
            path = os.path.join(REPO, "sample_assets", asset)
            stem = os.path.splitext(asset)[0]
            out = os.path.join(tmp, stem)
            if bake:
                bake_asset(path, out, load_recipe(recipe))
                json_path = os.path.join(out, f"{stem}.fracture.json")
            else:
                os.makedirs(out)
                json_path = os.path.join(CONFORMANCE, f"{stem}.fracture.json")
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
            c_table = _run_c_bench(c_bench, json_path, hits_file) if c_bench else {}
            c_compact = _run_c_bench(c_bench, json_path, hits_file, "--compact") if c_bench else {}
            c_state = _run_c_bench(c_bench, json_path, hits_file, "--state") if c_bench else {}
            table = (f"{float(c_table['memory_kib']) / 1024:.1f}, {float(c_table['load_ms']):.0f}"
                     if c_table else "n/a")
            rows.append(f"| {asset} | {recipe} | {data.num_sites} | {data.k} | {data.p} | {data.num_edges} | "
                        f"{np.median(groups):.0f} | {_us(np.median(times) * 1e9, np.percentile(times, 99) * 1e9)} | "
                        f"{_cell(c_table)} | {_cell(c_compact)} | {_cell(c_state)} | "
                        f"{_cell(_run_csharp_bench(cs_bench, json_path, hits_file) if cs_bench else {})} | "
                        f"{_cell(_run_js_bench(json_path, hits_file, notes))} | "
                        f"{_run_gdscript_bench(os.path.join(tmp, 'godot'), json_path, hits_file, notes)} | {table} |")
    load_after = os.getloadavg()
    notes.append(f"Load average (1 min) {load_before[0]:.1f} before and {load_after[0]:.1f} after these rows, on "
                 f"{os.cpu_count()} cores: wall-clock medians of sub-microsecond calls are noisy under load (the C "
                 "driver also prints the mean thread CPU time per call).")
    if not bake:
        notes.append("Runtime files: the committed tests/data/runtime_conformance/ copies (--no-bake).")
    text = "\n".join(rows) + "\n"
    return text + ("\n" + "\n".join(f"- {note}" for note in sorted(set(notes))) + "\n" if notes else "")


def _us(median_ns: float, p99_ns: float) -> str:
    digits = 2 if median_ns < 1e4 else 0
    return f"{median_ns / 1e3:.{digits}f} / {p99_ns / 1e3:.{digits}f}"


def _cell(values: dict[str, str]) -> str:
    """"median / p99" (us) from a driver's key-value output, or n/a."""
    if not values:
        return "n/a"
    return _us(float(values["median_ns"]), float(values["p99_ns"]))


def _key_values(text: str) -> dict[str, str]:
    fields = text.split()
    return dict(zip(fields[::2], fields[1::2]))


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
    notes.append(f"C reader: `cc -std=c99 -O2`, every hit timed on its own with CLOCK_MONOTONIC, {ROUNDS} rounds "
                 "over all hits, the clock's own cost subtracted; \"C jump table\": the memory fr_load takes "
                 "(fr_memory_size) and its CPU time, with the table (compact: no table).")
    return exe


def _run_c_bench(exe: str, json_path: str, hits_file: str, *flags: str) -> dict[str, str]:
    with open(hits_file) as fh:
        out = subprocess.run([exe, json_path, json_path[: -len(".json")] + ".bin", str(ROUNDS), *flags], stdin=fh,
                             capture_output=True, text=True, check=True).stdout
    return _key_values(out)


def _build_csharp_bench(tmp: str, notes: list[str]) -> list[str] | None:
    """Compile engines/csharp with its check/bench driver (Mono's mcs, optimized), or None."""
    mcs, mono = shutil.which("mcs"), shutil.which("mono")
    if mcs is None or mono is None:
        notes.append("C# reader: Mono (Debian packages mono-mcs, mono-runtime) not installed, not measured.")
        return None
    exe = os.path.join(tmp, "FractureCheck.exe")
    subprocess.run([mcs, "-langversion:7.2", "-optimize+", "-out:" + exe, os.path.join(CS_DIR, "FractureRuntime.cs"),
                    os.path.join(CS_DIR, "tools", "FractureCheck.cs")], check=True, capture_output=True)
    notes.append(f"C# reader: `mcs -optimize+`, Mono's JIT, `Stopwatch` around each call (0.1 us ticks), {ROUNDS} "
                 "rounds after one untimed warm-up round.")
    return [mono, exe]


def _run_csharp_bench(command: list[str], json_path: str, hits_file: str) -> dict[str, str]:
    with open(hits_file) as fh:
        out = subprocess.run([*command, "--bench", str(ROUNDS), json_path, json_path[: -len(".json")] + ".bin"],
                             stdin=fh, capture_output=True, text=True, check=True).stdout
    return _key_values(out)


def _run_js_bench(json_path: str, hits_file: str, notes: list[str]) -> dict[str, str]:
    node = shutil.which("node")
    if node is None:
        notes.append("JavaScript reader: Node.js not installed, not measured.")
        return {}
    notes.append(f"JavaScript reader: Node.js {_node_version(node)}, `process.hrtime` around each call, {ROUNDS} "
                 "rounds after one untimed warm-up round.")
    with open(hits_file) as fh:
        out = subprocess.run([node, JS_CHECK, f"--bench={ROUNDS}", "--jump-table", json_path,
                              json_path[: -len(".json")] + ".bin"], stdin=fh, capture_output=True, text=True,
                             check=True).stdout
    return _key_values(out)


def _node_version(node: str) -> str:
    return subprocess.run([node, "--version"], capture_output=True, text=True, check=False).stdout.strip()


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
    notes.append("GDScript reader: Godot 3 headless, `OS.get_ticks_usec()` around each "
                 "`project(..., with_displacement = false)` call.")
    return f"{fields[1]} / {fields[3]}"


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv, bake="--no-bake" not in sys.argv))
