"""The ``collision`` stage and the game-ready data of a bake: mass properties, pivots, convex parts.

The stage (:func:`collision`) computes the convex collision parts of every
fragment once, and the pipeline their mass properties and pivots with them
(:func:`fracture_cli.io.physics.fragment_physics`, the state's ``physics``); the
runtime stage and the GLB writer both read that, so the two files carry the same
parts and masses.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.stages.collision.options import STAGE, CollisionOptions

if TYPE_CHECKING:
    from fracture_cli.types import Fragments

log = logging.getLogger(__name__)

# Parts per fragment (model space, asset units): the corners of each convex part.
Parts = tuple[tuple[np.ndarray, ...], ...]


def collision(fragments: Fragments, options: CollisionOptions = CollisionOptions()) -> tuple[Parts, dict]:
    """Non-overlapping convex parts of every fragment, in the asset's units, and what the report says of them.

    Parameters
    ----------
    fragments : Fragments
        One-body fragments (normalized coordinates).
    options : CollisionOptions
        ``glb = "none"`` computes no parts.

    Returns
    -------
    parts : tuple of tuple of (k, 3) float64
        Per fragment, the corners of each convex part, model space (asset units).
    checks : dict
        ``collision_parts`` (total), ``collision_max_parts`` (per fragment),
        ``collision_max_overlap`` (largest overlap of two parts over the smaller
        one's volume, measured by exact booleans; pairs that a face plane of
        one part separates up to less than 1e-12 of it count as 0),
        ``collision_min_coverage``
        (smallest fraction of a fragment's volume inside its parts). Empty for
        ``glb = "none"``.
    """
    if options.glb == "none":
        return tuple(() for _ in fragments.fragments), {}
    # on first use: a recipe reads CollisionOptions from this package without loading manifold3d and scipy
    from fracture_cli.stages.collision.convex import collision_shapes, max_overlap_fraction

    interior = fragments.interior_slot
    # Fragments touch through their fault faces only: the outer surface (most faces of a large input) is not matched.
    shapes = collision_shapes([(f.vertices, f.faces) for f in fragments.fragments], options,
                              faults=[f.material_ids == interior for f in fragments.fragments])
    every = [p for parts in shapes.parts for p in parts]
    checks = {
        "collision_parts": len(every),
        "collision_max_parts": max((len(parts) for parts in shapes.parts), default=0),
        "collision_max_overlap": round(float(max_overlap_fraction(every, faces=shapes.part_faces)), 9),
        "collision_min_coverage": round(float(shapes.coverage.min()), 6) if len(shapes.coverage) else 1.0,
    }
    log.info("%s: %d convex parts for %d fragments (at most %d each), largest overlap %.2g, coverage >= %.3f",
             STAGE, checks["collision_parts"], len(shapes.parts), checks["collision_max_parts"],
             checks["collision_max_overlap"], checks["collision_min_coverage"])
    world = fragments.normalization.to_world
    return tuple(tuple(world(p) for p in parts) for parts in shapes.parts), checks

