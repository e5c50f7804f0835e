"""Options of the ``cage`` stage (what a recipe's ``[cage]`` section may say).

Apart from the stage's work so that resolving a recipe loads neither the distance field nor TetGen.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.options import option

STAGE = "cage"

DECIMATORS = ("fast-simplification", "open3d")


@dataclass(frozen=True)
class CageOptions:
    """Options of the ``cage`` stage. Lengths are relative to the input's bounding-box diagonal."""

    target_faces: int = option(2000, "number of cage triangles (the result is within 10%)", min=100, max=200_000)
    grid_resolution: int = option(
        0, "distance-grid cells along the bounding-box diagonal; 0 = automatic (about 2.2 sqrt(target_faces))",
        min=0, max=1024)
    initial_offset: float = option(0.01, "first offset tried; doubled until a cage is found, then bisected",
                                   min=0.0, max=1.0, min_exclusive=True)
    tolerance: float = option(0.002, "stop bisecting when the offset bracket is narrower than this",
                              min=0.0, max=1.0, min_exclusive=True)
    max_iterations: int = option(12, "largest number of offsets tried", min=1, max=100)
    max_offset: float = option(0.5, "give up rather than try an offset larger than this", min=0.0, max=10.0,
                               min_exclusive=True)
    tetgen_timeout: float = option(60.0, "seconds before one TetGen run is abandoned", min=1.0, max=3600.0)
    decimator: str = option("fast-simplification", "quadric decimation library", choices=DECIMATORS)
