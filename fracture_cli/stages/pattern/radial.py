"""``kind = "radial"``: rings and spokes around a centre and an axis (the glass-pane look).

A tet centroid at in-plane radius ``r`` and angle ``theta`` about the axis
through ``centre`` lies in sector ``j`` (between two spokes) and ring ``i`` of
that sector. Spoke angles are evenly spaced and moved by up to ``jitter`` of
their spacing; each sector has its own ring radii, ``R (i / rings) ** (1 /
ring_growth)`` (``R`` the farthest centroid) moved by up to ``jitter`` of the
ring spacing, so the rings are broken lines as in cracked glass.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.stages.pattern.cells import AXES, box_point
from fracture_cli.system import detmath
from fracture_cli.types import TetMesh

if TYPE_CHECKING:  # the options type only for annotations (the package imports this module)
    from fracture_cli.stages.pattern import PatternOptions
    from fracture_cli.stages.pattern.cells import Box

_TWO_PI = 2.0 * 3.141592653589793


def plane_axes(axis: str) -> tuple[int, int, int]:
    """``(normal, u, v)`` axis indices: the axis and the two that span its plane (right-handed)."""
    n = AXES[axis]
    return n, (n + 1) % 3, (n + 2) % 3


def assign(tet_mesh: TetMesh, held: np.ndarray, box: Box, options: PatternOptions) -> np.ndarray:
    """Cell (t,) of every tet centroid: ``ring * spokes + sector`` (the centre disc is ring 0 of every sector)."""
    rng = np.random.default_rng(options.seed)
    _, ua, va = plane_axes(options.axis)
    centre = box_point(box, options.centre)
    points = tet_mesh.tet_centroids
    du, dv = points[:, ua] - centre[ua], points[:, va] - centre[va]
    radius = np.sqrt(du * du + dv * dv)
    theta = np.asarray(detmath.atan2(dv, du)) % _TWO_PI  # [0, 2 pi)
    spokes, rings = int(options.spokes), int(options.rings)
    jitter = float(options.jitter)
    step = _TWO_PI / spokes
    start = rng.uniform(0.0, step)  # where the first spoke is
    bounds = start + step * (np.arange(spokes) + jitter * rng.uniform(-1.0, 1.0, spokes))
    # Sector j spans [bounds[j], bounds[j + 1]), the last one wraps round to bounds[0] + 2 pi.
    sector = (np.searchsorted(bounds, theta, side="right") - 1) % spokes
    largest = float(radius.max()) if len(radius) else 1.0
    fractions = np.arange(1, rings + 1, dtype=np.float64) / rings
    base = largest * np.asarray(detmath.power(fractions, 1.0 / float(options.ring_growth)))
    spacing = np.diff(np.concatenate([[0.0], base]))
    radii = base[None, :] + jitter * spacing[None, :] * rng.uniform(-1.0, 1.0, (spokes, rings))
    radii = np.sort(radii, axis=1)  # jittered rings of a sector may not cross
    radii[:, -1] = np.inf  # the outer ring takes everything beyond
    ring = np.zeros(len(points), dtype=np.int64)
    for j in range(spokes):
        mine = sector == j
        ring[mine] = np.searchsorted(radii[j], radius[mine], side="right")
    # The innermost ring is one disc (every sector's ring 0 joined): the point of impact of a pane.
    return np.where(ring == 0, 0, 1 + (ring - 1) * spokes + sector)
