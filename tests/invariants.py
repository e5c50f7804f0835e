"""Independent invariant checks on baked fragment meshes, as written in the GLB.

Test code only: it reads the GLB bytes with its own minimal reader and uses
numpy/scipy, never ``fracture_cli``'s geometry, so a bug in the library's own
checks (``fracture_cli.geometry.weld_check``, the report's ``watertight``)
cannot hide the same bug here.

Every fragment (a node with a mesh; all its primitives together) is welded by
exact position in the node's own coordinates (the float32 values stored), and
must be a closed, consistently oriented 2-manifold body:

* every edge in exactly two faces, run in opposite directions (no open,
  pinched or misoriented edges), no face with two corners at one position;
* one body: its faces connected through those two-face edges;
* positive volume;

and the set of fragments must have volumes summing to the input solid's
volume and lie inside the input's bounding box (1e-6 of its diagonal).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

_COMPONENT_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
                     5126: np.float32}
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_TRIANGLES = 4


# ----------------------------------------------------------------------------
# Reading


@dataclass(frozen=True)
class GlbFragment:
    """One node's mesh as written: local positions (float32 values as float64), faces, node-to-world matrix."""

    name: str
    positions: np.ndarray  # (n, 3) float64, exactly the stored float32 values
    faces: np.ndarray  # (m, 3) int64 into positions (all primitives of the mesh)
    matrix: np.ndarray  # (4, 4) local -> world


def _glb_chunks(data: bytes) -> tuple[dict, bytes]:
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF" or version != 2 or length != len(data):
        raise ValueError("not a GLB 2.0 file of the stated length")
    offset, doc, binary = 12, None, b""
    while offset < length:
        chunk_length, chunk_type = struct.unpack_from("<II", data, offset)
        body = data[offset + 8: offset + 8 + chunk_length]
        if chunk_type == 0x4E4F534A:
            doc = json.loads(body.decode("utf-8"))
        elif chunk_type == 0x004E4942:
            binary = body
        offset += 8 + chunk_length
    if doc is None:
        raise ValueError("GLB without a JSON chunk")
    return doc, binary


def _accessor(doc: dict, binary: bytes, index: int) -> np.ndarray:
    acc = doc["accessors"][index]
    dtype = np.dtype(_COMPONENT_DTYPES[acc["componentType"]]).newbyteorder("<")
    width = _TYPE_SIZES[acc["type"]]
    count = acc["count"]
    view = doc["bufferViews"][acc["bufferView"]]
    if view.get("buffer", 0) != 0:
        raise ValueError("only the GLB's own binary buffer is supported")
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride", dtype.itemsize * width)
    rows = np.ndarray((count, width), dtype=dtype, buffer=binary, offset=start, strides=(stride, dtype.itemsize))
    return np.array(rows)


def _node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T  # glTF stores column-major
    x, y, z, w = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    rotation = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    M = np.eye(4)
    M[:3, :3] = rotation * np.asarray(node.get("scale", [1.0, 1.0, 1.0]), dtype=np.float64)
    M[:3, 3] = node.get("translation", [0.0, 0.0, 0.0])
    return M


def read_glb_fragments(path: str) -> list[GlbFragment]:
    """Every mesh node of a GLB's default scene, with its world matrix, in scene order."""
    with open(path, "rb") as fh:
        doc, binary = _glb_chunks(fh.read())
    scene = doc.get("scenes", [{"nodes": list(range(len(doc.get("nodes", []))))}])[doc.get("scene", 0)]
    out: list[GlbFragment] = []

    def visit(index: int, parent: np.ndarray) -> None:
        node = doc["nodes"][index]
        M = parent @ _node_matrix(node)
        if "mesh" in node:
            mesh = doc["meshes"][node["mesh"]]
            positions, faces, n = [], [], 0
            for prim in mesh["primitives"]:
                if prim.get("mode", _TRIANGLES) != _TRIANGLES:
                    raise ValueError(f"{path}: primitive mode {prim['mode']} is not triangles")
                P = _accessor(doc, binary, prim["attributes"]["POSITION"]).astype(np.float64)
                if "indices" in prim:
                    idx = _accessor(doc, binary, prim["indices"]).reshape(-1).astype(np.int64)
                else:
                    idx = np.arange(len(P), dtype=np.int64)
                positions.append(P)
                faces.append(idx.reshape(-1, 3) + n)
                n += len(P)
            name = node.get("name", mesh.get("name", f"node_{index}"))
            out.append(GlbFragment(name, np.vstack(positions) if positions else np.zeros((0, 3)),
                                   np.vstack(faces) if faces else np.zeros((0, 3), np.int64), M))
        for child in node.get("children", []):
            visit(child, M)

    for root in scene["nodes"]:
        visit(root, np.eye(4))
    return out


def read_collision_parts(path: str) -> list[tuple[str, np.ndarray]]:
    """Every convex part of a GLB's ``OMI_physics_shape`` colliders: ``(owner node name, world corners (k, 3))``."""
    with open(path, "rb") as fh:
        doc, binary = _glb_chunks(fh.read())
    shapes = doc.get("extensions", {}).get("OMI_physics_shape", {}).get("shapes", [])
    out: list[tuple[str, np.ndarray]] = []

    def visit(index: int, parent: np.ndarray, owner: str) -> None:
        node = doc["nodes"][index]
        M = parent @ _node_matrix(node)
        collider = node.get("extensions", {}).get("OMI_physics_body", {}).get("collider")
        if collider is not None:
            shape = shapes[collider["shape"]]
            mesh = doc["meshes"][shape[shape["type"]]["mesh"]]
            points = np.vstack([_accessor(doc, binary, p["attributes"]["POSITION"]).astype(np.float64)
                                for p in mesh["primitives"]])
            out.append((owner, points @ M[:3, :3].T + M[:3, 3]))
        for child in node.get("children", []):
            visit(child, M, node.get("name", owner))

    scene = doc["scenes"][doc.get("scene", 0)]
    for root in scene["nodes"]:
        visit(root, np.eye(4), "")
    return out


def read_triangles(path: str) -> np.ndarray:
    """World-space triangles (m, 3, 3) of an input file: GLB and binary STL read here, other formats by trimesh."""
    lower = path.lower()
    if lower.endswith(".glb"):
        tris = []
        for frag in read_glb_fragments(path):
            world = frag.positions @ frag.matrix[:3, :3].T + frag.matrix[:3, 3]
            tris.append(world[frag.faces])
        return np.concatenate(tris) if tris else np.zeros((0, 3, 3))
    if lower.endswith(".stl"):
        with open(path, "rb") as fh:
            data = fh.read()
        if not data.startswith(b"solid") or len(data) == 84 + 50 * struct.unpack_from("<I", data, 80)[0]:
            count = struct.unpack_from("<I", data, 80)[0]
            rec = np.frombuffer(data, dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")], count=count,
                                offset=84)
            return rec["v"].astype(np.float64)
    import trimesh

    scene = trimesh.load_scene(path, process=False)
    return np.concatenate([np.asarray(g.triangles) for g in scene.dump()]).astype(np.float64)  # type: ignore


# ----------------------------------------------------------------------------
# Checking


@dataclass(frozen=True)
class FragmentCheck:
    """Invariants of one fragment, welded by exact position (counts of violations, volume in world units)."""

    name: str
    triangles: int
    open_edges: int
    pinched_edges: int
    misoriented_edges: int
    degenerate_faces: int
    components: int
    pinched_vertices: int
    volume: float
    bbox_min: np.ndarray
    bbox_max: np.ndarray

    @property
    def problems(self) -> list[str]:
        """One phrase per violated invariant (empty when the fragment is a closed manifold body)."""
        out = []
        for label, count in (("open edges", self.open_edges), ("pinched edges (3+ faces)", self.pinched_edges),
                             ("misoriented edges", self.misoriented_edges),
                             ("degenerate faces", self.degenerate_faces)):
            if count:
                out.append(f"{count} {label}")
        if self.components != 1:
            out.append(f"{self.components} bodies")
        if not self.volume > 0:
            out.append(f"volume {self.volume:.3g}")
        return out

    @property
    def ok(self) -> bool:
        """No violated invariant."""
        return not self.problems


def weld_by_position(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces (m, 3) over position ids: vertices with exactly equal coordinates are one vertex."""
    _, pos = np.unique(positions, axis=0, return_inverse=True)
    return pos.reshape(-1)[faces]


def edge_topology(W: np.ndarray) -> dict:
    """Undirected edge statistics of welded faces W (m, 3).

    Returns a dict: ``edge`` (3m,) undirected edge id per face side, ``count``
    (e,) faces per edge, ``balance`` (e,) forward minus backward runs,
    ``face`` (3m,) the face of each side, ``directed`` (3m, 2).
    """
    directed = np.concatenate([W[:, [0, 1]], W[:, [1, 2]], W[:, [2, 0]]])
    face = np.tile(np.arange(len(W)), 3)
    lo, hi = directed.min(axis=1), directed.max(axis=1)
    n = int(W.max()) + 1 if len(W) else 1
    _, edge = np.unique(lo * n + hi, return_inverse=True)
    edge = edge.reshape(-1)
    count = np.bincount(edge)
    balance = np.bincount(edge, weights=np.where(directed[:, 0] < directed[:, 1], 1, -1)).astype(np.int64)
    return {"edge": edge, "count": count, "balance": balance, "face": face, "directed": directed}


def _manifold_pairs(topo: dict) -> np.ndarray:
    """Side indices (k, 2) of the two faces of every edge that has exactly two."""
    order = np.argsort(topo["edge"], kind="stable")
    two = topo["count"][topo["edge"][order]] == 2
    return order[two].reshape(-1, 2)


def _face_components(m: int, topo: dict) -> int:
    pairs = _manifold_pairs(topo)
    f = topo["face"]
    graph = sp.coo_matrix((np.ones(len(pairs)), (f[pairs[:, 0]], f[pairs[:, 1]])), shape=(m, m))
    return int(connected_components(graph, directed=False)[0]) if m else 0


def _pinched_vertices(W: np.ndarray, topo: dict) -> int:
    """Vertices whose corners form more than one fan (joined across two-face edges through the vertex)."""
    m = len(W)
    pairs = _manifold_pairs(topo)
    f, directed = topo["face"], topo["directed"]
    rows, cols = [], []
    # The corner of face f at vertex v is 3 f + the position of v in W[f].
    fa, fb = f[pairs[:, 0]], f[pairs[:, 1]]
    for end in (0, 1):
        v = directed[pairs[:, 0], end]
        ca = 3 * fa + np.argmax(W[fa] == v[:, None], axis=1)
        cb = 3 * fb + np.argmax(W[fb] == v[:, None], axis=1)
        rows.append(ca)
        cols.append(cb)
    graph = sp.coo_matrix((np.ones(sum(len(r) for r in rows)), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(3 * m, 3 * m))
    _, fan = connected_components(graph, directed=False)
    vertex = W.reshape(-1)
    fans = np.unique(np.column_stack([vertex, fan]), axis=0)
    return int((np.bincount(fans[:, 0]) > 1).sum())


def check_fragment(frag: GlbFragment) -> FragmentCheck:
    """Check one fragment as written (see the module docstring)."""
    W = weld_by_position(frag.positions, frag.faces)
    degenerate = (W[:, 0] == W[:, 1]) | (W[:, 1] == W[:, 2]) | (W[:, 2] == W[:, 0])
    topo = edge_topology(W[~degenerate])
    count, balance = topo["count"], topo["balance"]
    world = frag.positions @ frag.matrix[:3, :3].T + frag.matrix[:3, 3]
    P = frag.positions
    centre = P.mean(axis=0) if len(P) else np.zeros(3)
    a, b, c = (P[frag.faces[:, k]] - centre for k in range(3))
    volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0) * float(np.linalg.det(frag.matrix[:3, :3]))
    return FragmentCheck(
        name=frag.name,
        triangles=len(frag.faces),
        open_edges=int((count == 1).sum()),
        pinched_edges=int((count > 2).sum()),
        misoriented_edges=int(((count == 2) & (balance != 0)).sum()),
        degenerate_faces=int(degenerate.sum()),
        components=_face_components(int((~degenerate).sum()), topo),
        pinched_vertices=_pinched_vertices(W[~degenerate], topo) if (~degenerate).any() else 0,
        volume=volume,
        bbox_min=world.min(axis=0) if len(world) else np.zeros(3),
        bbox_max=world.max(axis=0) if len(world) else np.zeros(3),
    )


@dataclass(frozen=True)
class GlbCheck:
    """Invariants of all fragments of one baked GLB."""

    fragments: tuple[FragmentCheck, ...]
    total_volume: float
    reference_volume: float | None
    volume_error: float | None
    bbox_excess: float | None  # how far fragments leave the reference box, relative to its diagonal
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Every fragment and the set as a whole pass."""
        return not self.problems

    @property
    def failing(self) -> list[FragmentCheck]:
        """The fragments with a violated invariant."""
        return [f for f in self.fragments if not f.ok]

    def summary(self) -> dict:
        """Counts for tables and messages: fragments, failing fragments and their kinds of violation."""
        kinds: dict[str, int] = {}
        for f in self.fragments:
            for label, value in (("open", f.open_edges), ("pinched", f.pinched_edges),
                                 ("misoriented", f.misoriented_edges), ("degenerate", f.degenerate_faces),
                                 ("multi_body", int(f.components != 1)), ("nonpositive", int(not f.volume > 0)),
                                 ("pinched_vertices", f.pinched_vertices)):
                if value:
                    kinds[label] = kinds.get(label, 0) + 1
        return {"fragments": len(self.fragments), "failing": len(self.failing), "fragments_with": kinds,
                "volume": self.total_volume, "volume_error": self.volume_error, "bbox_excess": self.bbox_excess}


def check_glb(path: str, *, reference_volume: float | None = None, volume_tolerance: float = 1e-3,
              reference_box: np.ndarray | None = None, box_tolerance: float = 1e-6) -> GlbCheck:
    """Check every fragment of a baked GLB and the set as a whole.

    Parameters
    ----------
    path : str
        The baked ``<stem>.glb``.
    reference_volume : float, optional
        The input solid's volume (world units); the fragments' volumes must sum to
        it within ``volume_tolerance`` (relative).
    reference_box : (2, 3) float, optional
        The input's bounding box; fragments must stay inside it within
        ``box_tolerance`` of its diagonal.

    Returns
    -------
    GlbCheck
        ``problems`` lists one line per violation (fragment name and what).
    """
    checks = tuple(check_fragment(f) for f in read_glb_fragments(path))
    problems = [f"{c.name}: {', '.join(c.problems)}" for c in checks if not c.ok]
    if not checks:
        problems.append("no fragments")
    total = float(sum(c.volume for c in checks))
    error = None
    if reference_volume is not None:
        error = abs(total - reference_volume) / abs(reference_volume)
        if error > volume_tolerance:
            problems.append(f"fragment volumes sum to {total:.6g}, the input solid has {reference_volume:.6g} "
                            f"(error {error:.3g} > {volume_tolerance:g})")
    excess = None
    if reference_box is not None and checks:
        lo, hi = np.asarray(reference_box[0], dtype=np.float64), np.asarray(reference_box[1], dtype=np.float64)
        diagonal = float(np.linalg.norm(hi - lo))
        low = np.min([c.bbox_min for c in checks], axis=0)
        high = np.max([c.bbox_max for c in checks], axis=0)
        excess = float(max(np.max(lo - low), np.max(high - hi), 0.0) / diagonal)
        if excess > box_tolerance:
            problems.append(f"fragments leave the input's bounding box by {excess:.3g} of its diagonal "
                            f"(> {box_tolerance:g})")
    return GlbCheck(checks, total, reference_volume, error, excess, problems)


def input_box(path: str) -> np.ndarray:
    """Bounding box (2, 3) of an input file's triangles, world units."""
    tris = read_triangles(path).reshape(-1, 3)
    return np.stack([tris.min(axis=0), tris.max(axis=0)])
