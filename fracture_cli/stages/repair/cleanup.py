"""Repair: welding by position, snapping near-coincident bodies together, and flatness."""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.edges import components
from fracture_cli.geometry.rows import used_vertices
from fracture_cli.geometry.solids import POS

# Smallest / largest singular value of the centred positions below which they are coplanar.
_FLAT = 1e-9


def snap_between_bodies(props: np.ndarray, faces: np.ndarray, weld: np.ndarray, tolerance: float) -> int:
    """Move vertices of different bodies that lie within ``tolerance`` of each other onto one position (in place).

    Parameters
    ----------
    props : (n, c) float64
        Split-vertex properties; columns :data:`POS` are moved (in place) onto
        the position of their group's lowest welded vertex.
    faces : (m, 3) int64
        Triangles over split vertices.
    weld : (n,) int64
        Representative of every split vertex (vertices at one position).
    tolerance : float
        Largest distance snapped (normalized units, i.e. of the bounding-box diagonal).

    Returns
    -------
    int
        How many welded vertices moved.

    Notes
    -----
    A baked output GLB stores each fragment in float32 about its own pivot, so
    the faces two neighbours share are a few float32 steps apart when read
    back, and their union would keep hairline gaps. Snapping makes those faces
    coincide exactly; the bodies stay topologically separate (nothing is
    welded across them), so each stays a closed solid and the union merges
    them. Only vertices of *different* bodies (faces connected through shared
    vertices) move, so small features within one body are never collapsed.
    """
    welded = weld[faces]
    reps = used_vertices(welded, len(weld))
    if len(reps) < 2 or tolerance <= 0:
        return 0
    local = np.searchsorted(reps, welded)
    body = components(len(reps), np.vstack([local[:, [0, 1]], local[:, [1, 2]]]))  # per welded vertex
    # on first use: scipy.spatial (0.4-0.7 s to import) is not loaded to resolve a recipe, which imports this module
    from scipy.spatial import cKDTree

    pairs = cKDTree(props[reps, POS]).query_pairs(tolerance, output_type="ndarray")
    pairs = pairs[body[pairs[:, 0]] != body[pairs[:, 1]]] if len(pairs) else pairs
    if not len(pairs):
        return 0
    group = components(len(reps), pairs)
    lowest = np.full(int(group.max()) + 1, len(reps), dtype=np.int64)
    np.minimum.at(lowest, group, np.arange(len(reps)))
    target = reps[lowest[group]]
    moved = np.any(props[target, POS] != props[reps, POS], axis=1)
    position = np.arange(len(weld))
    position[reps] = target
    props[:, POS] = props[position[weld], POS]
    return int(moved.sum())


def is_flat(P: np.ndarray) -> bool:
    """Whether points (k, 3) lie in one plane (or are fewer than 4)."""
    if len(P) < 4:
        return True
    s = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    return bool(s[0] == 0 or s[2] <= _FLAT * s[0])
