"""What every mesh reader returns: triangles of one material in the file's world space."""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass

import numpy as np

from fracture_cli.types import Material


@dataclass(frozen=True, eq=False)
class MeshPart:
    """Triangles of one material, placed in the file's world space.

    Attributes
    ----------
    vertices : (n, 3) float64
        World (file) units, node transforms applied.
    faces : (m, 3) int64
        Counter-clockwise seen from outside (as the file meant it).
    uvs : (n, 2) float64 or None
        OpenGL convention (v up).
    normals : (n, 3) float64 or None
        Unit shading normals.
    colors : (n, 4) float64 or None
        RGBA in [0, 1].
    material : Material
    material_key : hashable
        Parts with equal keys share one material slot (a glTF material
        index; an OBJ material name, which is how OBJ identifies materials).
    raw_vertices : (n, 3) float64 or None
        The coordinates as stored, before node transforms (for the float32
        precision warning); None means ``vertices``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    normals: np.ndarray | None
    colors: np.ndarray | None
    material: Material
    material_key: Hashable
    raw_vertices: np.ndarray | None = None
