"""Vectorized geometry of triangle meshes: measures, manifoldness and intersections.

The one home of the triangle-mesh helpers every stage shares: signed volume,
vertex normals, winding numbers, closest points, and the checks the cage stage
uses to reject a candidate cage (not closed, self-intersecting, crossing the
input). The intersection tests err on the side of reporting a problem: a false
alarm only costs the cage search one more iteration, while a missed
intersection breaks TetGen or the containment guarantee.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.system import detmath

# Point-triangle pairs per chunk of :func:`winding_numbers` (bounds its memory).
_WINDING_CHUNK = 2_000_000


def compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop the vertices (n, c) no face (m, 3) uses, keeping the order of the rest; faces renumbered."""
    used = np.unique(faces)
    if len(used) == len(vertices):
        return vertices, faces
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces]


def face_signed_volumes(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Signed volumes (m,) of the tets joining the origin to each triangle ``F`` (m, 3) over ``V`` (n, 3).

    Their sum over a closed mesh is its enclosed volume (positive when outward).
    """
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0


def signed_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Enclosed volume of a closed triangle mesh ``F`` (m, 3) over ``V`` (n, 3); negative when inside out."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    # Summed before the division (not face_signed_volumes().sum()): the bake's volumes are compared bit for bit.
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def vertex_normals(V: np.ndarray, F: np.ndarray, n: int | None = None, unit: bool = True) -> np.ndarray:
    """Area-weighted vertex normals (n, 3): the sum of the (twice-area) normals of the faces at each vertex.

    Parameters
    ----------
    V : (k, 3) float
        Vertex positions.
    F : (m, 3) int
        Triangles; their ids index the output (e.g. welded ids), not necessarily ``V``'s rows.
    n : int, optional (default len(V))
        Number of output rows.
    unit : bool, optional (default True)
        Normalize to unit length (vertices without faces stay 0).
    """
    n = len(V) if n is None else n
    F = np.asarray(F, dtype=np.int64)
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    # bincount adds in array order (first corners, then second, then third), as np.add.at over the three
    # corners did, bit for bit, several times faster.
    corners = F.T.reshape(-1)
    acc = np.stack([np.bincount(corners, weights=np.tile(fn[:, axis], 3), minlength=n) for axis in range(3)],
                   axis=1).reshape(n, 3)
    if not unit:
        return acc
    return acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)


def solid_angle_fraction(a: np.ndarray, b: np.ndarray, c: np.ndarray,
                         lengths: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Signed solid angle / 4 pi of triangles ``(a, b, c)`` seen from the origin (arrays (..., 3)).

    Van Oosterom and Strackee's formula, tan(omega / 2) = det / dot. ``lengths``: the corners' lengths
    (...,), when the caller already has them (as computed here: the same bits).
    """
    if lengths is None:
        la, lb, lc = (np.sqrt(np.einsum("...j,...j->...", x, x)) for x in (a, b, c))
    else:
        la, lb, lc = lengths
    det = np.einsum("...j,...j->...", a, np.cross(b, c))
    dot = (la * lb * lc + np.einsum("...j,...j->...", a, b) * lc + np.einsum("...j,...j->...", b, c) * la
           + np.einsum("...j,...j->...", c, a) * lb)
    return detmath.atan2(det, dot) / (2.0 * np.pi)


def triangle_winding(P: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Winding-number contribution (k,) of triangle ``(A[i], B[i], C[i])`` at ``P[i]`` (all (k, 3))."""
    return solid_angle_fraction(A - P, B - P, C - P)


def winding_numbers(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Generalized winding numbers (k,) of ``points`` (k, 3) w.r.t. triangles ``F`` (m, 3) over ``V``.

    1 inside and 0 outside a closed outward mesh; about 0.5 on it; fractional for open meshes.
    """
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    out = np.zeros(len(points))
    chunk = max(1, _WINDING_CHUNK // max(len(F), 1))
    for s in range(0, len(points), chunk):
        q = points[s:s + chunk, None, :]
        out[s:s + chunk] = solid_angle_fraction(A[None] - q, B[None] - q, C[None] - q).sum(axis=1)
    return out


def closest_points(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest points (k, 3) to ``p`` on triangles ``(a, b, c)`` (each (k, 3)), by Voronoi regions (Ericson).

    A degenerate triangle whose formula gives no finite point falls back to its corner ``a``.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp, cp = p - b, p - c
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        out = a + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        t_ac = d2 / (d2 - d6)
        t_ab = d1 / (d1 - d3)
    # Later regions override earlier ones (vertex regions last).
    out = np.where(np.isfinite(out), out, a)
    out = np.where(((va <= 0) & (d4 >= d3) & (d5 >= d6))[:, None], b + (c - b) * t_bc[:, None], out)
    out = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[:, None], a + ac * t_ac[:, None], out)
    out = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[:, None], a + ab * t_ab[:, None], out)
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    return np.where(np.isfinite(out), out, a)


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Distances (k,) from points (k, 3) to triangles (k, 3, 3), float64."""
    closest = closest_points(points, triangles[:, 0], triangles[:, 1], triangles[:, 2])
    return np.linalg.norm(points - closest, axis=1)


def edge_manifold_closed(F: np.ndarray) -> bool:
    """Whether every edge of ``F`` (m, 3) has exactly two faces, used once in each direction.

    This is "closed, edge-manifold and consistently oriented" in one test.
    """
    from fracture_cli.geometry.trigeom_topology import closed_oriented  # compiled; see vertex_manifold

    F = np.ascontiguousarray(F, dtype=np.int64)
    if len(F) == 0:
        return False
    return bool(closed_oriented(F.reshape(-1, 3), int(F.max()) + 1))


def vertex_manifold(F: np.ndarray) -> bool:
    """Whether the faces around every vertex of ``F`` (m, 3) form a single fan.

    Assumes :func:`edge_manifold_closed` holds. Two cones touching at a vertex
    pass the edge test but not this one.
    """
    # Compiled (a union-find of the corners glued across edges); imported here so that modules that never
    # test meshes do not import numba.
    from fracture_cli.geometry.trigeom_topology import single_fans

    F = np.ascontiguousarray(F, dtype=np.int64)
    return bool(single_fans(F, int(F.max()) + 1))


def face_components(F: np.ndarray) -> int:
    """How many groups the faces of ``F`` (m, 3) form, joined across shared edges (0 for no faces).

    Faces are joined when they use the same two vertex ids as an edge, in either direction and however many
    faces share it; faces that meet only at a vertex are not. Compiled, as :func:`vertex_manifold`.
    """
    # numba kernels load on first use
    from fracture_cli.geometry.trigeom_topology import edge_components

    F = np.ascontiguousarray(F, dtype=np.int64).reshape(-1, 3)
    if len(F) == 0:
        return 0
    return int(edge_components(F, int(F.max()) + 1))


def triangle_boxes(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Axis-aligned boxes (m, 2, 3) of triangles: ``[:, 0]`` min corner, ``[:, 1]`` max corner."""
    T = V[F]
    return np.stack([T.min(axis=1), T.max(axis=1)], axis=1)


class BoxGrid:
    """A uniform-grid broad phase over a fixed set of boxes.

    Parameters
    ----------
    boxes : (m, 2, 3) float
        Boxes to index (e.g. the input triangles' boxes).
    cell : float
        Grid cell size; about the typical box size of the queries works best.
    """

    def __init__(self, boxes: np.ndarray, cell: float):
        self.boxes = np.asarray(boxes, dtype=np.float64)
        self.cell = float(cell)
        self.origin = self.boxes[:, 0].min(axis=0) - self.cell
        self.lo_cells = self._cells(self.boxes)[0]
        ids, keys = self._expand(self.boxes)
        order = np.lexsort((ids, keys))
        self.keys = keys[order]
        self.ids = ids[order]

    def _cells(self, boxes: np.ndarray):
        return _cell_range(boxes, self.origin, self.cell)

    def _expand(self, boxes: np.ndarray, with_cells: bool = False):
        lo, hi = self._cells(boxes)
        span = hi - lo + 1
        count = span.prod(axis=1)
        ids = np.repeat(np.arange(len(boxes), dtype=np.int64), count)
        start = np.cumsum(count) - count
        local = np.arange(int(count.sum()), dtype=np.int64) - np.repeat(start, count)
        sx, sy = np.repeat(span[:, 0], count), np.repeat(span[:, 1], count)
        ix = np.repeat(lo[:, 0], count) + local % sx
        iy = np.repeat(lo[:, 1], count) + (local // sx) % sy
        iz = np.repeat(lo[:, 2], count) + local // (sx * sy)
        # Cells may be negative for queries outside the indexed region: a
        # collision-free key needs an offset and a generous stride.
        stride = np.int64(1 << 20)
        keys = ((ix + stride // 2) * stride + (iy + stride // 2)) * stride + (iz + stride // 2)
        if with_cells:
            return ids, keys, np.stack([ix, iy, iz], axis=1)
        return ids, keys

    def query(self, boxes: np.ndarray, pad: float = 0.0):
        """Pairs ``(i, j)`` of query box ``i`` and indexed box ``j`` that overlap.

        Parameters
        ----------
        boxes : (q, 2, 3) float
            Query boxes.
        pad : float, optional (default 0)
            Grow every query box by this much on each side.

        Returns
        -------
        i, j : (p,) int64
            Overlapping pairs, each once, in a deterministic order.
        """
        boxes = np.asarray(boxes, dtype=np.float64).copy()
        boxes[:, 0] -= pad
        boxes[:, 1] += pad
        qids, qkeys, qcells = self._expand(boxes, with_cells=True)
        left = np.searchsorted(self.keys, qkeys, side="left")
        right = np.searchsorted(self.keys, qkeys, side="right")
        count = right - left
        qi = np.repeat(qids, count)
        cell = np.repeat(qcells, count, axis=0)
        start = np.cumsum(count) - count
        local = np.arange(int(count.sum()), dtype=np.int64) - np.repeat(start, count)
        j = self.ids[np.repeat(left, count) + local]
        # A pair meets in every cell both boxes cover; keep it only in the cell
        # holding the corner max(lo_q, lo_j), so each pair is reported once.
        lo_q = self._cells(boxes)[0][qi]
        lo_j = self.lo_cells[j]
        once = np.all(cell == np.maximum(lo_q, lo_j), axis=1)
        qi, j = qi[once], j[once]
        b, c = boxes[qi], self.boxes[j]
        overlap = np.all((b[:, 0] <= c[:, 1]) & (c[:, 0] <= b[:, 1]), axis=1)
        return qi[overlap], j[overlap]


def default_cell(boxes: np.ndarray) -> float:
    """A grid cell size for :class:`BoxGrid`: the median box extent, bounded below."""
    extent = (boxes[:, 1] - boxes[:, 0]).max(axis=1)
    total = float((boxes[:, 1].max(axis=0) - boxes[:, 0].min(axis=0)).max())
    return max(float(np.median(extent)), total / 256.0, tol.ZERO_LENGTH)


def triangles_intersect(A: np.ndarray, B: np.ndarray, eps: float = tol.ZERO_LENGTH) -> np.ndarray:
    """Separating-axis test between triangle pairs.

    Parameters
    ----------
    A, B : (p, 3, 3) float
        Corner positions of the two triangles of each pair. A segment can be
        passed as a degenerate triangle ``(a, b, b)``.
    eps : float, optional (default :data:`~fracture_cli.geometry.tolerances.ZERO_LENGTH`)
        A gap no larger than this counts as touching.

    Returns
    -------
    hit : (p,) bool
        True where the triangles intersect or touch (or where degeneracy keeps
        the test from proving them separate).

    Notes
    -----
    Candidate axes: both normals, the 9 edge-edge cross products and the 12
    cross products of a normal with an edge (in-plane edge normals, needed for
    coplanar pairs, including a segment lying in the other triangle's plane). Axes of near-zero length
    are ignored, so degenerate input is reported as intersecting, never missed.
    """
    # Compiled: numpy's (p, 17, 3) temporaries of every axis were most of the callers' time. Imported
    # here so that modules that never test triangles do not import numba.
    from fracture_cli.geometry.trigeom_kernels import intersect_pairs

    A = np.ascontiguousarray(A, dtype=np.float64).reshape(-1, 3, 3)
    B = np.ascontiguousarray(B, dtype=np.float64).reshape(-1, 3, 3)
    return intersect_pairs(A, B, float(eps))


def self_intersections(V: np.ndarray, F: np.ndarray, fold_cos: float = -0.9998) -> np.ndarray:
    """Pairs of faces of one mesh that intersect other than along shared vertices or edges.

    Parameters
    ----------
    V : (n, 3) float
        Vertices.
    F : (m, 3) int
        Triangles of a consistently oriented mesh.
    fold_cos : float, optional (default -0.9998, about 1 degree)
        Two faces sharing an edge are reported when the cosine between their
        normals is below this (folded onto each other).

    Returns
    -------
    pairs : (k, 2) int64
        Intersecting face pairs ``(f, g)``, ``f < g``.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    boxes = triangle_boxes(V, F)
    from fracture_cli.geometry import trigeom_grid  # compiled; imported here as triangles_intersect's kernels are

    pairs = trigeom_grid.self_pairs(boxes, *_grid_cells(boxes))
    return _intersecting_pairs(V, F, pairs[:, 0], pairs[:, 1], fold_cos)


def self_intersections_among(V: np.ndarray, F: np.ndarray, faces: np.ndarray,
                             fold_cos: float = -0.9998) -> np.ndarray:
    """The pairs of :func:`self_intersections` that involve at least one of ``faces``.

    Only those faces' boxes are queried, so checking the few faces an edit changed costs little.

    Parameters
    ----------
    V, F, fold_cos
        As in :func:`self_intersections`: vertices (n, 3), triangles (m, 3), the fold cosine.
    faces : (c,) int
        The faces to check (against all faces).

    Returns
    -------
    pairs : (k, 2) int64
        Intersecting face pairs ``(f, g)``, ``f < g``, ascending, each once.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    faces = np.unique(np.asarray(faces, dtype=np.int64))
    if len(faces) == 0 or len(F) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    boxes = triangle_boxes(V, F)
    # numba kernels load on first use
    from fracture_cli.geometry import trigeom_grid

    pairs = trigeom_grid.among_pairs(boxes, *_grid_cells(boxes), faces)
    return _intersecting_pairs(V, F, pairs[:, 0], pairs[:, 1], fold_cos)


def _grid_cells(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last cells (m, 3) int64 of ``boxes`` (m, 2, 3) in ``BoxGrid(boxes, default_cell(boxes))``,
    without building its index: the compiled search (:mod:`fracture_cli.geometry.trigeom_grid`) walks these cells."""
    cell = float(default_cell(boxes))
    return _cell_range(boxes, boxes[:, 0].min(axis=0) - cell, cell)


def _cell_range(boxes: np.ndarray, origin: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """First and last grid cells (m, 3) int64 of ``boxes`` (m, 2, 3) in cells of size ``cell`` from ``origin``."""
    lo = np.floor((boxes[:, 0] - origin) / cell).astype(np.int64)
    hi = np.floor((boxes[:, 1] - origin) / cell).astype(np.int64)
    return lo, hi


def _intersecting_pairs(V: np.ndarray, F: np.ndarray, i: np.ndarray, j: np.ndarray, fold_cos: float) -> np.ndarray:
    """Of the candidate face pairs ``(i, j)`` (p,), those that intersect other than along shared corners/edges."""
    # numba kernels load on first use
    from fracture_cli.geometry.trigeom_grid import shared_corners

    Fi, Fj = F[i], F[j]
    # Compiled: numpy's (p, 3, 3) comparisons of every candidate pair were much of the fault checks' time.
    n_shared, first_i, first_j = shared_corners(F, np.ascontiguousarray(i, dtype=np.int64),
                                                np.ascontiguousarray(j, dtype=np.int64))
    bad = np.zeros(len(i), dtype=bool)

    # Disjoint vertex sets: plain triangle-triangle test.
    s0 = n_shared == 0
    bad[s0] = triangles_intersect(V[Fi[s0]], V[Fj[s0]])

    # One shared vertex: they overlap beyond it only if the edge opposite the
    # shared vertex in one triangle meets the other triangle.
    s1 = np.flatnonzero(n_shared == 1)
    if len(s1):
        fi, fj = Fi[s1], Fj[s1]
        ki, kj = first_i[s1], first_j[s1]  # corners of the shared vertex in fi and in fj
        r = np.arange(len(s1))
        opp_i = np.stack([fi[r, (ki + 1) % 3], fi[r, (ki + 2) % 3], fi[r, (ki + 2) % 3]], axis=1)
        opp_j = np.stack([fj[r, (kj + 1) % 3], fj[r, (kj + 2) % 3], fj[r, (kj + 2) % 3]], axis=1)
        hit = triangles_intersect(V[opp_i], V[fj]) | triangles_intersect(V[opp_j], V[fi])
        bad[s1] = hit

    # One shared edge: only a fold (the two faces on top of each other) overlaps.
    s2 = np.flatnonzero(n_shared == 2)
    if len(s2):
        def unit_normals(T):
            n = np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]])
            length = np.linalg.norm(n, axis=1, keepdims=True)
            return n / np.maximum(length, tol.SMALLEST_DIVISOR), length[:, 0]

        ni, li = unit_normals(Fi[s2])
        nj, lj = unit_normals(Fj[s2])
        folded = np.einsum("ij,ij->i", ni, nj) < fold_cos
        bad[s2] = folded | (li <= 0) | (lj <= 0)

    # Three shared vertices: a duplicated face.
    bad[n_shared == 3] = True
    return np.stack([i[bad], j[bad]], axis=1)


def mesh_intersections(V_a: np.ndarray, F_a: np.ndarray, V_b: np.ndarray, F_b: np.ndarray,
                       grid_b: BoxGrid | None = None, candidates_a: np.ndarray | None = None) -> np.ndarray:
    """Pairs of triangles, one from each mesh, that intersect or touch.

    Parameters
    ----------
    V_a, F_a : (n_a, 3) float, (m_a, 3) int
        First mesh.
    V_b, F_b : (n_b, 3) float, (m_b, 3) int
        Second mesh.
    grid_b : BoxGrid, optional
        A prebuilt :class:`BoxGrid` over the boxes of ``F_b`` (reused across calls).
    candidates_a : (k,) int, optional (default all faces)
        Only test these faces of the first mesh.

    Returns
    -------
    pairs : (p, 2) int64
        ``(face of a, face of b)`` pairs that intersect.
    """
    V_a = np.asarray(V_a, dtype=np.float64)
    V_b = np.asarray(V_b, dtype=np.float64)
    F_a = np.asarray(F_a, dtype=np.int64)
    F_b = np.asarray(F_b, dtype=np.int64)
    if grid_b is None:
        boxes_b = triangle_boxes(V_b, F_b)
        grid_b = BoxGrid(boxes_b, default_cell(boxes_b))
    ids_a = np.arange(len(F_a)) if candidates_a is None else np.asarray(candidates_a, dtype=np.int64)
    if len(ids_a) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    qi, j = grid_b.query(triangle_boxes(V_a, F_a[ids_a]), pad=tol.ZERO_LENGTH)
    i = ids_a[qi]
    hit = triangles_intersect(V_a[F_a[i]], V_b[F_b[j]])
    return np.stack([i[hit], j[hit]], axis=1)


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (..., 3) arrays (``np.cross`` without its axis handling, for hot loops)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)
