"""The ``pattern`` stage: authored fracture patterns (issue 32; ALGORITHM.md section 9).

``kind = "modes"`` (the default) leaves the pieces to the fracture modes, as
before this stage existed. Any other kind assigns every tet of the tet mesh to
a *cell* of an authored pattern (by the cell its centroid falls in); the cells
then become the atomic pieces (:func:`fracture_cli.stages.pieces.pieces`) and
the fracture modes are solved restricted to them, one constant value per cell
(:mod:`.restrict`), so every pattern still breaks by the impact.

One module per kind: :mod:`.voronoi`, :mod:`.clustered`, :mod:`.radial`,
:mod:`.slices`, :mod:`.bricks`, :mod:`.profile`; :mod:`.cells` has what they
share (sites in the solid, nearest-site cells, one connected body per cell).

Lengths are fractions of the bounding-box diagonal (the tet mesh's normalized
units, where the diagonal is 1); points (``centre``, ``centres``) are fractions
of the asset's bounding box per axis (0.5 = the middle).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import RecipeError
from fracture_cli.options import option
from fracture_cli.types import SurfaceMesh, TetMesh

log = logging.getLogger(__name__)

STAGE = "pattern"
KINDS = ("modes", "voronoi", "clustered", "radial", "slices", "bricks", "profile")


@dataclass(frozen=True)
class PatternOptions:
    """Options of the ``pattern`` stage (a recipe's ``[pattern]`` section)."""

    kind: str = option("modes", "what decides the pieces: 'modes' (the fracture modes) or an authored pattern",
                       choices=KINDS)
    seed: int = option(0, "seed of the pattern's uniform random draws (fixed: results are reproducible)", min=0)
    count: int = option(16, "voronoi: sites in the solid; clustered: sites per cluster", min=1, max=10000)
    clusters: int = option(3, "clustered: number of cluster centres (random in the solid unless 'centres')",
                           min=1, max=1000)
    centres: list = option([], "clustered: cluster centres [[x, y, z], ...] as fractions of the bounding box")
    spread: float = option(0.1, "clustered: radius of a cluster (fraction of the diagonal)", min=0.0, max=1.0,
                           min_exclusive=True)
    background: int = option(0, "clustered: extra sites uniform in the solid", min=0, max=10000)
    centre: list = option([0.5, 0.5, 0.5], "radial: centre as fractions of the bounding box per axis",
                          min=0.0, max=1.0)
    axis: str = option("z", "radial: axis of the rings and spokes (a pane's normal)", choices=("x", "y", "z"))
    rings: int = option(3, "radial: number of rings", min=1, max=100)
    spokes: int = option(8, "radial: number of spokes", min=1, max=360)
    ring_growth: float = option(1.5, "radial: ring radius i grows as (i / rings) ** (1 / ring_growth) of the "
                                "largest; above 1 rings crowd near the centre", min=0.1, max=10.0)
    jitter: float = option(0.25, "radial and slices: random offset of rings, spokes and planes, as a fraction "
                           "of their spacing", min=0.0, max=0.5)
    slice_axes: str = option("x", "slices: axes cut by planes, e.g. 'x' or 'xz'",
                             choices=("x", "y", "z", "xy", "xz", "yz", "xyz"))
    slices: int = option(3, "slices: planes per axis (evenly spaced)", min=1, max=100)
    angle_jitter: float = option(5.0, "slices: random tilt of each plane, degrees at most", min=0.0, max=45.0)
    brick_size: list = option([0.2, 0.1, 1.0], "bricks: length, height, depth of a brick (fractions of the "
                              "diagonal, along 'along', 'up' and the third axis)", min=1e-3, max=10.0)
    up: str = option("y", "bricks: axis across the bed joints (courses stack along it)", choices=("x", "y", "z"))
    along: str = option("x", "bricks: axis the courses run along", choices=("x", "y", "z"))
    bond_offset: float = option(0.5, "bricks: shift of every other course, as a fraction of a brick's length "
                                "(0.5 = running bond, 0 = stack bond)", min=0.0, max=1.0)
    profiles: list = option([], "profile: fracture patterns {points = [[u, v], ...], weight, rotation (degrees), "
                            "volume_ratio}; empty = one straight cut")
    cuts: int = option(3, "profile: cuts, each splitting the largest cell with a profile picked by weight",
                       min=1, max=1000)
    rotation_jitter: float = option(0.0, "profile: random change of each cut's rotation, degrees at most",
                                    min=0.0, max=180.0)


def pattern(tet_mesh: TetMesh, surface: SurfaceMesh | None, options: PatternOptions = PatternOptions()
            ) -> np.ndarray | None:
    """The cell of every tet under the recipe's pattern, or None for ``kind = "modes"``.

    Parameters
    ----------
    tet_mesh : TetMesh
        The cage's tet mesh (``t`` tets, normalized coordinates).
    surface : SurfaceMesh, optional
        The repaired input: sites are drawn in its solid and cell sizes are the
        asset volume they hold. Without it, the tet mesh's own volume.
    options : PatternOptions

    Returns
    -------
    (t,) int32 or None
        Cell ids 0..c-1 numbered by lowest tet, every cell one face-connected
        set of tets (:func:`.cells.connected_cells`).

    Raises
    ------
    RecipeError
        If the pattern's parameters do not describe cells (bad profile tables,
        ``up == along`` ...).
    """
    if options.kind == "modes":
        return None
    # each kind's module loads only when a recipe uses a pattern (recipes import this module)
    from fracture_cli.stages.pattern import bricks, cells, clustered, profile, radial, slices, voronoi

    started = time.perf_counter()
    held = cells.held_volumes(tet_mesh, surface)
    makers = {"voronoi": voronoi.assign, "clustered": clustered.assign, "radial": radial.assign,
              "slices": slices.assign, "bricks": bricks.assign, "profile": profile.assign}
    raw = makers[options.kind](tet_mesh, held, cells.solid_box(tet_mesh, surface), options)
    labels = cells.connected_cells(tet_mesh, raw, held)
    count = int(labels.max()) + 1
    log.info("%s: %s pattern, %d cells (%d before the connected split) in %.2f s", STAGE, options.kind, count,
             len(np.unique(raw)), time.perf_counter() - started)
    if count < 2:
        raise RecipeError(f"pattern.kind = '{options.kind}' gives a single cell on this asset; use more sites, "
                          "slices or smaller bricks")
    return labels.astype(np.int32)


__all__ = ["KINDS", "PatternOptions", "pattern"]
