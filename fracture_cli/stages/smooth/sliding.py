"""Geometric method, sliding: keep fault curves on the cage and the moved cage around the input."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.edgelengths import longest_edges
from fracture_cli.stages.smooth.pointgrid import PointGrid
from fracture_cli.system import detmath
from fracture_cli.types import SurfaceMesh

# Sliding: a cage triangle next to a slid vertex must stay this far (unit bbox diagonal) from the input; the
# triangle test is conservative (a separating-axis gap), so the true distance is at least this.
_SLIDE_CLEARANCE = 1e-3
# Broad-phase cells of the containment check, as a fraction of the cage's median triangle size.
_QUERY_CELL = 0.2
# Input triangles with edges up to this many query cells are found through their corners.
_SHORT_EDGE = 1.0


class CageSurface:
    """Closest points on the original cage surface (triangles ``F`` (b, 3) over ``V`` (n, 3))."""

    def __init__(self, V: np.ndarray, F: np.ndarray):
        self.V = V
        self.F = np.asarray(F, dtype=np.int64)
        self.tree = cKDTree(V[np.unique(self.F)])
        boxes = trigeom.triangle_boxes(V, self.F)
        self.grid = trigeom.BoxGrid(boxes, trigeom.default_cell(boxes))

    def project(self, points: np.ndarray) -> np.ndarray:
        """Closest points (k, 3) on the cage to ``points`` (k, 3) (lowest face id on ties)."""
        if len(points) == 0:
            return points.copy()
        # The closest point is no farther than the nearest cage vertex: only triangles whose boxes come that
        # near can hold it.
        d0, _ = self.tree.query(points)
        reach = d0 * (1.0 + tol.TIE) + tol.ZERO_LENGTH
        row, face = self.grid.query(np.stack([points - reach[:, None], points + reach[:, None]], axis=1))
        tri = self.V[self.F[face]]
        closest = trigeom.closest_points(points[row], tri[:, 0], tri[:, 1], tri[:, 2])
        dist = np.sum(np.square(closest - points[row]), axis=1)
        best = np.lexsort((face, dist, row))
        first = best[np.r_[True, row[best][1:] != row[best][:-1]]]
        return closest[first]


def _prism_winding(P: np.ndarray, V0: np.ndarray, X: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Winding numbers (k,) of points ``P`` (k, 3) w.r.t. the prisms swept by triangles ``faces`` (k, 3).

    Each triangle moves from ``V0`` to ``X``; its prism is the new triangle, the old one reversed and one
    side quad per edge. Each quad is split along the diagonal from the edge's lower vertex id (old) to its
    higher one (new), so the two triangles sharing an edge build the same wall with opposite orientations
    and their walls cancel exactly in a sum.

    The eight triangles share six corners: their vectors from ``P`` and lengths are computed once (the
    values :func:`fracture_cli.geometry.trigeom.triangle_winding` computes for each, bit for bit).
    """
    old = [_Corner(V0[faces[:, k]] - P) for k in range(3)]
    new = [_Corner(X[faces[:, k]] - P) for k in range(3)]
    total = _solid_angle_fraction(*new)
    total -= _solid_angle_fraction(*old)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        low_first = faces[:, i] < faces[:, j]
        p0, q0, p1, q1 = old[i], old[j], new[i], new[j]
        # Quad (p0, q0, q1, p1), outward for a counter-clockwise triangle moving along its normal.
        # Diagonal p0-q1 when p < q, else q0-p1.
        total += _solid_angle_fraction(p0, q0, _Corner.where(low_first, q1, p1))
        total += _solid_angle_fraction(_Corner.where(low_first, p0, q0), q1, p1)
    return total


class _Corner:
    """A triangle corner relative to the query point: vector (k, 3) and its length (k,)."""

    def __init__(self, vector: np.ndarray, length: np.ndarray | None = None):
        self.vector = vector
        self.length = np.sqrt(np.einsum("...j,...j->...", vector, vector)) if length is None else length

    @staticmethod
    def where(mask: np.ndarray, a: _Corner, b: _Corner) -> _Corner:
        return _Corner(np.where(mask[:, None], a.vector, b.vector), np.where(mask, a.length, b.length))


def _solid_angle_fraction(a: _Corner, b: _Corner, c: _Corner) -> np.ndarray:
    """:func:`fracture_cli.geometry.trigeom.solid_angle_fraction` of corners whose lengths are known."""
    return trigeom.solid_angle_fraction(a.vector, b.vector, c.vector, (a.length, b.length, c.length))


def _near_plane(P: np.ndarray, V0: np.ndarray, X: np.ndarray, faces: np.ndarray, box: np.ndarray,
                qi: np.ndarray, tiny: float) -> tuple[np.ndarray, np.ndarray]:
    """The (box, point) pairs whose point ``P`` (k, 3) can be inside the prism swept by triangle ``faces[box]``.

    A triangle whose corners move from ``V0`` to ``X`` by at most ``r`` sweeps a prism within ``r`` of the
    plane of its old corners (every point of it is a convex combination of corners within that slab), and a
    closed surface's winding number is 0 outside a convex set holding it. Points farther than ``r`` from the
    plane are dropped: their prism winding numbers are 0 (up to rounding, far from the 0.5 the caller tests).
    Triangles whose doubled area is at most ``tiny`` have no reliable plane and keep every pair.
    """
    if len(box) == 0:
        return box, qi
    old, new = V0[faces], X[faces]  # (t, 3, 3)
    normal = np.cross(old[:, 1] - old[:, 0], old[:, 2] - old[:, 0])
    length = np.linalg.norm(normal, axis=1)
    reach = np.linalg.norm(new - old, axis=2).max(axis=1)
    offset = np.abs(np.einsum("ij,ij->i", P - old[box, 0], normal[box]))
    # The margin covers rounding.
    keep = (length[box] <= tiny) | (offset <= (reach[box] * (1.0 + 1e-6) + tol.SAME_POINT) * length[box])
    return box[keep], qi[keep]


class Containment:
    """Checks that a moved cage (same triangles ``F`` (b, 3), outward) still strictly contains ``surface``."""

    def __init__(self, surface: SurfaceMesh, V0: np.ndarray, F: np.ndarray):
        self.SV = np.asarray(surface.vertices, dtype=np.float64)
        self.SF = np.asarray(surface.faces, dtype=np.int64)
        self.V0 = V0
        self.F = np.asarray(F, dtype=np.int64)
        # Cage triangles whose doubled area is at most this have no reliable plane to filter pairs with (far
        # above the separating-axis test's own threshold for an axis, 1e-12 times its pairs' extent squared).
        extent = max(float(np.ptp(self.SV, axis=0).max(initial=0.0)) if len(self.SV) else 0.0,
                     float(np.ptp(V0, axis=0).max(initial=0.0)) if len(V0) else 0.0)
        self.tiny = 1e-9 * detmath.square(2.0 * extent)
        self.boxes, longest = _boxes_and_longest_edges(self.SV, self.SF)
        cell = _QUERY_CELL * trigeom.default_cell(trigeom.triangle_boxes(V0, self.F))
        # Short input triangles are found from their corners (every corner of a triangle meeting a box lies
        # within its longest edge of the box); the few long ones, whose corners may be far, in a grid of their
        # own. ``reach``: the longest edge of a short triangle.
        self.reach = _SHORT_EDGE * cell
        long_ = np.flatnonzero(longest > self.reach)
        self.long = long_
        self.long_grid = trigeom.BoxGrid(self.boxes[long_], trigeom.default_cell(self.boxes[long_])) if len(long_) \
            else None
        # Short triangles by corner (CSR).
        short_faces = np.flatnonzero(longest <= self.reach)
        corners = self.SF[short_faces].reshape(-1)
        self.corner_face = short_faces[np.argsort(corners, kind="stable") // 3]
        self.corner_start = np.concatenate([[0], np.cumsum(np.bincount(corners, minlength=len(self.SV)))])
        # The input's vertices (points as boxes), indexed once and queried with the few cage-sized boxes of
        # each round, in cells of a fifth of a cage triangle (cells of an input triangle's size made every
        # query span thousands of cells on a million-triangle input). Indexing the query boxes instead and
        # querying every input vertex each round was slower still.
        self.points = PointGrid(self.SV, cell)
        # Whether each cage triangle comes near the input, for the corners it had when last tested: most
        # touched triangles keep their corners from one round to the next.
        self.tested = np.full((len(self.F), 3, 3), np.nan)
        self.near = np.zeros(len(self.F), dtype=bool)
        # Likewise the prism winding numbers of each touched triangle at the input vertices near it, with the
        # corners they were computed for (pairs (point ids, values) by cage triangle).
        self.swept_tested = np.full((len(self.F), 3, 3), np.nan)
        self.swept: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def offenders(self, X: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """Moved vertices (ascending ids) to send back: the cage over ``X`` (n, 3) near ``moved`` (n,) is unsafe.

        Unsafe: a cage triangle at a moved vertex within ``_SLIDE_CLEARANCE`` of an input triangle (which also
        catches crossings) or crossing another cage triangle; an input vertex near a moved vertex that the
        moved cage no longer encloses (its triangles swept past it).
        """
        blame = np.zeros(len(X), dtype=bool)
        touched = np.asarray(moved[self.F].any(axis=1))
        if not touched.any():
            return np.zeros(0, dtype=np.int64)
        faces = self.F[touched]
        blame[faces[self._near_input_cached(X, np.flatnonzero(touched))].reshape(-1)] = True
        pairs = trigeom.self_intersections(X, self.F)
        crossing = pairs[touched[pairs].any(axis=1)]
        blame[self.F[crossing.reshape(-1)].reshape(-1)] = True
        blame[faces[self._swept_past(X, np.flatnonzero(touched))].reshape(-1)] = True
        return np.flatnonzero(blame & moved)

    def _near_input_cached(self, X: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Whether the cage triangles ``ids`` (t,) over ``X`` come near the input (t,) bool; see :meth:`_near_input`."""
        corners = X[self.F[ids]]
        stale = ~np.all(corners == self.tested[ids], axis=(1, 2))
        if stale.any():
            fresh = ids[stale]
            near = np.zeros(len(fresh), dtype=bool)
            near[self._near_input(X, self.F[fresh])] = True
            self.tested[fresh] = corners[stale]
            self.near[fresh] = near
        return self.near[ids]

    def _near_input(self, X: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Which cage triangles ``faces`` (t, 3) over ``X`` come within ``_SLIDE_CLEARANCE`` of an input triangle.

        The pairs tested are those of a box broad phase (query boxes padded by the clearance) less the pairs the
        separating-axis test would reject on the cage triangle's normal anyway (every corner of the input
        triangle farther than the clearance below its plane): only input triangles with a corner above that
        are gathered, through their corners, so most of a million-triangle input is never paired.
        """
        boxes = trigeom.triangle_boxes(X, faces)
        padded = boxes.copy()
        padded[:, 0] -= _SLIDE_CLEARANCE
        padded[:, 1] += _SLIDE_CLEARANCE
        box, point = self.points.query(padded, pad=self.reach)
        A = X[faces]
        normal = np.cross(A[:, 1] - A[:, 0], A[:, 2] - A[:, 0])
        length = np.linalg.norm(normal, axis=1)
        side = np.einsum("ij,ij->i", self.SV[point] - A[box, 0], normal[box])
        # SAME_POINT: the rounding allowance of this plane test, which stands in for the separating-axis test's own.
        reach = (_SLIDE_CLEARANCE + tol.SAME_POINT) * length[box]
        # A triangle is separated on the normal if all its corners are beyond the slab on one side; the
        # input lies below the outward cage, so gathering triangles from their corners not below the slab
        # finds every other one (and a few above it). Degenerate cage triangles keep every corner.
        keep = (length[box] <= self.tiny) | (side >= -reach)
        box, point = box[keep], point[keep]
        count = self.corner_start[point + 1] - self.corner_start[point]
        qi = np.repeat(box, count)
        local = np.arange(int(count.sum()), dtype=np.int64) - np.repeat(np.cumsum(count) - count, count)
        j = self.corner_face[np.repeat(self.corner_start[point], count) + local]
        if self.long_grid is not None:
            long_qi, long_j = self.long_grid.query(padded)
            qi, j = np.concatenate([qi, long_qi]), np.concatenate([j, self.long[long_j]])
        qi, j = _unique_pairs(qi, j, len(self.SF))
        overlap = np.all((padded[qi, 0] <= self.boxes[j, 1]) & (self.boxes[j, 0] <= padded[qi, 1]), axis=1)
        qi, j = qi[overlap], j[overlap]
        hit = trigeom.triangles_intersect(A[qi], self.SV[self.SF[j]], eps=_SLIDE_CLEARANCE)
        return np.unique(qi[hit])

    def _swept_past(self, X: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Cage triangles ``ids`` (t,) (positions into ``ids``) whose swept box holds an input vertex the moved
        cage over ``X`` no longer encloses."""
        faces = self.F[ids]
        corners = X[faces]
        stale = ~np.all(corners == self.swept_tested[ids], axis=(1, 2))
        if stale.any():
            fresh = ids[stale]
            box, qi, values = self._swept_pairs(X, self.F[fresh])
            order = np.argsort(box, kind="stable")
            cuts = np.searchsorted(box[order], np.arange(1, len(fresh)))
            for face, q, v in zip(fresh.tolist(), np.split(qi[order], cuts), np.split(values[order], cuts)):
                self.swept[face] = (q, v)
            self.swept_tested[fresh] = corners[stale]
        kept = [self.swept[face] for face in ids.tolist()]
        qi = np.concatenate([q for q, _ in kept])
        if not len(qi):
            return np.zeros(0, dtype=np.int64)
        values = np.concatenate([v for _, v in kept])
        box = np.repeat(np.arange(len(ids), dtype=np.int64), [len(q) for q, _ in kept])
        order = np.lexsort((box, qi))  # by point, then box: the order the sums below were defined in
        qi = qi[order]
        # The input is strictly inside the original cage (winding number 1) and only the touched
        # triangles changed: the winding number w.r.t. the moved cage is 1 plus the winding numbers of
        # the prisms the touched triangles swept (their side walls cancel between neighbours), and a
        # prism's winding number is 0 outside its box: only (point, box) pairs contribute.
        change = np.bincount(qi, weights=values[order], minlength=len(self.SV))
        points = qi[np.r_[True, qi[1:] != qi[:-1]]]  # np.unique(qi): qi is sorted
        outside = points[1.0 + change[points] < 0.5]
        if not len(outside):
            return np.zeros(0, dtype=np.int64)
        all_box, all_qi = self.points.query(_swept_boxes(self.V0, X, faces))
        return all_box[np.isin(all_qi, outside)]

    def _swept_pairs(self, X: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(box, point) pairs (p,) of triangles ``faces`` (t, 3) moved to ``X`` and input vertices that may be inside
        their prisms, with each prism's winding number (p,) there."""
        # Moving each touched triangle straight from its old to its new corners, the cage sweeps over a point
        # (changing its winding number) only inside the box of some triangle's old and new corners.
        all_box, all_qi = self.points.query(_swept_boxes(self.V0, X, faces))
        box, qi = _near_plane(self.SV[all_qi], self.V0, X, faces, all_box, all_qi, self.tiny)
        values = _prism_winding(self.SV[qi], self.V0, X, faces[box]) if len(qi) else np.zeros(0)
        return box, qi, values


def _swept_boxes(V0: np.ndarray, X: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Boxes (t, 2, 3) of the old and new corners of triangles ``faces`` (t, 3)."""
    swept = np.concatenate([V0[faces], X[faces]], axis=1)
    return np.stack([swept.min(axis=1), swept.max(axis=1)], axis=1)


def _boxes_and_longest_edges(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounding boxes (m, 2, 3) and longest edge lengths (m,) of triangles ``F`` (m, 3) over ``V`` (n, 3).

    The values of ``trigeom.triangle_boxes`` (minima and maxima of the corners) and
    :func:`fracture_cli.geometry.edgelengths.longest_edges`, from the three corner arrays rather than reductions over a
    (m, 3, 3) array, which took several times longer on a million triangles.
    """
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return (np.stack([np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)], axis=1),
            longest_edges(V, F))


def _unique_pairs(i: np.ndarray, j: np.ndarray, num_j: int) -> tuple[np.ndarray, np.ndarray]:
    """The distinct pairs ``(i, j)`` (p,), sorted by ``i`` then ``j``."""
    key = np.unique(i * np.int64(num_j) + j)
    return key // num_j, key % num_j
