"""``kind = "voronoi"``: a Voronoi tessellation of uniform sites in the solid (seed 002's random pattern)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.stages.pattern.cells import nearest_site, sites_in_solid
from fracture_cli.types import TetMesh

if TYPE_CHECKING:  # the options type only for annotations (the package imports this module)
    from fracture_cli.stages.pattern import PatternOptions
    from fracture_cli.stages.pattern.cells import Box


def assign(tet_mesh: TetMesh, held: np.ndarray, box: Box, options: PatternOptions) -> np.ndarray:
    """The Voronoi cell (t,) of every tet centroid, for ``options.count`` sites drawn from ``options.seed``.

    Parameters
    ----------
    tet_mesh : TetMesh
    held : (t,) float
        Asset volume of every tet: sites are uniform in the asset's solid.
    box : ((3,), (3,)) float
        The asset's bounding box (unused: sites come from the solid itself).
    options : PatternOptions
    """
    rng = np.random.default_rng(options.seed)
    sites = sites_in_solid(rng, tet_mesh, held, int(options.count))
    return nearest_site(tet_mesh.tet_centroids, sites)
