"""Options of the ``fragments`` stage (what a recipe's ``[fragments]`` section may say).

Apart from the stage's work so that resolving a recipe loads neither manifold3d nor the cutting.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.options import option

STAGE = "fragments"


@dataclass(frozen=True)
class FragmentOptions:
    """Options of :func:`fragments`."""

    uv_scale: float = option(
        1.0,
        "interior faces' box-projected UVs: world units (input units) per UV unit",
        min=0.0,
        min_exclusive=True,
    )
    interior_color: list = option(
        [0.55, 0.5, 0.45, 1.0],
        "RGBA (0..1) base colour of the 'interior' material on the new fault faces",
        min=0.0,
        max=1.0,
    )
    pivot: str = option(
        "center_of_mass",
        "origin of every fragment node in the GLB: its centre of mass (where engines put a rigid body's origin) "
        "or its bounding-box centre (bbox)",
        choices=("center_of_mass", "bbox"),
    )
    min_body_fraction: float = option(
        0.001,
        "a fragment that falls apart is split into one fragment per closed body; bodies holding less than this "
        "fraction of the asset's volume are glued to the neighbour they share the most fault area with",
        min=0.0,
        max=1.0,
    )
