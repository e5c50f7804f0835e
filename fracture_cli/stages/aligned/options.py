"""Options of the ``aligned`` stage (what a recipe's ``[aligned]`` section may say).

Apart from the stage's work so that resolving a recipe loads neither scipy nor the stage.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.options import option

STAGE = "aligned"


@dataclass(frozen=True)
class AlignedOptions:
    """Options of :func:`fracture_cli.stages.aligned.aligned` (docs/FORMAT.md section 13)."""

    enabled: bool = option(False, "also write <stem>.aligned.json + .bin: the convex pieces, their triangles and "
                                  "fracture patterns for cutting the asset at the hit at runtime (seed 001)")
    sites: int = option(50, "Voronoi sites per fracture pattern (cells of the pattern, the centre one included)",
                        min=1, max=4096)
    patterns: int = option(2, "fracture patterns in the file (each from its own seed: a game may vary them)",
                           min=1, max=64)
    grading: float = option(1.5, "a site's distance from the pattern's centre is u**grading for u uniform in "
                                 "(0, 1): 1/3 spreads sites evenly in the unit ball, larger values make the "
                                 "cells finer near the hit", min=0.1, max=8.0)
    spacing: float = option(0.35, "a site keeps at least this fraction of its distance from the centre away from "
                                  "every other site (no needle cells)", min=0.0, max=1.0)
    bounded: bool = option(True, "cut the cells to a dodecahedron around the pattern's unit ball: what lies beyond "
                                 "it stays one piece, the rest of the object (false: the outer cells reach to "
                                 "infinity and cut the whole asset)")
    scale: float = option(0.25, "the pattern's default radius (its unit ball) as a fraction of the asset's "
                                "bounding-box diagonal; a game passes its own per hit", min=0.0,
                          min_exclusive=True)
    seed: int = option(1, "seed of the first pattern (pattern q uses seed + q)", min=0)
