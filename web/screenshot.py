"""Take the README's screenshot of `fracture view` (headless Chromium, like the browser test).

    .venv/bin/python web/screenshot.py build/demo chair docs/view_chair.png

Serves the bake folder with `fracture view --no-browser --port 0`, hits the asset on
the top of its back with a magnitude that breaks it into a few groups, and saves the
page mid-flight. Needs `make web` and Debian's chromium.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main(folder: str, stem: str, out_png: str) -> None:
    sys.path.insert(0, REPO)
    from fracture_cli.io.gltf import glb_meshes, read_glb_chunks
    from fracture_cli.runtime.format import load_runtime
    from fracture_cli.runtime.impact import project_impact

    doc, binary = read_glb_chunks(os.path.join(folder, f"{stem}.glb"))
    points = np.concatenate([prim.positions for mesh in glb_meshes(doc, binary) for prim in mesh.primitives])
    point = points[np.argmax(points[:, 1] + 0.3 * points[:, 0] + 0.3 * points[:, 2])].tolist()
    data = load_runtime(os.path.join(folder, f"{stem}.fracture.json"))
    magnitude = next((float(m) for m in np.geomspace(0.5, 500, 19)
                      if len(set(project_impact(data, point, (0, 0, -m)).groups.tolist())) >= 4), 10.0)
    server = subprocess.Popen([sys.executable, "-m", "fracture_cli", "view", folder, "--no-browser", "--port", "0"],
                              stdout=subprocess.PIPE, text=True, cwd=REPO)
    try:
        url = server.stdout.readline().split()[2]
        actions = [{"do": "wait_ready"}, {"do": "set", "id": "magnitude", "value": round(magnitude, 3)},
                   {"do": "click_model", "point": point}, {"do": "mouse", "x": 5, "y": 700},
                   {"do": "wait", "ms": 420},
                   {"do": "screenshot", "path": os.path.abspath(out_png)}]
        with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as fh:
            json.dump({"url": f"{url}#{stem}", "modules": os.path.join(REPO, "build", "web", "node_modules"),
                       "width": 1280, "height": 760, "actions": actions}, fh)
        result = subprocess.run(["node", os.path.join(REPO, "web", "e2e.cjs"), fh.name], capture_output=True,
                                text=True, check=True)
        os.unlink(fh.name)
        hit = json.loads(result.stdout)["results"][2]["hit"]
        print(f"{out_png}: magnitude {magnitude:.3g}, {hit['numGroups']} groups")
    finally:
        server.terminate()
        server.wait()


if __name__ == "__main__":
    main(*sys.argv[1:4])
