"""The tets a refined fragment is computed on: its piece's sub-mesh, and the tets around it labelled by child.

A level-1 fragment was cut from its piece's region, which is (up to fault smoothing) the
union of the piece's tets. Its children's modes are solved on those tets alone
(:func:`submesh`); the regions the children are cut with must cover the whole
fragment, smoothed faults included, so they are built on every tet near the fragment
(:func:`covering_tets`, closed to an edge-manifold set by :func:`manifold_cover`), each
labelled with the child piece of the nearest of the piece's tets across the tet mesh's
faces (:func:`propagate_labels`).
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.tetgeom import TET_EDGES, TET_FACES
from fracture_cli.types import TetMesh

# How far beyond a fragment's bounding box the covering tets reach (normalized units: bbox diagonal 1).
COVER_MARGIN = 1e-3


def submesh(tet_mesh: TetMesh, tets: np.ndarray) -> TetMesh:
    """The tet mesh of ``tets`` (q,) (indices into ``tet_mesh``), vertices renumbered in increasing order.

    Parameters
    ----------
    tet_mesh : TetMesh
        ``n`` vertices, ``t`` tets.
    tets : (q,) int
        Ascending tet indices.

    Returns
    -------
    TetMesh
        ``q`` tets (same order and orientation), the vertices they use (ascending original ids).
    """
    T = np.asarray(tet_mesh.tets)[np.asarray(tets, dtype=np.int64)]
    used = np.unique(T)
    local = np.full(tet_mesh.num_vertices, -1, dtype=np.int64)
    local[used] = np.arange(len(used))
    return TetMesh(vertices=np.asarray(tet_mesh.vertices)[used], tets=local[T], normalization=tet_mesh.normalization)


def _face_keys(faces: np.ndarray, n: int) -> np.ndarray:
    """One int64 per triangle (f, 3) of vertex ids < ``n``: its sorted ids in base ``n``."""
    s = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    return (s[:, 0] * n + s[:, 1]) * n + s[:, 2]


def submesh_eta(tet_mesh: TetMesh, tets: np.ndarray, sub: TetMesh, eta: np.ndarray | None) -> np.ndarray | None:
    """The material weights (f_sub,) or (f_sub, d) of ``sub``'s interior faces, taken from the full mesh's ``eta``.

    Every interior face of a sub-mesh is interior in the full mesh (its two tets are there too).
    """
    if eta is None:
        return None
    n = tet_mesh.num_vertices
    used = np.unique(np.asarray(tet_mesh.tets)[np.asarray(tets, dtype=np.int64)])
    full = _face_keys(tet_mesh.interior_faces, n)
    order = np.argsort(full, kind="stable")
    mine = _face_keys(used[sub.interior_faces], n)
    where = order[np.searchsorted(full, mine, sorter=order)]
    return np.asarray(eta)[where]


def covering_tets(tet_mesh: TetMesh, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Ascending indices of the tets whose bounding boxes meet the box ``lo``..``hi`` (widened by COVER_MARGIN).

    Their union holds every point of the cage inside the box: a tet containing such a point meets the box.
    """
    corners = np.asarray(tet_mesh.vertices)[np.asarray(tet_mesh.tets)]
    tlo, thi = corners.min(axis=1), corners.max(axis=1)
    meets = np.all((tlo <= np.asarray(hi) + COVER_MARGIN) & (thi >= np.asarray(lo) - COVER_MARGIN), axis=1)
    return np.flatnonzero(meets)


def manifold_cover(tet_mesh: TetMesh, tets: np.ndarray, rounds: int = 16) -> np.ndarray:
    """``tets`` (ascending) and the tets around every edge where their union's boundary is not edge-manifold.

    A set of tets chosen by their boxes touches itself along edges on its boundary (four or more boundary
    faces at one edge); a region built on it that reaches such an edge is not edge-manifold, and the
    smoothing then builds it again as a slow union of cells. Adding every tet around such an edge (it
    becomes interior, or a mesh-boundary edge of a manifold mesh), in rounds until none is left (at most
    ``rounds``), gives a set whose regions are built directly, as on the whole mesh at level 1.
    """
    T = np.asarray(tet_mesh.tets, dtype=np.int64)
    n = tet_mesh.num_vertices
    edges = np.sort(T[:, TET_EDGES], axis=2)
    edge_keys = edges[:, :, 0] * n + edges[:, :, 1]  # (t, 6)
    keep = np.zeros(len(T), dtype=bool)
    keep[np.asarray(tets, dtype=np.int64)] = True
    for _ in range(rounds):
        faces = np.sort(T[keep][:, TET_FACES].reshape(-1, 3), axis=1)
        keys = (faces[:, 0] * n + faces[:, 1]) * n + faces[:, 2]
        unique, counts = np.unique(keys, return_counts=True)
        boundary = faces[np.isin(keys, unique[counts == 1])]
        sides = np.concatenate([boundary[:, [0, 1]], boundary[:, [1, 2]], boundary[:, [0, 2]]])
        side_keys, side_counts = np.unique(sides[:, 0] * n + sides[:, 1], return_counts=True)
        bad = side_keys[side_counts > 2]
        if len(bad) == 0:
            break
        add = np.isin(edge_keys, bad).any(axis=1) & ~keep
        if not add.any():
            break
        keep |= add
    return np.flatnonzero(keep)


def propagate_labels(tet_mesh: TetMesh, tets: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Labels (q,) for ``tets`` (q,): those given (``labels >= 0``), the others from their labelled neighbours.

    Rounds of a breadth-first growth across shared faces among ``tets``: a tet takes the smallest label
    of its neighbours labelled in earlier rounds. Tets no growth reaches (another component of the set)
    take the label of the labelled tet with the nearest centroid (the first on ties).

    Parameters
    ----------
    tet_mesh : TetMesh
    tets : (q,) int
        Ascending tet indices.
    labels : (q,) int
        A label ``>= 0`` for some of them (at least one), -1 for the others.
    """
    tets = np.asarray(tets, dtype=np.int64)
    out = np.asarray(labels, dtype=np.int64).copy()
    position = np.full(tet_mesh.num_tets, -1, dtype=np.int64)
    position[tets] = np.arange(len(tets))
    pairs = position[np.asarray(tet_mesh.interior_face_tets)]
    pairs = pairs[np.all(pairs >= 0, axis=1)]
    a = np.concatenate([pairs[:, 0], pairs[:, 1]])
    b = np.concatenate([pairs[:, 1], pairs[:, 0]])
    big = np.iinfo(np.int64).max
    while True:
        todo = (out[a] < 0) & (out[b] >= 0)
        if not todo.any():
            break
        best = np.full(len(out), big, dtype=np.int64)
        np.minimum.at(best, a[todo], out[b[todo]])
        grown = best < big
        out[grown] = best[grown]
    missing = np.flatnonzero(out < 0)
    if len(missing):
        centroids = tet_mesh.tet_centroids[tets]
        known = np.flatnonzero(out >= 0)
        for m in missing.tolist():
            offsets = centroids[known] - centroids[m]
            d2 = np.sum(offsets * offsets, axis=1)
            out[m] = out[known[int(np.argmin(d2))]]
    return out
