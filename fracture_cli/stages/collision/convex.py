"""Collision shapes: a few convex parts per fragment that do not overlap each other.

Every engine turns a concave mesh into its convex hull for a moving body, and
the hulls of neighbouring fragments overlap where their shared fault curves,
so resting pieces push each other apart. Here each fragment gets a small set
of convex parts instead:

1. **Decomposition** (:func:`convex_decomposition`): the fragment's hull when
   it is nearly convex, otherwise a best-first binary space partition: the part
   whose hull wastes the most volume is cut by the plane (principal and
   coordinate axes, seven offsets each) that minimises the hull volume of the
   two halves, until every part is nearly convex or ``max_parts`` is reached.
   Parts of one fragment lie in disjoint cells of the partition, so their
   hulls cannot overlap.
2. **Vertex cap** (:func:`simplify_hull`): a hull with more than
   ``max_vertices`` corners is replaced by the hull of a subset of its
   corners (greedy farthest-point insertion), which lies inside the
   original: simplifying never creates an overlap.
3. **Separation** (:func:`separate_parts`): every pair of parts (any two
   fragments, or one fragment) whose hulls overlap gets one plane through
   the overlap that cuts off the least material; each part keeps its own
   side of all its planes. Clipping keeps parts convex and only shrinks
   them, so every pair ends up separated.

Fragments decompose, pairs find their planes and fragments finish their
parts (clip, cap, measure) on ``--jobs`` worker processes
(:func:`fracture_cli.system.parallel.ordered_map`). Everything is deterministic (no
randomness, fixed candidate order, stable tie-breaks, results independent of
the workers): the same meshes give the same bytes.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import manifold3d
import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.hulls import (
    canonical,
    face_planes,
    hull_corners,
    hull_mesh,
    hull_of,
    mesh_of,
    overlap_bound_separated,
    simplify_hull,
    solid_of,
    surface_area,
)
from fracture_cli.geometry.mass_kernels import mass_properties
from fracture_cli.io.physics import COLLISION_FORMATS
from fracture_cli.stages.collision.decompose import convex_decomposition, decomposition_hulls
from fracture_cli.stages.collision.options import STAGE, CollisionOptions
from fracture_cli.stages.collision.separate import (
    hull_faces,
    overlapping_boxes,
    separate_hulls,
    separate_parts,
    separated_corners,
    volume_beyond,
)
from fracture_cli.system import parallel

log = logging.getLogger(__name__)

# Overlap checks: a pair separated by a face plane of one part up to a slab this thin (fraction of the smaller
# volume, over the larger area) overlaps by less than this fraction of the smaller part; it counts as 0.
_NEGLIGIBLE = 1e-12
# Names the tests and the bench import from here.
__all__ = ["COLLISION_FORMATS", "CollisionOptions", "CollisionShapes", "collision_shapes", "convex_decomposition",
           "hull_corners", "hull_mesh", "max_overlap_fraction", "separate_parts", "simplify_hull", "volume_beyond"]
_solid, _hull, _mesh = solid_of, hull_of, mesh_of


@dataclass(frozen=True)
class CollisionShapes:
    """Convex parts of every fragment.

    Attributes
    ----------
    parts : tuple of tuple of (k, 3) float64
        Per fragment, the corners of each convex part (the part is their
        convex hull; every point is a corner), same coordinates as the input
        meshes. ``k <= max_vertices``.
    volumes : (p,) float64
        Volume of each fragment.
    hull_ratio : (p,) float64
        Hull volume over volume of each fragment before decomposition.
    parts_ratio : (p,) float64
        Total volume of the final parts over the fragment's volume (< 1 where
        clipping removed overlaps, > 1 where parts still bulge).
    coverage : (p,) float64
        Fraction of each fragment's volume inside its parts (1 = the parts
        hold all of its material).
    """

    parts: tuple[tuple[np.ndarray, ...], ...]
    volumes: np.ndarray
    hull_ratio: np.ndarray
    parts_ratio: np.ndarray
    coverage: np.ndarray
    part_faces: tuple | None = None  # per part in order, (face planes, surface area, volume) of its hull


def collision_shapes(meshes: Sequence[tuple[np.ndarray, np.ndarray]], options: CollisionOptions = CollisionOptions(),
                     faults: Sequence[np.ndarray] | None = None) -> CollisionShapes:
    """Non-overlapping convex parts for every fragment.

    Parameters
    ----------
    meshes : sequence of (vertices (n_i, 3) float, faces (m_i, 3) int)
        Closed fragments, one coordinate system (the pipeline's normalized
        coordinates, unit bounding-box diagonal, keep the tolerances meaningful).
    options : CollisionOptions, optional
    faults : sequence of (m_i,) bool, optional
        The faces of each fragment that may touch another fragment (its fault,
        interior-material faces); default all faces. Only these are matched
        between fragments for the separating planes' interface normals (the
        outer surface of a 1M-triangle input is most of its faces and touches
        no other fragment).

    Returns
    -------
    CollisionShapes
        At most ``max_parts`` parts per fragment with at most ``max_vertices``
        corners each; no two parts (of one fragment or of two) overlap by more
        than rounding.
    """
    solids = [solid_of(V, F) for V, F in meshes]
    boxes = np.array([s.bounding_box() for s in solids]).reshape(-1, 6)
    corners, materials, masses, owners, cells, volumes, hull_ratio, faces = [], [], [], [], [], [], [], []
    # Fragments decompose independently: on parallel.current_jobs() processes (forked: the solids are inherited).
    decomposed = parallel.ordered_map(_decompose, range(len(solids)), (solids, boxes, options))
    for index, (volume, ratio, leaves) in enumerate(decomposed):
        volumes.append(volume)
        hull_ratio.append(ratio)
        for leaf_corners, leaf_mesh, leaf_mass, cell, leaf_faces in leaves:
            corners.append(leaf_corners)
            faces.append(leaf_faces)
            materials.append(leaf_mesh)
            masses.append(leaf_mass)
            owners.append(index)
            cells.append((index, cell))
    # Parts in different cells of one fragment's partition cannot overlap: their pairs need no look.
    # The clipped hulls go to the workers of _finish as they are (forked: inherited), their corners read there.
    flat = separate_hulls(corners, materials, _groups(cells), (meshes, owners, faults), masses, faces)
    owned: list[list[manifold3d.Manifold]] = [[] for _ in volumes]
    for owner, hull in zip(owners, flat):
        owned[owner].append(hull)
    finished = parallel.ordered_map(_finish, range(len(solids)), (solids, owned, options.max_vertices))
    result = [parts for parts, _, _, _ in finished]
    volumes_arr = np.array(volumes)
    parts_volume = np.array([v for _, v, _, _ in finished])
    covered = np.array([c for _, _, c, _ in finished])
    empty = [i for i, parts in enumerate(result) if not parts]
    if empty:
        log.warning("%s: %d fragment(s) lost every collision part to their neighbours: %s", STAGE, len(empty),
                    ", ".join(map(str, empty[:10])))
    return CollisionShapes(parts=tuple(tuple(p) for p in result), volumes=volumes_arr,
                           hull_ratio=np.array(hull_ratio),
                           parts_ratio=parts_volume / np.maximum(volumes_arr, tol.SMALLEST_DIVISOR),
                           coverage=covered / np.maximum(volumes_arr, tol.SMALLEST_DIVISOR),
                           part_faces=tuple(f for _, _, _, faces in finished for f in faces))


def _decompose(shared: tuple, index: int) -> tuple[float, float, list[tuple]]:
    """Volume, hull ratio and convex leaves ``(corners, (V, F), mass properties, cell, hull faces)`` of fragment
    ``index`` (numpy only: picklable; hull faces as :func:`~fracture_cli.stages.collision.separate.hull_faces`)."""
    solids, boxes, options = shared
    solid = solids[index]
    volume = solid.volume()
    ratio = solid.hull().volume() / volume if volume > 0 else 1.0
    intrusion = _Intrusion(solids, boxes, index) if options.intrusion > 0 else None
    leaves, cells, hulls = decomposition_hulls(solid, options.max_parts, options.concavity, intrusion,
                                               options.intrusion)
    out = []
    for leaf, cell, hull in zip(leaves, cells, hulls):
        V, F = mesh_of(leaf)
        leaf_corners = simplify_hull(canonical(mesh_of(hull)[0]), options.max_vertices)
        # The separation's mass properties and hull planes of the leaf, here on a worker rather than serially there.
        out.append((leaf_corners, (V, F), mass_properties(V, F), cell, hull_faces(leaf_corners)))
    return volume, ratio, out


def _groups(cells: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Groups for :func:`separate_parts` from the parts' ``(fragment, cell)``: one group per fragment, except
    that parts sharing a cell (the interlocking components of one side of a cut) each get a group of their own."""
    count: dict[tuple[int, int], int] = {}
    for key in cells:
        count[key] = count.get(key, 0) + 1
    return [(key[0], -1 - k) if count[key] > 1 else (key[0], 0) for k, key in enumerate(cells)]


def _finish(shared: tuple, index: int) -> tuple[list[np.ndarray], float, float, list[tuple]]:
    """Fragment ``index``'s separated parts under the vertex cap, their total volume, the fragment's volume
    inside them and each part's ``(face planes, surface area, volume)`` for :func:`max_overlap_fraction`
    (numpy only: picklable)."""
    solids, owned, max_vertices = shared
    corners = [separated_corners(hull) for hull in owned[index]]
    parts = [simplify_hull(points, max_vertices) for points in corners if len(points) >= 4]
    if not parts:
        return parts, 0.0, 0.0, []
    hulls = [hull_of(p) for p in parts]
    meshes = [mesh_of(h) for h in hulls]
    faces = [(face_planes(V, F), surface_area(V, F), h.volume()) for h, (V, F) in zip(hulls, meshes)]
    union = manifold3d.Manifold.batch_boolean(hulls, manifold3d.OpType.Add)
    return parts, float(sum(h.volume() for h in hulls)), float((solids[index] ^ union).volume()), faces


class _Intrusion:
    """Volume of a hull inside the other fragments (the material a part would push against)."""

    def __init__(self, solids: list, boxes: np.ndarray, own: int):
        self.solids, self.boxes, self.own = solids, boxes, own

    def __call__(self, hull: manifold3d.Manifold) -> float:
        box = np.asarray(hull.bounding_box())
        near = np.flatnonzero(np.all(self.boxes[:, :3] <= box[3:], axis=1)
                              & np.all(box[:3] <= self.boxes[:, 3:], axis=1))
        return float(sum((hull ^ self.solids[k]).volume() for k in near.tolist() if k != self.own))


def max_overlap_fraction(parts_a: Sequence[np.ndarray], parts_b: Sequence[np.ndarray] | None = None,
                         faces: Sequence[tuple[tuple[np.ndarray, np.ndarray], float, float]] | None = None) -> float:
    """Largest overlap volume between two convex parts, over the smaller part's volume.

    Parameters
    ----------
    parts_a : sequence of (k_i, 3) float
        Corners of convex parts.
    parts_b : sequence of (k_j, 3) float, optional
        A second set; pairs are then one part from each. Without it, every pair
        of distinct parts of ``parts_a``.

    Returns
    -------
    float
        ``max vol(a ^ b) / min(vol(a), vol(b))``, 0 when nothing overlaps. The
        intersection is exact (manifold3d booleans of the two hulls) except
        for pairs that a face plane of one part separates up to a slab so thin
        that their overlap is below 1e-12 of the smaller part: they count as 0.
        Pairs are checked on ``--jobs`` worker processes.

    Other Parameters
    ----------------
    faces : sequence of (face planes, surface area, volume), optional
        Of each part of ``parts_a`` (without ``parts_b``), if already known
        (:class:`CollisionShapes` ``part_faces``); default computed here.
    """
    keep = [len(p) >= 4 for p in parts_a]
    a = [p for p, k in zip(parts_a, keep) if k]
    b = a if parts_b is None else [p for p in parts_b if len(p) >= 4]
    every = a if parts_b is None else a + b
    hulls = [hull_of(p) for p in every]
    boxes = np.array([h.bounding_box() for h in hulls]).reshape(-1, 6)
    pairs = overlapping_boxes(boxes)
    if parts_b is not None:
        pairs = pairs[(pairs[:, 0] < len(a)) & (pairs[:, 1] >= len(a))]
    if len(pairs) == 0:
        return 0.0
    if faces is None or parts_b is not None:
        meshes = [mesh_of(h) for h in hulls]
        faces = [(face_planes(V, F), surface_area(V, F), h.volume()) for h, (V, F) in zip(hulls, meshes)]
    else:
        faces = [f for f, k in zip(faces, keep) if k]
    shared = (every, hulls, [f[0] for f in faces], [f[1] for f in faces], [f[2] for f in faces])
    return max(parallel.ordered_map(_overlap_fraction, [(int(i), int(j)) for i, j in pairs], shared))


def _overlap_fraction(shared: tuple, pair: tuple[int, int]) -> float:
    """``vol(a ^ b) / min(vol(a), vol(b))`` of one pair (see :func:`max_overlap_fraction`)."""
    corners, hulls, planes, areas, volumes = shared
    i, j = pair
    smaller = min(volumes[i], volumes[j])
    if smaller <= 0:
        return 0.0
    # A cross-section of a convex part is at most half its surface.
    slack = 0.5 * _NEGLIGIBLE * smaller / max(areas[i], areas[j], tol.SMALLEST_DIVISOR)
    if (overlap_bound_separated(corners[i], planes[i], corners[j], slack)
            or overlap_bound_separated(corners[j], planes[j], corners[i], slack)):
        return 0.0
    return (hulls[i] ^ hulls[j]).volume() / smaller
