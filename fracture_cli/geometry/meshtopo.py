"""Topology of triangle soups given by welded vertex ids: edges, patches, components.

``W`` (m, 3) int is always a face list over *welded* vertex ids (vertices at
one position share an id), so edges are shared across UV seams. Used by the
repair stage and by the solid building shared with the fragments stage.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.edges import edge_table


def undirected_edges(W: np.ndarray):
    """Per corner edge (3m, 2) directed, its undirected id (3m,), and the face (3m,) it belongs to.

    The sides, edge ids and faces of :func:`~fracture_cli.geometry.edges.edge_table` (one int64 key per
    undirected edge, grouped in sorted key order).
    """
    table = edge_table(W)
    return table.sides, table.edge, table.face


def unique_edges(W: np.ndarray) -> np.ndarray:
    """The undirected edges (e, 2) of ``W``, ``a < b``, sorted (the rows :func:`undirected_edges` numbers)."""
    return edge_table(W).ends


def nonmanifold_edges(W: np.ndarray) -> int:
    """Number of edges of ``W`` shared by more than two faces."""
    _, edge_id, _ = undirected_edges(W)
    return int((np.bincount(edge_id) > 2).sum())


def manifold_patches(W: np.ndarray):
    """Patch id (m,) of each face (faces joined across edges with exactly two faces), and edge data."""
    # on first use: scipy.sparse costs 0.2-0.3 s to import, and resolving a recipe imports this module
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    m = len(W)
    directed, edge_id, face = undirected_edges(W)
    counts = np.bincount(edge_id)
    order = np.argsort(edge_id, kind="stable")
    pair = order[counts[edge_id[order]] == 2].reshape(-1, 2)
    graph = sp.coo_matrix((np.ones(len(pair)), (face[pair[:, 0]], face[pair[:, 1]])), shape=(m, m)).tocsr()
    _, patch = connected_components(graph, directed=False)
    return patch, edge_id, face, counts


def boundary_edges(W: np.ndarray) -> np.ndarray:
    """Directed edges (b, 2) used by exactly one face."""
    directed, edge_id, _ = undirected_edges(W)
    return directed[np.bincount(edge_id)[edge_id] == 1]


def components(W: np.ndarray, n: int) -> np.ndarray:
    """Component id (m,) of each face: faces sharing a welded vertex are connected."""
    # on first use: as in manifold_patches
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    m = len(W)
    incidence = sp.coo_matrix((np.ones(3 * m), (np.repeat(np.arange(m), 3), W.reshape(-1))), shape=(m, n))
    graph = sp.bmat([[None, incidence], [incidence.T, None]])
    _, labels = connected_components(graph, directed=False)
    _, component = np.unique(labels[:m], return_inverse=True)
    return component.reshape(-1)

