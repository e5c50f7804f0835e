"""Edge and corner tables of triangle meshes, shared by the meshfix modules."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry.rows import unique_inverse, unique_rows, used_vertices


@dataclass(frozen=True)
class EdgeTable:
    """Undirected edges of faces ``F`` (m, 3) and the face sides that use them.

    Side ``s = k * m + f`` is the edge of face ``f`` from corner ``k`` to
    corner ``(k + 1) % 3``.

    Attributes
    ----------
    sides : (3m, 2) int64
        Directed vertex pair of every side.
    face : (3m,) int64
        The face of every side.
    edge : (3m,) int64
        Undirected edge id of every side.
    ends : (e, 2) int64
        Vertex pair of every edge, smaller id first.
    count : (e,) int64
        Faces per edge.
    forward : (3m,) bool
        Whether a side runs ``ends[edge][0] -> ends[edge][1]``.
    """

    sides: np.ndarray
    face: np.ndarray
    edge: np.ndarray
    ends: np.ndarray
    count: np.ndarray
    forward: np.ndarray

    @property
    def num_faces(self) -> int:
        """Number of faces ``m``."""
        return len(self.face) // 3

    def balance(self) -> np.ndarray:
        """Forward minus backward sides (e,) per edge: 0 on a consistently oriented manifold edge."""
        return np.bincount(self.edge, weights=np.where(self.forward, 1, -1), minlength=len(self.count)).astype(
            np.int64)

    def sides_of_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Sides grouped by edge: ``order`` (3m,) sorts sides by edge, ``start`` (e + 1,) indexes into it."""
        order = np.argsort(self.edge, kind="stable")
        start = np.concatenate([[0], np.cumsum(self.count)])
        return order, start

    def manifold_pairs(self) -> np.ndarray:
        """Side pairs (k, 2) of every edge that has exactly two faces."""
        order, _ = self.sides_of_edges()
        return order[self.count[self.edge[order]] == 2].reshape(-1, 2)


def edge_table(F: np.ndarray) -> EdgeTable:
    """The :class:`EdgeTable` of faces ``F`` (m, 3) int."""
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    sides = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    face = np.tile(np.arange(len(F), dtype=np.int64), 3)
    n = int(F.max()) + 1 if len(F) else 1
    lo, hi = sides.min(axis=1), sides.max(axis=1)
    keys, edge = unique_inverse(lo * n + hi)
    edge = edge.reshape(-1)
    ends = np.column_stack([keys // n, keys % n])
    return EdgeTable(sides=sides, face=face, edge=edge, ends=ends, count=np.bincount(edge, minlength=len(keys)),
                     forward=sides[:, 0] == lo)


def components(num: int, pairs: np.ndarray) -> np.ndarray:
    """Connected component id (num,) of ``num`` nodes joined by ``pairs`` (k, 2), numbered by lowest member."""
    # on first use: scipy.sparse costs 0.2-0.3 s to import, and resolving a recipe imports this module
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(num, num))
    _, labels = connected_components(graph, directed=False)
    return renumber_by_first(labels)


def renumber_by_first(labels: np.ndarray) -> np.ndarray:
    """Labels (n,) renumbered 0, 1, ... in increasing order of their lowest index."""
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return rank[inverse.reshape(-1)]


def face_bodies(table: EdgeTable, glued: np.ndarray | None = None) -> np.ndarray:
    """Body id (m,) of each face: faces joined across edges with exactly two faces (or the given side pairs)."""
    pairs = table.manifold_pairs() if glued is None else glued
    return components(table.num_faces, table.face[pairs])


def corner_fans(F: np.ndarray, table: EdgeTable, glued: np.ndarray | None = None) -> np.ndarray:
    """Fan id (3m,) of every corner ``3 f + k``: corners of one vertex joined across glued edges through it.

    ``glued`` (k, 2) are side pairs whose faces are joined (default: the two
    sides of every two-face edge). A vertex whose corners have more than one
    fan id is pinched (several cones or sheets meet only there).
    """
    F = np.asarray(F, dtype=np.int64)
    pairs = table.manifold_pairs() if glued is None else glued
    rows, cols = [], []
    fa, fb = table.face[pairs[:, 0]], table.face[pairs[:, 1]]
    for end in (0, 1):
        v = table.sides[pairs[:, 0], end]
        rows.append(3 * fa + np.argmax(F[fa] == v[:, None], axis=1))
        cols.append(3 * fb + np.argmax(F[fb] == v[:, None], axis=1))
    return components(3 * len(F), np.column_stack([np.concatenate(rows), np.concatenate(cols)]))


def weld_by_position(V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique positions (u, 3) and the index (n,) of each vertex's position (exact equality)."""
    V = np.asarray(V)
    unique, index = unique_rows(V, return_inverse=True)
    return unique, index.reshape(-1)


def signed_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Signed volume enclosed by faces ``F`` (m, 3) over ``V`` (n, 3), measured about the vertices' mean."""
    V = np.asarray(V, dtype=np.float64)
    if len(F) == 0:
        return 0.0
    c = V[used_vertices(F, len(V))].mean(axis=0)
    a, b, d = V[F[:, 0]] - c, V[F[:, 1]] - c, V[F[:, 2]] - c
    return float(np.einsum("ij,ij->i", a, np.cross(b, d)).sum() / 6.0)

