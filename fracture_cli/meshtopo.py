"""Topology of triangle soups given by welded vertex ids: edges, patches, components, winding.

``W`` (m, 3) int is always a face list over *welded* vertex ids (vertices at
one position share an id), so edges are shared across UV seams. Used by the
repair stage and by the solid building shared with the fragments stage.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components


def unique_faces(W: np.ndarray):
    """Keep mask (m,) without repeats of a face; a face and its reverse both go. Returns (keep, dups, pairs)."""
    m = len(W)
    if m == 0:
        return np.ones(0, dtype=bool), 0, 0
    key = np.sort(W, axis=1)
    # Orientation parity of each face relative to its sorted corners.
    rot = np.argmin(W, axis=1)
    rolled = np.stack([W[np.arange(m), (rot + k) % 3] for k in range(3)], axis=1)
    positive = rolled[:, 1] < rolled[:, 2]
    _, group, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    if counts.max() == 1:
        return np.ones(m, dtype=bool), 0, 0
    net = np.bincount(group, weights=np.where(positive, 1.0, -1.0))
    # Keep the first face of each group that has the group's majority orientation (none if balanced).
    candidate = (net[group] != 0) & ((net[group] > 0) == positive)
    first = np.full(len(counts), m, dtype=np.int64)
    np.minimum.at(first, group[candidate], np.flatnonzero(candidate))
    keep = np.zeros(m, dtype=bool)
    keep[first[first < m]] = True
    pairs = int(np.minimum(np.bincount(group, weights=positive), np.bincount(group, weights=~positive)).sum())
    duplicates = m - int(keep.sum()) - 2 * pairs
    return keep, duplicates, pairs


def undirected_edges(W: np.ndarray):
    """Per corner edge (3m, 2) directed, its undirected id (3m,), and the face (3m,) it belongs to."""
    directed = np.concatenate([W[:, [0, 1]], W[:, [1, 2]], W[:, [2, 0]]])
    face = np.tile(np.arange(len(W)), 3)
    # One int64 key per undirected edge: 1-d unique is ~10x faster than unique over rows, same order.
    n = int(W.max()) + 1 if len(W) else 1
    key = np.minimum(directed[:, 0], directed[:, 1]) * n + np.maximum(directed[:, 0], directed[:, 1])
    _, edge_id = np.unique(key, return_inverse=True)
    return directed, edge_id.reshape(-1), face


def nonmanifold_edges(W: np.ndarray) -> int:
    """Number of edges of ``W`` shared by more than two faces."""
    _, edge_id, _ = undirected_edges(W)
    return int((np.bincount(edge_id) > 2).sum())


def manifold_patches(W: np.ndarray):
    """Patch id (m,) of each face (faces joined across edges with exactly two faces), and edge data."""
    m = len(W)
    directed, edge_id, face = undirected_edges(W)
    counts = np.bincount(edge_id)
    order = np.argsort(edge_id, kind="stable")
    pair = order[counts[edge_id[order]] == 2].reshape(-1, 2)
    graph = sp.coo_matrix((np.ones(len(pair)), (face[pair[:, 0]], face[pair[:, 1]])), shape=(m, m)).tocsr()
    _, patch = connected_components(graph, directed=False)
    return patch, edge_id, face, counts


def propagate_winding(W: np.ndarray):
    """Flip mask (m,) making winding consistent across edges shared by two faces, and patch id (m,) per face.

    A breadth-first spanning forest of the faces (edges: shared manifold
    edges) gives each face a path to its patch's root; the face is flipped when
    an odd number of steps on that path join faces that run their shared edge
    the same way. The parities are summed by pointer jumping (vectorized,
    O(m log m)). Each patch then keeps the winding most of its faces had.
    """
    m = len(W)
    directed, edge_id, face = undirected_edges(W)
    counts = np.bincount(edge_id)
    order = np.argsort(edge_id, kind="stable")
    pair = order[counts[edge_id[order]] == 2].reshape(-1, 2)
    fa, fb = face[pair[:, 0]], face[pair[:, 1]]
    # Two faces agree when they run the shared edge in opposite directions.
    same = directed[pair[:, 0], 0] == directed[pair[:, 1], 0]
    graph = sp.coo_matrix((np.ones(len(fa)), (fa, fb)), shape=(m, m)).tocsr()
    num_patches, patch = connected_components(graph, directed=False)
    # A virtual root (node m) joined to the first face of every patch makes the forest one tree.
    first_face = np.full(num_patches, m, dtype=np.int64)
    np.minimum.at(first_face, patch, np.arange(m))
    rows = np.concatenate([fa, fb, np.full(num_patches, m)])
    cols = np.concatenate([fb, fa, first_face])
    tree = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(m + 1, m + 1)).tocsr()
    _, parent = breadth_first_order(tree, m, directed=True, return_predecessors=True)
    parent = parent.astype(np.int64)
    parent[m] = m
    # Parity of each tree step (face, parent).
    code = np.concatenate([fa * (m + 1) + fb, fb * (m + 1) + fa])
    step_same = np.concatenate([same, same])
    parity = np.zeros(m + 1, dtype=bool)
    if len(code):
        sorter = np.argsort(code, kind="stable")
        wanted = np.arange(m) * (m + 1) + parent[:m]
        at = np.minimum(np.searchsorted(code[sorter], wanted), len(code) - 1)
        parity[:m] = (code[sorter[at]] == wanted) & step_same[sorter[at]]
    jump = parent.copy()
    while np.any(jump != m):
        parity = parity ^ parity[jump]
        jump = jump[jump]
    flip = parity[:m]
    # Keep the winding most faces of the patch already have.
    flipped = np.bincount(patch, weights=flip, minlength=num_patches)
    sizes = np.bincount(patch, minlength=num_patches)
    flip = flip ^ (2 * flipped > sizes)[patch]
    return flip, patch


def boundary_edges(W: np.ndarray) -> np.ndarray:
    """Directed edges (b, 2) used by exactly one face."""
    directed, edge_id, _ = undirected_edges(W)
    return directed[np.bincount(edge_id)[edge_id] == 1]


def boundary_edge_faces(W: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """The face (b,) of each boundary edge."""
    directed, _, face = undirected_edges(W)
    n = int(W.max()) + 1
    code = directed[:, 0] * n + directed[:, 1]
    order = np.argsort(code, kind="stable")
    at = np.searchsorted(code[order], boundary[:, 0] * n + boundary[:, 1])
    return face[order[at]]


def components(W: np.ndarray, n: int) -> np.ndarray:
    """Component id (m,) of each face: faces sharing a welded vertex are connected."""
    m = len(W)
    incidence = sp.coo_matrix((np.ones(3 * m), (np.repeat(np.arange(m), 3), W.reshape(-1))), shape=(m, n))
    graph = sp.bmat([[None, incidence], [incidence.T, None]])
    _, labels = connected_components(graph, directed=False)
    _, component = np.unique(labels[:m], return_inverse=True)
    return component.reshape(-1)

