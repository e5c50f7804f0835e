"""Regions built directly from the tet mesh: multi-label marching tets with combinatorial vertex keys.

:func:`direct_regions` turns a piece field (or tet-aligned pieces) into one
closed mesh per piece; :func:`repaired_regions` makes tets tet-aligned where a
region would touch itself along a line. ALGORITHM.md section 5 explains the
construction.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry import tetgeom
from fracture_cli.geometry.rows import group_rows
from fracture_cli.stages.smooth.pinches import aligned_pinches, notches, spindle_faces
from fracture_cli.stages.smooth.ties import fan, tie_points
from fracture_cli.stages.smooth.topology import Topology, join

# Rounds of making tets tet-aligned where a region touches itself along a line.
_MAX_REPAIRS = 12


def repaired_regions(V: np.ndarray, T: np.ndarray, topo: Topology, Zv: np.ndarray | None, forced: np.ndarray,
                     tet_piece: np.ndarray, p: int,
                     first: tuple | None = None) -> tuple[list[tuple[np.ndarray, np.ndarray]], int, int]:
    """Direct regions; where a region touches itself along a line, the tets there become tet-aligned (repeatedly).

    ``first``, when given, is :func:`direct_regions`' result for exactly these arguments (the caller built it
    already). Returns the meshes, the number of spindles carved and of tets made tet-aligned.
    """
    forced = forced.copy()
    start = int(forced.sum())
    for _ in range(_MAX_REPAIRS):
        if first is not None:
            (meshes, pinches, defects), first = first, None
        else:
            meshes, pinches, defects = direct_regions(V, T, topo, Zv, forced, tet_piece, p)
        if not defects or forced.all():
            break
        # A defect edge lies in the simplex spanned by its end points' simplices: the tets around that
        # simplex's vertices keep their own pieces (whole stars, so that this converges in few rounds).
        before = int(forced.sum())
        corners = np.unique(np.concatenate([site[site >= 0] for site in defects]))
        forced |= np.isin(T, corners).any(axis=1)
        if int(forced.sum()) == before:
            break
    return meshes, pinches, int(forced.sum()) - start


class _Builder:
    """Output vertices (position and the simplex each lies in) and the triangles emitted per piece.

    Every vertex has a combinatorial identity: ``sites`` rows hold the tet
    vertices spanning its simplex (-1 padded), so a defect can be traced back
    to the tets around it.
    """

    def __init__(self, V: np.ndarray):
        n = len(V)
        self.blocks: list[np.ndarray] = [V]
        self.sites: list[np.ndarray] = [np.column_stack([np.arange(n), np.full((n, 3), -1)])]
        self.next_id = n
        self.tris: list[np.ndarray] = []
        self.piece: list[np.ndarray] = []

    def add(self, positions: np.ndarray, simplices: np.ndarray) -> np.ndarray:
        """Append vertices (k, 3) lying in ``simplices`` (k, 2..4); returns their ids (k,)."""
        ids = self.next_id + np.arange(len(positions))
        self.blocks.append(positions)
        self.sites.append(np.pad(simplices, ((0, 0), (0, 4 - simplices.shape[1])), constant_values=-1))
        self.next_id += len(positions)
        return ids

    def positions(self) -> np.ndarray:
        return np.concatenate(self.blocks)

    def emit(self, tris: np.ndarray, pieces: np.ndarray, both: np.ndarray | None = None) -> None:
        """Triangles for ``pieces`` and, reversed, for ``both`` (where >= 0)."""
        self.tris.append(tris)
        self.piece.append(pieces)
        if both is not None:
            keep = both >= 0
            self.tris.append(tris[keep][:, ::-1])
            self.piece.append(both[keep])


@dataclass(frozen=True)
class _Ties:
    """Tie points used by the field tets: simplex ids (ascending), tied pieces and output vertex ids."""

    es: np.ndarray  # (a,) edges
    etie: np.ndarray  # (a, 2)
    eid: np.ndarray  # (a,)
    fs: np.ndarray  # (b,) faces
    ftie: np.ndarray  # (b, 3)
    fid: np.ndarray  # (b,)
    ts: np.ndarray  # (c,) tets
    ttie: np.ndarray  # (c, 4)
    tid: np.ndarray  # (c,)

    @classmethod
    def none(cls) -> _Ties:
        e = np.zeros(0, np.int64)
        return cls(e, np.zeros((0, 2), np.int64), e, e, np.zeros((0, 3), np.int64), e, e,
                   np.zeros((0, 4), np.int64), e)


def direct_regions(V: np.ndarray, T: np.ndarray, topo: Topology, Zv: np.ndarray | None, forced: np.ndarray,
                   tet_piece: np.ndarray, p: int,
                   check: bool = True) -> tuple[list[tuple[np.ndarray, np.ndarray]], int, list[np.ndarray]]:
    """Boundary meshes of every piece's region, built directly from keyed polygons.

    Parameters
    ----------
    V : (n, 3) float64
    T : (t, 4) int64
        Positively oriented tets.
    topo : Topology
    Zv : (n, p) float64 or None
        Field deciding the winner in the tets that are not ``forced``.
    forced : (t,) bool
        Tets that belong wholly to ``tet_piece`` (all of them when ``Zv`` is None).
    tet_piece : (t,) int64
    p : int
    check : bool, optional (default True)
        Look for edges that are not closed and manifold (the third result).

    Returns
    -------
    meshes : list of (vertices (n_i, 3) float64, faces (m_i, 3) int64)
    pinches : int
        Edges where a tet-aligned region touched itself and a spindle was carved.
    defects : list of (2, 4) int64
        For each defect edge, the simplices (tet vertices, -1 padded) of its two end points.

    Notes
    -----
    ALGORITHM.md section 5 ("Direct construction"). Each output vertex's
    position is computed once from its simplex's data, so the polygons of
    neighbouring pieces share vertices exactly; each fault polygon is
    triangulated once and emitted for both sides with opposite orientation.
    """
    out = _Builder(V)
    has2 = topo.face_tets[:, 1] >= 0
    side_forced = forced[topo.face_tets]  # (f, 2); the value for a missing side is ignored
    side_forced[~has2, 1] = True
    field = ~forced
    ties = _Ties.none()
    if field.any():
        assert Zv is not None, "tets not forced need a field"  # internal invariant, not user input
        ties = _field_ties(out, V, T, topo, Zv, field)
        _cell_polygons(out, V, T, topo, Zv, ties, np.flatnonzero(field), p)
        _field_face_polygons(out, topo, Zv, ties, side_forced, has2, tet_piece, p)
    pinches = _aligned_polygons(out, V, T, topo, forced, side_forced, has2, tet_piece, p, ties)
    positions = out.positions()
    tris = np.concatenate(out.tris) if out.tris else np.zeros((0, 3), np.int64)
    owner = np.concatenate(out.piece) if out.piece else np.zeros(0, np.int64)
    order = np.argsort(owner, kind="stable")
    tris, owner = tris[order], owner[order]
    bounds = np.searchsorted(owner, np.arange(p + 1))
    meshes = []
    for P in range(p):
        faces = tris[bounds[P]:bounds[P + 1]]
        used, local = np.unique(faces, return_inverse=True)
        meshes.append((positions[used], local.reshape(-1, 3).astype(np.int64)))
    defects = _defect_edges(positions, tris, owner) if check else []
    site_table = np.concatenate(out.sites)
    return meshes, pinches, [site_table[list(edge)] for edge in defects]


def _field_ties(out: _Builder, V: np.ndarray, T: np.ndarray, topo: Topology, Zv: np.ndarray,
                field: np.ndarray) -> _Ties:
    """The tie points on the edges, faces and insides of the ``field`` (t,) bool tets, added to ``out``."""
    # Tie points depend on the field only: computed once per field for all simplices, then selected.
    if topo.ties is None or topo.ties[0] is not Zv:
        topo.ties = (Zv, tie_points(V, Zv, topo.edges), tie_points(V, Zv, topo.faces),
                     tie_points(V, Zv, np.sort(T, axis=1)))
    ftets = np.flatnonzero(field)
    e_used = np.zeros(len(topo.edges), dtype=bool)
    e_used[topo.tet_edges[ftets]] = True
    f_used = np.zeros(len(topo.faces), dtype=bool)
    f_used[topo.tet_faces[ftets]] = True
    (es, etie, epos), (fs, ftie, fpos), (ts, ttie, tpos) = topo.ties[1:]
    keep_e, keep_f, keep_t = e_used[es], f_used[fs], field[ts]
    es, etie, epos = es[keep_e], etie[keep_e], epos[keep_e]
    fs, ftie, fpos = fs[keep_f], ftie[keep_f], fpos[keep_f]
    ts, ttie, tpos = ts[keep_t], ttie[keep_t], tpos[keep_t]
    eid = out.add(epos, topo.edges[es])
    fid = out.add(fpos, topo.faces[fs])
    tid = out.add(tpos, T[ts])
    return _Ties(es, etie, eid, fs, ftie, fid, ts, ttie, tid)


def _cell_polygons(out: _Builder, V: np.ndarray, T: np.ndarray, topo: Topology, Zv: np.ndarray, ties: _Ties,
                   ftets: np.ndarray, p: int) -> None:
    """Polygons between two pieces' cells inside a tet: all tie points with both pieces in the tie."""
    f_tet, f_P, f_Q, f_key = [], [], [], []
    rows, idx = join(topo.tet_edges[ftets].reshape(-1), ties.es)
    f_tet.append(np.repeat(ftets, 6)[rows])
    f_P.append(ties.etie[idx, 0])
    f_Q.append(ties.etie[idx, 1])
    f_key.append(ties.eid[idx])
    rows, idx = join(topo.tet_faces[ftets].reshape(-1), ties.fs)
    for a, b in ((0, 1), (0, 2), (1, 2)):
        f_tet.append(np.repeat(ftets, 4)[rows])
        f_P.append(ties.ftie[idx, a])
        f_Q.append(ties.ftie[idx, b])
        f_key.append(ties.fid[idx])
    for a, b in itertools.combinations(range(4), 2):
        f_tet.append(ties.ts)
        f_P.append(ties.ttie[:, a])
        f_Q.append(ties.ttie[:, b])
        f_key.append(ties.tid)
    tet, P, Q, key = (np.concatenate(x) for x in (f_tet, f_P, f_Q, f_key))
    code = (tet * p + P) * p + Q
    ucode, poly = np.unique(code, return_inverse=True)
    u_tet, u_P, u_Q = ucode // (p * p), (ucode // p) % p, ucode % p
    grads = tetgeom.barycentric_gradients(V, T[u_tet])  # (q, 4, 3)
    dz = Zv[T[u_tet], u_Q[:, None]] - Zv[T[u_tet], u_P[:, None]]  # (q, 4)
    normals = np.einsum("qi,qid->qd", dz, grads)  # out of P's cell
    tri, owner = fan(poly.reshape(-1), key, normals, out.positions())
    out.emit(tri, u_P[owner], u_Q[owner])


def _field_face_polygons(out: _Builder, topo: Topology, Zv: np.ndarray, ties: _Ties, side_forced: np.ndarray,
                         has2: np.ndarray, tet_piece: np.ndarray, p: int) -> None:
    """Face polygons of the field where the other side is the cage's outside or a forced tet."""
    on_field = ~side_forced[:, 0] | ~side_forced[:, 1]
    shown = np.flatnonzero(on_field & (~has2 | side_forced[:, 0] | side_forced[:, 1]))
    if not len(shown):
        return
    win = np.argmax(Zv, axis=1)
    field_side = np.where(side_forced[shown, 0], 1, 0)
    other_tet = topo.face_tets[shown, 1 - field_side]
    other_piece = np.where(other_tet >= 0, tet_piece[np.maximum(other_tet, 0)], -1)
    corners = topo.faces[shown]
    p_face, p_piece, p_key = [np.repeat(np.arange(len(shown)), 3)], [win[corners].reshape(-1)], [corners.reshape(-1)]
    rows, idx = join(topo.face_edges[shown].reshape(-1), ties.es)
    for a in range(2):
        p_face.append(rows // 3)
        p_piece.append(ties.etie[idx, a])
        p_key.append(ties.eid[idx])
    rows, idx = join(shown, ties.fs)
    for a in range(3):
        p_face.append(rows)
        p_piece.append(ties.ftie[idx, a])
        p_key.append(ties.fid[idx])
    face, piece, key = (np.concatenate(x) for x in (p_face, p_piece, p_key))
    code = face * p + piece
    ucode, poly = np.unique(code, return_inverse=True)
    u_face, u_piece = ucode // p, ucode % p
    positions = out.positions()
    oriented = topo.face_oriented[shown[u_face]]
    normals = np.cross(positions[oriented[:, 1]] - positions[oriented[:, 0]],
                       positions[oriented[:, 2]] - positions[oriented[:, 0]])
    normals[field_side[u_face] == 1] *= -1.0
    tri, owner = fan(poly.reshape(-1), key, normals, positions)
    X = other_piece[u_face[owner]]
    keep = X != u_piece[owner]
    out.emit(tri[keep], u_piece[owner][keep], X[keep])


def _aligned_polygons(out: _Builder, V: np.ndarray, T: np.ndarray, topo: Topology, forced: np.ndarray,
                      side_forced: np.ndarray, has2: np.ndarray, tet_piece: np.ndarray, p: int, ties: _Ties) -> int:
    """Tet-aligned parts: faces whose sides are both forced (or forced and outside); returns the pinches carved."""
    face_tets = topo.face_tets
    X1 = tet_piece[face_tets[:, 0]]
    X2 = np.where(has2, tet_piece[np.maximum(face_tets[:, 1], 0)], -1)
    aligned = side_forced[:, 0] & side_forced[:, 1]
    pinched, spindle_owner = aligned_pinches(V, T, topo, forced, tet_piece, p, aligned, X1, X2)
    n_face, n_edge, n_pos = notches(V, topo, pinched)
    nid = out.add(n_pos, topo.faces[n_face])
    shown = aligned & (X1 != X2)
    # Faces with vertices on their edges (ties seen from field tets) or notches become polygons.
    extra = np.zeros(len(topo.faces), dtype=bool)
    if len(ties.es):
        on_edge = np.zeros(len(topo.edges), dtype=bool)
        on_edge[ties.es] = True
        extra |= on_edge[topo.face_edges].any(axis=1)
    extra[n_face] = True
    plain = np.flatnonzero(shown & ~extra)
    out.emit(topo.face_oriented[plain], X1[plain], X2[plain])
    busy = np.flatnonzero(shown & extra)
    if len(busy):
        centre_pos = V[topo.faces[busy]].mean(axis=1)
        centre_ids = out.add(centre_pos, topo.faces[busy])
        b_poly = [np.repeat(np.arange(len(busy)), 3)]
        b_key = [topo.faces[busy].reshape(-1)]
        rows, idx = join(topo.face_edges[busy].reshape(-1), ties.es)
        b_poly.append(rows // 3)
        b_key.append(ties.eid[idx])
        mine = np.isin(n_face, busy)
        b_poly.append(np.searchsorted(busy, n_face[mine]))
        b_key.append(nid[mine])
        oriented = topo.face_oriented[busy]
        normals = np.cross(V[oriented[:, 1]] - V[oriented[:, 0]], V[oriented[:, 2]] - V[oriented[:, 0]])
        tri, owner = fan(np.concatenate(b_poly), np.concatenate(b_key), normals, out.positions(),
                         centre_ids=centre_ids, centre_pos=centre_pos)
        out.emit(tri, X1[busy][owner], X2[busy][owner])
    if len(pinched):
        tris, pcs, others = spindle_faces(V, T, topo, tet_piece, pinched, spindle_owner, n_face, n_edge, nid, X2)
        out.emit(tris, pcs, others)
    return len(pinched)


def _defect_edges(positions: np.ndarray, tris: np.ndarray, owner: np.ndarray) -> list:
    """Global vertex pairs of region edges not shared by exactly two oppositely oriented faces.

    Checked per region (``owner`` (s,) piece of each triangle), by vertex id and by position.
    """
    found = set()
    if len(tris) == 0:
        return []
    # Any ids: which edges are bad does not depend on their order (a relabelling turns every directed edge
    # of one undirected pair forward or backward together, so the forward count of a pair is n or count - n).
    weld = group_rows(positions)
    N = len(positions)
    original = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    piece = np.tile(owner, 3)
    for ids in (original, weld[original]):
        lo, hi = ids.min(axis=1), ids.max(axis=1)
        code = (piece * N + lo) * N + hi
        forward = ids[:, 0] < ids[:, 1]
        _, inverse, counts = np.unique(code, return_inverse=True, return_counts=True)
        inverse = inverse.reshape(-1)
        n_forward = np.bincount(inverse, weights=forward, minlength=len(counts))
        bad = ((counts != 2) | (2 * n_forward != counts))[inverse] | (ids[:, 0] == ids[:, 1])
        for row in np.flatnonzero(bad).tolist():
            found.add(tuple(sorted(original[row].tolist())))
    return sorted(found)


def region_defects(vertices: np.ndarray, faces: np.ndarray) -> int:
    """Edges of a mesh that are not shared by exactly two oppositely oriented faces (by index or position)."""
    if len(faces) == 0:
        return 1
    worst = 0
    weld = group_rows(vertices)  # any ids: the defect count does not depend on their order
    for F in (faces, weld[faces]):
        directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        m = int(directed.max()) + 1
        code = directed[:, 0] * m + directed[:, 1]
        reverse = directed[:, 1] * m + directed[:, 0]
        ucode, counts = np.unique(code, return_counts=True)
        pos = np.searchsorted(ucode, reverse)
        pos = np.minimum(pos, len(ucode) - 1)
        matched = ucode[pos] == reverse
        bad = int((counts > 1).sum()) + int((~matched).sum()) + int((directed[:, 0] == directed[:, 1]).sum())
        worst = max(worst, bad)
    return worst

