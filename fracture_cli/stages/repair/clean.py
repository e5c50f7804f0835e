"""Repair's fast path: is the input already one closed, outward, manifold solid that repair would keep as given?

Most inputs of a bake (and every million-triangle scan we have seen) are: the
full repair (welding through manifold3d, the winding search, the non-manifold
split, the manifold3d solid) then spends seconds to change nothing. The checks
here are each a sort, a gather or a compiled pass over the faces, and together
they imply that every step of :func:`~fracture_cli.stages.repair.repair_surface`
would record nothing and keep the surface:

* every vertex at its own position (no weld, no snap: one body has nothing to
  snap to), finite, no face with a repeated corner;
* every directed edge once, and its reverse once (closed, edge-manifold,
  consistently wound: no flip, no split edge, nothing open to fill);
* one fan of faces around every vertex (no pinched vertex to split);
* one connected body, of clearly positive volume (no cavity to orient, no
  union, nothing flat); with one body and closed edges, no face can repeat;
* no shading normal pointing against its faces (computed as repair does).

Anything else, or any doubt, takes the full repair.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import trigeom
from fracture_cli.geometry.rows import group_rows
from fracture_cli.types import SurfaceMesh

# Smallest volume (of a unit-diagonal box) accepted as "clearly positive"; repair refuses at or below 1e-9.
_MIN_FAST_VOLUME = 1e-6


def closed_as_given(surface: SurfaceMesh) -> tuple[bool, float]:
    """Whether repair would return ``surface`` unchanged with no record, and its volume (0 when not known).

    Parameters
    ----------
    surface : SurfaceMesh
        Vertices (n, 3) float64, faces (m, 3) int, normals (n, 3) or None.

    Returns
    -------
    ok : bool
        True only when every check of the module docstring passes.
    volume : float
        The enclosed volume when ``ok``.
    """
    V = np.asarray(surface.vertices, dtype=np.float64)
    F = np.asarray(surface.faces, dtype=np.int64).reshape(-1, 3)
    n, m = len(V), len(F)
    if m < 4 or n < 4 or F.min() < 0 or F.max() >= n:
        return False, 0.0
    if not all(a is None or np.isfinite(a).all() for a in (V, surface.normals, surface.uvs, surface.colors)):
        return False, 0.0
    if ((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])).any():
        return False, 0.0
    # Compiled, each a pass over every vertex's corners (trigeom_topology).
    if not trigeom.edge_manifold_closed(F) or not trigeom.vertex_manifold(F) or trigeom.face_components(F) != 1:
        return False, 0.0
    if not _distinct_positions(V):
        return False, 0.0
    volume = trigeom.signed_volume(V, F)
    if not volume > _MIN_FAST_VOLUME:
        return False, 0.0
    if surface.normals is not None and _normals_against(V, F, np.asarray(surface.normals, dtype=np.float64)):
        return False, 0.0
    return True, volume


def _distinct_positions(V: np.ndarray) -> bool:
    """Whether no two vertices share a position (exact equality, ``-0.0 == 0.0``)."""
    return int(group_rows(V).max()) + 1 == len(V)


def _normals_against(V: np.ndarray, F: np.ndarray, N: np.ndarray) -> bool:
    """Whether any shading normal points against the area-weighted normal of its faces.

    The sums are :func:`~fracture_cli.stages.repair.orient.fix_shading_normals`'s, bit for bit.
    """
    acc = trigeom.vertex_normals(V, F, unit=False)
    return bool((np.einsum("ij,ij->i", acc, N) < 0).any())
