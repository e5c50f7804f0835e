"""Shared by the aligned-fracture tests, generator and bench: drivers, summaries, comparisons, properties.

The C and JavaScript readers each have a driver (engines/c/tools/fracture_aligned_check.c,
engines/web/fracture_aligned_check.mjs) that loads one ``.aligned.json`` file and answers hits in one
line protocol: in, ``pattern px py pz dx dy dz scale`` per line; out, one JSON object per line,
``{"status": "ok", "fragments": [...]}`` (the keys of :func:`summarize`) or ``{"status": "error", ...}``.
With ``--full`` the cut parts also carry ``corners``, ``loops``, ``planes`` and ``new``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
from collections.abc import Sequence

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ALIGNED_CONFORMANCE = os.path.join(REPO, "tests", "data", "aligned_conformance")
C_DIR = os.path.join(REPO, "engines", "c")
C_SOURCES = [os.path.join(C_DIR, "fracture_aligned.c"), os.path.join(C_DIR, "tools", "fracture_aligned_check.c")]
C_FLAGS = ["-std=c99", "-D_POSIX_C_SOURCE=199309L", "-Wall", "-Wextra", "-Werror", "-pedantic"]
JS_DRIVER = os.path.join(REPO, "engines", "web", "fracture_aligned_check.mjs")
NODE = shutil.which("node")
TOLERANCE = 1e-9  # relative: volumes to the pieces' total, positions to the asset's size, areas to its square

Hit = tuple[int, Sequence[float], Sequence[float], float]  # pattern, point, direction, scale


def compile_c_driver(out: str, flags: Sequence[str] = ("-O2",)) -> str:
    """Build the C driver into ``out``; returns its path (raises with the compiler's message)."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise FileNotFoundError("no C compiler (cc) found")
    result = subprocess.run([compiler, *C_FLAGS, *flags, *C_SOURCES, "-o", out, "-lm"], capture_output=True,
                            text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"the C aligned reader does not compile:\n{result.stderr}")
    return out


def hit_lines(hits: Sequence[Hit]) -> str:
    """The drivers' input for ``hits`` (every number as Python's shortest round-trip repr)."""
    return "".join(f"{int(q)} " + " ".join(repr(float(x)) for x in (*p, *d, s)) + "\n" for q, p, d, s in hits)


def run_driver(command: Sequence[str], json_path: str, hits: Sequence[Hit], *flags: str, timeout: float = 600) -> list:
    """Answers of a driver (``[c_driver]`` or ``[node, JS_DRIVER]``) to ``hits``, one parsed line each."""
    bin_path = json_path[: -len(".json")] + ".bin"
    result = subprocess.run([*command, *flags, json_path, bin_path], input=hit_lines(hits), capture_output=True,
                            text=True, timeout=timeout, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"{command[-1]} failed ({result.returncode}): {result.stdout[-500:]}{result.stderr[-2000:]}")
    return [json.loads(line) for line in result.stdout.splitlines()]


def _area(tri: np.ndarray) -> float:
    u, v = tri[1] - tri[0], tri[2] - tri[0]
    x, y, z = u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]
    return 0.5 * math.sqrt((x * x + y * y) + z * z)


def summarize(data, fragments) -> dict:
    """The drivers' answer for the reference's fragments (:func:`fracture_cli.runtime.aligned.aligned_fracture`)."""
    offsets = data["piece_triangle_offsets"]
    out = []
    for f in fragments:
        areas = [_area(tri) for tri in f.positions]
        out.append({
            "cell": int(f.cell), "volume": float(f.volume), "center_of_mass": [float(x) for x in f.center_of_mass],
            "whole_pieces": [int(k) for k in f.whole_pieces], "new_triangles": int(len(f.materials)),
            "triangles": int(len(f.materials) + sum(int(offsets[k + 1] - offsets[k]) for k in f.whole_pieces)),
            "new_area": float(sum(areas)),
            "interior_area": float(sum(a for a, m in zip(areas, f.materials) if m == data.interior_material)),
            "parts": [{"piece": int(p.piece), "whole": bool(p.whole), "vertices": 0 if p.whole else len(p.vertices),
                       "faces": 0 if p.whole else len(p.loops), "volume": float(p.volume),
                       "centroid": [float(x) for x in p.centroid]} for p in f.parts],
        })
    return {"status": "ok", "fragments": out}


def data_scales(data) -> tuple[float, float]:
    """(total volume of the pieces, size of the asset: the diameter of the pieces' spheres' box)."""
    spheres = data["piece_sphere"].astype(np.float64)
    lo = (spheres[:, :3] - spheres[:, 3:]).min(axis=0)
    hi = (spheres[:, :3] + spheres[:, 3:]).max(axis=0)
    size = float(np.linalg.norm(hi - lo))
    # on first use: the reference (pure Python) only where a comparison needs the volume
    from fracture_cli.runtime.aligned import piece_volumes

    return float(sum(piece_volumes(data))), size


def compare(expected: dict, got: dict, volume: float, size: float, where: str = "") -> list[str]:
    """Differences between two answers: counts and indices exactly, numbers within :data:`TOLERANCE`."""
    if expected.get("status") != got.get("status"):
        return [f"{where}: status {got.get('status')} (expected {expected.get('status')})"]
    if expected["status"] != "ok":
        return []
    problems: list[str] = []
    scale = {"volume": volume, "center_of_mass": size, "centroid": size, "new_area": size * size,
             "interior_area": size * size}

    def walk(e, g, path: str, key: str) -> None:
        if isinstance(e, dict):
            for k in e:
                if k not in g:
                    problems.append(f"{where}{path}.{k}: missing")
                else:
                    walk(e[k], g[k], f"{path}.{k}", k)
        elif isinstance(e, list):
            if not isinstance(g, list) or len(e) != len(g):
                problems.append(f"{where}{path}: length {len(g) if isinstance(g, list) else g} (expected {len(e)})")
            else:
                for i, (x, y) in enumerate(zip(e, g)):
                    walk(x, y, f"{path}[{i}]", key)
        elif isinstance(e, float) and key in scale:
            if not abs(e - float(g)) <= TOLERANCE * max(abs(e), scale[key]):
                problems.append(f"{where}{path}: {g!r} (expected {e!r})")
        elif e != g:
            problems.append(f"{where}{path}: {g!r} (expected {e!r})")

    walk(expected, got, "", "")
    return problems[:20]


def random_hits(data, count: int, seed: int) -> list[Hit]:
    """``count`` hits on the asset: a random point of a random stored triangle, a random direction, a scale of
    0.5 to 1.5 times the file's default, a random pattern."""
    rng = np.random.default_rng(seed)
    triangles = data["triangle_positions"].astype(np.float64)
    hits = []
    for _ in range(count):
        a, b = rng.random(2)
        if a + b > 1:
            a, b = 1 - a, 1 - b
        tri = triangles[rng.integers(len(triangles))]
        point = tri[0] + a * (tri[1] - tri[0]) + b * (tri[2] - tri[0])
        hits.append((int(rng.integers(data.num_patterns)), point.tolist(), rng.normal(size=3).tolist(),
                     float(data.default_scale * rng.uniform(0.5, 1.5))))
    return hits


def part_geometry(data, part: dict) -> tuple[np.ndarray, list, np.ndarray]:
    """Corners (n, 3), face loops and planes (f, 4) of a part of a ``--full`` answer (whole: the stored piece)."""
    if not part["whole"]:
        return np.array(part["corners"], float), part["loops"], np.array(part["planes"], float)
    k = part["piece"]
    pv, pf, fl = data["piece_vertex_offsets"], data["piece_face_offsets"], data["face_loop_offsets"]
    loops = [data["face_loops"][fl[f]:fl[f + 1]].tolist() for f in range(pf[k], pf[k + 1])]
    return (data["piece_vertices"][pv[k]:pv[k + 1]].astype(np.float64), loops,
            data["face_planes"][pf[k]:pf[k + 1]].astype(np.float64))


def closed_and_convex(corners: np.ndarray, loops: list, planes: np.ndarray, size: float) -> str | None:
    """Why a part is not a closed convex polyhedron, or None.

    Closed: every directed edge of the face loops has exactly one reverse edge, and the faces' area vectors
    sum to zero (within 1e-9 of their total area). Convex: every corner lies inside every face plane
    (within 1e-6 of the asset's size: the stored planes are float32).
    """
    edges: dict[tuple[int, int], int] = {}
    total, vector = 0.0, np.zeros(3)
    for loop in loops:
        for i in range(len(loop)):
            edge = (loop[i], loop[(i + 1) % len(loop)])
            edges[edge] = edges.get(edge, 0) + 1
        points = corners[loop]
        normal = np.cross(points, np.roll(points, -1, axis=0)).sum(axis=0) / 2
        vector += normal
        total += float(np.linalg.norm(normal))
    if any(count != 1 or edges.get((b, a)) != 1 for (a, b), count in edges.items()):
        return "a face edge does not meet exactly one reverse edge"
    if np.linalg.norm(vector) > 1e-9 * total:
        return f"the faces' area vectors sum to {np.linalg.norm(vector):.3g} (of {total:.3g})"
    excess = float((corners @ planes[:, :3].T - planes[:, 3]).max())
    if excess > 1e-6 * size:
        return f"a corner lies {excess:.3g} outside a face plane"
    return None
