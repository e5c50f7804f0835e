"""Compiled (numba) kernels of the per-collapse numeric work of :mod:`.decimate`.

A collapse measures a few dozen points against a few triangles: numpy's
overhead per call, not the arithmetic, was most of the simplify stage's time.
These kernels do the same arithmetic, in the same order, on scalars, so their
results are bit for bit those of the numpy expressions they replace (checked
in tests/test_simplify_kernels.py):

* dot products of 3-vectors add as ``np.einsum("ij,ij->i")`` does here,
  ``(x0 y0 + x2 y2) + x1 y1``; norms as ``np.linalg.norm(axis=1)``, in order;
* the closest point on a triangle follows
  :func:`fracture_cli.geometry.trigeom.closest_points` region by region (its later
  regions override earlier ones: here the first that holds, in reverse);
* the quadric error adds ``(p_j Q_jk) p_k`` over j, then k, as
  ``np.einsum("ij,jk,ik->i")``.

It also holds the numpy set-up of a complex (its quadrics, the cell of its
grid of cut faces). This module imports numba: :mod:`.decimate` imports it only when a complex is
built, so other stages do not pay for it. Compiled code is cached (``cache=True``:
beside this file, or in the user's cache directory when that is read-only);
``error_model="numpy"`` makes a division by zero give inf or nan as numpy does.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.system.jit import njit


def grid_cell(triangles: np.ndarray) -> float:
    """A cell size for the grid of the centroids of ``triangles`` (r, 3, 3): twice their mean edge length, a
    few centroids per cell on a surface, at most 2**21 cells."""
    edges = np.linalg.norm(triangles - triangles[:, [1, 2, 0]], axis=2)
    extent = float((triangles.reshape(-1, 3).max(axis=0) - triangles.reshape(-1, 3).min(axis=0)).max())
    return max(2.0 * float(edges.mean()), extent / 128.0, 1e-9)


def quadrics(V: np.ndarray, faces: np.ndarray, fault: np.ndarray, n: int) -> np.ndarray:
    """Area-weighted plane quadrics (n, 4, 4) of the fault faces around every vertex (zero on outer faces)."""
    F = np.asarray(faces, dtype=np.int64)[np.asarray(fault, dtype=bool)]
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    normal = np.cross(b - a, c - a)
    area = np.linalg.norm(normal, axis=1)
    unit = normal / np.maximum(area, tol.SMALLEST_DIVISOR)[:, None]
    plane = np.sqrt(area)[:, None] * np.column_stack([unit, -np.einsum("ij,ij->i", unit, a)])
    outer = np.einsum("fi,fj->fij", plane, plane)
    Q = np.zeros((n, 4, 4))
    for k in range(3):
        np.add.at(Q, F[:, k], outer)
    return Q


@njit(cache=True, error_model="numpy")
def _point_triangle(px: float, py: float, pz: float, ax: float, ay: float, az: float, bx: float, by: float,
                    bz: float, cx: float, cy: float, cz: float) -> float:  # pragma: no cover (compiled)
    """Distance from point p to triangle (a, b, c), as :func:`fracture_cli.geometry.trigeom.point_triangle_distance`."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = (abx * apx + abz * apz) + aby * apy
    d2 = (acx * apx + acz * apz) + acy * apy
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d3 = (abx * bpx + abz * bpz) + aby * bpy
    d4 = (acx * bpx + acz * bpz) + acy * bpy
    d5 = (abx * cpx + abz * cpz) + aby * cpy
    d6 = (acx * cpx + acz * cpz) + acy * cpy
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    if d1 <= 0 and d2 <= 0:
        ox, oy, oz = ax, ay, az
    elif d3 >= 0 and d4 <= d3:
        ox, oy, oz = bx, by, bz
    elif d6 >= 0 and d5 <= d6:
        ox, oy, oz = cx, cy, cz
    elif vc <= 0 and d1 >= 0 and d3 <= 0:
        t = d1 / (d1 - d3)
        ox, oy, oz = ax + abx * t, ay + aby * t, az + abz * t
    elif vb <= 0 and d2 >= 0 and d6 <= 0:
        t = d2 / (d2 - d6)
        ox, oy, oz = ax + acx * t, ay + acy * t, az + acz * t
    elif va <= 0 and d4 >= d3 and d5 >= d6:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        ox, oy, oz = bx + (cx - bx) * t, by + (cy - by) * t, bz + (cz - bz) * t
    else:
        denom = va + vb + vc
        s = vb / denom
        t = vc / denom
        ox, oy, oz = ax + abx * s + acx * t, ay + aby * s + acy * t, az + abz * s + acz * t
    # A coordinate that is not finite falls back to corner a's, one by one (numpy's where(isfinite, out, a)).
    if not np.isfinite(ox):
        ox = ax
    if not np.isfinite(oy):
        oy = ay
    if not np.isfinite(oz):
        oz = az
    dx, dy, dz = px - ox, py - oy, pz - oz
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, error_model="numpy")
def point_triangle_distances(P: np.ndarray, T: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    """Distances (k,) from points P (k, 3) to triangles T (k, 3, 3) (for tests against numpy)."""
    out = np.empty(len(P))
    for i in range(len(P)):
        out[i] = _point_triangle(P[i, 0], P[i, 1], P[i, 2], T[i, 0, 0], T[i, 0, 1], T[i, 0, 2], T[i, 1, 0],
                                 T[i, 1, 1], T[i, 1, 2], T[i, 2, 0], T[i, 2, 1], T[i, 2, 2])
    return out


@njit(cache=True)
def probes(V: np.ndarray, tris: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    """The points (4k, 3) of triangles ``tris`` (k, 3) over ``V`` (n, 3) held near the cut fault.

    The k centroids, then per triangle the midpoints of edges 01, 12, 20 (as ``T.mean(axis=1)`` and
    ``(T + T[:, [1, 2, 0]]) / 2``).
    """
    k = len(tris)
    Q = np.empty((4 * k, 3))
    for i in range(k):
        a, b, c = tris[i, 0], tris[i, 1], tris[i, 2]
        for j in range(3):
            Q[i, j] = ((V[a, j] + V[b, j]) + V[c, j]) / 3.0
            Q[k + 3 * i, j] = (V[a, j] + V[b, j]) / 2.0
            Q[k + 3 * i + 1, j] = (V[b, j] + V[c, j]) / 2.0
            Q[k + 3 * i + 2, j] = (V[c, j] + V[a, j]) / 2.0
    return Q


@njit(cache=True)
def _to_triangle(V: np.ndarray, p: np.ndarray, a: int, b: int, c: int) -> float:  # pragma: no cover (compiled)
    return _point_triangle(p[0], p[1], p[2], V[a, 0], V[a, 1], V[a, 2], V[b, 0], V[b, 1], V[b, 2], V[c, 0],
                           V[c, 1], V[c, 2])


@njit(cache=True)
def within_tolerance(V: np.ndarray, points: np.ndarray, tris: np.ndarray, Q: np.ndarray, reference: np.ndarray,
                     near: np.ndarray, tolerance: float) -> np.ndarray:  # pragma: no cover (compiled)
    """The error bound of one collapse: for each removed fault point, its nearest new fault face, or none.

    Parameters
    ----------
    V : (n, 3) float
        Vertex positions.
    points : (p,) int
        The removed fault points (vertex ids).
    tris : (k, 3) int
        The new fault faces.
    Q : (q, 3) float
        :func:`probes` of ``tris``.
    reference : (r, 3, 3) float
        The cut fault faces.
    near : (q, c) int
        Rows of ``reference`` nearest each point of ``Q``.
    tolerance : float

    Returns
    -------
    nearest : (p,) int
        Index into ``tris`` of the face nearest each point (the first of equals), when every point lies
        within ``tolerance`` of a new face and every point of ``Q`` within ``tolerance`` of a cut face;
        an empty array otherwise.
    """
    failed = np.empty(0, dtype=np.int64)
    for i in range(len(Q)):
        best = np.inf
        for j in range(near.shape[1]):
            R = reference[near[i, j]]
            d = _point_triangle(Q[i, 0], Q[i, 1], Q[i, 2], R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2],
                                R[2, 0], R[2, 1], R[2, 2])
            if d < best:
                best = d
        if best > tolerance:
            return failed
    nearest = np.empty(len(points), dtype=np.int64)
    for i in range(len(points)):
        p = V[points[i]]
        best = np.inf
        at = 0
        for j in range(len(tris)):
            d = _to_triangle(V, p, tris[j, 0], tris[j, 1], tris[j, 2])
            if d < best:
                best, at = d, j
        if best > tolerance:
            return failed
        nearest[i] = at
    return nearest


@njit(cache=True)
def quadric_costs(H: np.ndarray, quadric: np.ndarray, u: int, targets: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Quadric errors (t,) of moving vertex ``u`` onto each of ``targets`` (t,): p Q_u p with p = ``H`` (n, 4) rows,
    ``quadric`` (n, 4, 4), added as ``np.einsum("ij,jk,ik->i")`` adds."""
    Q = quadric[u]
    out = np.empty(len(targets))
    for i in range(len(targets)):
        p = H[targets[i]]
        s = 0.0
        for j in range(4):
            for k in range(4):
                s += (p[j] * Q[j, k]) * p[k]
        out[i] = s
    return out


@njit(cache=True)
def grid_index(X: np.ndarray, cell: float) -> tuple:  # pragma: no cover (compiled)
    """A uniform grid over points X (n, 3) for :func:`nearest`: (origin (3,), dims (3,), starts (c + 1,),
    order (n,)), the points of cell c being ``order[starts[c]:starts[c + 1]]`` (ascending ids)."""
    origin = np.empty(3)
    dims = np.empty(3, dtype=np.int64)
    for j in range(3):
        origin[j] = X[:, j].min()
        dims[j] = int((X[:, j].max() - origin[j]) / cell) + 1
    key = np.empty(len(X), dtype=np.int64)
    for i in range(len(X)):
        c = 0
        for j in range(3):
            c = c * dims[j] + min(int((X[i, j] - origin[j]) / cell), dims[j] - 1)
        key[i] = c
    order = np.argsort(key, kind="mergesort")
    starts = np.zeros(dims[0] * dims[1] * dims[2] + 1, dtype=np.int64)
    for i in range(len(X)):
        starts[key[i] + 1] += 1
    for c in range(len(starts) - 1):
        starts[c + 1] += starts[c]
    return origin, dims, starts, order


@njit(cache=True)
def nearest(X: np.ndarray, grid: tuple, cell: float, Q: np.ndarray, k: int) -> np.ndarray:  # pragma: no cover
    """Rows (q, k) of X (n, 3) nearest each point of Q (q, 3), by squared distance then id (the grid of
    :func:`grid_index`): the cells are searched in shells of growing Chebyshev distance until the k-th
    nearest is closer than any point of the next shell can be."""
    origin, dims, starts, order = grid
    out = np.empty((len(Q), k), dtype=np.int64)
    best = np.empty(k)
    ids = np.empty(k, dtype=np.int64)
    home = np.empty(3, dtype=np.int64)
    for q in range(len(Q)):
        found = 0
        span = 0
        for j in range(3):
            home[j] = int(np.floor((Q[q, j] - origin[j]) / cell))
            span = max(span, home[j], dims[j] - 1 - home[j])
        for r in range(span + 1):
            for a in range(max(home[0] - r, 0), min(home[0] + r, dims[0] - 1) + 1):
                for b in range(max(home[1] - r, 0), min(home[1] + r, dims[1] - 1) + 1):
                    edge = abs(a - home[0]) == r or abs(b - home[1]) == r
                    step = 1 if edge else 2 * r
                    c = home[2] - r if r > 0 else home[2]
                    while c <= home[2] + r:
                        if 0 <= c < dims[2]:
                            key = (a * dims[1] + b) * dims[2] + c
                            for s in range(starts[key], starts[key + 1]):
                                i = order[s]
                                dx, dy, dz = Q[q, 0] - X[i, 0], Q[q, 1] - X[i, 1], Q[q, 2] - X[i, 2]
                                d = dx * dx + dy * dy + dz * dz
                                if found < k or d < best[found - 1] or (d == best[found - 1] and i < ids[found - 1]):
                                    m = found if found < k else k - 1
                                    while m > 0 and (best[m - 1] > d or (best[m - 1] == d and ids[m - 1] > i)):
                                        if m < k:
                                            best[m], ids[m] = best[m - 1], ids[m - 1]
                                        m -= 1
                                    best[m], ids[m] = d, i
                                    found = min(found + 1, k)
                        c += step
            # A point in a cell r + 1 shells away is more than r cells away along some axis (the margin: rounding
            # in the cell of a point).
            if found == k and best[k - 1] < (r * cell * (1.0 - tol.TIE)) * (r * cell * (1.0 - tol.TIE)):
                break
        out[q] = ids
    return out


@njit(cache=True)
def fault_bound(V: np.ndarray, points: np.ndarray, tris: np.ndarray, reference: np.ndarray, centroids: np.ndarray,
                origin: np.ndarray, dims: np.ndarray, starts: np.ndarray, order: np.ndarray, cell: float, k: int,
                tolerance: float) -> np.ndarray:  # pragma: no cover (compiled)
    """:func:`within_tolerance` of a collapse, its probes' ``k`` nearest cut faces found in the grid of their
    ``centroids`` (:func:`grid_index`: origin, dims, starts, order): one call per collapse."""
    Q = probes(V, tris)
    near = nearest(centroids, (origin, dims, starts, order), cell, Q, k)
    return within_tolerance(V, points, tris, Q, reference, near, tolerance)
