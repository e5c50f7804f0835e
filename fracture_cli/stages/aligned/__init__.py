"""The ``aligned`` stage: what a game needs to cut the asset where it is hit (seed 001, issue 35).

Off unless the recipe says ``aligned.enabled = true``; then the bake also writes the companion file
pair ``<stem>.aligned.json`` + ``<stem>.aligned.bin`` (docs/FORMAT.md section 13):

* the convex pieces: every fragment's collision parts (together a non-overlapping convex
  decomposition of the asset), with their planes, corners and face loops, and the fragment
  triangles that lie in each (:mod:`.pieces`);
* ``patterns`` graded Voronoi patterns of ``sites`` cells in a unit ball (:mod:`.pattern`).

The runtime (:func:`fracture_cli.runtime.aligned.aligned_fracture`, and the C and JavaScript
readers) places a pattern at the hit, clips the pieces with its cells and returns new fragments.

Notes
-----
Müller, Chentanez, Kim 2013, *Real Time Dynamic Fracture with Volumetric Approximate Convex
Decompositions*: the compound (section 3) is the collision stage's parts, the fracture patterns
(section 4) are precomputed here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fracture_cli.stages.aligned.options import STAGE, AlignedOptions

if TYPE_CHECKING:
    from fracture_cli.runtime.aligned_data import AlignedData
    from fracture_cli.types import Fragments

__all__ = ["STAGE", "AlignedOptions", "aligned"]


def aligned(fragments: Fragments, parts: tuple | None, options: AlignedOptions = AlignedOptions(), *,
            uv_scale: float = 1.0, stem: str | None = None) -> AlignedData | None:
    """The aligned-fracture data of a bake, or None when ``options.enabled`` is false.

    Parameters
    ----------
    fragments : Fragments
        The fragments as written (normalized coordinates; triangles, normals, UVs, materials).
    parts : tuple of tuple of (k, 3) float64
        Every fragment's convex collision parts, model space (the ``collision`` stage).
    options : AlignedOptions
    uv_scale : float, optional (default 1.0)
        Model units per UV unit of the box projection on new faces (``fragments.uv_scale``).
    stem : str, optional
        The asset's stem: material names are ``<stem>_<material>`` as in the GLB.

    Returns
    -------
    AlignedData or None

    Raises
    ------
    StageError
        When the bake computed no collision parts (``collision.glb = "none"``): there is nothing to cut.
    """
    # on first use: a recipe reads AlignedOptions from this package without loading the pieces' geometry
    from fracture_cli.stages.aligned.build import aligned_data

    return aligned_data(fragments, parts, options, uv_scale=uv_scale, stem=stem)
