"""Preview rendering time: a baked sample asset and a 50k-triangle asset."""

from __future__ import annotations

import os
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)


def _bumpy_sphere(subdivisions: int):
    import numpy as np
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = mesh.vertices
    mesh.vertices = v * (1.0 + 0.08 * np.sin(7 * v[:, [0]]) * np.cos(5 * v[:, [1]]))
    return mesh


def run(quick: bool = False) -> str:
    from fracture_cli.pipeline.bake import bake
    from fracture_cli.pipeline.recipe import load_recipe
    from fracture_cli.view.preview import render_preview

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        big = os.path.join(tmp, "bumpy.glb")
        mesh = _bumpy_sphere(5 if quick else 6)  # 20k or 82k triangles
        mesh.export(big)
        inputs = [(os.path.join(REPO, "sample_assets", "chair.glb"), "chair"), (big, "bumpy")]
        out = os.path.join(tmp, "out")  # never the inputs' folder: the bake refuses to replace an input
        for path, stem in inputs:
            bake(path, out, load_recipe("default"))
            t0 = time.perf_counter()
            info = render_preview(os.path.join(out, f"{stem}.fracture.json"), os.path.join(out, f"{stem}.png"))
            tris = len(mesh.faces) if stem == "bumpy" else None
            rows.append((stem, tris, info["fragments"], time.perf_counter() - t0))
    lines = ["## Preview rendering", "", "`fracture preview` (matplotlib Agg, 1600x1000, 9 panels). Target: a few "
             "seconds for a 50k-triangle asset.", "", "| asset | input tris | fragments | seconds |",
             "|---|---|---|---|"]
    for stem, tris, frags, secs in rows:
        lines.append(f"| {stem} | {tris if tris else '-'} | {frags} | {secs:.2f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run())
