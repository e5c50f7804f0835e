"""Small helpers shared by the smooth and fragments stages on manifold3d results."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components


def shell_mask(mesh, min_volume: float) -> np.ndarray:
    """Triangles (m,) bool of a manifold3d ``Mesh64`` that are not on a zero-volume shell.

    Booleans of solids with coincident faces can leave closed shells of
    (near) zero volume. ``Manifold.decompose`` finds them, but
    ``Manifold.compose`` of the remaining parts loses cavities (shells of
    negative volume), so the shells are removed on the mesh instead: triangles
    are grouped by connectivity (through shared, welded vertices) and every
    group whose signed volume is at most ``min_volume`` in magnitude is dropped.
    """
    tris = np.asarray(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)
    positions = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    n = len(positions)
    weld = np.arange(n)
    src = np.asarray(mesh.merge_from_vert, dtype=np.int64)
    if len(src):
        weld[src] = np.asarray(mesh.merge_to_vert, dtype=np.int64)
    corners = weld[tris]
    m = len(tris)
    if m == 0:
        return np.zeros(0, dtype=bool)
    # Triangle-vertex incidence: triangles sharing a vertex are connected.
    incidence = sp.coo_matrix((np.ones(3 * m), (np.repeat(np.arange(m), 3), corners.reshape(-1))), shape=(m, n))
    graph = sp.bmat([[None, incidence], [incidence.T, None]])
    _, labels = connected_components(graph, directed=False)
    labels = labels[:m]
    a, b, c = positions[tris[:, 0]], positions[tris[:, 1]], positions[tris[:, 2]]
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    _, group = np.unique(labels, return_inverse=True)
    shell_volume = np.bincount(group.reshape(-1), weights=volume)
    return np.abs(shell_volume[group.reshape(-1)]) > min_volume
