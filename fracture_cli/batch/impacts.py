"""Dataset mode: deterministic impacts on a baked asset and the groups they produce.

For impact ``i`` of an asset, with a generator seeded by the asset's content
hash (so every recipe sees the same hits):

* the point is uniform on the input surface (area-weighted triangle, uniform
  barycentric coordinates), in the asset's units;
* the direction is uniform on the unit sphere;
* the breaking impulse ``m*`` is the smallest magnitude along that direction
  that breaks a bond at that point: the projection is linear in the impulse,
  so ``m* = threshold / (largest bond jump of a unit impulse)``;
* the magnitude is log-uniform in ``[m* / SPREAD, m* * SPREAD]``, so about half
  of the hits break something and half do not.

The groups come from :func:`fracture_cli.runtime.impact.project_impact`, the
same code a game runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry.tetgeom import triangle_areas
from fracture_cli.runtime.format import RuntimeData
from fracture_cli.runtime.impact import project_impact
from fracture_cli.system import detmath

SPREAD = 4.0


@dataclass(frozen=True, eq=False)
class ImpactRows:
    """The impacts of one asset (``n`` impacts, ``p`` fragments).

    Attributes
    ----------
    points : (n, 3) float64
        Hit points on the input surface, asset units.
    impulses : (n, 3) float64
        Impulse vectors (same unit as ``threshold``).
    threshold : float
        Toughness used (the runtime file's default).
    breaking : (n,) float64
        Smallest impulse magnitude along each direction that breaks a bond
        (``inf`` when nothing can break, e.g. a single fragment).
    sites : (n,) int32
        Contact site nearest to each point.
    broken_bonds : (n,) int32
        Bonds broken by each impact.
    groups : (n, p) int32
        Group of every fragment (fragments with one value move together; the
        value is the smallest fragment index of the group).
    """

    points: np.ndarray
    impulses: np.ndarray
    threshold: float
    breaking: np.ndarray
    sites: np.ndarray
    broken_bonds: np.ndarray
    groups: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


def surface_points(vertices: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` points uniform on a triangle mesh.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int
    count : int
    rng : numpy.random.Generator

    Returns
    -------
    (count, 3) float64
    """
    areas = triangle_areas(vertices, faces)
    which = rng.choice(len(faces), size=count, p=areas / areas.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)  # uniform over the triangle, not biased towards a corner
    a, b, c = (vertices[faces[which, i]] for i in range(3))
    return (1 - s)[:, None] * a + (s * (1 - r2))[:, None] * b + (s * r2)[:, None] * c


def _largest_jump(data: RuntimeData, point: np.ndarray, direction: np.ndarray, threshold: float) -> float:
    """Largest bond jump of a unit impulse (the projection is linear in the impulse)."""
    displacement = project_impact(data, point, direction, threshold).displacement
    edges = np.asarray(data.edges, dtype=np.int64)
    if len(edges) == 0:
        return 0.0
    jumps = displacement[edges[:, 0]] - displacement[edges[:, 1]]
    return float(np.sqrt(np.einsum("ij,ij->i", jumps, jumps)).max())


def asset_impacts(data: RuntimeData, vertices: np.ndarray, faces: np.ndarray, count: int, seed: int) -> ImpactRows:
    """Sample and project ``count`` impacts on one asset.

    Parameters
    ----------
    data : RuntimeData
        The asset's runtime file.
    vertices : (n, 3) float64
        Input surface in the asset's units (the space of ``data.sites``).
    faces : (m, 3) int
    count : int
    seed : int
        From the asset's content hash.

    Returns
    -------
    ImpactRows
    """
    rng = np.random.default_rng(seed)
    points = surface_points(vertices, faces, count, rng)
    # No libm on the way (rng.normal and np.exp round by the CPU): the same dataset on every machine.
    directions = detmath.uniform_directions(rng, count)
    spread = detmath.log(SPREAD)
    factors = np.asarray(detmath.exp(rng.uniform(-spread, spread, count)))
    threshold = float(data.default_threshold)
    impulses = np.empty((count, 3))
    breaking = np.empty(count)
    sites = np.empty(count, dtype=np.int32)
    broken = np.empty(count, dtype=np.int32)
    groups = np.empty((count, len(data.fragment_names)), dtype=np.int32)
    for i in range(count):
        jump = _largest_jump(data, points[i], directions[i], threshold)
        breaking[i] = threshold / jump if jump > 0 else math.inf
        # Nothing can break: keep the magnitude on the threshold's scale so the row is still meaningful.
        magnitude = (breaking[i] if jump > 0 else max(threshold, 1.0)) * factors[i]
        impulses[i] = directions[i] * magnitude
        result = project_impact(data, points[i], impulses[i], threshold)
        sites[i], broken[i], groups[i] = result.site, int(result.broken.sum()), result.groups
    return ImpactRows(points=points, impulses=impulses, threshold=threshold, breaking=breaking, sites=sites,
                      broken_bonds=broken, groups=groups)
