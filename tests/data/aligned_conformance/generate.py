"""Generate the aligned-fracture conformance vectors in this folder (see README.md here).

    .venv/bin/python tests/data/aligned_conformance/generate.py            # regenerate the vectors
    .venv/bin/python tests/data/aligned_conformance/generate.py --rebake   # also re-bake the chair (seconds)
    .venv/bin/python tests/data/aligned_conformance/generate.py --out DIR  # write elsewhere (the test does)

Two synthetic files are made in code (two boxes, one of them in two convex parts; with the default
bounded patterns and with unbounded ones), one is the chair from a fast bake (``--rebake``; otherwise
read from this folder). Expected answers come from the Python reference
(fracture_cli/runtime/aligned.py): every reader must give the same fragments within 1e-9.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(os.path.dirname(HERE)))
sys.path.insert(0, os.path.join(REPO, "tests"))
sys.path.insert(0, REPO)

# fracture_cli first: it pins the numeric kernels before numpy loads (fracture_cli/system/numeric_env.py).
import fracture_cli  # noqa: E402, F401, I001

import numpy as np  # noqa: E402

from aligned_support import summarize  # noqa: E402
from fracture_cli.errors import UsageError  # noqa: E402
from fracture_cli.runtime.aligned import aligned_fracture  # noqa: E402
from fracture_cli.runtime.aligned_data import AlignedData, load_aligned, write_aligned  # noqa: E402
from fracture_cli.stages.aligned import aligned  # noqa: E402
from fracture_cli.stages.aligned.options import AlignedOptions  # noqa: E402
from fracture_cli.types import Fragment, Fragments, Material, Normalization  # noqa: E402

VECTORS_FORMAT = "fracture-aligned-conformance"
VECTORS_VERSION = 1
FAST_BAKE = ["--set", "cage.target_faces=600", "--set", "modes.num_modes=4", "--set", "aligned.enabled=true",
             "--set", "aligned.patterns=1"]


def _box(lo, hi) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A box as 12 outward triangles with split vertices: positions (24, 3), faces (12, 3), normals, uvs."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    vertices, faces, normals, uvs = [], [], [], []
    for axis in range(3):
        for side in (0, 1):
            u, v = [a for a in range(3) if a != axis]
            corners = []
            for a, b in ((0, 0), (1, 0), (1, 1), (0, 1)):
                x = np.array(lo)
                x[axis] = (lo, hi)[side][axis]
                x[u] = (lo, hi)[a][u]
                x[v] = (lo, hi)[b][v]
                corners.append(x)
            n = np.zeros(3)
            n[axis] = 1.0 if side else -1.0
            base = len(vertices)
            vertices += corners
            normals += [n] * 4
            uvs += [(c[u], c[v]) for c in corners]
            quad = [(0, 1, 2), (0, 2, 3)]
            for t in quad:
                tri = [base + i for i in t]
                if np.dot(np.cross(corners[t[1]] - corners[t[0]], corners[t[2]] - corners[t[0]]), n) < 0:
                    tri = [tri[0], tri[2], tri[1]]
                faces.append(tri)
    return np.array(vertices), np.array(faces), np.array(normals), np.array(uvs, float)


def boxes(options: AlignedOptions) -> AlignedData:
    """Two unit boxes side by side along x (fragments 0 and 1), the second one in two parts (z < 0.5, z > 0.5)."""
    frags, parts = [], []
    for j, (lo, hi) in enumerate((((0, 0, 0), (1, 1, 1)), ((1, 0, 0), (2, 1, 1)))):
        v, f, n, uv = _box(lo, hi)
        shared = np.isclose(v[f].mean(axis=1)[:, 0], 1.0)  # the faces on x = 1: the fault between them
        frags.append(Fragment(vertices=v, faces=f, uvs=uv, normals=n, material_ids=shared.astype(np.int32), piece=j))
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (0, 1) for z in (0, 1)], float)
        if j == 0:
            parts.append((corners,))
        else:
            low, high = corners.copy(), corners.copy()
            low[:, 2] = np.minimum(low[:, 2], 0.5)
            high[:, 2] = np.maximum(high[:, 2], 0.5)
            parts.append((low, high))
    fragments = Fragments(fragments=tuple(frags), materials=(Material("stone"), Material("interior")),
                          normalization=Normalization(center=np.zeros(3), scale=1.0), input_volume=2.0)
    data = aligned(fragments, tuple(parts), options, uv_scale=0.5, stem="boxes")
    assert data is not None
    return data


def box_hits(rng: np.random.Generator, patterns: int, count: int) -> list[dict]:
    """Hits on and around the boxes: random, axis-aligned directions (frame ties), far away, tiny, invalid."""
    hits = []
    for _ in range(count):
        point = rng.uniform((-0.2, -0.2, -0.2), (2.2, 1.2, 1.2))
        hits.append({"pattern": int(rng.integers(patterns)), "point": point.tolist(),
                     "direction": rng.normal(size=3).tolist(), "scale": float(rng.uniform(0.2, 2.5))})
    for direction in ((0, 0, 1), (1, 0, 0), (0, -1, 0), (1, 1, 0), (1, 1, 1), (0, 0, -3e-300)):
        hits.append({"pattern": 0, "point": [1.0, 0.5, 0.5], "direction": list(map(float, direction)), "scale": 0.7})
    hits.append({"pattern": 0, "point": [1.0, 0.5, 1.0], "direction": [0.0, 0.0, -1.0], "scale": 1e-3})
    hits.append({"pattern": patterns - 1, "point": [40.0, 0.5, 0.5], "direction": [1.0, 2.0, 3.0], "scale": 0.5})
    hits.append({"pattern": 0, "point": [1.0, 0.5, 0.5], "direction": [1e300, -1e300, 5e299], "scale": 1e6})
    for bad in ({"point": [float("nan"), 0, 0]}, {"direction": [0.0, 0.0, 0.0]}, {"scale": 0.0},
                {"scale": float("inf")}, {"pattern": patterns}, {"pattern": -1}):
        hit = {"pattern": 0, "point": [0.5, 0.5, 0.5], "direction": [0.0, 1.0, 0.0], "scale": 1.0}
        hit.update(bad)
        hits.append(hit)
    return hits


def surface_hits(data: AlignedData, rng: np.random.Generator, count: int) -> list[dict]:
    """Hits at random stored triangle corners, random directions, scales around the file's default."""
    corners = data["triangle_positions"].reshape(-1, 3).astype(np.float64)
    return [{"pattern": int(rng.integers(data.num_patterns)), "point": corners[rng.integers(len(corners))].tolist(),
             "direction": rng.normal(size=3).tolist(), "scale": float(data.default_scale * rng.uniform(0.3, 2.0))}
            for _ in range(count)]


def expected(data: AlignedData, hit: dict) -> dict:
    """The reference's answer to one hit (``{"status": "error", ...}`` when it refuses it)."""
    try:
        fragments = aligned_fracture(data, hit["point"], hit["direction"], hit["scale"], hit["pattern"])
    except UsageError as exc:
        return {"status": "error", "error": str(exc)}
    return summarize(data, fragments)


def _json_number(x):
    """NaN and infinities as strings (JSON has none); the drivers read them as numbers."""
    if isinstance(x, float) and not np.isfinite(x):
        return "nan" if np.isnan(x) else ("inf" if x > 0 else "-inf")
    return x


def write_vectors(name: str, data: AlignedData, hits: list[dict], out_dir: str) -> None:
    cases = []
    for hit in hits:
        case = {key: ([_json_number(float(x)) for x in hit[key]] if isinstance(hit[key], list) else
                      _json_number(hit[key])) for key in ("pattern", "point", "direction", "scale")}
        case["expect"] = expected(data, hit)
        cases.append(case)
    head = {"format": VECTORS_FORMAT, "version": VECTORS_VERSION, "file": f"{name}.aligned.json", "tolerance": 1e-9}
    lines = [json.dumps(case, sort_keys=True, allow_nan=False, separators=(",", ":")) for case in cases]
    with open(os.path.join(out_dir, f"{name}.vectors.json"), "w", encoding="utf-8") as fh:
        fh.write(json.dumps(head, sort_keys=True)[:-1] + ', "hits": [\n' + ",\n".join(lines) + "\n]}\n")


def bake_chair(out_dir: str) -> None:
    """The chair from a fast bake (default recipe, small cage, 4 modes) with one 50-site pattern."""
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([os.path.join(REPO, ".venv", "bin", "fracture"), "bake",
                        os.path.join(REPO, "sample_assets", "chair.glb"), "-o", tmp, "-q", *FAST_BAKE], check=True)
        for suffix in (".aligned.json", ".aligned.bin"):
            shutil.copyfile(os.path.join(tmp, "chair" + suffix), os.path.join(out_dir, "chair" + suffix))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=HERE)
    parser.add_argument("--rebake", action="store_true")
    args = parser.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    rng = np.random.default_rng(35)
    bounded = boxes(AlignedOptions(enabled=True, sites=12, patterns=2, grading=1.0, scale=0.5, seed=3))
    unbounded = boxes(AlignedOptions(enabled=True, sites=20, patterns=1, bounded=False, scale=0.5, seed=7))
    for name, data in (("boxes", bounded), ("boxes_unbounded", unbounded)):
        write_aligned(data, os.path.join(args.out, f"{name}.aligned.json"))
        write_vectors(name, data, box_hits(rng, data.num_patterns, 40), args.out)
    if args.rebake:
        bake_chair(HERE)
    if args.out != HERE:
        for suffix in (".aligned.json", ".aligned.bin"):
            shutil.copyfile(os.path.join(HERE, "chair" + suffix), os.path.join(args.out, "chair" + suffix))
    chair = load_aligned(os.path.join(args.out, "chair.aligned.json"))
    write_vectors("chair", chair, surface_hits(chair, rng, 24), args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
