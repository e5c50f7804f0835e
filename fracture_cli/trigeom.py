"""Vectorized checks on triangle meshes: manifoldness and triangle intersections.

Used by the cage stage to reject a candidate cage that is not a closed manifold,
that intersects itself, or that crosses the input surface. Every test errs on
the side of reporting a problem (touching counts as intersecting, degenerate
triangles are never proven separate), because a false alarm only costs the cage
search one more iteration while a missed intersection breaks TetGen or the
containment guarantee.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

# Separation below this (normalized units, unit bounding-box diagonal) counts
# as touching, i.e. as an intersection.
SEPARATION_EPS = 1e-12

_PAIR_CHUNK = 20_000


def edge_manifold_closed(F: np.ndarray) -> bool:
    """Whether every edge of ``F`` (m, 3) has exactly two faces, used once in each direction.

    This is "closed, edge-manifold and consistently oriented" in one test.
    """
    F = np.asarray(F, dtype=np.int64)
    if len(F) == 0:
        return False
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    if np.any(directed[:, 0] == directed[:, 1]):
        return False
    n = int(F.max()) + 1
    key = directed[:, 0] * n + directed[:, 1]
    if len(np.unique(key)) != len(key):
        return False  # a directed edge used twice: non-manifold or flipped neighbour
    twin = directed[:, 1] * n + directed[:, 0]
    return bool(np.all(np.isin(twin, key)))


def vertex_manifold(F: np.ndarray) -> bool:
    """Whether the faces around every vertex of ``F`` (m, 3) form a single fan.

    Assumes :func:`edge_manifold_closed` holds. Two cones touching at a vertex
    pass the edge test but not this one.
    """
    F = np.asarray(F, dtype=np.int64)
    m = len(F)
    n = int(F.max()) + 1
    # Corner (f, k) is vertex F[f, k] in face f; the corner of vertex a in face f
    # is glued to the corner of a in the face across edge (a -> b).
    corner = np.arange(3 * m).reshape(m, 3)
    a = F.reshape(-1)
    b = F[:, [1, 2, 0]].reshape(-1)
    key_ab = a * n + b
    order = np.argsort(key_ab, kind="stable")
    twin_pos = np.searchsorted(key_ab[order], b * n + a)
    twin_pos = np.minimum(twin_pos, len(order) - 1)
    twin_edge = order[twin_pos]  # the halfedge b -> a, starting at corner of b
    ok = key_ab[twin_edge] == b * n + a
    # In the twin face the halfedge is b -> a, so a is the next corner after b.
    twin_face = twin_edge // 3
    twin_corner_of_a = twin_face * 3 + (twin_edge % 3 + 1) % 3
    src = corner.reshape(-1)[ok]
    dst = twin_corner_of_a[ok]
    graph = sp.coo_matrix((np.ones(len(src)), (src, dst)), shape=(3 * m, 3 * m))
    _, labels = connected_components(graph, directed=False)
    pairs = np.unique(np.stack([a, labels], axis=1), axis=0)
    fans_per_vertex = np.bincount(pairs[:, 0], minlength=n)
    used = np.bincount(a, minlength=n) > 0
    return bool(np.all(fans_per_vertex[used] == 1))


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
        lo = np.floor((boxes[:, 0] - self.origin) / self.cell).astype(np.int64)
        hi = np.floor((boxes[:, 1] - self.origin) / self.cell).astype(np.int64)
        return lo, hi

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
    return max(float(np.median(extent)), total / 256.0, 1e-12)


def triangles_intersect(A: np.ndarray, B: np.ndarray, eps: float = SEPARATION_EPS) -> np.ndarray:
    """Separating-axis test between triangle pairs.

    Parameters
    ----------
    A, B : (p, 3, 3) float
        Corner positions of the two triangles of each pair. A segment can be
        passed as a degenerate triangle ``(a, b, b)``.
    eps : float, optional (default 1e-12)
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
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    hit = np.zeros(len(A), dtype=bool)
    for s in range(0, len(A), _PAIR_CHUNK):
        a, b = A[s:s + _PAIR_CHUNK], B[s:s + _PAIR_CHUNK]
        # Work relative to one corner: smaller numbers, better cancellation.
        origin = a[:, :1, :]
        a, b = a - origin, b - origin
        scale = max(float(np.abs(a).max(initial=0.0)), float(np.abs(b).max(initial=0.0)), 1e-300)
        ea = a[:, [1, 2, 0]] - a  # (p, 3, 3) edges
        eb = b[:, [1, 2, 0]] - b
        na = np.cross(ea[:, 0], ea[:, 1])
        nb = np.cross(eb[:, 0], eb[:, 1])
        # The two normals separate most pairs; test the other 15 axes only on the rest.
        open_ = ~_separated(np.stack([na, nb], axis=1), a, b, scale, eps)
        idx = np.flatnonzero(open_)
        if len(idx):
            a, b, ea, eb, na, nb = a[idx], b[idx], ea[idx], eb[idx], na[idx], nb[idx]
            axes = np.concatenate([
                np.cross(ea[:, :, None, :], eb[:, None, :, :]).reshape(-1, 9, 3),
                np.cross(na[:, None, :], ea), np.cross(nb[:, None, :], eb),
                # In-plane normals of one triangle's edges in the other's plane:
                # needed when a triangle is degenerate (a segment) and coplanar.
                np.cross(na[:, None, :], eb), np.cross(nb[:, None, :], ea)], axis=1)
            open_[idx] = ~_separated(axes, a, b, scale, eps)
        hit[s:s + _PAIR_CHUNK] = open_
    return hit


def _separated(axes: np.ndarray, a: np.ndarray, b: np.ndarray, scale: float, eps: float) -> np.ndarray:
    """Whether any of ``axes`` (p, k, 3) separates triangles ``a``, ``b`` (p, 3, 3) by more than ``eps``."""
    length = np.sqrt(np.sum(axes * axes, axis=2))
    valid = length > 1e-12 * scale * scale
    axes = axes / np.where(valid, length, 1.0)[:, :, None]
    pa = np.matmul(axes, a.transpose(0, 2, 1))  # (p, k, 3) projections of a's corners
    pb = np.matmul(axes, b.transpose(0, 2, 1))
    # Explicit 3-way min/max: reductions over a length-3 axis are slow in numpy.
    a0, a1, a2 = pa[:, :, 0], pa[:, :, 1], pa[:, :, 2]
    b0, b1, b2 = pb[:, :, 0], pb[:, :, 1], pb[:, :, 2]
    gap = np.maximum(np.minimum(np.minimum(a0, a1), a2) - np.maximum(np.maximum(b0, b1), b2),
                     np.minimum(np.minimum(b0, b1), b2) - np.maximum(np.maximum(a0, a1), a2))
    return np.any(valid & (gap > eps), axis=1)


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
    grid = BoxGrid(boxes, default_cell(boxes))
    i, j = grid.query(boxes)
    keep = i < j
    i, j = i[keep], j[keep]
    Fi, Fj = F[i], F[j]
    shared = (Fi[:, :, None] == Fj[:, None, :])  # (p, 3, 3)
    n_shared = shared.any(axis=2).sum(axis=1)
    bad = np.zeros(len(i), dtype=bool)

    # Disjoint vertex sets: plain triangle-triangle test.
    s0 = n_shared == 0
    bad[s0] = triangles_intersect(V[Fi[s0]], V[Fj[s0]])

    # One shared vertex: they overlap beyond it only if the edge opposite the
    # shared vertex in one triangle meets the other triangle.
    s1 = np.flatnonzero(n_shared == 1)
    if len(s1):
        fi, fj, sh = Fi[s1], Fj[s1], shared[s1]
        ki = np.argmax(sh.any(axis=2), axis=1)  # corner of the shared vertex in fi
        kj = np.argmax(sh.any(axis=1), axis=1)
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
            return n / np.maximum(length, 1e-300), length[:, 0]

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
    qi, j = grid_b.query(triangle_boxes(V_a, F_a[ids_a]), pad=SEPARATION_EPS)
    i = ids_a[qi]
    hit = triangles_intersect(V_a[F_a[i]], V_b[F_b[j]])
    return np.stack([i[hit], j[hit]], axis=1)
