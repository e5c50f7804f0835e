"""Texture coordinates for new faces: the box (tri-planar) projection of fault faces."""

from __future__ import annotations

import numpy as np

# Normal components (unit normals) closer than this count as a tie in the box projection.
_UV_AXIS_TIE = 1e-9


def box_uvs(world: np.ndarray, normals: np.ndarray, uv_scale: float) -> np.ndarray:
    """Box (tri-planar) projection UVs (n, 2) of world positions along each normal's dominant axis."""
    magnitude = np.abs(normals)
    # Near-ties (45-degree faces) go to the lowest axis, so rounding noise (e.g. the same shape at another
    # scale) cannot flip a face to another projection.
    axis = np.argmax(magnitude >= magnitude.max(axis=1, keepdims=True) - _UV_AXIS_TIE, axis=1)
    sign = np.sign(normals[np.arange(len(normals)), axis])
    sign[sign == 0] = 1.0
    # (u, v) axes per dominant axis; u flips with the normal's sign so textures are not mirrored.
    u_axis = np.array([1, 0, 0])[axis]
    v_axis = np.array([2, 2, 1])[axis]
    rows = np.arange(len(world))
    u = world[rows, u_axis] * sign * np.where(axis == 1, -1.0, 1.0)
    v = world[rows, v_axis]
    return np.column_stack([u, v]) / uv_scale
