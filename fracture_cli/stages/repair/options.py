"""Options of the ``repair`` stage (what a recipe's ``[repair]`` section may say) and what the stage returns.

Apart from the stage's work so that resolving a recipe loads neither manifold3d nor the repair steps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from fracture_cli.options import option

if TYPE_CHECKING:
    from fracture_cli.stages.repair.records import RepairRecord
    from fracture_cli.types import SurfaceMesh

STAGE = "repair"

# Vertices of different bodies closer than this (of the diagonal) are one point: a few float32 steps of a
# fragment's pivot-relative coordinates (a baked GLB read back), far below any modelled feature.
SNAP_TOLERANCE = 2e-7

FLAT_HINT = ("give it thickness in your modelling tool, or use --set repair.open_surface=shell to thicken it "
             "into a thin solid")


@dataclass(frozen=True)
class RepairOptions:
    """Options of :func:`repair`."""

    open_surface: str = option(
        "auto",
        "what to do with a surface that is open after welding: 'auto' fills the holes of each body that close "
        "into a solid (see hole_planarity, small_hole, max_fill_share) and thickens the rest inward as sheets; "
        "'fill' fills every hole that can be filled; 'shell' thickens every open body; 'error' stops",
        choices=("auto", "fill", "shell", "error"),
    )
    shell_thickness: float = option(
        0.01,
        "thickness of a thickened sheet, relative to the bounding-box diagonal (thinner where the sheet folds "
        "tighter than that or meets its bounding box)",
        min=0.0,
        max=0.5,
        min_exclusive=True,
    )
    hole_planarity: float = option(
        0.1,
        "'auto' fills a hole whose outline lies within this fraction of its diameter of a plane (or is small)",
        min=0.0,
    )
    small_hole: float = option(
        0.1,
        "'auto' fills a hole whose diameter is at most this fraction of its body's bounding-box diagonal "
        "(whatever its shape)",
        min=0.0,
    )
    max_fill_share: float = option(
        0.5,
        "'auto' fills a body's holes only while the patches are at most this fraction of the filled surface "
        "(unless hidden inside another body); above it the body is a sheet",
        min=0.0,
        max=1.0,
    )
    fins: str = option(
        "thicken",
        "fins and sheets of zero thickness hinged on a solid's edge (edges of more than two faces that do not pair "
        "into closed bodies): cut off and thickened as sheets of their own ('thicken'), left out ('drop'), or "
        "refused ('error'); closed bodies enclosing no volume are left out unless 'error'",
        choices=("thicken", "drop", "error"),
    )
    touching: str = option(
        "separate",
        "closed bodies that only touch (along a face, an edge or at a point: wheels against a chassis, a lid on a "
        "pot) stay separate bodies, each breaking on its own ('separate'), or are united with what they touch "
        "('unite'); bodies that overlap are always united",
        choices=("separate", "unite"),
    )
    container_opening: float = option(
        0.5,
        "'auto' keeps a body hollow, as a thin wall, when a planar hole at its top (the whole body below the "
        "hole's plane) is at least this fraction of the body's width there: an open container (a pot without "
        "its lid), unless another body covers the opening (a lid); above 1: never",
        min=0.0,
    )

    # Keys of older recipes: read with a warning and ignored (see fracture_cli.pipeline.recipe).
    RETIRED = {"max_fill_ratio": "holes are now filled when they close into a solid, whatever their share of "
                                 "the area (see repair.max_fill_share, repair.hole_planarity, repair.small_hole)"}



@dataclass(frozen=True)
class RepairResult:
    """What :func:`repair_surface` made and did.

    Attributes
    ----------
    surface : SurfaceMesh
        The closed solid (the input itself when nothing needed repair).
    records : tuple of RepairRecord
        Every repair, in the order done, positions and areas in normalized
        units; the first is the ``decision`` (solid or shell).
    """

    surface: SurfaceMesh
    records: tuple[RepairRecord, ...]
