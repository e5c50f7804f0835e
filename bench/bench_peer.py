"""The peer in the bench (issues 32 and 33): Blender's Cell Fracture beside ``fracture bake``, side by side.

    python bench/bench_peer.py [--quick] [--assets chair.glb,vase.obj] [--reps 3]

Needs Debian's ``blender`` (and ``python3-numpy``, which its glTF importer
uses) on PATH; without it the section says so and measures nothing. Every run is
a fresh process timed from outside (wall and CPU of the whole process, workers
included), and the runs alternate per repetition, so the shared machine's load
drifts alike for all of them:

1. ``fracture bake`` with the default recipe (every core);
2. Blender: Cell Fracture into as many pieces as that bake made fragments, one
   convex hull per piece, one GLB (bench/peer_blender.py says exactly what it does);
3. ``fracture -j 1 bake``, default recipe (issue 33: the default ``-j`` never slower);
4. ``fracture bake`` with ``pattern.kind = "voronoi"``, 100 cells, every cell a
   fragment (``pieces.min_fragment_fraction = 0``; collision parts,
   simplification and the runtime file included);
5. Blender: Cell Fracture into 100 pieces, hulls, GLB;
6. the plain Voronoi shatter into 100 pieces with manifold3d that the recipes
   section times (bench_recipes.py's child, unchanged; no hulls, nothing written).

Ratios are fracture's wall over the peer's of the same repetition; the table
gives the smallest and the median. Then ``-j`` default against ``-j 1`` once
more, alternating, while one more default bake of the same asset runs in a
loop beside them. Every GLB (the last of each kind) is checked by the same code
here, which reads the file itself and uses trimesh and manifold3d, none of
fracture's own checks.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
ASSETS = ("chair.glb", "pillar.glb", "vase.obj", "pane.glb", "wall.glb")
CELLS = 100
# Every cell a fragment: the default recipe merges pieces under 1% of the asset (pieces.min_fragment_fraction),
# which would leave about half of 100 cells on the chair; Cell Fracture keeps every cell.
VORONOI = ("pattern.kind=voronoi", f"pattern.count={CELLS}", "pieces.min_fragment_fraction=0")
VORONOI_MERGED = VORONOI[:2]  # where every cell as a fragment fails: the recipe's merging, fewer fragments
# Targets. Issue 33: the default bake at most 1.0x Cell Fracture's whole process for the same count (hulls and GLB
# export included), start-up at most 0.3 s, -j default never slower than -j 1 (idle, and beside one more bake).
# Issue 32: a 100-cell voronoi bake at most 1.5x Cell Fracture's 100 pieces with hulls, at most 3x the plain shatter.
TARGET_DEFAULT = 1.0
TARGET_STARTUP = 0.3
TARGET_JOBS = 1.0
TARGET_VORONOI_PEER = 1.5
TARGET_VORONOI_SHATTER = 3.0


# ----------------------------------------------------------------------------------------------------------------
# Processes, timed from outside


def _timed(command: list[str], cwd: str, log: str) -> tuple[float, float, int]:
    """Run ``command`` (output into ``log``): wall seconds, CPU seconds of it and its reaped workers, exit code."""
    with open(log, "w") as out:
        t0 = time.perf_counter()
        proc = subprocess.Popen(command, cwd=cwd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    return wall, usage.ru_utime + usage.ru_stime, proc.returncode


def _tail(log: str, lines: int = 3) -> str:
    with open(log, errors="replace") as fh:
        return " / ".join(line.strip() for line in fh.read().strip().splitlines()[-lines:])


def fracture_command() -> list[str]:
    """The console script a user runs (it skips the interpreter's teardown), else ``python -m fracture_cli``."""
    script = os.path.join(os.path.dirname(sys.executable), "fracture")
    return [script] if os.access(script, os.X_OK) else [sys.executable, "-m", "fracture_cli"]


def bake(asset: str, out: str, jobs: int | None = None, settings: tuple[str, ...] = ()) -> dict:
    """``fracture bake`` of a sample asset into ``out`` (default recipe): wall, CPU, the report, the GLB."""
    command = fracture_command() + ["-q"] + (["-j", str(jobs)] if jobs else [])
    for item in settings:
        command += ["--set", item]
    command += ["bake", os.path.join(REPO, "sample_assets", asset), "-o", out]
    os.makedirs(out, exist_ok=True)
    wall, cpu, code = _timed(command, REPO, os.path.join(out, "bake.log"))
    if code != 0:
        log = _tail(os.path.join(out, "bake.log"))
        raise RuntimeError(f"fracture bake {asset} {' '.join(settings)}: exit {code}: {log}")
    stem = os.path.splitext(asset)[0]
    with open(os.path.join(out, f"{stem}.report.json")) as fh:
        report = json.load(fh)
    return {"wall": wall, "cpu": cpu, "report": report, "glb": os.path.join(out, f"{stem}.glb"),
            "fragments": int(report["counts"]["fragments"]), "startup": float(report["seconds"]["startup"])}


def blender_peer(blender: str, asset: str, pieces: int, out_glb: str) -> dict:
    """Blender's Cell Fracture of a sample asset into ``pieces``, hulls and GLB export (bench/peer_blender.py)."""
    log = out_glb + ".log"
    command = [blender, "-b", "--factory-startup", "--python", os.path.join(HERE, "peer_blender.py"), "--",
               os.path.join(REPO, "sample_assets", asset), out_glb, str(pieces), "--seed", "0"]
    wall, cpu, code = _timed(command, os.path.dirname(out_glb), log)
    with open(log, errors="replace") as fh:
        found = [line for line in fh if line.startswith("PEER_JSON ")]
    if code != 0 or not found or not os.path.exists(out_glb):
        raise RuntimeError(f"Blender on {asset} ({pieces} pieces): exit {code}: {_tail(log)}")
    return {"wall": wall, "cpu": cpu, "glb": out_glb, **json.loads(found[-1][len("PEER_JSON "):])}


def shatter_input(asset: str, tmp: str) -> str:
    """What the plain shatter cuts: the asset, or (open, as the vase) the solid bench_recipes shells it into once."""
    from bench_recipes import _shelled, _watertight

    path = os.path.join(REPO, "sample_assets", asset)
    if _watertight(path):
        return path
    solid = os.path.join(tmp, os.path.splitext(asset)[0] + ".shelled.ply")
    if not os.path.exists(solid):
        _shelled(path, solid)
    return solid


def shatter(solid: str, cells: int, out: str, glb: str | None = None) -> dict:
    """bench_recipes.py's plain manifold3d Voronoi shatter in a fresh process (with ``glb``: also writes its pieces,
    after its own clock stops)."""
    from bench_recipes import _BASELINE_CHILD

    os.makedirs(out, exist_ok=True)
    log = os.path.join(out, "shatter.log")
    wall, cpu, code = _timed([sys.executable, "-c", _BASELINE_CHILD, solid, str(cells), *([glb] if glb else [])],
                             REPO, log)
    if code != 0:
        raise RuntimeError(f"shatter {solid}: exit {code}: {_tail(log)}")
    with open(log) as fh:
        data = json.loads(fh.read().strip().splitlines()[-1])
    return {"wall": wall, "cpu": cpu, "glb": glb, **data}


class Competitor:
    """One more default bake of an asset, again and again in its own process group, until stopped."""

    def __init__(self, asset: str, out: str) -> None:
        self.asset, self.out = asset, out
        self.stopping = threading.Event()
        self.proc: subprocess.Popen | None = None
        self.count = 0
        self.thread = threading.Thread(target=self._loop, daemon=True)

    def _loop(self) -> None:
        command = fracture_command() + ["-q", "bake", os.path.join(REPO, "sample_assets", self.asset), "-o", self.out]
        while not self.stopping.is_set():
            self.proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                         stdin=subprocess.DEVNULL, start_new_session=True)
            self.proc.wait()
            self.count += not self.stopping.is_set()

    def __enter__(self) -> Competitor:
        self.thread.start()
        time.sleep(1.0)  # past its start-up, into its stages
        return self

    def __exit__(self, *_: object) -> None:
        self.stopping.set()
        proc = self.proc
        if proc is not None and proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGTERM)  # the group this bench started: the bake and its workers
            except ProcessLookupError:
                pass
        self.thread.join()


# ----------------------------------------------------------------------------------------------------------------
# Quality: the same independent checks on every GLB


def read_glb(path: str) -> tuple[list[tuple[str, object, object]], list[tuple[str, object, object]]]:
    """The render meshes and the collision parts of a GLB, in world space: ([(name, V, F)], [(owner, V, F)]).

    A part is a mesh node named ``UCX_<owner>_NN`` (Unreal's convention, what peer_blender.py writes), or a node
    whose ``OMI_physics_body`` has a ``collider`` whose ``OMI_physics_shape`` is a convex mesh (fracture's
    default); its owner is the piece it belongs to (the name in UCX_, the OMI node's parent).
    """
    import numpy as np

    with open(path, "rb") as fh:
        data = fh.read()
    magic, _, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF":
        raise ValueError(f"{path}: not a GLB")
    doc, binary, offset = None, b"", 12
    while offset < length:
        size, kind = struct.unpack_from("<II", data, offset)
        chunk = data[offset + 8:offset + 8 + size]
        if kind == 0x4E4F534A:
            doc = json.loads(chunk)
        elif kind == 0x004E4942:
            binary = chunk
        offset += 8 + size
    assert doc is not None
    dtypes = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
    widths = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}

    def accessor(index: int) -> np.ndarray:
        acc = doc["accessors"][index]
        view = doc["bufferViews"][acc["bufferView"]]
        dtype, width = np.dtype(dtypes[acc["componentType"]]), widths[acc["type"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        stride = view.get("byteStride") or dtype.itemsize * width
        rows = np.ndarray((acc["count"], width), dtype, binary, start, (stride, dtype.itemsize))
        return np.array(rows)

    def mesh(index: int) -> tuple[np.ndarray, np.ndarray]:
        verts, faces, base = [], [], 0
        for prim in doc["meshes"][index]["primitives"]:
            if prim.get("mode", 4) != 4:
                continue
            v = accessor(prim["attributes"]["POSITION"]).astype(np.float64)
            f = (accessor(prim["indices"]).reshape(-1, 3) if "indices" in prim
                 else np.arange(len(v)).reshape(-1, 3)).astype(np.int64)
            verts.append(v)
            faces.append(f + base)
            base += len(v)
        return (np.concatenate(verts) if verts else np.zeros((0, 3)),
                np.concatenate(faces) if faces else np.zeros((0, 3), np.int64))

    def local(node: dict) -> np.ndarray:
        if "matrix" in node:
            return np.asarray(node["matrix"], np.float64).reshape(4, 4).T
        x, y, z, w = node.get("rotation", (0.0, 0.0, 0.0, 1.0))
        rotation = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                             [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                             [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        out = np.eye(4)
        out[:3, :3] = rotation * np.asarray(node.get("scale", (1.0, 1.0, 1.0)))
        out[:3, 3] = node.get("translation", (0.0, 0.0, 0.0))
        return out

    shapes = doc.get("extensions", {}).get("OMI_physics_shape", {}).get("shapes", [])
    pieces: list = []
    parts: list = []

    def visit(index: int, parent: np.ndarray, parent_name: str) -> None:
        node = doc["nodes"][index]
        world = parent @ local(node)
        name = node.get("name", f"node{index}")

        def placed(mesh_index: int) -> tuple[np.ndarray, np.ndarray]:
            v, f = mesh(mesh_index)
            return v @ world[:3, :3].T + world[:3, 3], f

        collider = node.get("extensions", {}).get("OMI_physics_body", {}).get("collider")
        if collider is not None:
            shape = shapes[collider["shape"]]
            if shape.get("type") in ("convex", "hull"):
                parts.append((parent_name, *placed(shape[shape["type"]]["mesh"])))
        if "mesh" in node:
            if name.startswith("UCX_"):
                parts.append((name[4:].rsplit("_", 1)[0], *placed(node["mesh"])))
            else:
                pieces.append((name, *placed(node["mesh"])))
        for child in node.get("children", []):
            visit(child, world, name)

    for root in doc["scenes"][doc.get("scene", 0)]["nodes"]:
        visit(root, np.eye(4), "")
    return pieces, parts


def reference_volume(asset: str) -> float | None:
    """The input's volume (welded), or None where it is open (no volume to compare with)."""
    import trimesh

    mesh = trimesh.load(os.path.join(REPO, "sample_assets", asset), force="mesh")
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    return float(mesh.volume) if mesh.is_watertight else None


def quality(glb: str, volume: float | None) -> dict:
    """The same checks on any GLB: pieces, closed share, bodies per piece, volume error, triangles, hull overlap."""
    import manifold3d
    import numpy as np
    import trimesh

    pieces, parts = read_glb(glb)
    closed, bodies, total, triangles = 0, [], 0.0, 0
    for _, v, f in pieces:
        mesh = trimesh.Trimesh(v, f, process=False)
        mesh.merge_vertices()  # glTF splits a vertex where its normal or UV changes
        mesh.remove_unreferenced_vertices()
        triangles += len(f)
        closed += bool(mesh.is_watertight and mesh.is_winding_consistent)
        bodies.append(len(trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(mesh.faces)),
                                                              min_len=1)))
        total += float(mesh.volume)
    out = {"pieces": len(pieces), "closed": closed / max(len(pieces), 1), "bodies_max": max(bodies, default=0),
           "bodies_mean": float(np.mean(bodies)) if bodies else 0.0, "triangles": triangles,
           "volume_error": abs(total - volume) / volume if volume else None, "parts": len(parts),
           "part_triangles": sum(len(f) for _, _, f in parts), "overlap_max": None, "overlap_share": None}
    if not parts:
        return out
    hulls = [manifold3d.Manifold.hull_points(np.asarray(v, np.float64)) for _, v, _ in parts]
    volumes = np.array([h.volume() for h in hulls])
    boxes = np.array([[*v.min(axis=0), *v.max(axis=0)] for _, v, _ in parts])
    owners = [owner for owner, _, _ in parts]
    worst, overlap = 0.0, 0.0
    for i in range(len(parts)):
        # Parts of different pieces whose boxes meet (parts of one piece may overlap: they move together).
        hit = np.nonzero(np.all(boxes[i + 1:, :3] < boxes[i, 3:], axis=1)
                         & np.all(boxes[i + 1:, 3:] > boxes[i, :3], axis=1))[0] + i + 1
        for j in hit:
            if owners[j] == owners[i]:
                continue
            shared = (hulls[i] ^ hulls[j]).volume()
            if shared > 0.0:
                overlap += shared
                worst = max(worst, shared / max(min(volumes[i], volumes[j]), 1e-300))
    out["overlap_max"] = worst
    out["overlap_share"] = overlap / (volume or float(volumes.sum()))
    return out


# ----------------------------------------------------------------------------------------------------------------
# The section


def run(quick: bool = False, assets: tuple[str, ...] | None = None, reps: int | None = None) -> str:
    sys.path.insert(0, HERE)
    blender = shutil.which("blender")
    title = "## Peer: Blender's Cell Fracture beside fracture bake (issues 32, 33)"
    if blender is None:
        return (f"{title}\n\nSkipped: no `blender` on PATH (Debian: `apt-get install blender python3-numpy`). "
                "Nothing was measured.\n")
    assets = assets or (ASSETS[:1] if quick else ASSETS)
    reps = reps or (1 if quick else 3)
    load_before = os.getloadavg()
    t_start = time.perf_counter()
    results: dict[str, dict] = {}
    failures: list[str] = []
    with tempfile.TemporaryDirectory(prefix="fracture-bench-peer-") as tmp:
        for asset in assets:
            results[asset] = _asset(blender, asset, reps, os.path.join(tmp, os.path.splitext(asset)[0]))
            failures += [f"{asset}, {LABELS[kind]}: {why.replace(REPO + os.sep, '')}"  # paths as in the repository
                         for kind, why in results[asset]["failed"].items()]
        jobs = {}
        for asset in assets:
            try:
                jobs[asset] = _jobs_beside(asset, reps, os.path.join(tmp, os.path.splitext(asset)[0] + "-jobs"))
            except RuntimeError as error:
                failures.append(f"{asset} (-j beside a bake): {error}")
    load_after = os.getloadavg()
    return _section(title, results, jobs, failures, reps, load_before, load_after, time.perf_counter() - t_start)


KINDS = ("default", "peer", "j1", "voronoi", "peer100", "shatter")


def _asset(blender: str, asset: str, reps: int, tmp: str) -> dict:
    """Alternating runs of one asset: A (default bake), B (Blender, same count), -j 1, voronoi, Blender 100, shatter.

    A kind that fails is reported with its reason and not run again; the others go on. The voronoi bake falls
    back to the recipe's merging of small pieces where every cell as a fragment fails (said in the section).
    """
    runs: dict[str, list[dict]] = {k: [] for k in KINDS}
    failed: dict[str, str] = {}
    notes: dict[str, str] = {}  # failures with a fallback
    solid = shatter_input(asset, tmp)
    count = 0
    voronoi = [VORONOI]

    def voronoi_bake() -> dict:
        out = os.path.join(tmp, "voronoi")
        try:
            return bake(asset, out, settings=voronoi[0])
        except RuntimeError as error:
            if voronoi[0] is VORONOI_MERGED:
                raise
            notes["voronoi"] = (f"{error}; measured with the recipe's merging of pieces under 1% of the asset "
                                 "instead (fewer fragments)")
            voronoi[0] = VORONOI_MERGED
            runs["voronoi"] = []  # every repetition with the same settings
            return bake(asset, out, settings=VORONOI_MERGED)

    def attempt(kind: str, make) -> None:
        if kind in failed:
            return
        try:
            result = make()  # first: a fallback may start the kind's list anew
        except RuntimeError as error:
            failed[kind] = str(error)
            runs[kind] = []  # ratios pair runs of one repetition: none of a kind that failed
            print(f"  peer: {asset} {kind} failed: {error}", file=sys.stderr)
            return
        runs[kind].append(result)

    for rep in range(reps):
        t0 = time.perf_counter()
        attempt("default", lambda: bake(asset, os.path.join(tmp, "default")))
        count = count or (runs["default"][0]["fragments"] if runs["default"] else 0)
        if count:
            attempt("peer", lambda n=count: blender_peer(blender, asset, n, os.path.join(tmp, f"peer-{n}.glb")))
        else:
            failed.setdefault("peer", "no piece count: the default bake failed")
        attempt("j1", lambda: bake(asset, os.path.join(tmp, "j1"), jobs=1))
        attempt("voronoi", voronoi_bake)
        attempt("peer100", lambda: blender_peer(blender, asset, CELLS, os.path.join(tmp, f"peer-{CELLS}.glb")))
        attempt("shatter", lambda: shatter(solid, CELLS, os.path.join(tmp, "shatter")))
        print(f"  peer: {asset} repetition {rep + 1}/{reps}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    volume = reference_volume(asset)
    checks = {kind: quality(runs[kind][-1]["glb"], volume) for kind in ("default", "peer", "voronoi", "peer100")
              if runs[kind]}
    if runs["shatter"]:
        glb = os.path.join(tmp, "shatter", "shatter.glb")
        shatter(solid, CELLS, os.path.join(tmp, "shatter"), glb=glb)  # once more, untimed, for its pieces
        checks["shatter"] = quality(glb, volume)
    return {"runs": runs, "count": count, "checks": checks, "volume": volume, "failed": {**notes, **failed},
            "merged": voronoi[0] is VORONOI_MERGED}


def _jobs_beside(asset: str, reps: int, tmp: str) -> dict:
    """-j default and -j 1 alternating while one more default bake of the asset runs in a loop."""
    runs: dict[str, list[dict]] = {"default": [], "j1": []}
    with Competitor(asset, os.path.join(tmp, "competitor")) as competitor:
        for _ in range(reps):
            runs["default"].append(bake(asset, os.path.join(tmp, "default")))
            runs["j1"].append(bake(asset, os.path.join(tmp, "j1"), jobs=1))
    return {"runs": runs, "competing": competitor.count}


LABELS = {"default": "fracture default", "peer": "Cell Fracture, same count", "j1": "fracture -j 1",
          "voronoi": f"fracture voronoi {CELLS}", "peer100": f"Cell Fracture {CELLS}",
          "shatter": f"plain shatter {CELLS}"}


def _median(runs: list[dict], key: str = "wall", fmt: str = "{:.1f}") -> str:
    return fmt.format(statistics.median(r[key] for r in runs)) if runs else "-"


def _ratios(ours: list[dict], theirs: list[dict], key: str = "wall") -> list[float]:
    return [a[key] / b[key] for a, b in zip(ours, theirs)] if ours and theirs else []


def _fmt_ratio(ratios: list[float]) -> str:
    return f"{min(ratios):.2f} / {statistics.median(ratios):.2f}" if ratios else "-"


def _fmt_median(ratios: list[float]) -> str:
    return f"{statistics.median(ratios):.2f}" if ratios else "-"


def _last(runs: list[dict], key: str) -> str:
    return str(runs[-1][key]) if runs else "-"


def _section(title: str, results: dict, jobs: dict, failures: list[str], reps: int, load_before: tuple,
             load_after: tuple, seconds: float) -> str:
    version = next((r["runs"]["peer"][0].get("blender") for r in results.values() if r["runs"]["peer"]), "?")
    lines = [title, "",
             f"Blender {version} (Debian's package; its own Python, numpy.bool shimmed for the glTF importer) runs "
             "`blender -b --factory-startup --python bench/peer_blender.py`: import (glTF with \"Merge Vertices\", "
             "or OBJ), a particle system of N particles from the volume (the add-on's default source), Cell "
             "Fracture (`object_fracture_cell`, `source_limit` N, the add-on's defaults otherwise: margin 0.001, "
             "island split, boolean intersect with the original; no debug redraw), the original deleted, one convex "
             "hull per piece as a mesh named `UCX_<piece>_00` (the rigid body's convex-hull shape would not reach "
             "a GLB: Blender's glTF exporter writes no physics), GLB export with the exporter's defaults. "
             "`fracture bake` runs as a user runs it (`fracture -q bake IN -o OUT`, default recipe, default `-j`: "
             "every core; its GLB carries the convex parts as OMI_physics_shape, plus the runtime file and the "
             f"report); the voronoi bake adds `--set pattern.kind=voronoi --set pattern.count={CELLS} --set "
             "pieces.min_fragment_fraction=0` (every cell a fragment: the default recipe merges pieces under 1% "
             "of the asset). The plain shatter is bench_recipes.py's manifold3d Voronoi shatter (sites in the "
             "bounding box, so fewer pieces on a sparse asset; the vase is shelled first, outside its time; no "
             "hulls, nothing written). Every run is a fresh process timed from outside, whole process; the kinds "
             f"alternate in every repetition ({reps} per asset) and the ratios pair runs of the same repetition: "
             "smallest / median. CPU: user + system seconds of the process and its reaped workers; the CPU ratio "
             "(median) depends less on what else the machine runs.", ""]
    lines += _tables(results) if results else ["No asset was measured.", ""]
    if jobs:
        lines += _jobs_table(results, jobs)
    lines += _targets(results, jobs)
    lines += ["", f"Load average (1 min) {load_before[0]:.1f} before and {load_after[0]:.1f} after this section "
              f"({seconds / 60:.0f} min), on {os.cpu_count()} cores shared with other jobs: seconds are noisy, "
              "ratios of neighbouring runs less so."]
    if failures:
        lines += ["", "Failures (that kind was not run again on that asset, unless a fallback is named; the others "
                  "went on):", ""]
        lines += [f"- {f}" for f in failures]
    return "\n".join(lines) + "\n"


def _tables(results: dict) -> list[str]:
    lines = ["### Default bake against Cell Fracture, same piece count (issue 33)", "",
             "| asset | fragments | Blender pieces | bake wall s | bake CPU s | start-up s | Blender wall s | "
             "Blender CPU s | bake / Blender (min / median) | CPU ratio |", "|---|" + "---:|" * 9]
    for asset, r in results.items():
        runs = r["runs"]
        ours, peer = runs["default"], runs["peer"]
        lines.append(f"| {asset} | {r['count'] or '-'} | {_last(peer, 'pieces')} | {_median(ours)} | "
                     f"{_median(ours, 'cpu')} | {_median(ours, 'startup', '{:.2f}')} | {_median(peer)} | "
                     f"{_median(peer, 'cpu')} | {_fmt_ratio(_ratios(ours, peer))} | "
                     f"{_fmt_median(_ratios(ours, peer, 'cpu'))} |")
    lines += ["", f"### Voronoi bake of {CELLS} cells against Cell Fracture's {CELLS} pieces and the plain shatter "
              "(issue 32)", "",
              "| asset | fragments | Blender pieces | bake wall s | bake CPU s | Blender wall s | Blender CPU s | "
              "shatter wall s | bake / Blender | CPU ratio | bake / shatter |", "|---|" + "---:|" * 10]
    for asset, r in results.items():
        runs = r["runs"]
        ours, peer, plain = runs["voronoi"], runs["peer100"], runs["shatter"]
        merged = " (merged)" if r.get("merged") and ours else ""
        lines.append(f"| {asset} | {_last(ours, 'fragments')}{merged} | {_last(peer, 'pieces')} | {_median(ours)} | "
                     f"{_median(ours, 'cpu')} | {_median(peer)} | {_median(peer, 'cpu')} | "
                     f"{_median(plain, 'wall', '{:.2f}')} | {_fmt_ratio(_ratios(ours, peer))} | "
                     f"{_fmt_median(_ratios(ours, peer, 'cpu'))} | {_fmt_ratio(_ratios(ours, plain))} |")
    steps = ("startup", "setup", "import", "fracture", "hulls", "export")
    lines += ["", "Blender's steps (median seconds, from peer_blender.py; start-up: the process's start to the "
              "script's first line; setup: enabling the add-on), and fracture's start-up and total from its "
              "report:", "",
              "| asset | pieces | " + " | ".join(steps) + " | whole process | fracture start-up | fracture total |",
              "|---|---:|" + "---:|" * (len(steps) + 3)]
    for asset, r in results.items():
        runs = r["runs"]
        for peer, ours in (("peer", "default"), ("peer100", "voronoi")):
            if not runs[peer]:
                continue
            cells = [f"{statistics.median(p['seconds'][s] for p in runs[peer]):.2f}" for s in steps]
            total = (f"{statistics.median(float(b['report']['seconds']['total']) for b in runs[ours]):.2f}"
                     if runs[ours] else "-")
            lines.append(f"| {asset} | {runs[peer][-1]['pieces']} | " + " | ".join(cells)
                         + f" | {_median(runs[peer], 'wall', '{:.2f}')} | "
                         f"{_median(runs[ours], 'startup', '{:.2f}')} | {total} |")
    lines += ["", "### Quality of the written GLBs (the same checks on each)", "",
              "Pieces: render meshes (not collision). Closed: share of pieces whose welded mesh is watertight "
              "with consistent winding. Bodies: connected components per piece, most (mean). Volume error: "
              "|sum of piece volumes - input volume| / input volume ('-': the input is open, as the vase). "
              "Triangles: of the pieces; parts: collision meshes (their triangles). Overlap: between the convex "
              "hulls of parts of different pieces whose boxes meet, largest as a fraction of the smaller hull, and "
              "the sum over all pairs as a share of the input's volume.", "",
              "| asset | output | pieces | closed | bodies | volume error | triangles | parts (tris) | overlap max | "
              "overlap sum |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for asset, r in results.items():
        for kind in ("default", "peer", "voronoi", "peer100", "shatter"):
            q = r["checks"].get(kind)
            if q is None:
                lines.append(f"| {asset} | {LABELS[kind]} | failed | | | | | | | |")
                continue
            err = "-" if q["volume_error"] is None else f"{q['volume_error']:.1e}"
            parts = f"{q['parts']} ({q['part_triangles']:,})" if q["parts"] else "-"
            over = "-" if q["overlap_max"] is None else f"{q['overlap_max']:.3f}"
            share = "-" if q["overlap_share"] is None else f"{q['overlap_share']:.1e}"
            lines.append(f"| {asset} | {LABELS[kind]} | {q['pieces']} | {100 * q['closed']:.0f} % | "
                         f"{q['bodies_max']} ({q['bodies_mean']:.2f}) | {err} | {q['triangles']:,} | {parts} | "
                         f"{over} | {share} |")
    return lines + [""]


def _jobs_table(results: dict, jobs: dict) -> list[str]:
    lines = ["### `-j` default against `-j 1` (issue 33)", "",
             "Default bake, median wall seconds, ratio default / `-j 1` (smallest / median). Alone: the runs of the "
             "tables above (alternating with Blender and the others; no other run of this bench at the same time, "
             "but whatever else the shared machine runs, see the load average below). Beside a bake: alternating "
             "while one more default bake of the same asset runs in a loop (how many of those finished meanwhile).",
             "", "| asset | alone: default -j s | alone: -j 1 s | alone: ratio | beside a bake: default -j s "
             "| beside a bake: -j 1 s | beside a bake: ratio | other bakes finished |", "|---|" + "---:|" * 7]
    for asset, j in jobs.items():
        alone = results.get(asset, {}).get("runs", {})
        default, j1 = alone.get("default", []), alone.get("j1", [])
        runs = j["runs"]
        lines.append(f"| {asset} | {_median(default)} | {_median(j1)} | {_fmt_ratio(_ratios(default, j1))} | "
                     f"{_median(runs['default'])} | {_median(runs['j1'])} | "
                     f"{_fmt_ratio(_ratios(runs['default'], runs['j1']))} | {j['competing']} |")
    return lines + [""]


def _target(what: str, medians: dict[str, float | None], limit: float, unit: str = "x") -> str:
    """One target's line: the worst median over the assets measured, and which were not."""
    measured = {a: m for a, m in medians.items() if m is not None}
    missing = sorted(a for a, m in medians.items() if m is None)
    if not measured:
        return f"- {what}: not measured ({', '.join(missing)} failed)."
    worst_at = max(measured, key=lambda a: measured[a])
    worst = measured[worst_at]
    verdict = "**missed**" if worst > limit else ("**met where measured**" if missing else "**met**")
    gap = f"; not measured on {', '.join(missing)} (see the failures)" if missing else ""
    fmt = f"{worst:.2f}{unit}" if unit == "x" else f"{worst:.2f} {unit}"
    return f"- {what}: worst {fmt} ({worst_at}{gap}): {verdict}."


def _targets(results: dict, jobs: dict) -> list[str]:
    if not results:
        return []

    def medians(ours: str, theirs: str) -> dict[str, float | None]:
        return {a: (statistics.median(x) if (x := _ratios(r["runs"][ours], r["runs"][theirs])) else None)
                for a, r in results.items()}

    startups = {a: [b["startup"] for k in ("default", "voronoi", "j1") for b in r["runs"][k]]
                for a, r in results.items()}
    largest = max((max(s) for s in startups.values() if s), default=float("nan"))
    lines = ["Targets (per asset the median of the paired ratios; the worst asset named):", "",
             _target(f"issue 33, default bake at most {TARGET_DEFAULT:.1f}x Cell Fracture's whole process for the "
                     "same count with hulls and GLB export", medians("default", "peer"), TARGET_DEFAULT),
             _target(f"issue 33, start-up (process start to the first stage, the report's `seconds.startup`; median "
                     f"per asset, largest of any bake {largest:.2f} s) at most {TARGET_STARTUP} s",
                     {a: statistics.median(s) if s else None for a, s in startups.items()}, TARGET_STARTUP, "s"),
             _target("issue 33, `-j` default never slower than `-j 1`, alone", medians("default", "j1"), TARGET_JOBS)]
    if jobs:
        lines.append(_target("issue 33, `-j` default never slower than `-j 1` beside one more bake",
                             {a: (statistics.median(x) if (x := _ratios(j["runs"]["default"], j["runs"]["j1"]))
                                  else None) for a, j in jobs.items()}, TARGET_JOBS))
    lines += [_target(f"issue 32, voronoi bake of {CELLS} cells at most {TARGET_VORONOI_PEER}x Cell Fracture's "
                      f"{CELLS} pieces with hulls", medians("voronoi", "peer100"), TARGET_VORONOI_PEER),
              _target(f"issue 32, the same bake at most {TARGET_VORONOI_SHATTER:.0f}x the plain shatter",
                      medians("voronoi", "shatter"), TARGET_VORONOI_SHATTER)]
    return lines


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--assets", default="")
    parser.add_argument("--reps", type=int, default=0)
    args = parser.parse_args()
    sys.path.insert(0, REPO)
    import fracture_cli  # noqa: F401  (first: pins the kernels before numpy loads, as bench/run.py does)

    print(run(args.quick, tuple(a for a in args.assets.split(",") if a) or None, args.reps or None))
