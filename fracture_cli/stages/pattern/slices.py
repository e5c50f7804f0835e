"""``kind = "slices"``: planes along one or more axes, with offset and angle jitter.

Along each axis of ``slice_axes``, ``slices`` planes are evenly spaced over the
asset's extent (each moved by up to ``jitter`` of the spacing) and tilted by up
to ``angle_jitter`` degrees about a random direction in the plane. A tet's cell
is the side of every plane its centroid is on (planes may cross).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.stages.pattern.cells import AXES, label_rows
from fracture_cli.system import detmath
from fracture_cli.types import TetMesh

if TYPE_CHECKING:  # the options type only for annotations (the package imports this module)
    from fracture_cli.stages.pattern import PatternOptions
    from fracture_cli.stages.pattern.cells import Box

_DEGREE = 3.141592653589793 / 180.0


def planes(rng: np.random.Generator, box: Box, options: PatternOptions) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (n, 3) and offsets (n,) of the planes ``normal . x = offset``."""
    lo, hi = box
    normals, offsets = [], []
    for name in options.slice_axes:
        a = AXES[name]
        b, c = (a + 1) % 3, (a + 2) % 3
        count = int(options.slices)
        spacing = (hi[a] - lo[a]) / (count + 1)
        positions = lo[a] + spacing * (np.arange(1, count + 1) + options.jitter * rng.uniform(-1.0, 1.0, count))
        tilt = options.angle_jitter * _DEGREE * rng.uniform(0.0, 1.0, count)
        turn = rng.uniform(0.0, 2.0 * 3.141592653589793, count)
        st, ct = detmath.sin_cos(tilt)
        sp, cp = detmath.sin_cos(turn)
        centre = 0.5 * (lo + hi)
        for i in range(count):
            n = np.zeros(3)
            n[a], n[b], n[c] = ct[i], st[i] * cp[i], st[i] * sp[i]
            point = centre.copy()
            point[a] = positions[i]
            normals.append(n)
            offsets.append(n[0] * point[0] + n[1] * point[1] + n[2] * point[2])
    return np.asarray(normals), np.asarray(offsets)


def assign(tet_mesh: TetMesh, held: np.ndarray, box: Box, options: PatternOptions) -> np.ndarray:
    """Cell (t,) of every tet centroid: its row of plane sides."""
    rng = np.random.default_rng(options.seed)
    normals, offsets = planes(rng, box, options)
    x = tet_mesh.tet_centroids
    side = (x[:, 0:1] * normals[None, :, 0] + x[:, 1:2] * normals[None, :, 1] + x[:, 2:3] * normals[None, :, 2]
            > offsets[None, :])
    return label_rows(side)
