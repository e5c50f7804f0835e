"""``kind = "clustered"``: Voronoi cells of sites clustered around centres (denser where the centres are)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.errors import RecipeError
from fracture_cli.stages.pattern.cells import box_point, nearest_site, sites_in_solid
from fracture_cli.types import TetMesh

if TYPE_CHECKING:  # the options type only for annotations (the package imports this module)
    from fracture_cli.stages.pattern import PatternOptions
    from fracture_cli.stages.pattern.cells import Box


def _ball(rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` points (count, 3) uniform in the unit ball (rejection from the cube: uniform draws only)."""
    found: list[np.ndarray] = []
    have = 0
    while have < count:
        v = rng.uniform(-1.0, 1.0, (2 * (count - have) + 8, 3))
        v = v[v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2] <= 1.0]
        found.append(v)
        have += len(v)
    return np.concatenate(found)[:count]


def centres_of(rng: np.random.Generator, tet_mesh: TetMesh, held: np.ndarray, box: Box,
               options: PatternOptions) -> np.ndarray:
    """Cluster centres (c, 3): ``options.centres`` (bounding-box fractions), else random in the solid."""
    if not options.centres:
        return sites_in_solid(rng, tet_mesh, held, int(options.clusters))
    try:
        fractions = np.asarray(options.centres, dtype=np.float64).reshape(-1, 3)
    except (TypeError, ValueError):
        raise RecipeError(f"pattern.centres = {options.centres!r} must be a list of [x, y, z] "
                          "(fractions of the bounding box)") from None
    if not np.all(np.isfinite(fractions)):
        raise RecipeError("pattern.centres must hold finite numbers")
    return np.stack([box_point(box, f) for f in fractions])


def assign(tet_mesh: TetMesh, held: np.ndarray, box: Box, options: PatternOptions) -> np.ndarray:
    """The cell (t,) of every tet centroid: nearest of ``count`` sites per cluster plus ``background`` sites.

    Sites of a cluster are uniform in a ball of radius ``spread`` (a fraction of
    the diagonal, the normalized unit) about its centre.
    """
    rng = np.random.default_rng(options.seed)
    centres = centres_of(rng, tet_mesh, held, box, options)
    per = int(options.count)
    sites = [c + float(options.spread) * _ball(rng, per) for c in centres]
    if options.background:
        sites.append(sites_in_solid(rng, tet_mesh, held, int(options.background)))
    return nearest_site(tet_mesh.tet_centroids, np.concatenate(sites))
