"""Separation of overlapping convex parts by one plane per pair (the collision parts' last step).

Every pair of parts whose hulls overlap gets one plane through the overlap
(the candidate that cuts off the least material); each part keeps its own side
of every plane of its pairs. A part only shrinks and stays convex, and the two
parts of a pair lie on opposite sides of their plane, so no pair overlaps
afterwards whatever else was clipped. The planes of all pairs are found on the
parts as decomposed, independently of each other: on ``--jobs`` worker
processes, with results that do not depend on scheduling.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import cast

import manifold3d
import numpy as np
import numpy.typing as npt

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.hulls import (
    MIN_PART_VOLUME,
    face_planes,
    hull_corners,
    hull_of,
    max_beyond,
    mesh_of,
    overlap_bound_separated,
    surface_area,
)
from fracture_cli.geometry.mass import MassProperties
from fracture_cli.geometry.mass_kernels import mass_properties
from fracture_cli.geometry.rows import unique_rows
from fracture_cli.geometry.trigeom import cross3
from fracture_cli.stages.collision import kernels
from fracture_cli.stages.fragments.interfaces import coincident_faces
from fracture_cli.system import detmath, parallel

# A closed mesh: vertices (n, 3), faces (m, 3).
_Mesh = tuple[np.ndarray, np.ndarray]
# separate_hulls' bodies: the meshes, the body of each part[, per body the faces that may touch another].
_FullBodies = tuple[Sequence[_Mesh], Sequence[int] | np.ndarray, Sequence[np.ndarray] | None]
_Bodies = tuple[Sequence[_Mesh], Sequence[int] | np.ndarray] | _FullBodies
# hull_faces of a part: face planes (normals (m, 3), offsets (m,)) and surface area.
_HullFaces = tuple[tuple[np.ndarray, np.ndarray], float]

# Offsets tried for a separating plane, as fractions of the overlap's extent along its normal.
_PLANE_FRACTIONS = np.linspace(0.0, 1.0, 9)


class _Material:
    """A closed mesh as triangles (t, 3, 3) with their area vectors (t, 3) (for :func:`volume_beyond`)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        self.triangles = self.vertices[self.faces]
        a, b, c = self.triangles[:, 0], self.triangles[:, 1], self.triangles[:, 2]
        self.area = 0.5 * cross3(b - a, c - a)
        self.centroid = self.triangles.mean(axis=1)
        # A corner's height along a unit normal is within this of its centroid's (radius, grown for rounding).
        arm = self.triangles - self.centroid[:, None, :]
        squared = np.einsum("tcj,tcj->tc", arm, arm)
        radius = np.sqrt(np.maximum(np.maximum(squared[:, 0], squared[:, 1]), squared[:, 2]))
        scale = float(np.abs(self.vertices).max()) if len(self.vertices) else 0.0
        self.radius = radius * (1.0 + tol.TIE) + tol.SAME_POINT * scale


@dataclass(frozen=True)
class _Shared:
    """What every pair's plane search reads (inherited by the forked workers)."""

    hulls: list
    corners: list
    materials: list
    masses: list
    tolerance: float
    planes: list  # face planes (normals (m, 3), offsets (m,)) of each part's hull
    areas: list  # surface area of each part's hull
    body: np.ndarray  # (parts,) the body each part is a piece of
    contacts: dict  # (body P, body Q), P < Q -> (signed area-weighted normals (f, 3) from P to Q, centroids (f, 3))


def volume_beyond(vertices: np.ndarray, faces: np.ndarray, normal: np.ndarray,
                  offsets: np.ndarray | float) -> np.ndarray:
    """Exact volume of a closed mesh on the side ``normal . x > offset`` of parallel planes.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
        A closed, outward-oriented mesh.
    normal : (3,) float
        Unit plane normal.
    offsets : (k,) float
        Plane offsets.

    Returns
    -------
    (k,) float64
        The volume beyond each plane (>= 0 up to rounding).

    Notes
    -----
    Divergence theorem with the field ``h(x) n``, ``h = normal . x - offset``
    (divergence 1): the volume is the sum over triangles of
    ``(n . area vector) * mean of max(h, 0)`` over the triangle; the cap that
    closes the cut has ``h = 0`` and adds nothing. ``h`` is linear on a
    triangle, so the mean of its positive part is closed-form in the corner
    values ``h0 <= h1 <= h2``: their mean when all are positive,
    ``h2^3 / (3 (h2 - h0)(h2 - h1))`` when only ``h2`` is, and the mean plus
    ``(-h0)^3 / (3 (h1 - h0)(h2 - h0))`` when only ``h0`` is not (no
    denominator can vanish there). Every plane and triangle is evaluated at
    once, without clipping a triangle.
    """
    return _volume_beyond(_Material(vertices, faces), normal, offsets)


def _volume_beyond(material: _Material, normal: np.ndarray, offsets: np.ndarray | float) -> np.ndarray:
    normal = np.asarray(normal, dtype=np.float64)
    offsets = np.atleast_1d(np.asarray(offsets, dtype=np.float64))
    # Triangles wholly below every plane add nothing: only the others are measured (found from their centroids'
    # heights; a part's overlap with its neighbour is near its surface, so they are few). The kept triangles are
    # in order and measured as if all were: the same sums, bit for bit. Triangles wholly beyond every plane add
    # a mean that is linear in the offset, summed once. Compiled (.kernels.beyond_terms): numpy's masks and
    # temporaries over an overlap's few dozen triangles were most of the time; the sums stay numpy's.
    full_weight, full_mean, heights, weight = kernels.beyond_terms(
        material.triangles, material.area, material.centroid, material.radius, normal, float(offsets.min()),
        float(offsets.max()))
    result = full_weight @ full_mean - offsets * full_weight.sum()
    # The mean of the positive part per plane and triangle, case by case (compiled as well).
    return result + kernels.positive_means(heights, offsets) @ weight


def separate_parts(parts: list[np.ndarray], materials: Sequence[_Mesh] | None = None,
                   groups: Sequence[Hashable] | None = None, bodies: _Bodies | None = None,
                   masses: list[MassProperties] | None = None,
                   hull_faces: Sequence[_HullFaces] | None = None) -> list[np.ndarray]:
    """Clip every overlapping pair of convex parts by one plane so that they only touch: the corners of
    :func:`separate_hulls` (same parameters), an empty (0, 3) array for a part clipped away."""
    return [separated_corners(h) for h in separate_hulls(parts, materials, groups, bodies, masses, hull_faces)]


def separated_corners(hull: manifold3d.Manifold) -> np.ndarray:
    """Hull corners (k, 3) of a part from :func:`separate_hulls`, sorted; (0, 3) if it was clipped away."""
    return hull_corners(hull) if not hull.is_empty() and hull.volume() > MIN_PART_VOLUME else np.zeros((0, 3))


def separate_hulls(parts: list[np.ndarray], materials: Sequence[_Mesh] | None = None,
                   groups: Sequence[Hashable] | None = None, bodies: _Bodies | None = None,
                   masses: list[MassProperties] | None = None,
                   hull_faces: Sequence[_HullFaces] | None = None) -> list[manifold3d.Manifold]:
    """Clip every overlapping pair of convex parts by one plane so that they only touch.

    Parameters
    ----------
    parts : list of (k_i, 3) float
        Corners of convex parts.
    materials : list of (vertices (n_i, 3), faces (m_i, 3)), optional
        The closed piece of material each part stands for (a fragment, or a
        piece of one from :func:`~fracture_cli.stages.collision.decompose.convex_decomposition`);
        default the parts themselves.
    groups : sequence of hashable, optional
        Parts of one group are known not to overlap (the cells of one
        fragment's partition): their pairs are not looked at. Default: every
        part its own group.
    bodies : (meshes, body of each part[, faces that may touch]), optional
        The closed bodies (fragments) the materials are pieces of, and the
        index of each part's body: shared faces are matched once between
        bodies instead of between pieces. Default: each material its own body.
        A third item, per body a (m_i,) bool mask (or None: all faces),
        restricts the matching to the faces that may touch another body.

    masses : list of MassProperties, optional
        :func:`~fracture_cli.geometry.mass.mass_properties` of each material, if already known (the stage
        computes them on its worker processes); default computed here.
    hull_faces : list of ((normals (m_i, 3), offsets (m_i,)), area), optional
        :func:`hull_faces` of each part, if already known (the stage computes them on its worker processes);
        default computed here.

    Returns
    -------
    list of manifold3d.Manifold
        Each clipped part (its corners by :func:`separated_corners`; the stage
        reads them on its worker processes).

    Notes
    -----
    For each pair ``(i, j)``, ``i < j``, whose hulls overlap, ``i`` keeps the
    side of the plane below it, ``j`` the side above. The plane is the
    candidate that cuts off the least *material* (the pieces the parts stand
    for, as a fraction of each; a part only bulging over its neighbour loses
    its bulge, not its substance): normals are the interface's area-weighted
    normal where the two materials share faces (the faces their bodies share
    that lie in both parts' hulls), the thinnest direction of the
    overlap ``O = a ^ b`` (its second moment's smallest eigenvector) and the
    direction between the two materials' centroids; offsets span ``O`` along
    each normal. Material volume on the wrong side is exact
    (:func:`volume_beyond`). All planes are found on the unclipped parts, so
    pairs are independent (worker processes); they are then applied in the
    order ``(i, j)``, skipping a pair that earlier clips already separated.
    """
    hulls = [hull_of(p) for p in parts]
    corners = [np.asarray(p, dtype=np.float64) for p in parts]
    if materials is None:
        materials = [mesh_of(h) for h in hulls]
    solids = [_Material(V, F) for V, F in materials]
    if masses is None:
        masses = [mass_properties(V, F) for V, F in materials]
    points = np.vstack([m.vertices for m in solids]) if solids else np.zeros((1, 3))

    tolerance = tol.ON_SURFACE * float(np.linalg.norm(np.ptp(points, axis=0)))
    pairs = overlapping_boxes([h.bounding_box() for h in hulls])
    if groups is not None:
        index: dict = {}
        group = np.array([index.setdefault(g, len(index)) for g in groups], dtype=np.int64)
        pairs = pairs[group[pairs[:, 0]] != group[pairs[:, 1]]]
    meshes, body, candidates = cast(_FullBodies, (tuple(bodies) + (None,))[:3]) if bodies is not None else (
        materials, np.arange(len(materials)), None)
    if hull_faces is None:
        hull_faces = [_faces_of(h) for h in hulls]
    shared = _Shared(hulls, corners, solids, masses, tolerance, [f[0] for f in hull_faces],
                     [f[1] for f in hull_faces], np.asarray(body, dtype=np.int64),
                     _contacts(meshes, tolerance, candidates))
    planes = parallel.ordered_map(_pair_plane, [(int(i), int(j)) for i, j in pairs], shared)
    clipped = [False] * len(hulls)
    trims: list[list[tuple[np.ndarray, float]]] = [[] for _ in hulls]  # the half-spaces side . x >= level kept
    stale: set[int] = set()  # clipped parts whose corners are read back from their hull when next needed

    def current(part: int) -> np.ndarray:
        if part in stale:
            stale.discard(part)
            corners[part] = mesh_of(hulls[part])[0]
        return corners[part]

    volumes = [h.volume() for h in hulls]  # before any clip: at least each part's volume as clipped later
    for (i, j), plane in zip(pairs, planes):
        if plane is None:
            continue
        normal, offset, centre = plane
        # A ball of this radius lies in both parts as clipped so far (none if <= 0): when it holds far more than
        # contact, they overlap, and a part reaching beyond its side of the plane inside the ball needs its trim,
        # both known without reading the clipped corners back (a clip is only computed when they are). ON_SURFACE
        # allows for the rounding of a plane distance and of a clip's corners.
        radius = _depth(shared, trims, (i, j), centre) - tol.ON_SURFACE if clipped[i] or clipped[j] else 0.0
        deep = radius > 0 and (4.0 / 3.0 * np.pi * detmath.cube(radius)
                               > 1e3 * tol.SLIVER_VOLUME * min(volumes[i], volumes[j]))
        # Once a part was clipped by an earlier pair, this pair may be apart already: then it keeps its material.
        if (clipped[i] or clipped[j]) and not deep and not _overlapping(hulls[i], hulls[j], current(i), current(j),
                                                                        normal, offset):
            continue
        # A part wholly on its side of the plane stays as it is (and needs no trim).
        for part, side, level in ((i, -normal, -offset), (j, normal, offset)):
            if ((deep and part in stale and float(side @ centre) - radius < level - tol.ON_SURFACE)
                    or (len(current(part)) and (corners[part] @ side).min() < level)):
                hulls[part] = hulls[part].trim_by_plane(side, level)
                trims[part].append((side, level))
                stale.add(part)
                clipped[part] = True
    return hulls


def hull_faces(points: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], float]:
    """Face planes (unit normals (m, 3), offsets (m,)) and surface area of the hull of points (k, 3), as
    :func:`separate_parts` reads them."""
    return _faces_of(hull_of(points))


def _faces_of(hull: manifold3d.Manifold) -> tuple[tuple[np.ndarray, np.ndarray], float]:
    V, F = mesh_of(hull)
    return face_planes(V, F), surface_area(V, F)


def _overlapping(a: manifold3d.Manifold, b: manifold3d.Manifold, corners_a: np.ndarray, corners_b: np.ndarray,
                 normal: np.ndarray, offset: float) -> bool:
    """Whether two convex parts overlap by more than contact (their plane ``normal . x = offset`` first)."""
    if a.is_empty() or b.is_empty() or len(corners_a) == 0 or len(corners_b) == 0:
        return False
    if (corners_a @ normal).max() <= offset <= (corners_b @ normal).min():
        return False
    return (a ^ b).volume() > tol.SLIVER_VOLUME * min(a.volume(), b.volume())


def _depth(shared: _Shared, trims: list, pair: tuple[int, int], centre: np.ndarray) -> float:
    """How deep a point (3,) lies inside both parts of a pair as clipped so far (< 0: outside one): its least
    distance to their hulls' face planes and to the clip planes applied to them (each part is the intersection
    of these half-spaces)."""
    depth = np.inf
    for part in pair:
        normal, offset = shared.planes[part]
        if len(normal) == 0:
            return 0.0  # no face planes (a degenerate hull): nothing known
        depth = min(depth, float((offset - normal @ centre).min()))
        for side, level in trims[part]:
            depth = min(depth, float(side @ centre - level))
    return depth if np.isfinite(depth) else 0.0


def overlapping_boxes(boxes: npt.ArrayLike) -> np.ndarray:
    """Pairs ``(i, j)``, ``i < j`` (e, 2), of axis-aligned boxes (n, 6) (min, max) that touch or overlap."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 6)
    lo, hi = boxes[:, :3], boxes[:, 3:]
    touching = np.all((lo[:, None, :] <= hi[None, :, :]) & (lo[None, :, :] <= hi[:, None, :]), axis=2)
    return np.argwhere(np.triu(touching, 1))


def _pair_plane(shared: _Shared, pair: tuple[int, int]) -> tuple[np.ndarray, float, np.ndarray] | None:
    """The separating plane of pair ``(i, j)`` and its overlap's centre (:func:`_best_plane`), None if their
    hulls do not overlap (numpy only: picklable)."""
    i, j = pair
    a, b = shared.hulls[i], shared.hulls[j]
    mass_a, mass_b = shared.masses[i], shared.masses[j]
    if a.is_empty() or b.is_empty() or _separated(shared.corners[i], shared.corners[j], mass_a.center,
                                                  mass_b.center):
        return None
    smaller = min(a.volume(), b.volume())
    # A face plane of one hull with the other's corners beyond it (up to a slab too thin to matter) separates them.
    slack = 0.5 * tol.SLIVER_VOLUME * smaller / max(shared.areas[i], shared.areas[j], tol.SMALLEST_DIVISOR)
    if (overlap_bound_separated(shared.corners[i], shared.planes[i], shared.corners[j], slack)
            or overlap_bound_separated(shared.corners[j], shared.planes[j], shared.corners[i], slack)):
        return None
    overlap = a ^ b
    # Overlaps below SLIVER_VOLUME of the smaller part are contact, not overlap.
    if overlap.is_empty() or overlap.volume() <= tol.SLIVER_VOLUME * smaller:
        return None
    interface = _interface_normal(shared, i, j)
    return _best_plane(overlap, shared.materials[i], shared.materials[j], mass_a, mass_b, interface)


def _separated(a: np.ndarray, b: np.ndarray, centre_a: np.ndarray, centre_b: np.ndarray) -> bool:
    """Whether the hulls of corner sets a and b are separated along the line between two centres (cheap test)."""
    axis = centre_b - centre_a
    return bool(len(a) == 0 or len(b) == 0 or (a @ axis).max() < (b @ axis).min())


def _contacts(meshes: Sequence[_Mesh], tolerance: float,
              candidates: Sequence[np.ndarray] | None = None) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """The faces every pair of bodies share: ``(P, Q) -> (area-weighted normals from P to Q (f, 3), centroids)``;
    ``candidates``: per body, the (m_i,) bool mask of faces that may touch another (None: all)."""

    match = coincident_faces(meshes, candidates, tolerance=tolerance)
    lo, hi = np.minimum(match.owner, match.other), np.maximum(match.owner, match.other)
    weighted = (match.area * np.where(match.owner < match.other, 1.0, -1.0))[:, None] * match.normal
    order = np.lexsort((hi, lo))
    keys, start = unique_rows(np.stack([lo[order], hi[order]], axis=1), return_index=True)
    stops = np.append(start[1:], len(order))
    return {(int(p), int(q)): (weighted[order[a:b]], match.centroid[order[a:b]])
            for (p, q), a, b in zip(keys, start, stops)}


def _interface_normal(shared: _Shared, i: int, j: int) -> np.ndarray | None:
    """Unit area-weighted normal (from part i to part j) of the faces their bodies share inside both hulls, None
    if there are none (a face on the interface of two pieces lies in both pieces, hence in both hulls)."""
    p, q = int(shared.body[i]), int(shared.body[j])
    if p == q or (min(p, q), max(p, q)) not in shared.contacts:
        return None
    weighted, centroid = shared.contacts[(min(p, q), max(p, q))]
    inside = np.ones(len(centroid), dtype=bool)
    for normal, offset in (shared.planes[i], shared.planes[j]):
        inside &= max_beyond(centroid, normal, offset) <= shared.tolerance
    total = weighted[inside].sum(axis=0) * (1.0 if p < q else -1.0)
    length = float(np.linalg.norm(total))
    return total / length if length > 0 else None


def _best_plane(overlap: manifold3d.Manifold, material_a: _Material, material_b: _Material, mass_a: MassProperties,
                mass_b: MassProperties, interface_normal: np.ndarray | None
                ) -> tuple[np.ndarray, float, np.ndarray] | None:
    """The candidate plane ``(unit normal from a to b, offset)`` that leaves the least material on the wrong side,
    and the overlap's centre of volume (3,)."""
    corners, triangles = mesh_of(overlap)
    towards_b = mass_b.center - mass_a.center
    # Largest principal moment of inertia = smallest second moment: the overlap's thinnest direction.
    overlap_mass = mass_properties(corners, triangles)
    moments, axes = overlap_mass.principal()
    candidates = [axes[:, int(np.argmax(moments))], towards_b]
    if interface_normal is not None:
        candidates.insert(0, interface_normal)
    volume_a, volume_b = max(mass_a.volume, tol.SMALLEST_DIVISOR), max(mass_b.volume, tol.SMALLEST_DIVISOR)
    best, best_cost = None, np.inf
    for normal in candidates:
        length = np.linalg.norm(normal)
        if length == 0:
            continue
        normal = normal / length
        if normal @ towards_b < 0:
            normal = -normal
        s = corners @ normal
        offsets = s.min() + (s.max() - s.min()) * _PLANE_FRACTIONS
        # Fractions of a's material beyond the plane and of b's before it: relative, so a small part
        # is not sacrificed to save a sliver of a big one.
        cost = (_volume_beyond(material_a, normal, offsets) / volume_a
                + _volume_beyond(material_b, -normal, -offsets) / volume_b)
        k = int(np.argmin(cost))
        if cost[k] < best_cost - 1e-15:
            best, best_cost = (normal, float(offsets[k])), float(cost[k])
    # With the overlap's centre: a point that is in both parts unless later clips cut it off (see _depth).
    return None if best is None else (best[0], best[1], overlap_mass.center)
