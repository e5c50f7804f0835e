"""``kind = "bricks"``: a brick bond for walls.

Courses of height ``brick_size[1]`` stack along ``up`` from the bottom of the
asset; along ``along`` each course is cut every ``brick_size[0]``, every other
course shifted by ``bond_offset`` of a brick (0.5: running bond); across the
third axis every ``brick_size[2]`` (a deep wall is several bricks thick).
Sizes are fractions of the bounding-box diagonal.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.errors import RecipeError
from fracture_cli.stages.pattern.cells import AXES, label_rows
from fracture_cli.types import TetMesh

if TYPE_CHECKING:  # the options type only for annotations (the package imports this module)
    from fracture_cli.stages.pattern import PatternOptions
    from fracture_cli.stages.pattern.cells import Box


def assign(tet_mesh: TetMesh, held: np.ndarray, box: Box, options: PatternOptions) -> np.ndarray:
    """Cell (t,) of every tet centroid: its (course, brick, layer)."""
    up, along = AXES[options.up], AXES[options.along]
    if up == along:
        raise RecipeError(f"pattern.up and pattern.along are both '{options.up}'; bricks need two different axes")
    depth = 3 - up - along
    length, height, thick = (float(v) for v in options.brick_size)
    lo, _ = box
    x = tet_mesh.tet_centroids
    course = np.floor((x[:, up] - lo[up]) / height).astype(np.int64)
    shift = np.where(course % 2 == 1, float(options.bond_offset) * length, 0.0)
    brick = np.floor((x[:, along] - lo[along] + shift) / length).astype(np.int64)
    layer = np.floor((x[:, depth] - lo[depth]) / thick).astype(np.int64)
    return label_rows(np.stack([course, brick, layer], axis=1))
