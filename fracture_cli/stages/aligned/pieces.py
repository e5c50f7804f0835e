"""The asset's convex pieces for aligned fracture: the collision parts, as planes, corners and face loops,
each with the visual triangles that lie in it.

* **Pieces** are the collision stage's parts of every fragment, together a non-overlapping convex
  decomposition of the asset (seed 001's compound). Each is stored as a boundary representation:
  its corners (rounded to float32 first, so the stored corners are exactly the B-rep's), and its
  faces, the hull's coplanar triangles merged into one convex loop each, with the face's plane.
* **Triangles** of a fragment (outer surface and fault faces, as in the fragments GLB) go whole to
  the part of that fragment that contains their centroid, or to the part it lies least outside of
  (the parts cover most, not all, of a fragment): a piece that stays whole at runtime shows all of its
  triangles, and no triangle is lost or shown twice. The fault faces close a piece where it meets
  another fragment's.
* **Inner faces**: where two parts of one fragment meet (a plane of the decomposition, with opposite
  normals), each part's face on that plane is added as interior-material triangles, so a fragment
  split there at runtime is closed too. Inside one fragment such faces are hidden.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry.uvs import box_uvs

# Hull triangles whose unit normals differ by less than this (and offsets by less than _SAME_OFFSET of the part's
# size) are one face.
_SAME_NORMAL = 1e-6
_SAME_OFFSET = 1e-6
# Two parts' faces are one plane of the decomposition when normals are opposite within this and offsets agree.
_SHARED_NORMAL = 1e-6
_SHARED_OFFSET = 1e-6
# The sphere around a piece (its corners) grows by this fraction (float32 rounding stays inside).
_SPHERE_MARGIN = 1e-5


@dataclass(frozen=True)
class Piece:
    """One convex piece, model space.

    Attributes
    ----------
    fragment : int
    vertices : (n, 3) float64
        Corners (float32-exact).
    loops : list of list of int
        Face loops, counter-clockwise seen from outside.
    planes : (f, 4) float64
        Unit outward normal and offset per face.
    """

    fragment: int
    vertices: np.ndarray
    loops: list[list[int]]
    planes: np.ndarray


def convex_piece(corners: np.ndarray, fragment: int) -> Piece:
    """The boundary representation of the convex hull of ``corners`` (k, 3), rounded to float32 first."""
    # on first use: scipy only for baking
    from scipy.spatial import ConvexHull

    points = np.asarray(corners, dtype=np.float32).astype(np.float64)
    hull = ConvexHull(points)
    used = np.unique(hull.simplices)
    local = np.full(len(points), -1)
    local[used] = np.arange(len(used))
    vertices = points[used]
    size = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    triangles = []
    for simplex, equation in zip(hull.simplices, hull.equations):
        a, b, c = (vertices[local[v]] for v in simplex)
        tri = [int(local[v]) for v in simplex]
        if np.dot(np.cross(b - a, c - a), equation[:3]) < 0:
            tri = [tri[0], tri[2], tri[1]]
        triangles.append((tri, equation[:3] / np.linalg.norm(equation[:3]), float(-equation[3])))
    loops, planes = _merged_faces(vertices, triangles, size)
    return Piece(fragment=fragment, vertices=vertices, loops=loops, planes=planes)


def _merged_faces(vertices: np.ndarray, triangles: list, size: float) -> tuple[list[list[int]], np.ndarray]:
    """Coplanar hull triangles merged into one loop per face (their boundary, chained), with its plane."""
    group = list(range(len(triangles)))

    def root(i: int) -> int:
        while group[i] != i:
            group[i] = group[group[i]]
            i = group[i]
        return i

    by_edge: dict[tuple[int, int], int] = {}
    for t, (tri, _, _) in enumerate(triangles):
        for e in range(3):
            by_edge[(tri[e], tri[(e + 1) % 3])] = t
    for t, (tri, normal, offset) in enumerate(triangles):
        for e in range(3):
            other = by_edge.get((tri[(e + 1) % 3], tri[e]))
            if other is None:
                continue
            n2, h2 = triangles[other][1], triangles[other][2]
            if np.linalg.norm(normal - n2) < _SAME_NORMAL and abs(offset - h2) < _SAME_OFFSET * size:
                group[root(t)] = root(other)
    members: dict[int, list[int]] = {}
    for t in range(len(triangles)):
        members.setdefault(root(t), []).append(t)
    loops, planes = [], []
    for ts in sorted(members.values()):
        loop = _boundary_loop([triangles[t][0] for t in ts])
        if loop is None:  # not one simple loop (should not happen on a hull): keep the triangles
            parts = [triangles[t][0] for t in ts]
        else:
            parts = [loop]
        for poly in parts:
            p = vertices[poly]
            normal = np.zeros(3)
            for i in range(len(poly)):  # Newell's normal
                a, b = p[i], p[(i + 1) % len(poly)]
                normal += np.array([(a[1] - b[1]) * (a[2] + b[2]), (a[2] - b[2]) * (a[0] + b[0]),
                                    (a[0] - b[0]) * (a[1] + b[1])])
            normal /= np.linalg.norm(normal)
            loops.append([int(v) for v in poly])
            planes.append([*normal, float((vertices @ normal).max())])
    return loops, np.array(planes, dtype=np.float64)


def _boundary_loop(tris: list[list[int]]) -> list[int] | None:
    """The boundary of a disc of triangles as one loop (its orientation), or None if it is not one loop."""
    edges = {(t[e], t[(e + 1) % 3]) for t in tris for e in range(3)}
    boundary = {a: b for a, b in edges if (b, a) not in edges}
    if len(boundary) != sum(1 for a, b in edges if (b, a) not in edges):
        return None  # a vertex starts two boundary edges
    start = min(boundary)
    loop, v = [start], boundary[start]
    while v != start:
        if v not in boundary or len(loop) > len(boundary):
            return None
        loop.append(v)
        v = boundary[v]
    return loop if len(loop) == len(boundary) else None


def assign_triangles(pieces: list[Piece], centroids: np.ndarray) -> np.ndarray:
    """For triangle centroids (t, 3) of one fragment, the index into ``pieces`` (that fragment's parts) of the
    piece each lies in, or least outside of (largest plane excess smallest; the first on ties)."""
    excess = np.stack([(centroids @ p.planes[:, :3].T - p.planes[:, 3]).max(axis=1) for p in pieces], axis=1)
    return np.argmin(excess, axis=1)


def inner_faces(pieces: list[Piece], size: float) -> list[list[int]]:
    """Per piece, its faces on a plane it shares (with opposite normals) with another piece of its fragment."""
    found: list[list[int]] = [[] for _ in pieces]
    for a, pa in enumerate(pieces):
        for b, pb in enumerate(pieces):
            if a == b or pa.fragment != pb.fragment:
                continue
            for f, (na, ha) in enumerate(zip(pa.planes[:, :3], pa.planes[:, 3])):
                opposite = (np.linalg.norm(pb.planes[:, :3] + na, axis=1) < _SHARED_NORMAL) & (
                    np.abs(pb.planes[:, 3] + ha) < _SHARED_OFFSET * size)
                if opposite.any() and f not in found[a]:
                    found[a].append(f)
    return [sorted(f) for f in found]


def face_triangles(piece: Piece, faces: list[int], uv_scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fans of the piece's faces ``faces`` as triangles: positions, normals (t, 3, 3), box-projected UVs (t, 3, 2)."""
    positions, normals = [], []
    for f in faces:
        loop = piece.loops[f]
        for q in range(1, len(loop) - 1):
            positions.append(piece.vertices[[loop[0], loop[q], loop[q + 1]]])
            normals.append(np.repeat(piece.planes[f:f + 1, :3], 3, axis=0))
    if not positions:
        return np.zeros((0, 3, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3, 2))
    pos, nrm = np.array(positions), np.array(normals)
    uvs = box_uvs(pos.reshape(-1, 3), nrm.reshape(-1, 3), uv_scale).reshape(-1, 3, 2)
    return pos, nrm, uvs


def bounding_sphere(points: np.ndarray) -> np.ndarray:
    """Centre and radius (4,) float32 of a sphere holding ``points`` (n, 3) after float32 rounding."""
    centre = (points.min(axis=0) + points.max(axis=0)) * 0.5
    centre32 = centre.astype(np.float32)
    delta = points - centre32.astype(np.float64)
    radius = float(np.sqrt((delta * delta).sum(axis=1).max()))
    radius = radius * (1.0 + _SPHERE_MARGIN) + 1e-30
    r32 = np.float32(radius)
    if float(r32) < radius:
        r32 = np.nextafter(r32, np.float32(np.inf))
    return np.array([*centre32, r32], dtype=np.float32)
