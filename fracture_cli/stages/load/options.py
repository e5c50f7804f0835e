"""Options of the ``load`` stage (what a recipe's ``[load]`` section may say) and the formats it reads.

Apart from the stage's work so that resolving a recipe loads none of the readers.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.options import option

# Extension -> file type; the only formats we promise to read.
READERS = {
    ".obj": "obj",
    ".ply": "ply",
    ".stl": "stl",
    ".off": "off",
    ".glb": "glb",
    ".gltf": "gltf",
}


@dataclass(frozen=True)
class LoadOptions:
    """Options of the ``load`` stage."""

    max_triangles: int = option(5_000_000, "refuse inputs with more triangles than this", min=1)
