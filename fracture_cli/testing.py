"""Tiny meshes built in code, for tests and benchmarks.

Not used by the pipeline itself; kept in the package so tests, benchmarks and
helpers share one definition.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import tetgeom
from fracture_cli.types import Normalization, TetMesh

# Kuhn subdivision of a cube into 6 tets sharing the main diagonal (0 -> 7);
# corner index = x + 2 y + 4 z. Neighbouring cubes match face to face.
_KUHN = np.array(
    [[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7], [0, 5, 1, 7]],
    dtype=np.int64,
)


def grid_tetmesh(shape=(2, 2, 2), mask=None, spacing=1.0, origin=(0.0, 0.0, 0.0)) -> TetMesh:
    """A conforming tet mesh of a voxel grid (6 tets per voxel).

    Parameters
    ----------
    shape : (3,) int, optional (default (2, 2, 2))
        Number of voxels along x, y, z.
    mask : (nx, ny, nz) bool, optional (default all True)
        Which voxels to fill; e.g. two boxes joined by a thin neck.
    spacing : float, optional (default 1.0)
        Voxel edge length.
    origin : (3,) float, optional (default 0)
        Position of the grid's minimum corner.

    Returns
    -------
    TetMesh
        Positively oriented tets; unused grid vertices are removed.
    """
    nx, ny, nz = (int(s) for s in shape)
    if mask is None:
        mask = np.ones((nx, ny, nz), dtype=bool)
    mask = np.asarray(mask, dtype=bool)
    gx, gy, gz = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij")
    points = np.stack([gx, gy, gz], axis=-1).reshape(-1, 3).astype(np.float64) * spacing + np.asarray(origin)

    def vid(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    vi, vj, vk = np.nonzero(mask)
    corners = np.stack(
        [vid(vi + (c & 1), vj + ((c >> 1) & 1), vk + ((c >> 2) & 1)) for c in range(8)], axis=1
    )  # (voxels, 8)
    T = corners[:, _KUHN].reshape(-1, 4)
    used, T = np.unique(T, return_inverse=True)
    T = T.reshape(-1, 4)
    V = points[used]
    T = tetgeom.orient_positive(V, T)
    return TetMesh(vertices=V, tets=T, normalization=Normalization.identity())


def two_boxes_with_neck(n: int = 4) -> TetMesh:
    """Two ``n``-cubes joined by a one-voxel-thick neck along x (breaks at the neck)."""
    mask = np.zeros((2 * n + 1, n, n), dtype=bool)
    mask[:n] = True
    mask[n + 1 :] = True
    mask[n, n // 2, n // 2] = True
    return grid_tetmesh(mask.shape, mask=mask, spacing=1.0 / (2 * n + 1))


def jittered_grid_tetmesh(n: int, half_extent: float, jitter: float, seed: int = 0) -> TetMesh:
    """A cube grid tet mesh centred at 0 whose interior vertices are jittered (generic faults).

    Parameters
    ----------
    n : int
        Voxels per side.
    half_extent : float
        Half the cube's side; the boundary vertices stay on the cube.
    jitter : float
        Largest displacement of an interior vertex per axis, in the mesh's units.
    seed : int, optional (default 0)
    """
    spacing = 2.0 * half_extent / n
    g = grid_tetmesh((n, n, n), spacing=spacing, origin=(-half_extent,) * 3)
    V = g.vertices.copy()
    inside = np.all(np.abs(V) < half_extent - 1e-9, axis=1)
    V[inside] += np.random.default_rng(seed).uniform(-jitter, jitter, (inside.sum(), 3))
    return TetMesh(vertices=V, tets=g.tets)
