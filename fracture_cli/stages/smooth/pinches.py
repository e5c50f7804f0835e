"""Spindles carved around tet edges where a tet-aligned region would touch itself (ALGORITHM.md section 5)."""

from __future__ import annotations

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry import tetgeom
from fracture_cli.stages.smooth.options import STAGE
from fracture_cli.stages.smooth.topology import FACE_EDGE_PAIRS, Topology

# Relative width of the spindle carved around an edge where a tet-aligned region
# touches itself: its notches sit this fraction of the way from the edge's
# midpoint to the opposite vertices (volume change eps^2 of the tets around it).
_PINCH_SPINDLE = 0.02


def aligned_pinches(V: np.ndarray, T: np.ndarray, topo: Topology, forced: np.ndarray, tet_piece: np.ndarray, p: int,
                    aligned: np.ndarray, X1: np.ndarray, X2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges, all of whose tets are forced, around which some piece's tets form two or more runs.

    Returns the pinched edge ids (ascending) and the piece that gets each edge's spindle (the piece with
    the most volume around the edge, lowest id on a tie).
    """
    E = len(topo.edges)
    not_all_forced = np.zeros(E, dtype=bool)
    not_all_forced[topo.tet_edges[~forced].reshape(-1)] = True
    te = topo.tet_edges.reshape(-1)
    tp = np.repeat(tet_piece, 6)
    keep = ~not_all_forced[te]
    code = te[keep] * p + tp[keep]
    vol = np.repeat(np.abs(tetgeom.tet_volumes(V, T)), 6)[keep]
    ucode, inverse, n_tets = np.unique(code, return_inverse=True, return_counts=True)
    # Faces around an edge that glue two tets of the same piece join consecutive runs.
    glued = np.flatnonzero(aligned & (X1 == X2))
    ge = topo.face_edges[glued].reshape(-1)
    gcode = ge * p + np.repeat(X1[glued], 3)
    gcode = gcode[np.isin(gcode, ucode)]
    n_glued = np.bincount(np.searchsorted(ucode, gcode), minlength=len(ucode))
    runs = n_tets - n_glued
    bad_edges = np.unique(ucode[runs >= 2] // p)
    if len(bad_edges) == 0:
        return bad_edges, bad_edges
    ring_vol = np.bincount(inverse.reshape(-1), weights=vol, minlength=len(ucode))
    edge_of = ucode // p
    sel = np.isin(edge_of, bad_edges)
    e_sel, piece_sel, vol_sel = edge_of[sel], ucode[sel] % p, ring_vol[sel]
    order = np.lexsort((piece_sel, -vol_sel, e_sel))  # per edge: largest volume, then lowest id
    e_sorted = e_sel[order]
    first = np.r_[True, e_sorted[1:] != e_sorted[:-1]]
    return e_sorted[first], piece_sel[order][first]


def notches(V: np.ndarray, topo: Topology, pinched: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Notch vertices in every face next to a pinched edge.

    Returns, per notch, its face (ascending), its edge and its position
    ``m + eps (w - m)``: ``m`` the edge's midpoint, ``w`` the face's third
    vertex, computed from that face's vertices only.
    """
    face, local = np.nonzero(np.isin(topo.face_edges, pinched))
    edge = topo.face_edges[face, local]
    pair = FACE_EDGE_PAIRS[local]
    verts = topo.faces[face]
    u = np.take_along_axis(verts, pair[:, :1], axis=1)[:, 0]
    v = np.take_along_axis(verts, pair[:, 1:], axis=1)[:, 0]
    w = verts.sum(axis=1) - u - v
    mid = (V[u] + V[v]) / 2.0
    return face, edge, mid + _PINCH_SPINDLE * (V[w] - mid)


def spindle_faces(V: np.ndarray, T: np.ndarray, topo: Topology, tet_piece: np.ndarray, pinched: np.ndarray,
                  owner: np.ndarray, n_face: np.ndarray, n_edge: np.ndarray, nid: np.ndarray,
                  X2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangles of the spindles carved around pinched tet-aligned edges.

    Around a pinched edge ``(a, b)`` each tet ``(a, b, c, d)`` loses the
    sliver tet ``(a, b, n_c, n_d)`` (``n_c``, ``n_d`` the notches of its two
    faces at the edge) to the edge's spindle piece. The spindle meets the rest
    of the mesh only at ``a`` and ``b``, so pieces that touched each other
    along the edge now touch at points at most, and the spindle's piece
    surrounds the edge. Volumes change by ``eps^2`` of the tets around the
    edge.

    Returns triangles (s, 3), their pieces (s,) and the pieces of their back
    sides (s,) (-1: none).
    """
    notch = {(f, e): i for f, e, i in zip(n_face.tolist(), n_edge.tolist(), nid.tolist())}
    npos = {i: x for i, x in zip(nid.tolist(), notches(V, topo, pinched)[2])}
    rows: list[tuple] = []
    for f, e, i in zip(n_face.tolist(), n_edge.tolist(), nid.tolist()):
        if X2[f] < 0:  # the sliver's face on the cage boundary, oriented like the face
            u, v = [x for x in topo.face_oriented[f].tolist() if x in topo.edges[e]]
            oriented = topo.face_oriented[f].tolist()
            if (oriented.index(u) + 1) % 3 != oriented.index(v):
                u, v = v, u
            rows.append((u, v, i, int(owner[np.searchsorted(pinched, e)]), -1))
    for e, Q in zip(pinched.tolist(), owner.tolist()):
        a, b = topo.edges[e].tolist()
        for t in np.flatnonzero((topo.tet_edges == e).any(axis=1)).tolist():
            X = int(tet_piece[t])
            if X == Q:
                continue
            c, d = [int(x) for x in T[t] if x != a and x != b]
            nc, nd = notch[(face_id(topo, t, (a, b, c)), e)], notch[(face_id(topo, t, (a, b, d)), e)]
            xa, xb = V[a], V[b]
            if np.linalg.det(np.stack([xb - xa, npos[nc] - xa, npos[nd] - xa])) > 0:
                rows += [(b, nc, nd, Q, X), (a, nd, nc, Q, X)]
            else:
                rows += [(b, nd, nc, Q, X), (a, nc, nd, Q, X)]
    out = np.array(rows, dtype=np.int64).reshape(-1, 5)
    return out[:, :3], out[:, 3], out[:, 4]


def face_id(topo: Topology, t: int, vertices: tuple[int, ...]) -> int:
    """The id of the face of tet ``t`` with the given vertices."""
    target = sorted(vertices)
    for f in topo.tet_faces[t].tolist():
        if topo.faces[f].tolist() == target:
            return f
    raise StageError("internal error: a tet does not contain its face", stage=STAGE)

