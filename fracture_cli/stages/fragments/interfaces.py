"""Where meshes touch face to face: interface areas, the faces that lie on another mesh, the fragment graph.

Two fragments are bonded where their fault faces lie on each other (opposite normals, a centroid on the other's
face within :data:`~fracture_cli.geometry.tolerances.ON_SURFACE` of the bounding-box diagonal); the shared area is
the bond's area.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.boxlevels import LevelGrid
from fracture_cli.system import detmath, parallel
from fracture_cli.types import Fragments

# Normals of the two sides of an interface: cosine below this counts as opposite.
_OPPOSITE_COS = -0.5


def interface_areas(meshes: Sequence[tuple[np.ndarray, np.ndarray]], candidates: Sequence[np.ndarray] | None = None,
                    tolerance: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Area of the coincident, opposite-facing faces between every pair of meshes.

    Parameters
    ----------
    meshes : sequence of (vertices (n_i, 3) float, faces (m_i, 3) int)
        Closed meshes in one coordinate system (e.g. fragments or bodies).
    candidates : sequence of (m_i,) bool, optional (default all faces)
        Faces that may lie on an interface (the fault faces).
    tolerance : float, optional
        Distance of a face centroid from the other face's plane that still
        counts as on it (default :data:`~fracture_cli.geometry.tolerances.ON_SURFACE` times the bounding-box
        diagonal of all meshes).

    Returns
    -------
    pairs : (e, 2) int64
        ``(i, j)`` with ``i < j``, sorted.
    areas : (e,) float64
        Interface area of each pair.

    Notes
    -----
    Face ``f`` of mesh ``i`` lies on mesh ``j`` when its centroid is within
    ``tolerance`` of the plane of a face ``g`` of ``j``, inside ``g`` and the
    normals are opposite. This does not need the two sides to be triangulated
    alike (a boolean may split one side's faces differently). The area of a
    pair is the larger of the two one-sided sums, so a side triangulated more
    coarsely than the other (big faces whose centroids fall on a third mesh)
    cannot hide an interface.
    """
    match = coincident_faces(meshes, candidates, tolerance)
    n = len(meshes)
    one_sided = np.zeros((n, n))
    np.add.at(one_sided, (match.owner, match.other), match.area)
    both = np.maximum(one_sided, one_sided.T)
    i, j = np.nonzero(np.triu(both, 1))
    return np.stack([i, j], axis=1).astype(np.int64), both[i, j]


@dataclass(frozen=True)
class FaceMatches:
    """Faces lying on another mesh's surface (see :func:`coincident_faces`).

    Attributes
    ----------
    owner, other : (q,) int64
        Mesh of each matched face and the mesh it lies on.
    area : (q,) float64
    normal : (q, 3) float64
        Unit outward normal (from ``owner`` into ``other``).
    centroid : (q, 3) float64
    face : (q,) int64
        Index of the matched face in its own mesh (``meshes[owner][1]``).
    """

    owner: np.ndarray
    other: np.ndarray
    area: np.ndarray
    normal: np.ndarray
    centroid: np.ndarray
    face: np.ndarray


# Faces whose candidate matches are found together (bounds the memory of coincident_faces).
_QUERY_BLOCK = 65_536


def coincident_faces(meshes: Sequence[tuple[np.ndarray, np.ndarray]], candidates: Sequence[np.ndarray] | None = None,
                     tolerance: float | None = None) -> FaceMatches:
    """Faces of each mesh that lie on the surface of another mesh, facing it.

    Parameters
    ----------
    meshes, candidates, tolerance
        As in :func:`interface_areas`.

    Returns
    -------
    FaceMatches
        One entry per matched face (each face matches at most one other mesh),
        in the order of the meshes and their candidate faces.
    """
    tris, owner, index = [], [], []
    for i, (V, F) in enumerate(meshes):
        F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
        kept = np.arange(len(F)) if candidates is None else np.flatnonzero(np.asarray(candidates[i], dtype=bool))
        tris.append(np.asarray(V, dtype=np.float64)[F[kept]])
        owner.append(np.full(len(kept), i, dtype=np.int64))
        index.append(kept.astype(np.int64))
    T = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
    owner_all = np.concatenate(owner) if owner else np.zeros(0, dtype=np.int64)
    if len(T) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return FaceMatches(empty, empty, np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), empty)
    if tolerance is None:
        tolerance = tol.ON_SURFACE * float(np.linalg.norm(np.ptp(T.reshape(-1, 3), axis=0)))
    normal = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    area = 0.5 * np.linalg.norm(normal, axis=1)
    unit = normal / np.maximum(2.0 * area, tol.SMALLEST_DIVISOR)[:, None]
    centroid = T.mean(axis=1)
    boxes = np.stack([T.min(axis=1), T.max(axis=1)], axis=1)
    grid = LevelGrid(boxes)  # BoxGrid's pairs and order without its 45M entries for large fault triangles
    # Candidates per block of faces: all at once, their pairs and (p, 3) temporaries took the 1M-triangle
    # bench bake's collision stage to an 11.2 GB peak (4.3 GB in blocks).
    # Blocks are independent: on parallel.current_jobs() forked workers (they inherit the grid), in order.
    found = parallel.ordered_map(_block_matches, list(range(0, len(T), _QUERY_BLOCK)),
                                 (grid, T, owner_all, unit, centroid, tolerance))
    q, g = np.concatenate([f[0] for f in found]), np.concatenate([f[1] for f in found])
    q, first = np.unique(q, return_index=True)  # one match per face: it lies on one other mesh
    g = g[first]
    return FaceMatches(owner_all[q], owner_all[g], area[q], unit[q], centroid[q], np.concatenate(index)[q])


def _block_matches(shared: tuple, start: int) -> tuple[np.ndarray, np.ndarray]:
    """Matched ``(face, face it lies on)`` pairs (p,) int64 for the faces ``start : start + _QUERY_BLOCK``."""
    grid, T, owner_all, unit, centroid, tolerance = shared
    block = centroid[start:start + _QUERY_BLOCK]
    points = np.stack([block, block], axis=1)
    # The grid's order (it picks each face's match) only for the pairs kept: most overlapping boxes fail below.
    local, g = grid.pairs(points, pad=tolerance)
    q = local + start
    keep = (owner_all[q] != owner_all[g]) & (np.einsum("ij,ij->i", unit[q], unit[g]) < _OPPOSITE_COS)
    q, g = q[keep], g[keep]
    keep = np.abs(np.einsum("ij,ij->i", unit[g], centroid[q] - T[g, 0])) <= tolerance
    q, g = q[keep], g[keep]
    keep = _inside(centroid[q], T[g], tolerance)
    local, g = grid.in_order(points, tolerance, q[keep] - start, g[keep])
    return local + start, g


def _inside(points: np.ndarray, triangles: np.ndarray, tolerance: float) -> np.ndarray:
    """Whether points (p, 3) project inside triangles (p, 3, 3), with an edge margin of ``tolerance``."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    inside = np.ones(len(points), dtype=bool)
    normal = np.cross(b - a, c - a)
    for u, v in ((a, b), (b, c), (c, a)):
        edge = v - u
        # Signed distance of the point from the edge, inward positive, in the triangle's plane.
        inward = np.cross(normal, edge)
        inward /= np.maximum(np.linalg.norm(inward, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
        inside &= np.einsum("ij,ij->i", points - u, inward) >= -tolerance
    return inside


def fragment_graph(meshes: Sequence[tuple[np.ndarray, np.ndarray]], candidates: Sequence[np.ndarray] | None = None,
                   min_area: float = 0.0, tolerance: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The fragment graph from the meshes: one edge per pair of fragments sharing more than ``min_area``.

    Parameters
    ----------
    meshes : sequence of (vertices (n_i, 3) float, faces (m_i, 3) int)
        The fragments, one coordinate system.
    candidates : sequence of (m_i,) bool, optional
        Their fault (interior-material) faces; default all faces.
    min_area : float, optional (default 0)
        Pairs touching with at most this area (squared mesh units) are not
        bonded: a contact along a curve or at a point holds nothing.
    tolerance : float, optional
        As in :func:`interface_areas`.

    Returns
    -------
    edges : (e, 2) int64
        ``(P, Q)`` with ``P < Q``, sorted, as the runtime file's ``edges``.
    areas : (e,) float64
        Interface area of each edge (squared mesh units).
    """
    pairs, areas = interface_areas(meshes, candidates, tolerance)
    keep = areas > min_area
    return pairs[keep], areas[keep]


# Fragments sharing less fault area than this (fraction of the input's volume to the power 2/3) are not bonded:
# a contact along a curve or at a point, or a sliver of rounding, holds nothing.
_MIN_BOND_AREA = 1e-8


def fragments_graph(fragments: Fragments, contacts: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The bonds of :func:`fragment_graph` between baked fragments, through their fault (interior) faces.

    Parameters
    ----------
    fragments : Fragments
    contacts : bool, optional (default False)
        Also bond fragments of separate bodies that touch face to face (a
        wheel pressed against the chassis, a lid on its pot): their outer
        faces that lie on each other count as an interface too. Bodies
        touching only along an edge or at a point share no area and stay
        unbonded.

    Returns
    -------
    edges : (e, 2) int64
        Pairs ``P < Q`` of fragment indices, sorted.
    areas : (e,) float64
        Shared fault area, normalized units squared.
    """
    interior = fragments.interior_slot
    meshes = [(f.vertices, f.faces) for f in fragments.fragments]
    fault = [np.ones(len(f.faces), dtype=bool) if contacts else f.material_ids == interior
             for f in fragments.fragments]
    return fragment_graph(meshes, fault, min_area=_MIN_BOND_AREA * detmath.square(detmath.cbrt(fragments.input_volume)))
