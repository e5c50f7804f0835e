"""Write the real-world mesh corpus in tests/data/realworld/ (run from anywhere).

Procedural stand-ins for the inputs artists actually have (issue 15): open
multi-body heads, scans with holes, non-manifold gear-like bodies, a triangle
soup, an open sheet, a teapot of open bodies, a 32-triangle model, a coarse
blob of overlapping bodies and fragments touching along faces; and (issue 39,
shapes in artist_shapes.py, ``recipes = "all"``: baked with every built-in
recipe) a closed teapot of touching parts, an open pot, a bust with a
non-planar hole, thin gear teeth, a truck of touching bodies, overlapping
boxes touching along edges, fins on a solid, a wall with a window far from
the origin, a soup of many rocks and a GLB with an unpadded chunk. Every file is
small and deterministic (fixed seeds, no timestamps); ``expected.toml`` beside
them says what a bake of each must give and why.

    python tests/data/make_realworld_corpus.py

The files are committed; re-run this script after changing it and commit the
result. tests/test_realworld.py bakes every entry and checks the written
fragments with tests/invariants.py (independent of the library's geometry).
"""

from __future__ import annotations

import functools
import itertools
import json
import math
import os
import struct
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "realworld")
sys.path.insert(0, os.path.dirname(os.path.dirname(HERE)))

# fracture_cli first: it pins the numeric kernels before numpy loads (fracture_cli/system/numeric_env.py).
import fracture_cli  # noqa: E402, F401, I001

import numpy as np  # noqa: E402

from fracture_cli.system import detmath  # noqa: E402
from fracture_cli.io.gltf import Primitive, glb_bytes  # noqa: E402  (after the sys.path line)
from fracture_cli.types import Material  # noqa: E402

def _sin(x):
    """sin with the same bits on every CPU (libm's rounds by the CPU, and the corpus must regenerate exactly)."""
    return detmath.sin_cos(x)[0]


def _cos(x):
    """cos with the same bits on every CPU (see :func:`_sin`)."""
    return detmath.sin_cos(x)[1]


# ----------------------------------------------------------------------------
# Shapes (world units, outward winding unless said otherwise)


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: vertices (n, 3) on the sphere, outward faces (m, 3)."""
    V, F = _icosphere(subdivisions)
    return V.copy(), F.copy()


@functools.cache
def _icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    t = (1.0 + math.sqrt(5.0)) / 2.0
    V = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
         [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    F = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11],
         [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    verts = [np.array(v, dtype=np.float64) / np.linalg.norm(v) for v in V]
    faces = [tuple(f) for f in F]
    for _ in range(subdivisions):
        midpoint: dict[tuple[int, int], int] = {}
        nxt = []
        for a, b, c in faces:
            ab, bc, ca = (_midpoint(verts, midpoint, u, v) for u, v in ((a, b), (b, c), (c, a)))
            nxt += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = nxt
    return np.array(verts), np.array(faces, dtype=np.int64)


def _midpoint(verts: list[np.ndarray], midpoint: dict[tuple[int, int], int], a: int, b: int) -> int:
    """Index of the unit-sphere midpoint of edge (a, b), appended to ``verts`` once."""
    key = (min(a, b), max(a, b))
    if key not in midpoint:
        m = verts[a] + verts[b]
        verts.append(m / np.linalg.norm(m))
        midpoint[key] = len(verts) - 1
    return midpoint[key]


def bumpy(V: np.ndarray, amplitude: float, seed: int) -> np.ndarray:
    """Scale unit-sphere points radially by a smooth random field (a few low-frequency waves)."""
    rng = np.random.default_rng(seed)
    r = np.ones(len(V))
    for _ in range(6):
        k = rng.normal(size=3) * 2.5
        r += amplitude / 6.0 * _sin(V @ k + rng.uniform(0, 2 * np.pi))
    return V * r[:, None]


def prism(polygon: np.ndarray, z0: float, z1: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed prism over a convex counter-clockwise polygon (k, 2): 2k vertices, 4k - 4 faces."""
    k = len(polygon)
    V = np.vstack([np.column_stack([polygon, np.full(k, z0)]), np.column_stack([polygon, np.full(k, z1)])])
    F = []
    for i in range(1, k - 1):
        F.append([0, i + 1, i])  # bottom, facing -z
        F.append([k, k + i, k + i + 1])  # top, facing +z
    for i in range(k):
        j = (i + 1) % k
        F.append([i, j, k + j])
        F.append([i, k + j, k + i])
    return V, np.array(F, dtype=np.int64)


def revolve(profile: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Surface of revolution about +z of a profile (k, 2) of (radius, z), bottom to top.

    A profile point with radius 0 is a pole (one vertex); elsewhere the surface
    is open where the profile ends. Faces point away from the axis when the
    profile runs upwards.
    """
    angles = 2 * np.pi * np.arange(segments) / segments
    rings: list[np.ndarray] = []
    V: list[np.ndarray] = []
    for r, z in profile:
        start = len(V)
        if r == 0.0:
            V.append(np.array([0.0, 0.0, z]))
            rings.append(np.full(segments, start))
        else:
            V.extend(np.column_stack([r * _cos(angles), r * _sin(angles), np.full(segments, z)]))
            rings.append(start + np.arange(segments))
    F = []
    for lower, upper in itertools.pairwise(rings):
        for i in range(segments):
            j = (i + 1) % segments
            tri1, tri2 = [lower[i], lower[j], upper[j]], [lower[i], upper[j], upper[i]]
            F += [t for t in (tri1, tri2) if len(set(t)) == 3]
    return np.array(V), np.array(F, dtype=np.int64)


def tube(path: np.ndarray, radii: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Open tube (no end caps) along a polyline path (k, 3) with radii (k,); faces point outward."""
    tangents = np.gradient(path, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    helper = np.array([0.0, 1.0, 0.0])
    angles = 2 * np.pi * np.arange(segments) / segments
    V = []
    for p, t, r in zip(path, tangents, radii):
        u = np.cross(t, helper)
        u /= np.linalg.norm(u)
        w = np.cross(t, u)
        V.extend(p + r * (_cos(angles)[:, None] * u + _sin(angles)[:, None] * w))
    F = []
    for a in range(len(path) - 1):
        for i in range(segments):
            j = (i + 1) % segments
            p0, p1, q0, q1 = a * segments + i, a * segments + j, (a + 1) * segments + i, (a + 1) * segments + j
            F += [[p0, p1, q1], [p0, q1, q0]]
    return np.array(V), np.array(F, dtype=np.int64)


def grid_faces(nx: int, ny: int) -> np.ndarray:
    """Faces (2 (nx - 1)(ny - 1), 3) of an nx x ny vertex grid (vertex i * ny + j), two per cell."""
    F = []
    for i in range(nx - 1):
        for j in range(ny - 1):
            a, b, c, d = i * ny + j, (i + 1) * ny + j, (i + 1) * ny + j + 1, i * ny + j + 1
            F += [[a, b, c], [a, c, d]]
    return np.array(F, dtype=np.int64)


def concat(*parts: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    V, F, n = [], [], 0
    for v, f in parts:
        V.append(v)
        F.append(np.asarray(f) + n)
        n += len(v)
    return np.vstack(V), np.vstack(F)


def areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)


def volume(V: np.ndarray, F: np.ndarray) -> float:
    return float(np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0)


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    acc = np.zeros_like(V)
    for k in range(3):
        np.add.at(acc, F[:, k], fn)
    return acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-300)


def drop_faces(V: np.ndarray, F: np.ndarray, remove: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Remove faces (mask (m,)) and unreferenced vertices."""
    F = F[~remove]
    used, local = np.unique(F, return_inverse=True)
    return V[used], local.reshape(-1, 3)


# ----------------------------------------------------------------------------
# Writers


def glb(bodies: list[tuple[str, np.ndarray, np.ndarray]], materials: tuple[Material, ...] = (Material("surface"),),
        uvs: bool = True) -> bytes:
    """One node and mesh per body (name, V, F); normals from the faces, spherical UVs."""
    meshes = []
    for name, V, F in bodies:
        N = vertex_normals(V, F)
        UV = None
        if uvs:
            c = V - V.mean(axis=0)
            UV = np.column_stack([detmath.atan2(c[:, 1], c[:, 0]) / (2 * np.pi) + 0.5,
                                  c[:, 2] / max(np.ptp(c[:, 2]), 1e-9) + 0.5])
        meshes.append((name, [Primitive(positions=V, normals=N, uvs=UV, indices=F, material=0)]))
    return glb_bytes(meshes, materials)


def stl_binary(tris: np.ndarray) -> bytes:
    """Binary STL of triangles (m, 3, 3), normals left zero (as many exporters do)."""
    rec = np.zeros(len(tris), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec["v"] = tris
    return b"fracture realworld corpus: triangle soup".ljust(80, b" ") + struct.pack("<I", len(tris)) + rec.tobytes()


# ----------------------------------------------------------------------------
# The entries


def scan_with_holes(fraction: float, seed: int = 11) -> tuple[np.ndarray, np.ndarray, float, float]:
    """A bumpy closed blob with five round holes totalling ``fraction`` of its area.

    Returns the open mesh, the realized hole fraction and the closed blob's volume.
    """
    S, F = icosphere(4)
    V = bumpy(S, 0.25, seed) * np.array([1.0, 0.8, 0.7])
    face_area = areas(V, F)
    total = face_area.sum()
    centres = np.array([[1, 0.2, 0.1], [-0.3, 1, 0.3], [0.1, -0.4, 1], [-1, -0.5, -0.2], [0.3, 0.2, -1]],
                       dtype=np.float64)
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    weights = np.array([1.0, 0.6, 0.45, 0.3, 0.2])  # holes of different sizes, like a real scan

    def removed(scale: float) -> np.ndarray:
        # A vertex-based cap (every face touching a vertex inside) keeps each hole a simple disk.
        inside_v = np.zeros(len(S), dtype=bool)
        for c, w in zip(centres, weights):
            inside_v |= S @ c > 1.0 - scale * w
        return inside_v[F].any(axis=1)

    lo, hi = 0.0, 0.5
    for _ in range(60):
        mid = (lo + hi) / 2
        if face_area[removed(mid)].sum() / total < fraction:
            lo = mid
        else:
            hi = mid
    cut = removed(hi)
    realized = float(face_area[cut].sum() / total)
    OV, OF = drop_faces(V, F, cut)
    return OV, OF, realized, volume(V, F)


def head_with_open_eyes():
    """A closed bumpy head and two open hemispherical eye shells whose rims sit inside it (like Suzanne)."""
    S, F = icosphere(3)
    head = bumpy(S, 0.08, 3) * np.array([0.8, 0.9, 1.0])
    bodies = [("head", head, F)]
    E, EF = icosphere(2)
    keep = (E[EF][:, :, 1].mean(axis=1) > -0.25)  # a bit more than the front half: the rim is a circle
    for side, x in (("eye_left", -0.3), ("eye_right", 0.3)):
        centre = np.array([x, 0.72, 0.25])
        V, Fe = drop_faces(E * 0.2 + centre, EF, ~keep)
        bodies.append((side, V, Fe))
    return bodies


def gear_edge_contact(teeth: int = 8):
    """An octagonal hub prism and closed wedge teeth, each touching the hub only along a vertical hub edge."""
    angles = 2 * np.pi * (np.arange(teeth) + 0.5) / teeth
    hub_poly = np.column_stack([_cos(angles), _sin(angles)])
    bodies = [("hub", *prism(hub_poly, -0.2, 0.2))]
    half = np.radians(18)
    for i, a in enumerate(angles):
        apex = hub_poly[i]
        left = apex + 0.45 * np.array([_cos(a + half), _sin(a + half)])
        right = apex + 0.45 * np.array([_cos(a - half), _sin(a - half)])
        bodies.append((f"tooth_{i}", *prism(np.array([apex, right, left]), -0.2, 0.2)))
    return bodies


def gear_coplanar(teeth: int = 8):
    """A 16-sided hub and box teeth on every other side, their base faces triangulated the other way.

    Each tooth's base quad has the hub side's four corners, so the four quad
    edges are shared by four faces (hub side, hub cap or neighbour, tooth base,
    tooth side) and the coincident faces are not identical triangles.
    """
    sides = 2 * teeth
    angles = 2 * np.pi * np.arange(sides) / sides
    hub_poly = np.column_stack([_cos(angles), _sin(angles)])
    bodies = [("hub", *prism(hub_poly, -0.15, 0.15))]
    for i in range(0, sides, 2):
        a, b = hub_poly[i], hub_poly[i + 1]
        outward = (a + b) / np.linalg.norm(a + b)
        poly = np.array([b, a, a + 0.3 * outward + 0.05 * (b - a), b + 0.3 * outward - 0.05 * (b - a)])
        V, F = prism(poly, -0.15, 0.15)
        # prism() splits the side quad (poly[0], poly[1]) along the diagonal poly[0]-top(poly[1]); the hub splits
        # the same quad (a=hub i, b=hub i+1) along a-top(b). poly[0]=b, so the diagonals differ.
        bodies.append((f"tooth_{i // 2}", V, F))
    return bodies


def vertex_contact():
    """Two boxes touching at one corner, and a third touching the second along an edge."""
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    a = prism(square * 0.5, 0.0, 0.5)
    b = prism(square * 0.5 + 0.5, 0.5, 1.0)
    c = prism(square * 0.5 + np.array([1.0, 0.5]), 0.0, 0.5)
    return [("box_a", *a), ("box_b", *b), ("box_c", *c)]


def triangle_soup(seed: int = 5):
    """Triangles (m, 3, 3) of a closed blob: unwelded, 10% duplicated (random winding), every winding random."""
    rng = np.random.default_rng(seed)
    S, F = icosphere(3)
    V = bumpy(S, 0.2, 9) * np.array([1.0, 0.7, 0.5])
    closed_volume = volume(V, F)
    dup = rng.choice(len(F), size=len(F) // 10, replace=False)
    F = np.vstack([F, F[dup]])
    flip = rng.random(len(F)) < 0.5
    F[flip] = F[flip][:, ::-1]
    F = F[rng.permutation(len(F))]
    return V[F], closed_volume


def awning_sheet():
    """An open curved sheet without thickness: a wavy half-cylinder awning, normals facing outward (up)."""
    theta = np.linspace(-np.pi / 2, np.pi / 2, 25)
    y = np.linspace(-1.0, 1.0, 17)
    T, Y = np.meshgrid(theta, y, indexing="ij")
    R = 0.8 * (1 + 0.04 * _sin(3 * Y) * _cos(T))
    V = np.column_stack([(R * _sin(T)).ravel(), Y.ravel(), (R * _cos(T)).ravel()])
    return V, grid_faces(*T.shape)


def teapot():
    """Four open bodies: a body open at the top, a lid open at its rim, an open spout and an open handle."""
    body_profile = np.array([[0.0, 0.0], [0.55, 0.0], [0.75, 0.15], [0.85, 0.4], [0.8, 0.65], [0.62, 0.85],
                             [0.55, 0.9]])
    lid_profile = np.array([[0.53, 0.87], [0.5, 0.95], [0.3, 1.02], [0.08, 1.05], [0.08, 1.12], [0.0, 1.14]])
    body = revolve(body_profile, 24)
    lid = revolve(lid_profile, 24)
    s = np.linspace(0, 1, 9)[:, None]
    spout_path = (1 - s) * (1 - s) * np.array([0.55, 0, 0.3]) + 2 * s * (1 - s) * np.array([1.05, 0, 0.35]) \
        + s * s * np.array([1.25, 0, 0.8])
    spout = tube(spout_path, np.linspace(0.14, 0.06, 9), 10)
    u = np.linspace(0, np.pi, 11)
    handle_path = np.column_stack([-0.55 - 0.55 * _sin(u), np.zeros(11), 0.45 + 0.28 * _cos(u)])
    handle = tube(handle_path, np.full(11, 0.06), 8)
    return [("body", *body), ("lid", *lid), ("spout", *spout), ("handle", *handle)]


def two_prisms():
    """32 triangles: two pentagonal prisms touching along a side, the second raised by a third of its height."""
    a = 2 * np.pi * np.arange(5) / 5
    pent = np.column_stack([_cos(a), _sin(a)])  # a vertex at +x: rotate so a side faces +x
    pent = pent @ np.array([[_cos(np.pi / 5), _sin(np.pi / 5)], [-_sin(np.pi / 5), _cos(np.pi / 5)]])
    side_x = pent[:, 0].max()
    first = prism(pent, 0.0, 1.0)
    mirrored = pent * np.array([-1.0, 1.0])
    mirrored = mirrored[::-1] + np.array([2 * side_x, 0.0])  # counter-clockwise again, touching at x = side_x
    second = prism(mirrored, 1.0 / 3.0, 4.0 / 3.0)
    return [("prism_a", *first), ("prism_b", *second)]


def duck():
    """A coarse duck-like blob: three overlapping closed bodies (body, head, beak), 172 triangles in all."""
    S, F = icosphere(1)
    body = bumpy(S, 0.05, 2) * np.array([1.0, 0.65, 0.55])
    head = S * 0.38 + np.array([0.7, 0.0, 0.55])
    beak_poly = np.array([[0.95, -0.1], [1.35, -0.02], [1.35, 0.02], [0.95, 0.1]])
    beak, beak_faces = prism(beak_poly, 0.45, 0.55)  # sticks out of the head along +x, thin in z
    return [("body", body, F), ("head", head, F.copy()), ("beak", beak, beak_faces)]


def touching_fragments():
    """Four closed boxes filling a 2 x 2 x 1 block, the faces they share triangulated differently on each side.

    The shape of a baked output GLB: fragments touching along faces, each closed
    on its own, the coincident fault faces not identical triangles.
    """
    bodies = []
    for i, (x, y) in enumerate([(0, 0), (1, 0), (0, 1), (1, 1)]):
        square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64) + np.array([x, y])
        if (x + y) % 2:
            square = np.roll(square, 1, axis=0)  # other diagonals on the shared side quads
        bodies.append((f"fragment_{i:03d}", *prism(square, 0.0, 0.6)))
    return bodies


# ----------------------------------------------------------------------------
# Reference solids (manifold3d, not the library): what a correct repair encloses


def fan_filled(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Close every boundary loop of an oriented surface with a fan around the loop's centroid."""
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    forward = {(int(a), int(b)) for a, b in directed}
    boundary = [(a, b) for a, b in forward if (b, a) not in forward]
    nxt = {a: b for a, b in boundary}
    assert len(nxt) == len(boundary), "holes must be simple loops"
    seen: set[int] = set()
    V, F = list(V), [np.asarray(F)]
    for a0, _ in sorted(boundary):
        if a0 in seen:
            continue
        loop = [a0]
        while nxt[loop[-1]] != a0:
            loop.append(nxt[loop[-1]])
        seen.update(loop)
        centre = len(V)
        V.append(np.mean([V[i] for i in loop], axis=0))
        F.append(np.array([[nxt[i], i, centre] for i in loop], dtype=np.int64))
    return np.array(V), np.vstack(F)


def solid_volume(bodies: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Volume of the union of closed bodies (each welded by exact position)."""
    import manifold3d

    parts = []
    for V, F in bodies:
        _, first, inverse = np.unique(V, axis=0, return_index=True, return_inverse=True)
        parts.append(manifold3d.Manifold(manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(V[first], dtype=np.float64),
            tri_verts=np.ascontiguousarray(inverse.reshape(-1)[F], dtype=np.uint64))))
        assert parts[-1].status() == manifold3d.Error.NoError, parts[-1].status()
    return float(manifold3d.Manifold.batch_boolean(parts, manifold3d.OpType.Add).volume())


# ----------------------------------------------------------------------------
# The corpus and what a bake of each must give

CASES: list[dict] = []


def case(file: str, data: bytes, *, kind: str, outcome: str, why: str, volume: float | None = None,
         volume_tolerance: float = 1e-3, max_fragments: int | None = None, recipes: str | None = None) -> None:
    """Register one corpus file and its expected outcome.

    ``outcome`` is ``solid`` (closed fragments whose volumes sum to ``volume``)
    or ``shell`` (a sheet thickened inward: closed fragments inside the input's
    bounding box). ``max_fragments`` bounds the count with the default recipe
    (fragment counts follow the recipe, not the tessellation).
    """
    CASES.append({"file": file, "data": data, "kind": kind, "outcome": outcome, "why": why, "volume": volume,
                  "volume_tolerance": volume_tolerance, "max_fragments": max_fragments, "recipes": recipes})


def build() -> None:
    head = head_with_open_eyes()
    case("head_open_eyes.glb", glb(head), kind="open multi-body head", outcome="solid",
         volume=solid_volume([(head[0][1], head[0][2])] + [fan_filled(V, F) for _, V, F in head[1:]]),
         volume_tolerance=2e-3,
         why="a closed head and two open hemispherical eye shells whose rims sit inside it (Suzanne): each eye "
             "closes with a small planar cap and is united with the head")
    for label, fraction in (("01", 0.01), ("037", 0.037), ("06", 0.06), ("10", 0.10)):
        V, F, realized, _ = scan_with_holes(fraction)
        assert abs(realized - fraction) < 0.1 * fraction, (label, realized)
        case(f"scan_holes_{label}.glb", glb([("scan", V, F)]), kind="scan with holes", outcome="solid",
             volume=solid_volume([fan_filled(V, F)]), volume_tolerance=0.01, max_fragments=60,
             why=f"a bumpy closed blob with five holes totalling {100 * realized:.2f}% of its area: the holes are "
                 "nearly planar loops that close into a consistent solid, so it is filled, not shelled")
    gear = gear_edge_contact()
    case("gear_edge_contact.glb", glb(gear), kind="non-manifold edges (bodies touching along an edge)",
         outcome="solid", volume=sum(volume(V, F) for _, V, F in gear),
         why="an octagonal hub and 8 closed wedge teeth each touching it only along a vertical edge (4 faces per "
             "edge): the fans split into closed bodies; no fragment may keep the 4-face edge")
    gear = gear_coplanar()
    case("gear_coplanar.glb", glb(gear), kind="non-manifold edges (coincident faces, other triangulation)",
         outcome="solid", volume=sum(volume(V, F) for _, V, F in gear),
         why="a 16-sided hub and 8 box teeth whose base quads coincide with hub sides but are split along the "
             "other diagonal: the faces around each shared edge pair up into closed bodies, kept apart where they "
             "only touch (issue 39) and cut one by one")
    boxes = vertex_contact()
    case("vertex_contact.glb", glb(boxes), kind="bodies sharing a vertex or an edge", outcome="solid",
         volume=sum(volume(V, F) for _, V, F in boxes),
         why="two boxes touching at a corner and a third touching one along an edge: every fragment must still be "
             "one body with manifold edges and vertices")
    tris, closed_volume = triangle_soup()
    case("soup.stl", stl_binary(tris), kind="triangle soup", outcome="solid", volume=closed_volume,
         volume_tolerance=1e-4,
         why="a closed blob as unwelded triangles, 10% duplicated with random winding, every winding random: "
             "welding, de-duplication and re-winding give the closed solid (a duplicate pair of opposite winding "
             "is one face, not a hole)")
    case("awning_sheet.glb", glb([("awning", *awning_sheet())]), kind="open sheet", outcome="shell",
         why="a wavy half-cylinder without thickness: really a sheet, thickened inward (behind its outward "
             "normals) so its visible side stays put and the fragments stay in its bounding box")
    pot = teapot()
    case("teapot.glb", glb(pot), kind="teapot of 4 open bodies", outcome="solid",
         volume=solid_volume([fan_filled(V, F) for _, V, F in pot]), volume_tolerance=2e-3,
         why="body open at the top, lid open at its rim, spout and handle open tubes whose ends sit inside the "
             "body: every opening is a planar loop, each body fills into a solid and they are united")
    prisms = two_prisms()
    case("two_prisms.glb", glb(prisms), kind="32-triangle model", outcome="solid",
         volume=sum(volume(V, F) for _, V, F in prisms), max_fragments=60,
         why="two pentagonal prisms touching along part of a side (32 triangles): a recipe must give as many "
             "fragments as on a finely tessellated body of the same size, not hundreds")
    bird = duck()
    case("duck.glb", glb(bird), kind="coarse overlapping blob", outcome="solid",
         volume=solid_volume([(V, F) for _, V, F in bird]), max_fragments=60,
         why="a coarse duck: body, head and beak as overlapping closed bodies (172 triangles), united")
    frags = touching_fragments()
    case("touching_fragments.glb", glb(frags), kind="fragments touching along faces", outcome="solid",
         volume=sum(volume(V, F) for _, V, F in frags),
         why="four closed boxes filling a block, their shared faces triangulated differently on each side (a baked "
             "output GLB used as input): they stay separate bodies (issue 39), each cut further, and no fragment has "
             "an open or pinched edge")
    build_issue39()


def build_issue39() -> None:
    """The failure classes of issue 39, each baked with every built-in recipe (tests/test_realworld_recipes.py)."""
    import artist_shapes as art  # beside this script; it imports this module's shape helpers

    every = "all"
    pot = art.teapot_touching()
    case("teapot_touching.glb", glb(pot), kind="closed teapot, parts touching", outcome="solid", recipes=every,
         volume=solid_volume([(V, F) for _, V, F in pot]),
         why="a closed pot and a closed lid touching along the rim (the lid's flat underside on the pot's flat "
             "top: edges of four faces), a closed spout and handle sunk into the pot: one solid, and no cut may "
             "leave an edge of more than two faces")
    case("open_pot.glb", glb([("pot", *art.open_pot())]), kind="open container", outcome="shell", recipes=every,
         why="a pot without its lid, a single surface: a rim around a large opening is a container, so it becomes "
             "a thin wall (hollow), not a filled lump")
    closed, holed = art.bust_with_hole()
    case("bust_hole.glb", glb([("bust", *holed)]), kind="bust with a small non-planar hole", outcome="solid",
         recipes=every, volume=volume(*closed), volume_tolerance=0.01,
         why="a closed bust with one small hole wrapping around its thin stem: no flat patch exists, so it is "
             "filled by a non-planar patch (checked for self-intersection) and the bust stays solid")
    gear = art.gear_thin_teeth()
    case("gear_thin_teeth.glb", glb(gear), kind="gear with thin teeth", outcome="solid", recipes=every,
         volume=solid_volume([(V, F) for _, V, F in gear]),
         why="a hub and 24 thin teeth (1% of the diagonal wide) sunk into it as separate bodies: united, cut "
             "into closed one-body fragments although the teeth are thinner than the cage's tets")
    truck = art.vehicle()
    case("vehicle_wheels.glb", glb(truck), kind="vehicle of separate touching bodies", outcome="solid",
         recipes=every, volume=sum(volume(V, F) for _, V, F in truck),
         why="a truck of 14 closed bodies that only touch (wheels against the chassis, cab on it, lights, "
             "mirrors, exhaust, hitch): the bodies stay separate, no fragment joins a wheel to the chassis")
    boxes = art.overlapping_edges()
    case("overlap_edges.glb", glb(boxes), kind="overlapping bodies touching along edges", outcome="solid",
         recipes=every, volume=solid_volume([(V, F) for _, V, F in boxes]),
         why="boxes overlapping with shared face planes and edge lines, one touching only along an edge, one only "
             "at a corner: united where they overlap, split where they only touch")
    V, F = art.fins_on_solid()
    case("fins_on_solid.glb", glb([("finned", V, F)], uvs=False), kind="fins hinged on a solid", outcome="shell",
         recipes=every, volume=1.0, volume_tolerance=0.05,
         why="a box with two zero-thickness fins hinged on its edges and a double-sided card: the fins are cut "
             "off and thickened as sheets (the card, enclosing nothing, goes), not refused")
    V, F = art.wall_with_hole()
    case("wall_hole.glb", glb([("wall", V, F)]), kind="thin wall with a through hole, far from the origin",
         outcome="solid", recipes=every, volume=volume(V, F), volume_tolerance=1e-4,
         why="a 400 x 300 x 12 wall with a window, 1000 units from the origin: the volume check must hold in "
             "float64 (or say truthfully what it measured)")
    tris = art.debris_soup()
    case("debris_soup.stl", stl_binary(tris), kind="triangle soup of many bodies", outcome="solid",
         recipes=every, volume=_soup_volume(tris),
         why="14 small closed rocks (overlapping, touching, apart) as an STL triangle soup with random winding: "
             "every fragment one body, or the bake says which cannot be")
    bird = duck()
    case("unpadded_chunk.glb", art.unpadded_glb(glb(bird)), kind="GLB with an unpadded JSON chunk",
         outcome="solid", recipes=every, volume=solid_volume([(V, F) for _, V, F in bird]),
         why="the duck with its JSON chunk not padded to 4 bytes (the binary chunk right after it): every "
             "accessor fits, so it is read (with a warning), not refused as truncated")


def _soup_volume(tris: np.ndarray) -> float:
    """Volume of the union of the closed bodies a triangle soup describes (welded by exact position, each
    connected part turned outward)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    U, index = np.unique(tris.reshape(-1, 3), axis=0, return_inverse=True)
    F = index.reshape(-1, 3)
    n = int(F.max()) + 1
    graph = coo_matrix((np.ones(2 * len(F)), (np.concatenate([F[:, 0], F[:, 1]]), np.concatenate([F[:, 1], F[:, 2]]))),
                       shape=(n, n))
    label = connected_components(graph, directed=False)[1]
    bodies = []
    for part in np.unique(label[F[:, 0]]):
        faces = F[label[F[:, 0]] == part]
        faces = faces[np.unique(np.sort(faces, axis=1), axis=0, return_index=True)[1]]
        bodies.append(_outward(U, faces))
    return solid_volume(bodies)


def _outward(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One closed connected surface (V, F) with consistent outward winding (breadth-first across edges)."""
    F = F.copy()
    edges: dict[tuple[int, int], list[int]] = {}
    for f, (a, b, c) in enumerate(F.tolist()):
        for u, v in ((a, b), (b, c), (c, a)):
            edges.setdefault((min(u, v), max(u, v)), []).append(f)
    done = np.zeros(len(F), dtype=bool)
    done[0] = True
    queue = [0]
    while queue:
        f = queue.pop()
        a, b, c = F[f].tolist()
        for u, v in ((a, b), (b, c), (c, a)):
            for g in edges[min(u, v), max(u, v)]:
                if not done[g]:
                    runs = {(int(F[g, k]), int(F[g, (k + 1) % 3])) for k in range(3)}
                    if (u, v) in runs:
                        F[g] = F[g][::-1]
                    done[g] = True
                    queue.append(g)
    return (V, F) if volume(V, F) > 0 else (V, F[:, ::-1])


def manifest() -> str:
    """expected.toml: one [[case]] per file."""
    lines = ["# Expected outcome of `fracture bake` on each real-world corpus file (written by",
             "# make_realworld_corpus.py). outcome = \"solid\": closed fragments whose volumes sum to",
             "# `volume` (input units) within `volume_tolerance`; outcome = \"shell\": a sheet thickened",
             "# inward, closed fragments inside the input's bounding box. `max_fragments`: with the",
             "# default recipe. tests/test_realworld.py checks them with tests/invariants.py.", ""]
    for c in CASES:
        lines.append("[[case]]")
        for key in ("file", "kind", "outcome", "volume", "volume_tolerance", "max_fragments", "recipes", "why"):
            value = c[key]
            if value is None:
                continue
            if isinstance(value, str):
                lines.append(f"{key} = {json.dumps(value)}")
            else:
                lines.append(f"{key} = {value!r}")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    os.makedirs(OUT, exist_ok=True)
    build()
    for c in CASES:
        with open(os.path.join(OUT, c["file"]), "wb") as fh:
            fh.write(c["data"])
        print(f"{c['file']}: {len(c['data'])} bytes")
    with open(os.path.join(OUT, "expected.toml"), "w") as fh:
        fh.write(manifest())


if __name__ == "__main__":
    main()
