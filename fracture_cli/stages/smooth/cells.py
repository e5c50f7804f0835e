"""Regions as unions of convex cells (manifold3d): the slow, independent fallback of the direct construction."""

from __future__ import annotations

import logging

import manifold3d
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from fracture_cli.errors import StageError
from fracture_cli.geometry import tetgeom, tolerances, trigeom
from fracture_cli.geometry.rows import group_rows
from fracture_cli.geometry.solids import shell_mask
from fracture_cli.stages.smooth.field import forced_field
from fracture_cli.stages.smooth.options import STAGE
from fracture_cli.stages.smooth.topology import SINGULAR_TOL, combinations

log = logging.getLogger(__name__)

# Fallback (union) path only: how far apart (unit bbox diagonal) the copies of
# a vertex where a region touches itself are moved.
_PINCH_SEPARATION = 1e-7


def union_regions(V: np.ndarray, T: np.ndarray, Z: np.ndarray | None, tet_piece: np.ndarray, p: int,
                  vanished: list[int], only: list[int]) -> list:
    """Regions of the pieces ``only`` as manifold3d unions of their convex cells (slow, independent path).

    ``Z`` (n, p) is the smoothed field, or None for tet-aligned regions.
    """
    if Z is None:
        cells = _CellList()
        cells.add_tets(np.arange(len(T)), tet_piece)
    else:
        forced, _ = forced_field(Z, tet_piece, vanished)
        cells = _field_cells(V, T, Z, forced, tet_piece, vanished)
    return cells.union_by_piece(V, T, p, only)


class _CellList:
    """Convex cells (whole tets or clipped corner sets) tagged with their piece."""

    def __init__(self) -> None:
        self.tets: list[np.ndarray] = []
        self.tet_pieces: list[np.ndarray] = []
        self.clipped: list[tuple[int, int, np.ndarray]] = []  # (tet, piece, corners (c, 3))
        self.clipped_volumes: list[float] = []

    def add_tets(self, tets: np.ndarray, pieces: np.ndarray) -> None:
        self.tets.append(np.asarray(tets, dtype=np.int64))
        self.tet_pieces.append(np.asarray(pieces, dtype=np.int64))

    def add_clipped(self, tet: int, piece: int, corners: np.ndarray) -> None:
        hull = manifold3d.Manifold.hull_points(corners)
        volume = hull.volume()
        if volume <= 0.0:
            return
        self.clipped.append((tet, piece, hull))
        self.clipped_volumes.append(volume)

    @property
    def count(self) -> int:
        return sum(len(x) for x in self.tets) + len(self.clipped)

    @property
    def clipped_count(self) -> int:
        return len(self.clipped)

    def piece_array(self) -> np.ndarray:
        whole = np.concatenate(self.tet_pieces) if self.tets else np.zeros(0, np.int64)
        return np.concatenate([whole, np.array([c[1] for c in self.clipped], dtype=np.int64)])

    def volume_array(self, tet_volumes: np.ndarray) -> np.ndarray:
        whole = tet_volumes[np.concatenate(self.tets)] if self.tets else np.zeros(0)
        return np.concatenate([whole, np.array(self.clipped_volumes, dtype=np.float64)])

    def union_by_piece(self, V: np.ndarray, T: np.ndarray, p: int,
                       only: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
        """Closed, edge-manifold meshes (vertices, faces) of the union of the cells of each piece in ``only``."""
        parts: list[list] = [[] for _ in range(p)]
        tets = np.concatenate(self.tets) if self.tets else np.zeros(0, np.int64)
        owners = np.concatenate(self.tet_pieces) if self.tets else np.zeros(0, np.int64)
        order = np.argsort(owners, kind="stable")
        tets, owners = tets[order], owners[order]
        bounds = np.searchsorted(owners, np.arange(p + 1))
        for P in only:
            parts[P].extend(_whole_tets_solids(V, T, tets[bounds[P]:bounds[P + 1]]))
        for _, P, hull in self.clipped:
            parts[P].append(hull)
        meshes = []
        for P in only:
            if not parts[P]:
                raise StageError(f"piece {P} has no cells; this is a bug in the smoothing stage", stage=STAGE)
            region = manifold3d.Manifold.batch_boolean(parts[P], manifold3d.OpType.Add)
            if region.status() != manifold3d.Error.NoError or region.is_empty():
                raise StageError(f"the region of piece {P} could not be built ({region.status()})", stage=STAGE)
            mesh = region.to_mesh64()
            vertices = np.array(mesh.vert_properties[:, :3], dtype=np.float64)
            faces = np.array(mesh.tri_verts, dtype=np.int64)
            # Coplanar cell faces can leave zero-volume shells in a union; drop them (not cavities).
            faces = faces[shell_mask(mesh, tolerances.SLIVER_VOLUME * region.volume())]
            meshes.append(_separate_pinches(*trigeom.compact(vertices, faces)))
        return meshes


def _whole_tets_solids(V: np.ndarray, T: np.ndarray, tets: np.ndarray) -> list:
    """Manifolds whose union is the union of ``tets``: one boundary mesh plus single tets.

    The boundary faces of a tet set form a closed surface, but it is not
    edge-manifold where the set touches itself along an edge; manifold3d
    accepts such a mesh without an error and can then get volumes wrong. So the
    tets around every such edge are taken out (repeatedly, as removing tets can
    create new ones) and passed on as single-tet solids, whose union is
    edge-manifold by construction.
    """
    local_faces = np.ascontiguousarray(tetgeom.TET_FACES.astype(np.uint64))

    def tet_solid(tet: int) -> manifold3d.Manifold:
        corners = np.ascontiguousarray(V[T[tet]], dtype=np.float64)
        return manifold3d.Manifold(manifold3d.Mesh64(vert_properties=corners, tri_verts=local_faces))

    singles: list[int] = []
    body = np.asarray(tets, dtype=np.int64)
    for _ in range(8):
        if len(body) == 0:
            break
        faces = T[body][:, tetgeom.TET_FACES].reshape(-1, 3)
        owner = np.repeat(body, 4)
        # Which faces are equal is all that counts here (not the ids' order): a row hash is enough.
        same_face = group_rows(np.sort(faces, axis=1))
        outer = np.bincount(same_face)[same_face] == 1
        faces, owner = faces[outer], owner[outer]
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        same_edge = group_rows(edges)
        bad = np.bincount(same_edge)[same_edge] > 2
        if not bad.any():
            used, local = np.unique(faces, return_inverse=True)
            mesh = manifold3d.Mesh64(
                vert_properties=np.ascontiguousarray(V[used], dtype=np.float64),
                tri_verts=np.ascontiguousarray(local.reshape(-1, 3), dtype=np.uint64),
            )
            solid = manifold3d.Manifold(mesh)
            if solid.status() != manifold3d.Error.NoError:
                raise StageError(f"a piece's tet boundary is not a closed mesh ({solid.status()})", stage=STAGE)
            return [solid] + [tet_solid(t) for t in singles]
        # Tets owning a face on a non-manifold edge become single solids.
        moving = np.unique(np.tile(owner, 3)[bad])
        singles.extend(moving.tolist())
        body = body[~np.isin(body, moving)]
    return [tet_solid(t) for t in singles + body.tolist()]


def _separate_pinches(vertices: np.ndarray, faces: np.ndarray,
                      distance: float = _PINCH_SEPARATION) -> tuple[np.ndarray, np.ndarray]:
    """Move apart the vertex copies where a region touches itself.

    A union of cells is edge-manifold by index, but where a region touches
    itself along an edge or at a point (e.g. a tet-aligned piece wrapping
    around another piece's edge) it keeps two vertices at one position. Tools
    that weld by position (and the fragments cut from such a region) would see
    an edge with four faces. Each copy is moved ``distance`` into its own part
    of the solid (against the mean normal of its faces), which opens a gap far
    below any modelling tolerance but above position-welding tolerances.
    """
    pos = group_rows(vertices)  # only which vertices share a position counts
    shared = np.bincount(pos)[pos] > 1
    if not shared.any():
        return vertices, faces
    step = trigeom.vertex_normals(vertices, faces) * distance
    moved = vertices.copy()
    moved[shared] -= step[shared]
    log.debug("%s: separated %d vertex copies where a region touches itself", STAGE, int(shared.sum()))
    return moved, faces


def _field_cells(V: np.ndarray, T: np.ndarray, Z: np.ndarray, forced: np.ndarray, tet_piece: np.ndarray,
                 vanished: list[int]) -> _CellList:
    """Cells of the pieces that win in each tet under the smoothed field ``Z`` (n, p)."""
    cells = _CellList()
    Zv = Z.copy()
    if vanished:
        # A vanished piece keeps its own tets and wins nowhere else.
        Zv[:, vanished] = -1.0
    Zt = Zv[T]  # (t, 4, p)
    # Piece P can win somewhere in the tet only if its largest corner value
    # reaches the best guaranteed value max_Q min_corners Z_Q (a necessary test).
    floor = Zt.min(axis=1).max(axis=1)  # (t,)
    candidate = Zt.max(axis=1) >= floor[:, None]
    counts = candidate.sum(axis=1)
    counts[forced] = 1
    single = np.flatnonzero(counts == 1)
    whole_piece = np.where(forced[single], tet_piece[single], np.argmax(candidate[single], axis=1))
    cells.add_tets(single, whole_piece)
    multi = np.flatnonzero(counts > 1)
    if len(multi) == 0:
        return cells
    # Group the mixed tets by candidate count so each group is one batched computation.
    pending = []  # (tet, piece, first corner, corner count) into the global corner list
    corner_blocks = [V]
    offset = len(V)
    for m in np.unique(counts[multi]):
        group = multi[counts[multi] == m]
        cand = np.stack([np.flatnonzero(candidate[i]) for i in group])  # (N, m) sorted piece ids
        G = np.take_along_axis(Zt[group], cand[:, None, :], axis=2).transpose(0, 2, 1)  # (N, m, 4)
        corners, valid = _cell_corners(G)  # (N, m, C, 4), (N, m, C)
        points = np.einsum("nmcj,njd->nmcd", corners, V[T[group]])
        counts_cell = valid.sum(axis=2)  # (N, m)
        flat = points[valid]  # cells' corners, cell by cell in (N, m) order
        corner_blocks.append(flat)
        starts = offset + np.concatenate([[0], np.cumsum(counts_cell.reshape(-1))[:-1]])
        tets_cell = np.repeat(group, int(m))
        for tet, piece, start, count in zip(tets_cell.tolist(), cand.reshape(-1).tolist(), starts.tolist(),
                                            counts_cell.reshape(-1).tolist()):
            if count >= 4:
                pending.append((tet, piece, start, count))
        offset += len(flat)
    # Corners that neighbouring cells share are computed from different plane
    # triples (and in different tets), so they differ in the last bits. Snap
    # every cluster of near-identical corners (tet vertices first) to one
    # point: cells then meet exactly and the unions leave no slivers.
    allpoints = _snap(np.concatenate(corner_blocks))
    for tet, piece, start, count in pending:
        cells.add_clipped(tet, piece, allpoints[start:start + count])
    return cells


def _snap(points: np.ndarray, tol: float = 1e-10) -> np.ndarray:
    """Replace each cluster of points closer than ``tol`` by its lowest-index member."""
    pairs = cKDTree(points).query_pairs(tol, output_type="ndarray")
    if len(pairs) == 0:
        return points
    n = len(points)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    # Lowest index per label: np.unique's return_index gives first occurrences.
    _, first = np.unique(labels, return_index=True)
    return points[first[labels]]


def _cell_corners(G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corners, in barycentric coordinates, of the cell of each candidate in each tet.

    Parameters
    ----------
    G : (N, m, 4) float
        Field values of the ``m`` candidate pieces at the 4 corners of ``N`` tets.

    Returns
    -------
    corners : (N, m, C, 4) float64
        Barycentric coordinates of every intersection of three bounding planes.
    valid : (N, m, C) bool
        Which of them are feasible (inside the tet and on the winning side of
        every other candidate).
    """
    N, m, _ = G.shape
    # Planes of cell j: b_i >= 0 (4 rows) and (G_j - G_q) . b >= 0 for q != j.
    others = np.array([[q for q in range(m) if q != j] for j in range(m)], dtype=np.int64).reshape(m, m - 1)
    diff = G[:, :, None, :] - G[:, others, :]  # (N, m, m-1, 4)
    eye = np.broadcast_to(np.eye(4), (N, m, 4, 4))
    H = np.concatenate([eye, diff], axis=2)  # (N, m, m+3, 4)
    planes = m + 3
    combos = combinations(planes, 3)  # (C, 3)
    C = len(combos)
    A = np.empty((N, m, C, 4, 4))
    A[:, :, :, :3, :] = H[:, :, combos, :]
    A[:, :, :, 3, :] = 1.0
    rows = np.linalg.norm(A, axis=4).prod(axis=3)
    det = np.linalg.det(A)
    ok = np.abs(det) > SINGULAR_TOL * rows
    A[~ok] = np.eye(4)
    rhs = np.zeros((N, m, C, 4, 1))
    rhs[..., 3, 0] = 1.0
    b = np.linalg.solve(A, rhs)[..., 0]  # (N, m, C, 4)
    # Corners on tet faces/edges: snap the coordinates that a chosen plane b_i = 0 forces to exactly 0.
    chosen_eye = combos < 4  # (C, 3)
    for s in range(3):
        idx = np.where(chosen_eye[:, s], combos[:, s], -1)
        for i in range(4):
            b[:, :, idx == i, i] = 0.0
    slack = np.einsum("nmpj,nmcj->nmcp", H, b)  # (N, m, C, planes)
    # Barycentric feasibility up to rounding: the fields are O(1) (smoothed one-hot values), so an absolute
    # tolerance is meaningful.
    valid = ok & (slack >= -tolerances.ROUNDOFF).all(axis=3)
    b = np.clip(b, 0.0, None)
    b /= b.sum(axis=3, keepdims=True)
    return b, valid

