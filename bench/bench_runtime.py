"""Benchmark: realtime impact projection (fracture_cli.runtime.impact.project_impact).

Median time per call over random surface hits, for synthetic runtime files of
realistic sizes (sites ~ a cage's boundary vertices, k modes, p fragments, e
graph edges). The threshold is calibrated per file so a typical hit breaks a few
edges (3% of the jumps exceed it), like a game's ordinary hits. Target: median
under 100 microseconds in Python with numpy, aiming for 50 (paper: 1-2 ms).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from fracture_cli.runtime.format import RuntimeData, load_runtime, write_runtime  # noqa: E402
from fracture_cli.runtime.impact import prepare, project_impact  # noqa: E402

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
            f"Median time per `project_impact` call over {hits} random surface hits on each sample asset baked with "
            "its manifest recipe (default threshold, impulses of magnitude 4 in random directions), then on "
            "synthetic files of larger sizes. Target < 100 us (aim 50 us); paper 1-2 ms.\n\n"
            + _sample_assets(hits, rng) + "\n" + "\n".join(rows) + "\n")


def _sample_assets(hits: int, rng) -> str:
    """Rows for the sample assets: bake each, then time random hits on its input surface."""
    import tomllib

    from fracture_cli.bake import bake
    from fracture_cli.io.read import load_surface
    from fracture_cli.recipe import load_recipe

    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(repo, "sample_assets", "manifest.toml"), "rb") as fh:
        assets = sorted(tomllib.load(fh)["assets"].items())
    rows = ["| asset | recipe | sites | k | fragments | bonds | file (KiB) | median (us) | p90 (us) | groups (median) |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for asset, recipe in assets:
        path = os.path.join(repo, "sample_assets", asset)
        stem = os.path.splitext(asset)[0]
        with tempfile.TemporaryDirectory() as tmp:
            bake(path, tmp, load_recipe(recipe))
            json_path = os.path.join(tmp, f"{stem}.fracture.json")
            size = (os.path.getsize(json_path) + os.path.getsize(json_path[:-5] + ".bin")) / 1024
            data = load_runtime(json_path)
        surface = load_surface(path)
        world = surface.world_vertices()
        tri = world[surface.faces]
        area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        pick = rng.choice(len(tri), size=hits, p=area / area.sum())
        bary = rng.dirichlet(np.ones(3), size=hits)
        points = np.einsum("ij,ijk->ik", bary, tri[pick])
        directions = rng.normal(size=(hits, 3))
        impulses = 4.0 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
        prepare(data)
        times, groups = np.empty(hits), np.empty(hits)
        for i in range(hits):
            t = time.perf_counter()
            result = project_impact(data, points[i], impulses[i])
            times[i] = time.perf_counter() - t
            groups[i] = result.num_groups
        rows.append(f"| {asset} | {recipe} | {data.num_sites} | {data.k} | {data.p} | {data.num_edges} | {size:.0f} | "
                    f"{np.median(times) * 1e6:.0f} | {np.percentile(times, 90) * 1e6:.0f} | {np.median(groups):.0f} |")
    return "\n".join(rows) + "\n"


if __name__ == "__main__":
    print(run())
