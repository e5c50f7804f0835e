"""Tie points of a piecewise-linear field and the fan triangulation of keyed polygons (multi-label marching tets)."""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.stages.smooth.topology import SINGULAR_TOL, combinations
from fracture_cli.system import detmath


def tie_points(V: np.ndarray, Zv: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points inside simplices where ``k + 1`` pieces tie for the maximum of the field.

    Parameters
    ----------
    V : (n, 3) float64
    Zv : (n, p) float64
        Field at the vertices.
    S : (N, k + 1) int64
        Simplices (edges, faces or tets), vertex ids sorted ascending.

    Returns
    -------
    simplex : (r,) int64
        Row of ``S`` each point lies strictly inside, ascending.
    tie : (r, k + 1) int64
        The tied pieces, ascending.
    position : (r, 3) float64

    Notes
    -----
    Every point is computed from its simplex's own vertex values only (in a
    canonical vertex and piece order), so all tets that share the simplex see
    a bit-identical point.
    """
    k1 = S.shape[1]
    kept = np.arange(len(S))
    if Zv.shape[1] > 1 and len(S):
        # Most simplices lie inside one region: one piece wins at every corner, and even the runner-up at
        # any corner stays below its value at every corner, so no other piece is a candidate (the test
        # below would skip them). Dropping them first keeps the (N, k+1, p) arrays small.
        # (Which of tied best pieces argmax picks does not matter: a tie fails the margin test.)
        best = Zv.argmax(axis=1)
        z2, z1 = np.partition(Zv, -2, axis=1)[:, -2:].T
        clear = np.all(best[S] == best[S[:, :1]], axis=1) & (z2[S].max(axis=1) < z1[S].min(axis=1) - tol.ROUNDOFF)
        kept = np.flatnonzero(~clear)
        S = S[kept]
    Zs = Zv[S]  # (N, k+1, p)
    floor = Zs.min(axis=1).max(axis=1)
    # Pieces that can win somewhere on the simplex (necessary test, with a margin for rounding: field values
    # are O(1)).
    cand = Zs.max(axis=1) >= floor[:, None] - tol.ROUNDOFF
    counts = cand.sum(axis=1)
    out_s, out_tie, out_pos = [], [], []
    for m in np.unique(counts).tolist():
        if m < k1:
            continue
        group = np.flatnonzero(counts == m)
        cidx = np.nonzero(cand[group])[1].reshape(-1, m)  # (N, m) sorted piece ids
        G = np.take_along_axis(Zs[group], cidx[:, None, :], axis=2)  # (N, k+1, m)
        combos = combinations(m, k1)  # (C, k+1)
        Gc = G[:, :, combos].transpose(0, 2, 3, 1)  # (N, C, k+1 pieces, k+1 corners)
        A = np.empty(Gc.shape)
        A[:, :, :-1, :] = Gc[:, :, :1, :] - Gc[:, :, 1:, :]
        A[:, :, -1, :] = 1.0
        rows = np.linalg.norm(A, axis=3).prod(axis=2)
        ok = np.abs(np.linalg.det(A)) > SINGULAR_TOL * rows
        A[~ok] = np.eye(k1)
        rhs = np.zeros(A.shape[:3] + (1,))
        rhs[:, :, -1, 0] = 1.0
        beta = np.linalg.solve(A, rhs)[..., 0]  # (N, C, k+1)
        values = np.einsum("nkm,nck->ncm", G, beta)  # every candidate's value at every point
        in_tie = np.zeros((len(combos), m), dtype=bool)
        in_tie[np.arange(len(combos))[:, None], combos] = True
        tie_value = np.where(in_tie, values, np.inf).min(axis=2)
        other = np.where(in_tie, -np.inf, values).max(axis=2)
        feasible = ok & (beta > 0.0).all(axis=2) & (tie_value >= other)
        ni, ci = np.nonzero(feasible)
        out_s.append(group[ni])
        out_tie.append(np.take_along_axis(cidx[ni], combos[ci], axis=1))
        out_pos.append(np.einsum("rk,rkd->rd", beta[ni, ci], V[S[group[ni]]]))
    if not out_s:
        return np.zeros(0, np.int64), np.zeros((0, k1), np.int64), np.zeros((0, 3))
    simplex = np.concatenate(out_s)
    order = np.argsort(simplex, kind="stable")
    return kept[simplex[order]], np.concatenate(out_tie)[order], np.concatenate(out_pos)[order]


def fan(poly: np.ndarray, keys: np.ndarray, normals: np.ndarray, positions: np.ndarray,
        centre_ids: np.ndarray | None = None, centre_pos: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate convex polygons given as unordered vertex sets.

    Parameters
    ----------
    poly : (r,) int64
        Polygon id of each incidence row (ids 0..q-1).
    keys : (r,) int64
        Global vertex id of each row.
    normals : (q, 3) float64
        Orientation of each polygon: its vertices are ordered counter-clockwise
        about it.
    positions : (v, 3) float64
        Global vertex positions.

    Returns
    -------
    triangles : (s, 3) int64 global vertex ids
    owner : (s,) int64 polygon of each triangle

    Notes
    -----
    Each polygon is fanned from its smallest vertex id, so a polygon computed
    once and emitted for both of its sides is triangulated identically.
    Polygons with fewer than three vertices are dropped. With ``centre_ids``
    (q,) and ``centre_pos`` (q, 3), polygons are star-shaped about their
    centres (e.g. triangles with extra vertices on their edges) and are fanned
    from them instead.
    """
    q = len(normals)
    if len(poly) == 0:
        return np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    count = np.bincount(poly, minlength=q)
    P = positions[keys]
    centre = np.zeros((q, 3))
    for d in range(3):
        centre[:, d] = np.bincount(poly, weights=P[:, d], minlength=q)
    centre /= np.maximum(count, 1)[:, None]
    if centre_pos is not None:
        centre = centre_pos
    nrm = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    helper = np.where(np.abs(nrm[:, :1]) < 0.6, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(nrm, helper)
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    w = np.cross(nrm, u)
    d = P - centre[poly]
    angle = detmath.atan2(np.einsum("ij,ij->i", d, w[poly]), np.einsum("ij,ij->i", d, u[poly]))
    order = np.lexsort((keys, angle, poly))
    poly, keys = poly[order], keys[order]
    start = np.cumsum(count) - count
    # Rotate each cycle to start at its smallest vertex id.
    local = np.arange(len(poly)) - start[poly]
    smallest = np.full(q, np.iinfo(np.int64).max)
    np.minimum.at(smallest, poly, keys)
    first_local = np.zeros(q, np.int64)
    is_min = keys == smallest[poly]
    first_local[poly[is_min]] = local[is_min]
    L = count
    if centre_ids is not None:
        tri_poly = poly
        following = np.where(local + 1 < L[poly], np.arange(len(poly)) + 1, start[poly])
        tri = np.stack([centre_ids[poly], keys, keys[following]], axis=1)
        return tri, tri_poly
    ntri = np.maximum(L - 2, 0)
    tri_poly = np.repeat(np.arange(q), ntri)
    j = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1  # 1..L-2
    base = start[tri_poly]
    f0 = first_local[tri_poly]
    Lp = L[tri_poly]
    tri = np.stack([keys[base + f0], keys[base + (f0 + j) % Lp], keys[base + (f0 + j + 1) % Lp]], axis=1)
    return tri, tri_poly
