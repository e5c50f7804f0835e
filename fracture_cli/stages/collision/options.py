"""Options of the ``collision`` stage (what a recipe's ``[collision]`` section may say).

Apart from the stage's work so that resolving a recipe loads neither manifold3d nor scipy.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.io.names import COLLISION_FORMATS
from fracture_cli.options import option

STAGE = "collision"

# How the GLB carries the parts (fracture_cli.io.physics); "none" computes none.
# PhysX and Chaos cook at most 255 vertices per convex mesh.
ENGINE_MAX_VERTICES = 255


@dataclass(frozen=True)
class CollisionOptions:
    """Options of :func:`collision_shapes`."""

    max_parts: int = option(8, "convex parts per fragment at most", min=1, max=64)
    max_vertices: int = option(64, "vertices per convex part at most (PhysX/Chaos accept 255)", min=8,
                               max=ENGINE_MAX_VERTICES)
    concavity: float = option(0.1, "a part is convex enough when its hull volume is within this fraction of its "
                                   "volume", min=0.0, min_exclusive=True)
    intrusion: float = option(0.0, "also cut a part while its hull reaches into other fragments by more than this "
                                   "fraction of its volume (0: off; costs a boolean per part and neighbour)", min=0.0)
    glb: str = option("omi", "how the GLB carries the parts: OMI_physics_shape/OMI_physics_body extensions (omi), "
                             "'<fragment>_NN-convcolonly' child meshes (godot), 'UCX_<fragment>_NN' child meshes "
                             "(unreal), or no parts at all (none; the runtime file then has none either)",
                      choices=COLLISION_FORMATS)
