"""The compiled vertex-manifold test agrees with a corner-graph reference built with scipy."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from fracture_cli.geometry import trigeom
from fracture_cli.geometry.trigeom_topology import single_fans, warm_kernels


def _reference(F):
    """The numpy/scipy test vertex_manifold used before the kernel."""
    m, n = len(F), int(F.max()) + 1
    a, b = F.reshape(-1), F[:, [1, 2, 0]].reshape(-1)
    key = a * n + b
    order = np.argsort(key, kind="stable")
    pos = np.minimum(np.searchsorted(key[order], b * n + a), len(order) - 1)
    twin = order[pos]
    ok = key[twin] == b * n + a
    dst = (twin // 3) * 3 + (twin % 3 + 1) % 3
    src = np.arange(3 * m)
    graph = sp.coo_matrix((np.ones(int(ok.sum())), (src[ok], dst[ok])), shape=(3 * m, 3 * m))
    _, labels = connected_components(graph, directed=False)
    fans = np.bincount(np.unique(np.stack([a, labels], axis=1), axis=0)[:, 0], minlength=n)
    return bool(np.all(fans[np.bincount(a, minlength=n) > 0] == 1))


def _octahedron():
    return np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])


@pytest.mark.parametrize("seed", range(30))
def test_single_fans_match_reference(seed):
    rng = np.random.default_rng(seed)
    F = np.concatenate([_octahedron(), _octahedron() + 6])
    if seed % 2:
        F = np.where(F == 6 + int(rng.integers(0, 6)), int(rng.integers(0, 6)), F)  # two solids pinched at a vertex
    F = rng.permutation(12)[F][rng.permutation(len(F))]
    assert single_fans(F, 12) == _reference(F) == trigeom.vertex_manifold(F) == (seed % 2 == 0)
    G = rng.integers(0, 8, (int(rng.integers(1, 30)), 3))
    assert single_fans(G, int(G.max()) + 1) == _reference(G)


def test_warm_kernels():
    warm_kernels()


def _closed_reference(F):
    """The numpy test edge_manifold_closed used before the kernel."""
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    if np.any(directed[:, 0] == directed[:, 1]):
        return False
    n = int(F.max()) + 1
    key = directed[:, 0] * n + directed[:, 1]
    if len(np.unique(key)) != len(key):
        return False
    return bool(np.all(np.isin(directed[:, 1] * n + directed[:, 0], key)))


@pytest.mark.parametrize("seed", range(30))
def test_closed_oriented_matches_reference(seed):
    rng = np.random.default_rng(seed)
    F = np.concatenate([_octahedron(), _octahedron() + 6])
    if seed % 3 == 1:
        F[int(rng.integers(0, len(F)))] = F[int(rng.integers(0, len(F)))][::-1]  # a flipped or duplicated face
    elif seed % 3 == 2:
        F = F[1:]  # a hole
    F = rng.permutation(12)[F][rng.permutation(len(F))]
    assert trigeom.edge_manifold_closed(F) == _closed_reference(F)
    G = rng.integers(0, 6, (int(rng.integers(1, 30)), 3))
    assert trigeom.edge_manifold_closed(G) == _closed_reference(G)
    assert trigeom.edge_manifold_closed(_octahedron()) and not trigeom.edge_manifold_closed(np.zeros((0, 3), int))


def _components_reference(F):
    """Faces joined across shared undirected edges, by scipy on the face-edge incidence graph."""
    m = len(F)
    a, b = F.reshape(-1), F[:, [1, 2, 0]].reshape(-1)
    _, edge = np.unique(np.minimum(a, b) * (int(F.max()) + 1) + np.maximum(a, b), return_inverse=True)
    size = m + int(edge.max()) + 1
    graph = sp.coo_matrix((np.ones(3 * m), (np.repeat(np.arange(m), 3), m + edge.reshape(-1))), shape=(size, size))
    labels = connected_components(graph, directed=False)[1]
    return len(np.unique(labels[:m]))


@pytest.mark.parametrize("seed", range(30))
def test_face_components_match_reference(seed):
    rng = np.random.default_rng(seed)
    F = np.concatenate([_octahedron(), _octahedron() + 6, _octahedron() + 12])
    if seed % 3 == 1:
        F = np.where(F == 6 + int(rng.integers(0, 6)), int(rng.integers(0, 6)), F)  # two solids pinched at a vertex
    elif seed % 3 == 2:
        F = np.where(F == 12, 0, np.where(F == 14, 2, F))  # two solids on one edge (four faces)
    F = rng.permutation(18)[F][rng.permutation(len(F))]
    # A shared vertex joins nothing; a shared edge joins its four faces.
    assert trigeom.face_components(F) == _components_reference(F) == (2 if seed % 3 == 2 else 3)
    G = rng.integers(0, 12, (int(rng.integers(1, 30)), 3))
    assert trigeom.face_components(G) == _components_reference(G)
    assert trigeom.face_components(np.zeros((0, 3), int)) == 0
