"""Material weights ``eta`` on the interior faces of the tet mesh.

The discontinuity energy charges ``w_f * eta_f`` for cutting face ``f``
(ALGORITHM.md section 2): ``eta`` is where a destructible material's character
lives. This stage turns a recipe's material section into one weight per face:

* grain (wood): cutting across the grain costs ``grain_strength`` times more
  than splitting along it, ``eta_f = 1 + (s - 1) (n_f . a)^2`` with ``n_f`` the
  face normal and ``a`` the grain axis;
* a strength map from a vertex-colour channel of the input: channel value
  ``c`` in [0, 1] gives ``strength_min * (strength_max / strength_min) ** c``
  (geometric, since strength is a ratio), taken from the nearest input vertex;
* named axis-aligned boxes in the input's units, each multiplying ``eta`` of the
  faces whose centroid lies inside (a large value makes a part unbreakable, a
  value below 1 makes it weaker).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import RecipeError
from fracture_cli.options import option
from fracture_cli.system import detmath
from fracture_cli.types import SurfaceMesh, TetMesh

log = logging.getLogger(__name__)

_AXES = {"x": 0, "y": 1, "z": 2}
_CHANNELS = {"r": 0, "g": 1, "b": 2, "a": 3}


@dataclass(frozen=True)
class MaterialOptions:
    """Options of the ``material`` stage (a recipe's ``[material]`` section)."""

    grain_axis: str = option("none", "axis of the grain, in the input's frame (wood splits along it)",
                             choices=("none", "x", "y", "z"))
    grain_strength: float = option(1.0, "how much harder cutting across the grain is than along it",
                                   min=1.0, max=1e4)
    strength_channel: str = option("none", "vertex-colour channel that paints strength",
                                   choices=("none", "r", "g", "b", "a"))
    strength_min: float = option(1.0, "strength multiplier where the painted channel is 0", min=1e-3, max=1e6)
    strength_max: float = option(1.0, "strength multiplier where the painted channel is 1", min=1e-3, max=1e6)
    boxes: list = option([], "named boxes {name, min = [x, y, z], max = [x, y, z], strength} in input units")


def _check_boxes(boxes: Sequence[object]) -> list[tuple[str, np.ndarray, np.ndarray, float]]:
    out = []
    for i, box in enumerate(boxes):
        if not isinstance(box, dict):
            raise RecipeError(f"material.boxes[{i}] must be a table with name, min, max, strength")
        unknown = set(box) - {"name", "min", "max", "strength"}
        if unknown:
            raise RecipeError(f"material.boxes[{i}] has unknown key(s) {', '.join(sorted(unknown))}; "
                              "valid: name, min, max, strength")
        try:
            lo = np.asarray(box["min"], dtype=np.float64).reshape(3)
            hi = np.asarray(box["max"], dtype=np.float64).reshape(3)
            strength = float(box["strength"])
        except (KeyError, ValueError, TypeError) as exc:
            raise RecipeError(f"material.boxes[{i}] needs min = [x, y, z], max = [x, y, z] and a number "
                              f"strength ({exc})") from None
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
            raise RecipeError(f"material.boxes[{i}]: min must be <= max, both finite")
        if not (1e-3 <= strength <= 1e6):
            raise RecipeError(f"material.boxes[{i}].strength = {strength} is out of range [0.001, 1000000.0]")
        out.append((str(box.get("name", f"box_{i}")), lo, hi, strength))
    return out


def material(tet_mesh: TetMesh, surface: SurfaceMesh | None, options: MaterialOptions) -> np.ndarray:
    """Per-face material weights ``eta`` for the interior faces of ``tet_mesh``.

    Parameters
    ----------
    tet_mesh : TetMesh
        The cage's tet mesh (normalized coordinates).
    surface : SurfaceMesh or None
        The input surface, for vertex-colour strength maps (may be None when
        no strength channel is used).
    options : MaterialOptions

    Returns
    -------
    eta : (f,) float64
        Positive weight per interior face; all ones for the default material.

    Notes
    -----
    ALGORITHM.md section 2: "eta_f is the material weight: anisotropy (wood
    grain) and strength maps".
    """
    faces = tet_mesh.interior_faces
    eta = np.ones(len(faces))
    if options.grain_axis != "none" and options.grain_strength != 1.0:
        cos = tet_mesh.interior_face_normals[:, _AXES[options.grain_axis]]
        eta *= 1.0 + (options.grain_strength - 1.0) * np.square(cos)
    centroids = tet_mesh.vertices[faces].mean(axis=1)
    if options.strength_channel != "none":
        if surface is None or surface.colors is None:
            name = surface.name if surface is not None else "input"
            raise RecipeError(f"material.strength_channel = '{options.strength_channel}' but {name} has no vertex "
                              "colours; paint them or set strength_channel = 'none'")
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(surface.vertices).query(centroids)
        c = np.clip(surface.colors[nearest, _CHANNELS[options.strength_channel]], 0.0, 1.0)
        eta *= options.strength_min * detmath.power(options.strength_max / options.strength_min, c)
    if options.boxes:
        world = tet_mesh.normalization.to_world(centroids)
        for name, lo, hi, strength in _check_boxes(options.boxes):
            inside = np.all((world >= lo) & (world <= hi), axis=1)
            eta[inside] *= strength
            log.info("material: box '%s' scales %d faces by %g", name, int(inside.sum()), strength)
    return eta
