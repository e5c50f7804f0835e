"""Edges and faces of a tet mesh and their incidences, shared by the smoothing methods and region builders."""

from __future__ import annotations

import itertools

import numpy as np

from fracture_cli.geometry import tetgeom

# Below this |det| (rows are O(1)) three planes are treated as not meeting in a point.
SINGULAR_TOL = 1e-13


EDGE_PAIRS = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)


FACE_EDGE_PAIRS = np.array([[0, 1], [0, 2], [1, 2]], dtype=np.int64)


class Topology:
    """Unique edges and faces of a tet mesh and their incidences (all arrays int64)."""

    def __init__(self, T: np.ndarray, n: int):
        t = len(T)
        local = T[:, tetgeom.TET_FACES].reshape(-1, 3)  # (4t, 3) outward for positive tets
        ordered = np.sort(local, axis=1)
        face_key = (ordered[:, 0] * n + ordered[:, 1]) * n + ordered[:, 2]
        _, first, inverse = np.unique(face_key, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        owner = np.repeat(np.arange(t), 4)
        self.faces = ordered[first]  # (f, 3) sorted vertex ids
        self.face_oriented = local[first]  # (f, 3) outward from face_tets[:, 0]
        self.tet_faces = inverse.reshape(t, 4)
        self.face_tets = np.full((len(first), 2), -1, dtype=np.int64)
        self.face_tets[:, 0] = owner[first]
        second = np.ones(len(local), dtype=bool)
        second[first] = False
        self.face_tets[inverse[second], 1] = owner[second]
        edges = np.sort(T[:, EDGE_PAIRS], axis=2).reshape(-1, 2)
        edge_key = edges[:, 0] * n + edges[:, 1]
        unique_keys, efirst, einverse = np.unique(edge_key, return_index=True, return_inverse=True)
        self.edges = edges[efirst]  # (e, 2) sorted
        self.tet_edges = einverse.reshape(t, 6)
        fe = self.faces[:, FACE_EDGE_PAIRS]  # (f, 3, 2)
        self.face_edges = np.searchsorted(unique_keys, fe[..., 0] * n + fe[..., 1])  # (f, 3)
        self.ties: tuple | None = None  # cache: (field, edge ties, face ties, tet ties)


_COMBOS: dict[tuple[int, int], np.ndarray] = {}


def combinations(m: int, k: int) -> np.ndarray:
    """All ``k``-subsets of ``range(m)`` (C, k), in lexicographic order (cached)."""
    key = (m, k)
    if key not in _COMBOS:
        _COMBOS[key] = np.array(list(itertools.combinations(range(m), k)), dtype=np.int64).reshape(-1, k)
    return _COMBOS[key]


def join(owners: np.ndarray, point_simplex: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (owner row, point index) for every point whose simplex is ``owners[row]``.

    ``owners`` (q,) simplex ids (any order, repeats allowed), ``point_simplex`` sorted.
    """
    lo = np.searchsorted(point_simplex, owners, side="left")
    hi = np.searchsorted(point_simplex, owners, side="right")
    count = hi - lo
    rows = np.repeat(np.arange(len(owners)), count)
    offsets = np.repeat(lo - (np.cumsum(count) - count), count)
    return rows, np.arange(int(count.sum())) + offsets

