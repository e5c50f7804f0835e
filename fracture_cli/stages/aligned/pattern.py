"""Fracture patterns: Voronoi cells of sites in a unit ball, finer near its centre (seed 001, section 4).

A pattern is its sites (site 0 at the centre, where the hit will be) and, per cell, the cells it
shares a face with; the runtime builds each cell's half-spaces from the placed sites
(docs/FORMAT.md sections 13.3-13.4), so it never computes a Voronoi diagram. Cells of sites on the
pattern's outside are unbounded: the pattern covers all of space.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from fracture_cli.runtime.aligned_clip import Polyhedron, cap_loop, clip_polyhedron
from fracture_cli.system import detmath

# Candidates tried for one site before the spacing is relaxed by _RELAX (deterministic either way).
_TRIES = 200
_RELAX = 0.8
_MIN_RADIUS = 0.02  # u is drawn from [_MIN_RADIUS, 1): no site on top of the centre


@dataclass(frozen=True)
class Pattern:
    """One fracture pattern.

    Attributes
    ----------
    sites : (m, 3) float32
        Voronoi sites in the unit ball; site 0 is the origin.
    neighbors : tuple of (k_i,) int32
        Per cell, the cells whose bisector plane bounds it (ascending).
    boundary : tuple of (b_i,) int32
        Per cell, the boundary planes that bound it (ascending; empty without a boundary).
    """

    sites: np.ndarray
    neighbors: tuple[np.ndarray, ...]
    boundary: tuple[np.ndarray, ...] = ()

    def planes(self) -> np.ndarray:
        """Per neighbour entry, the bisector plane in pattern coordinates: unit normal, offset (n, 4) float64."""
        rows = []
        sites = self.sites.astype(np.float64)
        for i, nbs in enumerate(self.neighbors):
            for j in nbs:
                n = sites[j] - sites[i]
                n = n / np.sqrt(n @ n)
                rows.append([*n, float(n @ ((sites[i] + sites[j]) * 0.5))])
        return np.array(rows, dtype=np.float64).reshape(-1, 4)


def graded_sites(count: int, grading: float, spacing: float, seed: int) -> np.ndarray:
    """``count`` sites (float32-exact) in the unit ball: the origin, then ``r = u**grading`` along uniform directions.

    Parameters
    ----------
    count : int
        Sites, the centre included.
    grading : float
        Exponent of the radius (see :class:`~fracture_cli.stages.aligned.options.AlignedOptions`).
    spacing : float
        A candidate closer than ``spacing * r`` to an accepted site is drawn again (after ``_TRIES``
        refusals in a row the spacing shrinks by ``_RELAX``).
    seed : int
        Seed of numpy's PCG64 generator: the same sites on every machine.

    Returns
    -------
    (count, 3) float32
    """
    rng = np.random.default_rng(seed)
    sites = [np.zeros(3)]
    refused, factor = 0, spacing
    while len(sites) < count:
        direction = detmath.uniform_directions(rng, 1)[0]
        u = _MIN_RADIUS + (1.0 - _MIN_RADIUS) * float(rng.random())
        radius = float(detmath.power(u, grading))
        candidate = (direction * radius).astype(np.float32).astype(np.float64)
        delta = np.array(sites) - candidate
        gaps = np.sqrt((delta * delta).sum(axis=1))
        if gaps.min() >= factor * radius and gaps.min() > 0:
            sites.append(candidate)
            refused, factor = 0, spacing
        else:
            refused += 1
            if refused >= _TRIES:
                refused, factor = 0, factor * _RELAX
    return np.array(sites, dtype=np.float32)


def voronoi_neighbors(sites: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per site, the sites whose Voronoi cells share a face with its cell (Delaunay edges; all pairs below 5 sites)."""
    count = len(sites)
    pairs: set[tuple[int, int]] = set()
    if count >= 5:
        # on first use: scipy only for baking a pattern
        from scipy.spatial import Delaunay

        for simplex in Delaunay(sites.astype(np.float64)).simplices:
            pairs.update(combinations(sorted(int(v) for v in simplex), 2))
    else:
        pairs.update(combinations(range(count), 2))
    lists: list[list[int]] = [[] for _ in range(count)]
    for i, j in sorted(pairs):
        lists[i].append(j)
        lists[j].append(i)
    return tuple(np.array(sorted(nb), dtype=np.int32) for nb in lists)


def fracture_pattern(count: int, grading: float, spacing: float, seed: int,
                     boundary: np.ndarray | None = None) -> Pattern:
    """A graded Voronoi pattern: :func:`graded_sites` and their :func:`voronoi_neighbors`, cut to ``boundary``.

    With boundary planes (b, 4), each cell keeps only the neighbours and boundary planes that bound its
    part inside the boundary (:func:`bounded_cells`): the same cells, fewer planes to clip with at runtime.
    """
    sites = graded_sites(count, grading, spacing, seed)
    neighbors = voronoi_neighbors(sites)
    if boundary is None or len(boundary) == 0:
        return Pattern(sites=sites, neighbors=neighbors, boundary=tuple(np.zeros(0, np.int32) for _ in sites))
    kept, walls = bounded_cells(sites, neighbors, boundary)
    return Pattern(sites=sites, neighbors=kept, boundary=walls)


def _box(half: float) -> Polyhedron:
    """An axis-aligned cube ``[-half, half]^3`` as a polyhedron (faces counter-clockwise seen from outside)."""
    vertices = [((-half, half)[i & 1], (-half, half)[(i >> 1) & 1], (-half, half)[(i >> 2) & 1]) for i in range(8)]
    faces = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = [0.0, 0.0, 0.0]
            n[axis] = sign
            corners = [i for i in range(8) if ((i >> axis) & 1) == (1 if sign > 0 else 0)]
            faces.append((cap_loop(vertices, corners, (n[0], n[1], n[2])), (n[0], n[1], n[2], half), False))
    return vertices, faces


def bounded_cells(sites: np.ndarray, neighbors: tuple[np.ndarray, ...],
                  boundary: np.ndarray) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """Per cell, the neighbours and boundary planes that are faces of (Voronoi cell) ∩ (boundary region).

    Each cell is clipped, in pattern coordinates, by its bisectors and the boundary planes; a plane is kept
    when the clipped cell has a face on it. A neighbour pair is kept for both cells when either has the face,
    so two cells never disagree about the plane between them.
    """
    points = sites.astype(np.float64).tolist()
    walls = [tuple(float(x) for x in plane) for plane in np.asarray(boundary, dtype=np.float64)]
    faces_on: list[set] = []
    for i, nbs in enumerate(neighbors):
        planes = []
        for j in nbs.tolist():
            n = np.subtract(points[j], points[i])
            n = n / np.sqrt(n @ n)
            planes.append((("site", j), (*n, float(n @ (np.add(points[i], points[j]) * 0.5)))))
        planes += [(("wall", b), wall) for b, wall in enumerate(walls)]
        poly: Polyhedron | None = _box(4.0)
        for _, plane in planes:
            poly = clip_polyhedron(poly, plane, 1e-12)  # type: ignore[arg-type]
            if poly is None:
                break
        found = set()
        if poly is not None:
            labels = {plane: label for label, plane in planes}
            found = {labels[plane] for _, plane, new in poly[1] if new and plane in labels}
        faces_on.append(found)
    kept = [sorted(j for j in nbs.tolist() if ("site", j) in faces_on[i] or ("site", i) in faces_on[j])
            for i, nbs in enumerate(neighbors)]
    return (tuple(np.array(k, dtype=np.int32) for k in kept),
            tuple(np.array(sorted(b for kind, b in f if kind == "wall"), dtype=np.int32) for f in faces_on))


def dodecahedron_planes() -> np.ndarray:
    """The 12 face planes (unit normal, offset 1) of the regular dodecahedron around the unit ball (12, 4) float64.

    The patterns' boundary: cells are cut to it, and what lies beyond it stays one piece (the rest of the
    object), so a hit breaks the region around it and not the whole asset.
    """
    phi = (1.0 + np.sqrt(5.0)) / 2.0
    normals = []
    for a in (1.0, -1.0):
        for b in (1.0, -1.0):
            normals += [(0.0, a, b * phi), (a, b * phi, 0.0), (a * phi, 0.0, b)]
    n = np.array(normals, dtype=np.float64)
    n /= np.sqrt((n * n).sum(axis=1))[:, None]
    return np.column_stack([n, np.ones(len(n))])
