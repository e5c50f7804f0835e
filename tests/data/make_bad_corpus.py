"""Write the malformed and awkward input corpus in tests/data/bad/ (run from anywhere).

Each file is small (a few KB) and deterministic; ``expected.toml`` beside them
says what ``fracture bake`` must do with each: bake it into valid fragments, or
exit with code 1 and a one-line message containing a given substring.

    python tests/data/make_bad_corpus.py

The files are committed; re-run this script after changing it and commit the
result. tests/test_bad_inputs.py checks every entry of the manifest.
"""

from __future__ import annotations

import json
import os
import struct
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "bad")
sys.path.insert(0, os.path.dirname(os.path.dirname(HERE)))

# fracture_cli first: it pins the numeric kernels before numpy loads (fracture_cli/system/numeric_env.py).
import fracture_cli  # noqa: E402, F401, I001

import numpy as np  # noqa: E402

from fracture_cli.io.gltf import Primitive, glb_bytes  # noqa: E402
from fracture_cli.types import Material  # noqa: E402

# ----------------------------------------------------------------------------
# Shapes (world units, outward winding)


def box(extents=(1.0, 1.0, 1.0), centre=(0.0, 0.0, 0.0)):
    """8 vertices, 12 outward triangles."""
    e = np.asarray(extents, dtype=np.float64) / 2
    c = np.asarray(centre, dtype=np.float64)
    V = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64) * e + c
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64)
    return V, F


def seamed_box(extents=(1.0, 1.0, 1.0), centre=(0.0, 0.0, 0.0)):
    """24 vertices (4 per side, split at every edge like a UV-unwrapped cube), UVs, normals."""
    V8, _ = box(extents, centre)
    sides = [  # corner ids (counter-clockwise seen from outside), outward normal
        ([0, 1, 3, 2], (-1, 0, 0)), ([4, 6, 7, 5], (1, 0, 0)), ([0, 4, 5, 1], (0, -1, 0)),
        ([2, 3, 7, 6], (0, 1, 0)), ([0, 2, 6, 4], (0, 0, -1)), ([1, 5, 7, 3], (0, 0, 1)),
    ]
    V, N, UV, F = [], [], [], []
    for k, (quad, normal) in enumerate(sides):
        base = 4 * k
        V.extend(V8[quad])
        N.extend([normal] * 4)
        u0 = (k % 3) / 3.0
        v0 = (k // 3) / 2.0
        UV.extend([[u0, v0], [u0 + 1 / 3, v0], [u0 + 1 / 3, v0 + 0.5], [u0, v0 + 0.5]])
        F.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]])
    return np.array(V), np.array(F), np.array(UV, dtype=np.float64), np.array(N, dtype=np.float64)


def icosphere(subdivisions=2, radius=1.0, centre=(0.0, 0.0, 0.0)):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices) + np.asarray(centre), np.asarray(s.faces, dtype=np.int64)


def concat(*parts):
    V, F, n = [], [], 0
    for v, f in parts:
        V.append(v)
        F.append(f + n)
        n += len(v)
    return np.vstack(V), np.vstack(F)


# ----------------------------------------------------------------------------
# Writers (hand-rolled so the bytes are exactly what we mean)


def fmt(x: float) -> str:
    if not np.isfinite(x):
        return "nan" if np.isnan(x) else ("inf" if x > 0 else "-inf")
    return repr(float(x))


def obj_text(V, F, uvs=None, normals=None, header="") -> str:
    lines = [f"# {header}"] if header else []
    lines += ["v " + " ".join(fmt(c) for c in v) for v in V]
    if uvs is not None:
        lines += ["vt " + " ".join(fmt(c) for c in t) for t in uvs]
    if normals is not None:
        lines += ["vn " + " ".join(fmt(c) for c in n) for n in normals]
    for f in np.asarray(F) + 1:
        if uvs is not None and normals is not None:
            lines.append("f " + " ".join(f"{i}/{i}/{i}" for i in f))
        elif uvs is not None:
            lines.append("f " + " ".join(f"{i}/{i}" for i in f))
        else:
            lines.append("f " + " ".join(str(i) for i in f))
    return "\n".join(lines) + "\n"


def ply_text(V, F=None, header="") -> str:
    F = np.zeros((0, 3), dtype=np.int64) if F is None else F
    lines = ["ply", "format ascii 1.0"] + ([f"comment {header}"] if header else []) + [
        f"element vertex {len(V)}", "property float x", "property float y", "property float z"]
    if len(F):
        lines += [f"element face {len(F)}", "property list uchar int vertex_indices"]
    lines.append("end_header")
    lines += [" ".join(fmt(c) for c in v) for v in V]
    lines += ["3 " + " ".join(str(i) for i in f) for f in F]
    return "\n".join(lines) + "\n"


def off_text(V, F) -> str:
    lines = ["OFF", f"{len(V)} {len(F)} 0"]
    lines += [" ".join(fmt(c) for c in v) for v in V]
    lines += ["3 " + " ".join(str(i) for i in f) for f in F]
    return "\n".join(lines) + "\n"


def stl_binary(V, F, count=None) -> bytes:
    tris = np.asarray(V, dtype=np.float64)[np.asarray(F)]
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    rec = np.zeros(len(F), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec["n"] = n
    rec["v"] = tris
    header = b"fracture bad-input corpus".ljust(80, b" ")
    return header + struct.pack("<I", len(F) if count is None else count) + rec.tobytes()


def glb(primitive_sets, materials) -> bytes:
    """primitive_sets: list of (node name, [(V, F, normals or None, uvs or None, material)])."""
    meshes = []
    for name, prims in primitive_sets:
        out = []
        for V, F, N, UV, mat in prims:
            if N is None:
                import trimesh

                N = np.asarray(trimesh.Trimesh(V, F, process=False).vertex_normals)
            out.append(Primitive(positions=np.asarray(V, dtype=np.float64), normals=np.asarray(N, dtype=np.float64),
                                 uvs=UV, indices=np.asarray(F, dtype=np.int64), material=mat))
        meshes.append((name, out))
    return glb_bytes(meshes, tuple(materials))


class Gltf:
    """A hand-built glTF document: one binary buffer, views and accessors added in order."""

    def __init__(self):
        self.binary = bytearray()
        self.doc = {"asset": {"version": "2.0"}, "bufferViews": [], "accessors": [], "meshes": [], "nodes": []}

    def view(self, data: bytes, stride: int | None = None) -> int:
        while len(self.binary) % 4:
            self.binary.append(0)
        entry = {"buffer": 0, "byteOffset": len(self.binary), "byteLength": len(data)}
        if stride:
            entry["byteStride"] = stride
        self.binary.extend(data)
        self.doc["bufferViews"].append(entry)
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, array, component: int, kind: str, normalized: bool = False, view: bool = True, **extra) -> int:
        array = np.asarray(array)
        entry = {"componentType": component, "count": int(len(array)), "type": kind, **extra}
        if view:
            entry["bufferView"] = self.view(np.ascontiguousarray(array).tobytes())
        if normalized:
            entry["normalized"] = True
        if kind == "VEC3" and component == 5126 and view:
            entry["min"] = [float(x) for x in array.min(axis=0)]
            entry["max"] = [float(x) for x in array.max(axis=0)]
        self.doc["accessors"].append(entry)
        return len(self.doc["accessors"]) - 1

    def mesh(self, primitives: list[dict]) -> int:
        self.doc["meshes"].append({"primitives": primitives})
        return len(self.doc["meshes"]) - 1

    def node(self, **fields) -> int:
        self.doc["nodes"].append(fields)
        return len(self.doc["nodes"]) - 1

    def glb(self, roots: list[int]) -> bytes:
        from fracture_cli.io.gltf import pack_glb

        while len(self.binary) % 4:
            self.binary.append(0)
        doc = dict(self.doc, scenes=[{"nodes": roots}], scene=0, buffers=[{"byteLength": len(self.binary)}])
        return pack_glb(doc, bytes(self.binary))

    def gltf(self, roots: list[int], uri: str, length: int | None = None) -> tuple[str, bytes]:
        doc = dict(self.doc, scenes=[{"nodes": roots}], scene=0,
                   buffers=[{"uri": uri, "byteLength": len(self.binary) if length is None else length}])
        return json.dumps(doc, indent=1), bytes(self.binary)


def box_primitive(g: Gltf, extents=(1.0, 1.0, 1.0), centre=(0.0, 0.0, 0.0), material: int | None = None) -> dict:
    V, F = box(extents, centre)
    prim = {"attributes": {"POSITION": g.accessor(V.astype("<f4"), 5126, "VEC3")},
            "indices": g.accessor(F.reshape(-1).astype("<u2"), 5123, "SCALAR")}
    if material is not None:
        prim["material"] = material
    return prim


def strip_triangles(strip) -> list[list[int]]:
    """Triangles of one strip, as the PLY/OpenGL convention defines them: every second one swapped."""
    return [[strip[i], strip[i + 1], strip[i + 2]] if i % 2 == 0 else [strip[i + 1], strip[i], strip[i + 2]]
            for i in range(len(strip) - 2)]


def tristrip_box_ply() -> bytes:
    """A unit box as binary PLY triangle strips of different lengths, separated by -1 (as scanners write)."""
    V, F = box()
    # The four sides around z as one strip zig-zagging between z = -0.5 and z = +0.5 (corner id x*4 + y*2 + z).
    ring = [(0, 0), (1, 0), (1, 1), (0, 1), (0, 0)]
    wall = [c for x, y in ring for c in (x * 4 + y * 2 + 1, x * 4 + y * 2)]
    # The two caps (z = -0.5 and +0.5), each a 4-vertex strip b, c, a, d of its quad's triangles (a, b, c), (a, c, d).
    caps = [[F[k][1], F[k][2], F[k][0], F[k + 1][2]] for k in (4, 10)]
    rows = [wall, caps[0] + [-1] + caps[1]]
    tris = [t for row in rows for part in " ".join(map(str, row)).split("-1") for t in strip_triangles(
        [int(w) for w in part.split()])]
    volume = sum(np.dot(V[a], np.cross(V[b], V[c])) for a, b, c in tris) / 6.0
    assert len(tris) == 12 and abs(volume - 1.0) < 1e-12, (len(tris), volume)  # the strips really are the box
    header = ("ply\nformat binary_little_endian 1.0\ncomment fracture corpus: triangle strips\n"
              f"element vertex {len(V)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element tristrips {len(rows)}\nproperty list int int vertex_indices\nend_header\n").encode()
    body = V.astype("<f4").tobytes()
    for row in rows:
        body += struct.pack("<i", len(row)) + np.asarray(row, dtype="<i4").tobytes()
    return header + body


def relative_obj() -> str:
    """Two unit boxes, each object's faces with negative indices written right after its own vertices."""
    lines = []
    for centre in ((0.0, 0.0, 0.0), (3.0, 0.0, 0.0)):
        V, F = box((1, 1, 1), centre)
        lines += ["o box", *("v " + " ".join(fmt(c) for c in v) for v in V)]
        lines += ["f " + " ".join(str(i - len(V)) for i in f) for f in F]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------
# The corpus

CASES: list[dict] = []


def case(file: str, data, *, outcome: str, why: str, message: str | None = None, volume: float | None = None,
         overrides: tuple[str, ...] = (), known_issue: str | None = None, check: str = "bake",
         bbox: tuple | None = None, reference: str | None = None, companions: dict | None = None):
    """Register one corpus file: its bytes (or text) and what a bake must do with it.

    ``known_issue`` marks an expected outcome the tool does not reach yet (the
    test reports it as an expected failure, naming the issue). ``check =
    "load"`` checks an "ok" file at the reader (volume and bounding box of the
    loaded triangles against the known geometry, in milliseconds) instead of
    baking it. ``reference`` names an OBJ of the intended triangles, for files
    that trimesh (the tests' independent reader) misreads. ``companions`` are
    extra files written beside it (``{name: bytes}``).
    """
    CASES.append(dict(file=file, data=data, outcome=outcome, why=why, message=message, volume=volume,
                      overrides=list(overrides), known_issue=known_issue, check=check,
                      bbox=[list(map(float, b)) for b in bbox] if bbox is not None else None,
                      reference=reference, companions=companions or {}))


def build() -> None:
    V, F = box()
    SV, SF = icosphere(2)
    sphere_volume = None  # measured from the mesh (an icosphere is smaller than the sphere)
    import trimesh

    sphere_volume = float(trimesh.Trimesh(SV, SF, process=False).volume)

    # --- unreadable files ---------------------------------------------------
    case("empty.obj", b"", outcome="error", message="file is empty", why="0-byte OBJ")
    case("zero_byte.glb", b"", outcome="error", message="file is empty", why="0-byte GLB")
    whole = glb([("box", [(V, F, None, None, 0)])], [Material("stone")])
    case("truncated.glb", whole[: len(whole) * 2 // 3], outcome="error", message="truncated",
         why="GLB cut off part-way through its binary chunk")
    case("not_a_mesh.stl", "This is a README that was renamed to .stl by mistake.\nIt has no triangles.\n",
         outcome="error", message="not a valid STL", why="text file with a mesh extension")
    case("text_as.glb", "{\"hello\": \"this is JSON, not a binary glTF\"}\n", outcome="error",
         message="does not start with 'glTF'",
         why="text file with a .glb extension")
    case("point_cloud.ply", ply_text(V), outcome="error", message="no triangles", why="vertices only, no faces")
    case("bad_index.obj", obj_text(V, np.vstack([F, [[0, 1, 40]]])), outcome="error",
         message="missing vertices", why="a face references vertex 41 of 8")
    case("missing_buffer.gltf", json.dumps({
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "missing_buffer.bin", "byteLength": 132}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 96},
                        {"buffer": 0, "byteOffset": 96, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3",
                       "min": [-1, -1, -1], "max": [1, 1, 1]},
                      {"bufferView": 1, "componentType": 5125, "count": 9, "type": "SCALAR"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0,
    }), outcome="error", message="missing_buffer.bin", why="glTF whose .bin buffer file is missing")
    case("stl_count_lies.stl", stl_binary(V, F, count=2_000_000_000), outcome="ok", check="load", volume=1.0,
         bbox=((-0.5,) * 3, (0.5,) * 3),
         why="binary STL whose header claims 2e9 triangles: its size (84 + 50 * 12) says 12; read with a warning")
    case("stl_truncated.stl", stl_binary(V, F)[:-7], outcome="error", message="does not match the triangle count",
         why="binary STL cut off mid-record: its size fits no triangle count")
    case("limit.stl", stl_binary(V, F), outcome="error", message="has 12 triangles, more than the limit",
         overrides=("load.max_triangles=10",), why="binary STL over load.max_triangles (refused from its header)")
    case("limit.glb", glb([("box", [(V, F, None, None, 0)]), ("copy", [(V + 3, F, None, None, 0)])],
                          [Material("stone")]),
         outcome="error", message="has 24 triangles, more than the limit", overrides=("load.max_triangles=20",),
         why="GLB over load.max_triangles (counted from its JSON chunk before decoding buffers)")
    case("too_many_triangles.obj", obj_text(SV, SF), outcome="error", message="more than the limit",
         overrides=("load.max_triangles=100",), why="320 triangles with load.max_triangles=100")

    # --- coordinates ----------------------------------------------------------
    Vn = V.copy()
    Vn[3, 1] = np.nan
    case("nan_coords.obj", obj_text(Vn, F), outcome="error", message="non-finite", why="one NaN coordinate")
    Vi = V.copy()
    Vi[5, 2] = np.inf
    case("inf_coords.ply", ply_text(Vi, F), outcome="error", message="non-finite", why="one inf coordinate")

    # --- no inside ------------------------------------------------------------
    case("single_triangle.obj", obj_text(V[[0, 1, 3]], [[0, 1, 2]]), outcome="error", message="flat",
         why="one triangle has no inside")
    case("flat_quad.obj", obj_text(V[[0, 1, 3, 2]], [[0, 1, 2], [0, 2, 3]]), outcome="error", message="flat",
         why="a zero-volume quad has no inside")
    case("all_degenerate.obj", obj_text(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 1.0]]),
                                        [[0, 1, 2], [0, 0, 3], [1, 2, 0]]),
         outcome="error", message="flat", why="every triangle has zero area (repeated or collinear corners)")

    # --- repairable -----------------------------------------------------------
    case("duplicated_faces.obj", obj_text(V, np.vstack([F, F[:5], F[2:4]])), outcome="ok", volume=1.0,
         why="7 faces stored twice")
    Vd = np.vstack([V, [[0.5, 0.5, 0.5], [0.5, 0.5, 0.5]]])
    Fd = np.vstack([F, [[0, 0, 1], [8, 9, 8], [2, 2, 2]]])
    case("degenerate_triangles.obj", obj_text(Vd, Fd), outcome="ok", volume=1.0,
         why="zero-area triangles (repeated corners) mixed into a closed box")
    case("inverted_normals.obj", obj_text(SV, SF[:, ::-1]), outcome="ok", volume=sphere_volume,
         why="every triangle wound inwards")
    Fo = F[2:]  # the -x side removed
    case("open_box_side.obj", obj_text(V, Fo), outcome="ok",
         why="box with one side missing (large hole: auto shells it into a thin-walled cup)")
    keep = np.ones(len(SF), dtype=bool)
    keep[0] = False
    case("sphere_small_hole.obj", obj_text(SV, SF[keep]), outcome="ok", volume=sphere_volume,
         why="sphere with one triangle missing (small hole: auto fills it)")
    BV, BF, BUV, BN = seamed_box((2.0, 1.0, 0.5))
    case("uv_seams.obj", obj_text(BV, BF, BUV, BN), outcome="ok", volume=1.0,
         why="box split at UV seams (24 vertices, 8 positions)")
    case("uv_no_normals.obj", obj_text(BV, BF, BUV), outcome="ok", volume=1.0,
         why="OBJ with UVs but no normals")
    A = box((1, 1, 1))
    B = box((1, 1, 1), (0.5, 0.25, 0.0))
    case("interpenetrating_boxes.obj", obj_text(*concat(A, B)), outcome="ok", volume=2 - 0.5 * 0.75,
         why="two closed boxes overlapping (self-intersecting as one mesh)")
    shells = concat(box((1, 1, 1)), box((1, 1, 1), (3, 0, 0)), icosphere(1, 0.5, (0, 3, 0)))
    shell_volume = 2.0 + float(trimesh.Trimesh(*icosphere(1, 0.5), process=False).volume)
    case("disconnected_shells.obj", obj_text(*shells), outcome="ok", volume=shell_volume,
         why="three separate closed bodies")
    inner = box((1, 1, 1))
    case("nested_cavity.obj", obj_text(*concat(box((2, 2, 2)), (inner[0], inner[1][:, ::-1]))), outcome="ok",
         volume=7.0, why="closed box with an inward-wound box inside: a cavity")
    case("nested_solid.obj", obj_text(*concat(box((2, 2, 2)), inner)), outcome="ok", volume=8.0,
         why="closed box with an outward-wound box inside (internal geometry, same winding): solid")
    quad = np.array([[-0.4, -0.4, 0.1], [0.4, -0.4, 0.1], [0.4, 0.4, 0.1], [-0.4, 0.4, 0.1]])
    case("internal_faces.obj", obj_text(*concat((V, F), (quad, np.array([[0, 1, 2], [0, 2, 3]])))),
         outcome="ok", volume=1.0, why="closed box with a loose quad floating inside it")
    # Two unit cells side by side sharing their middle wall: the wall's edges have three faces.
    P = np.array([[x, y, z] for x in (0, 1, 2) for y in (0, 1) for z in (0, 1)], dtype=np.float64)

    def vid(x, y, z):
        return x * 4 + y * 2 + z

    def quad_faces(a, b, c, d):
        return [[a, b, c], [a, c, d]]

    walls = []
    walls += quad_faces(vid(0, 0, 0), vid(0, 0, 1), vid(0, 1, 1), vid(0, 1, 0))  # -x
    walls += quad_faces(vid(2, 0, 0), vid(2, 1, 0), vid(2, 1, 1), vid(2, 0, 1))  # +x
    walls += quad_faces(vid(1, 0, 0), vid(1, 1, 0), vid(1, 1, 1), vid(1, 0, 1))  # middle wall
    for x in (0, 1):
        walls += quad_faces(vid(x, 0, 0), vid(x + 1, 0, 0), vid(x + 1, 0, 1), vid(x, 0, 1))  # -y
        walls += quad_faces(vid(x, 1, 0), vid(x, 1, 1), vid(x + 1, 1, 1), vid(x + 1, 1, 0))  # +y
        walls += quad_faces(vid(x, 0, 0), vid(x, 1, 0), vid(x + 1, 1, 0), vid(x + 1, 0, 0))  # -z
        walls += quad_faces(vid(x, 0, 1), vid(x + 1, 0, 1), vid(x + 1, 1, 1), vid(x, 1, 1))  # +z
    case("internal_wall.obj", obj_text(P, np.array(walls)), outcome="ok", volume=2.0,
         why="two cells sharing an internal wall (its edges have three faces), as voxel/CAD exports do")
    C = box((1, 1, 1), (1, 1, 0))
    case("nonmanifold_edge4.obj", obj_text(*concat((V, F), C)), outcome="ok", volume=2.0,
         why="two closed boxes touching along one edge: welded, that edge has four triangles")
    case("millimetres.stl", stl_binary(*icosphere(2, 250.0, (1200.0, -800.0, 40.0))), outcome="ok",
         volume=sphere_volume * 250.0**3, why="binary STL in millimetres (coordinates around 1e3)")
    case("micro.off", off_text(V * 2e-3 + 1e-3, F), outcome="ok", volume=8e-9,
         why="OFF around 1e-3 units")
    OV, OF = icosphere(2, 10.0)
    case("offset_1e6.glb", glb([("far", [(OV + np.array([1.0e6, -2.0e6, 0.5e6]), OF, None, None, 0)])],
                               [Material("stone")]),
         outcome="ok",
         why="float32 GLB of a 20-unit sphere 1e6..2e6 from the origin: positions quantized to 1/16..1/4 unit "
             "(loads with a precision warning)")
    TV, TF = icosphere(1, 0.5, (0, 0, 0))
    top = TV[:, 2] >= 0
    face_top = top[TF].all(axis=1)
    case("two_materials.glb", glb([("jar", [(TV, TF[face_top], None, None, 0),
                                           (TV, TF[~face_top], None, None, 1)])],
                                  [Material("lid", (0.8, 0.2, 0.2, 1.0)), Material("body", (0.2, 0.2, 0.8, 1.0))]),
         outcome="ok", volume=float(trimesh.Trimesh(TV, TF, process=False).volume),
         why="one mesh, two primitives with two materials (the primitives' vertices are split)")
    reader_cases(V, F, SV, SF, sphere_volume)
    from bad_corpus_round3 import add_cases

    add_cases(sys.modules[__name__])  # issue 38: hostile and odd-but-valid inputs, round 3


def reader_cases(V, F, SV, SF, sphere_volume) -> None:
    """Files that only a reader following the format's specification reads right (issue 13)."""
    unit = ((-0.5,) * 3, (0.5,) * 3)
    # glTF sparse accessor: the dense positions are a box squashed flat; the sparse part restores the top corners.
    g = Gltf()
    flat = V.copy()
    top = np.flatnonzero(V[:, 2] > 0)
    flat[top, 2] = -0.5
    pos = g.accessor(flat.astype("<f4"), 5126, "VEC3", sparse={
        "count": len(top), "indices": {"bufferView": g.view(top.astype("<u2").tobytes()), "componentType": 5123},
        "values": {"bufferView": g.view(V[top].astype("<f4").tobytes())}})
    idx = g.accessor(F.reshape(-1).astype("<u1"), 5121, "SCALAR")
    g.node(mesh=g.mesh([{"attributes": {"POSITION": pos}, "indices": idx}]))
    case("sparse.glb", g.glb([0]), outcome="ok", volume=1.0, bbox=unit, reference="sparse.ref.obj",
         companions={"sparse.ref.obj": obj_text(V, F)},
         why="positions in a sparse accessor (dense values flat, the sparse values lift four corners)")
    # KHR_mesh_quantization: normalized int16 positions and int8 normals, dequantized by the node's scale.
    g = Gltf()
    extent = np.array([4.0, 2.0, 1.0])
    q = np.round(V / 0.5 * 32767).astype("<i2")  # corners at +-32767 = +-1.0 normalized
    nrm = np.round(V / np.linalg.norm(V, axis=1, keepdims=True) * 127).astype("i1")
    prim = {"attributes": {"POSITION": g.accessor(q, 5122, "VEC3", normalized=True, min=[-32767] * 3,
                                                  max=[32767] * 3),
                           "NORMAL": g.accessor(np.pad(nrm, ((0, 0), (0, 1))), 5120, "VEC4", normalized=True)},
            "indices": g.accessor(F.reshape(-1).astype("<u2"), 5123, "SCALAR")}
    prim["attributes"]["NORMAL"] = prim["attributes"]["NORMAL"]
    g.doc["accessors"][prim["attributes"]["NORMAL"]]["type"] = "VEC4"
    g.node(mesh=g.mesh([prim]), scale=list(extent / 2))
    g.doc["extensionsUsed"] = g.doc["extensionsRequired"] = ["KHR_mesh_quantization"]
    case("quantized.glb", g.glb([0]), outcome="ok", check="load", volume=8.0, bbox=(-extent / 2, extent / 2),
         why="KHR_mesh_quantization: normalized int16 positions scaled by the node (a 4 x 2 x 1 box, not 65534 wide)")
    # Node hierarchy: one box mesh, instanced under a mirroring parent (scale -1 on x) and a rotated, moved node.
    g = Gltf()
    mesh = g.mesh([box_primitive(g, (1.0, 2.0, 1.0), (1.0, 0.0, 0.0))])
    child = g.node(mesh=mesh, translation=[2.0, 0.0, 0.0])
    mirror = g.node(children=[child], scale=[-1.0, 1.0, 1.0])
    turned = g.node(mesh=mesh, matrix=[0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 1, 0, 0, 5, 0, 1])  # 90 deg about z, y += 5
    case("mirrored_nodes.glb", g.glb([mirror, turned]), outcome="ok", check="load", volume=4.0,
         bbox=((-3.5, -1.0, -0.5), (1.0, 6.5, 0.5)),
         why="node hierarchy: a box under a mirroring parent (winding must flip) and one placed by a matrix")
    # extensionsRequired that cannot be read.
    g = Gltf()
    g.node(mesh=g.mesh([box_primitive(g)]))
    g.doc["extensionsUsed"] = g.doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    case("draco_required.glb", g.glb([0]), outcome="error", message="KHR_draco_mesh_compression",
         why="requires Draco decompression (refused by the extension's name, never read as an empty or flat mesh)")
    g.doc["extensionsUsed"] = g.doc["extensionsRequired"] = ["EXT_made_up_geometry"]
    text, _ = g.gltf([0], "unused.bin")
    case("unknown_required.gltf", text, outcome="error", message="EXT_made_up_geometry",
         why="requires an extension nobody knows")
    # A percent-encoded uri, and a short external buffer.
    g = Gltf()
    g.node(mesh=g.mesh([box_primitive(g)]))
    text, binary = g.gltf([0], "box%20data%231.bin")
    case("percent_uri.gltf", text, outcome="ok", check="load", volume=1.0, bbox=unit,
         companions={"box data#1.bin": binary}, why="buffer uri 'box%20data%231.bin' (percent-encoded file name)")
    text, binary = g.gltf([0], "short_buffer.bin")
    case("short_buffer.gltf", text, outcome="error", message="has 40 bytes but buffer 0 needs",
         companions={"short_buffer.bin": binary[:40]}, why="the external .bin is shorter than its byteLength")
    # Two materials with one name.
    g = Gltf()
    g.doc["materials"] = [{"name": "paint", "pbrMetallicRoughness": {"baseColorFactor": [1, 0, 0, 1]}},
                          {"name": "paint", "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 1, 1]}}]
    g.node(mesh=g.mesh([box_primitive(g, material=0), box_primitive(g, centre=(2.0, 0.0, 0.0), material=1)]))
    case("shared_material_name.glb", g.glb([0]), outcome="ok", check="load", volume=2.0,
         bbox=((-0.5,) * 3, (2.5, 0.5, 0.5)), why="two materials named 'paint' (red and blue) stay two materials")
    # OBJ relative indices, index 0, a relative index before the first vertex.
    case("obj_relative.obj", relative_obj(), outcome="ok", check="load", volume=2.0,
         bbox=((-0.5,) * 3, (3.5, 0.5, 0.5)), reference="obj_relative.ref.obj",
         companions={"obj_relative.ref.obj": obj_text(*concat(box(), box((1, 1, 1), (3, 0, 0))))},
         why="two boxes, each with faces -8..-1 right after its own vertices (relative to that line)")
    case("obj_index_zero.obj", obj_text(V, F).replace("f 1 2 4", "f 0 2 4"), outcome="error", message="face index 0",
         why="OBJ index 0 does not exist (indices start at 1)")
    case("obj_relative_too_far.obj", obj_text(V, F) + "f -1 -2 -9\n", outcome="error",
         message="reaches before the first vertex", why="relative index -9 with 8 vertices above")
    # PLY triangle strips.
    case("tristrips.ply", tristrip_box_ply(), outcome="ok", volume=1.0, bbox=unit, reference="tristrips.ref.obj",
         companions={"tristrips.ref.obj": obj_text(V, F)}, check="load",
         why="PLY 'element tristrips' (two strips of different lengths, -1 restarts), as scan archives store meshes")
    # Binary STL whose header starts with 'solid' and whose count is wrong.
    solid = stl_binary(SV, SF, count=0)
    solid = b"solid exported by a CAD tool".ljust(80, b" ") + solid[80:]
    case("stl_solid_header.stl", solid, outcome="ok", check="load", volume=sphere_volume,
         bbox=(SV.min(axis=0), SV.max(axis=0)),
         why="binary STL with 320 triangles whose header starts with 'solid' and whose count field says 0")
    # A double-sided closed surface.
    case("double_sided_sphere.obj", obj_text(*concat((SV, SF), (SV, SF[:, ::-1]))), outcome="ok",
         volume=sphere_volume, bbox=(SV.min(axis=0), SV.max(axis=0)),
         why="a sphere stored twice, once facing in (double-sided export): one side is kept, not 'flat'")


def write_toml(cases: list[dict]) -> str:
    lines = ["# Expected outcome of `fracture bake` on each file (written by make_bad_corpus.py).",
             "# outcome = \"ok\": bakes into closed fragments; volume (input units) when known.",
             "# outcome = \"error\": exit code 1, one line naming the file and containing `message`.", ""]
    for c in cases:
        lines.append("[[case]]")
        lines.append(f"file = {json.dumps(c['file'])}")
        lines.append(f"outcome = {json.dumps(c['outcome'])}")
        if c["message"]:
            lines.append(f"message = {json.dumps(c['message'])}")
        if c["volume"] is not None:
            lines.append(f"volume = {c['volume']!r}")
        if c["overrides"]:
            lines.append("overrides = [" + ", ".join(json.dumps(o) for o in c["overrides"]) + "]")
        lines.append(f"why = {json.dumps(c['why'])}")
        if c["known_issue"]:
            lines.append(f"known_issue = {json.dumps(c['known_issue'])}")
        if c["check"] != "bake":
            lines.append(f"check = {json.dumps(c['check'])}")
        if c["bbox"] is not None:
            lines.append(f"bbox = {json.dumps(c['bbox'])}")
        if c["reference"]:
            lines.append(f"reference = {json.dumps(c['reference'])}")
        if c["companions"]:
            lines.append(f"companions = {json.dumps(sorted(c['companions']))}")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    build()
    os.makedirs(OUT, exist_ok=True)
    total = 0
    for c in CASES:
        for name, data in [(c["file"], c["data"]), *c["companions"].items()]:
            data = data.encode() if isinstance(data, str) else data
            with open(os.path.join(OUT, name), "wb") as fh:
                fh.write(data)
            total += len(data)
    with open(os.path.join(OUT, "expected.toml"), "w") as fh:
        fh.write(write_toml(CASES))
    print(f"wrote {len(CASES)} files ({total / 1024:.1f} KiB) and expected.toml to {OUT}")


if __name__ == "__main__":
    main()
