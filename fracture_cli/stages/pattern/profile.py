"""``kind = "profile"``: seed 004's fracture patterns, a polyline extruded into a cutting surface.

A profile is a polyline ``points = [[u, v], ...]`` in a unit space: ``u`` in
[0, 1] runs along the cut, ``v`` is the surface's offset across it, both in
units of the cell's length along the cut. Extruded along the third axis it is
a cutting surface, placed in the principal frame of the cell it cuts (``up``
the axis of largest spread, the object's "principal axis"; ``right`` the
second; the extrusion runs along the third):

* ``rotation`` (degrees) is the angle between the principal axis and the cut:
  the cut runs along ``cos(a) up + sin(a) right``. 0 cuts lengthwise (long,
  thin fragments), 90 across (shorter, squarer ones), as in the seed;
* ``volume_ratio`` moves the surface along its normal until that share of the
  cell's asset volume is on its lower side (0.5 halves the cell);
* ``weight`` is the profile's chance of being picked for a cut.

``cuts`` cuts are made one after the other, each splitting the cell that
holds the most asset volume with a profile drawn by weight (``seed``), its
rotation moved by up to ``rotation_jitter`` degrees. A material is thus a
reusable set of patterns that fits any object.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from fracture_cli.errors import RecipeError
from fracture_cli.geometry import tolerances as tol
from fracture_cli.system import detmath
from fracture_cli.types import TetMesh

if TYPE_CHECKING:  # the options type only for annotations (the package imports this module)
    from fracture_cli.stages.pattern import PatternOptions
    from fracture_cli.stages.pattern.cells import Box

_DEGREE = math.pi / 180.0
_KEYS = {"points", "weight", "rotation", "volume_ratio"}
_STRAIGHT = {"points": [[0.0, 0.0], [1.0, 0.0]], "weight": 1.0, "rotation": 0.0, "volume_ratio": 0.5}


def checked_profiles(profiles: list[dict[str, Any]]) -> list[tuple[np.ndarray, float, float, float]]:
    """``(points (n, 2) sorted by u, weight, rotation degrees, volume_ratio)`` of every profile table."""
    out = []
    for i, raw in enumerate(profiles or [_STRAIGHT]):
        where = f"pattern.profiles[{i}]"
        if not isinstance(raw, dict):
            raise RecipeError(f"{where} must be a table with points, weight, rotation, volume_ratio")
        unknown = set(raw) - _KEYS
        if unknown:
            raise RecipeError(f"{where} has unknown key(s) {', '.join(sorted(unknown))}; valid: "
                              f"{', '.join(sorted(_KEYS))}")
        table = {**_STRAIGHT, **raw}
        try:
            points = np.asarray(table["points"], dtype=np.float64).reshape(-1, 2)
            weight, rotation, ratio = (float(table[k]) for k in ("weight", "rotation", "volume_ratio"))
        except (TypeError, ValueError):
            raise RecipeError(f"{where} needs points = [[u, v], ...] and numbers weight, rotation, "
                              "volume_ratio") from None
        if len(points) < 2 or not np.all(np.isfinite(points)):
            raise RecipeError(f"{where}.points must hold at least two finite [u, v] pairs")
        if not (np.all(points[:, 0] >= 0.0) and np.all(points[:, 0] <= 1.0)):
            raise RecipeError(f"{where}.points: every u must be in [0, 1]")
        if not (math.isfinite(weight) and weight >= 0.0 and math.isfinite(rotation) and abs(rotation) <= 360.0):
            raise RecipeError(f"{where}: weight must be >= 0 and rotation in [-360, 360] degrees")
        if not 0.0 < ratio < 1.0:
            raise RecipeError(f"{where}.volume_ratio = {ratio} must be in (0, 1)")
        points = points[np.argsort(points[:, 0], kind="stable")]
        out.append((points, weight, rotation, ratio))
    if not sum(p[1] for p in out) > 0.0:
        raise RecipeError("pattern.profiles: at least one profile needs a weight above 0")
    return out


def principal_frame(points: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted centroid (3,) and principal axes (3, 3) of ``points`` (n, 3), rows by decreasing spread.

    Sums are :func:`math.fsum` and the 3 x 3 eigenproblem is cyclic Jacobi in
    plain floats (``sqrt`` only), so the frame is the same bits on every CPU.
    """
    total = math.fsum(weights.tolist())
    mean = np.array([math.fsum((weights * points[:, a]).tolist()) / total for a in range(3)])
    d = points - mean
    A = [[math.fsum((weights * d[:, i] * d[:, j]).tolist()) / total for j in range(3)] for i in range(3)]
    V = [[1.0 if i == j else 0.0 for j in range(3)] for i in range(3)]
    for _ in range(64):
        off = A[0][1] * A[0][1] + A[0][2] * A[0][2] + A[1][2] * A[1][2]
        scale = A[0][0] * A[0][0] + A[1][1] * A[1][1] + A[2][2] * A[2][2]
        if not off > 1e-30 * scale:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if A[p][q] == 0.0:
                continue
            theta = (A[q][q] - A[p][p]) / (2.0 * A[p][q])
            if abs(theta) > 1e150:
                t = 0.5 / theta
            else:
                t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):
                akp, akq = A[k][p], A[k][q]
                A[k][p], A[k][q] = c * akp - s * akq, s * akp + c * akq
            for k in range(3):
                apk, aqk = A[p][k], A[q][k]
                A[p][k], A[q][k] = c * apk - s * aqk, s * apk + c * aqk
            for k in range(3):
                vkp, vkq = V[k][p], V[k][q]
                V[k][p], V[k][q] = c * vkp - s * vkq, s * vkp + c * vkq
    order = sorted(range(3), key=lambda i: (-A[i][i], i))
    return mean, np.array([[V[k][i] for k in range(3)] for i in order])


def split_cell(points: np.ndarray, weights: np.ndarray, profile: tuple[np.ndarray, float, float, float],
               rotation: float) -> np.ndarray:
    """Which of ``points`` (n, 3) lie above the cutting surface of ``profile`` (n,) bool."""
    shape, _, _, ratio = profile
    mean, axes = principal_frame(points, weights)
    sin, cos = detmath.sin_cos(rotation * _DEGREE)
    along = cos * axes[0] + sin * axes[1]
    normal = cos * axes[1] - sin * axes[0]
    d = points - mean
    s = d[:, 0] * along[0] + d[:, 1] * along[1] + d[:, 2] * along[2]
    h = d[:, 0] * normal[0] + d[:, 1] * normal[1] + d[:, 2] * normal[2]
    lo, hi = float(s.min()), float(s.max())
    length = max(hi - lo, tol.ZERO_LENGTH)
    offset = np.interp((s - lo) / length, shape[:, 0], shape[:, 1]) * length
    g = h - offset
    # The surface's height: the volume_ratio quantile of g by asset volume (a sequential sum of a sorted order).
    order = np.argsort(g, kind="stable")
    below = np.cumsum(weights[order])
    i = int(np.searchsorted(below, ratio * below[-1], side="left"))
    i = min(max(i, 0), len(order) - 2)
    level = 0.5 * (g[order[i]] + g[order[i + 1]])
    return g > level


def assign(tet_mesh: TetMesh, held: np.ndarray, box: Box, options: PatternOptions) -> np.ndarray:
    """Cell (t,) of every tet centroid after ``options.cuts`` profile cuts (see the module docstring)."""
    profiles = checked_profiles(options.profiles)
    cdf = np.cumsum([p[1] for p in profiles])
    rng = np.random.default_rng(options.seed)
    x = tet_mesh.tet_centroids
    volumes = np.abs(np.asarray(tet_mesh.tet_volumes, dtype=np.float64))
    # A cell's size and frame by the asset it holds; tets outside the asset count a little, so a cell
    # of cage only still has a frame.
    weights = held + 1e-9 * volumes
    labels = np.zeros(len(x), dtype=np.int64)
    for cut in range(int(options.cuts)):
        sizes = np.bincount(labels, weights=weights)
        splittable = np.bincount(labels) >= 2
        if not splittable.any():
            break
        cell = int(np.lexsort((np.arange(len(sizes)), -np.where(splittable, sizes, -1.0)))[0])
        choice = int(np.searchsorted(cdf, rng.uniform(0.0, cdf[-1]), side="right"))
        profile = profiles[min(choice, len(profiles) - 1)]
        rotation = profile[2] + float(options.rotation_jitter) * rng.uniform(-1.0, 1.0)
        mine = np.flatnonzero(labels == cell)
        above = split_cell(x[mine], weights[mine], profile, rotation)
        labels[mine[above]] = cut + 1
    return labels
