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
   corners (picked by quadric decimation, snapped back to corners), which lies
   inside the original: simplifying never creates an overlap.
3. **Separation** (:func:`separate_parts`): every pair of parts (any two
   fragments, or one fragment) whose hulls still overlap is clipped by one
   plane through the centroid of the overlap, across its thinnest direction;
   each part keeps its own side. Clipping keeps parts convex and only
   shrinks them, so pairs already separated stay separated.

Everything is deterministic (no randomness, fixed candidate order, stable
tie-breaks): the same meshes give the same bytes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import manifold3d
import numpy as np

from fracture_cli import parallel
from fracture_cli.gameready.mass import mass_properties
from fracture_cli.options import option

log = logging.getLogger(__name__)

STAGE = "collision"

# How the GLB carries the parts (fracture_cli.gameready.export_shapes); "none" computes none.
COLLISION_FORMATS = ("omi", "godot", "unreal", "none")
# PhysX and Chaos cook at most 255 vertices per convex mesh.
ENGINE_MAX_VERTICES = 255
# A coordinate axis is not tried as a cut normal when a principal axis is this close (cosine, ~15 degrees).
_SAME_AXIS = 0.966
# Offsets tried along each candidate normal, as fractions of the part's extent.
_CUT_FRACTIONS = np.arange(1, 8) / 8.0
# Overlaps below this volume (fraction of the smaller part) are contact, not overlap.
_TOUCH = 1e-9
# Offsets tried for a separating plane, as fractions of the overlap's extent along its normal.
_PLANE_FRACTIONS = np.linspace(0.0, 1.0, 9)
# Parts thinner than this (relative to the unit diagonal) or with less volume are dropped.
_MIN_PART_VOLUME = 1e-12


@dataclass(frozen=True)
class CollisionOptions:
    """Options of :func:`collision_shapes`."""

    max_parts: int = option(8, "convex parts per fragment at most", min=1, max=64)
    max_vertices: int = option(64, "vertices per convex part at most (PhysX/Chaos accept 255)", min=8,
                               max=ENGINE_MAX_VERTICES)
    concavity: float = option(0.1, "a part is convex enough when its hull volume is within this fraction of its "
                                   "volume", min=0.0, min_exclusive=True)
    intrusion: float = option(0.0, "also cut a part while its hull reaches into other fragments by more than this "
                                   "fraction of its volume (0: off; costs a boolean per part and neighbour)", min=0.0)
    glb: str = option("omi", "how the GLB carries the parts: OMI_physics_shape/OMI_physics_body extensions (omi), "
                             "'<fragment>_NN-convcolonly' child meshes (godot), 'UCX_<fragment>_NN' child meshes "
                             "(unreal), or no parts at all (none; the runtime file then has none either)",
                      choices=COLLISION_FORMATS)


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


def collision_shapes(meshes, options: CollisionOptions = CollisionOptions()) -> CollisionShapes:
    """Non-overlapping convex parts for every fragment.

    Parameters
    ----------
    meshes : sequence of (vertices (n_i, 3) float, faces (m_i, 3) int)
        Closed fragments, one coordinate system (the pipeline's normalized
        coordinates, unit bounding-box diagonal, keep the tolerances meaningful).
    options : CollisionOptions, optional

    Returns
    -------
    CollisionShapes
        At most ``max_parts`` parts per fragment with at most ``max_vertices``
        corners each; no two parts (of one fragment or of two) overlap by more
        than rounding.
    """
    solids = [_solid(V, F) for V, F in meshes]
    boxes = np.array([s.bounding_box() for s in solids]).reshape(-1, 6)
    corners, materials, owners, volumes, hull_ratio = [], [], [], [], []
    # Fragments decompose independently: on parallel.current_jobs() processes (forked: the solids are inherited).
    decomposed = parallel.ordered_map(_decompose, range(len(solids)), (solids, boxes, options))
    for index, (volume, ratio, leaves) in enumerate(decomposed):
        volumes.append(volume)
        hull_ratio.append(ratio)
        for leaf_corners, leaf_mesh in leaves:
            corners.append(leaf_corners)
            materials.append(leaf_mesh)
            owners.append(index)
    flat = separate_parts(corners, materials)
    result: list[list[np.ndarray]] = [[] for _ in volumes]
    for owner, points in zip(owners, flat):
        if len(points) >= 4:
            result[owner].append(simplify_hull(points, options.max_vertices))
    volumes_arr = np.array(volumes)
    parts_volume = np.array([sum(_hull(p).volume() for p in parts) for parts in result])
    covered = np.array([(solid ^ manifold3d.Manifold.batch_boolean([_hull(p) for p in parts], manifold3d.OpType.Add))
                        .volume() if parts else 0.0 for solid, parts in zip(solids, result)])
    empty = [i for i, parts in enumerate(result) if not parts]
    if empty:
        log.warning("%s: %d fragment(s) lost every collision part to their neighbours: %s", STAGE, len(empty),
                    ", ".join(map(str, empty[:10])))
    return CollisionShapes(parts=tuple(tuple(p) for p in result), volumes=volumes_arr,
                           hull_ratio=np.array(hull_ratio),
                           parts_ratio=parts_volume / np.maximum(volumes_arr, 1e-300),
                           coverage=covered / np.maximum(volumes_arr, 1e-300))


def _decompose(shared: tuple, index: int) -> tuple[float, float, list[tuple[np.ndarray, tuple]]]:
    """Volume, hull ratio and convex leaves ``(corners, (V, F))`` of fragment ``index`` (numpy only: picklable)."""
    solids, boxes, options = shared
    solid = solids[index]
    volume = solid.volume()
    ratio = solid.hull().volume() / volume if volume > 0 else 1.0
    intrusion = _Intrusion(solids, boxes, index) if options.intrusion > 0 else None
    leaves = convex_decomposition(solid, options.max_parts, options.concavity, intrusion, options.intrusion)
    return volume, ratio, [(simplify_hull(hull_corners(leaf), options.max_vertices), _mesh(leaf)) for leaf in leaves]


def _mesh(solid: manifold3d.Manifold) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and faces (m, 3) of a manifold3d solid."""
    mesh = solid.to_mesh64()
    # Copies: manifold3d hands out read-only buffers, and its constructors refuse read-only input.
    return (np.array(mesh.vert_properties, dtype=np.float64)[:, :3].copy(),
            np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3))


def _solid(vertices: np.ndarray, faces: np.ndarray) -> manifold3d.Manifold:
    """A manifold3d solid of a closed mesh whose vertices may be split (welded by position)."""
    V, weld = np.unique(np.asarray(vertices, dtype=np.float64), axis=0, return_inverse=True)
    F = weld.reshape(-1)[np.asarray(faces, dtype=np.int64)]
    return manifold3d.Manifold(manifold3d.Mesh64(vert_properties=V, tri_verts=F.astype(np.uint64)))


def _hull(points: np.ndarray) -> manifold3d.Manifold:
    return manifold3d.Manifold.hull_points(np.ascontiguousarray(points, dtype=np.float64))


def hull_mesh(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The convex hull of points (k, 3) as a triangle mesh: vertices (n, 3), outward faces (m, 3)."""
    return _mesh(_hull(points))


def hull_corners(solid: manifold3d.Manifold) -> np.ndarray:
    """Corners (k, 3) of a solid's convex hull, sorted lexicographically (a canonical order)."""
    V = _mesh(solid.hull())[0]
    return V[np.lexsort(V.T[::-1])]


class _Intrusion:
    """Volume of a hull inside the other fragments (the material a part would push against)."""

    def __init__(self, solids: list, boxes: np.ndarray, own: int):
        self.solids, self.boxes, self.own = solids, boxes, own

    def __call__(self, hull: manifold3d.Manifold) -> float:
        box = np.asarray(hull.bounding_box())
        near = np.flatnonzero(np.all(self.boxes[:, :3] <= box[3:], axis=1)
                              & np.all(box[:3] <= self.boxes[:, 3:], axis=1))
        return float(sum((hull ^ self.solids[k]).volume() for k in near.tolist() if k != self.own))


def convex_decomposition(solid: manifold3d.Manifold, max_parts: int, concavity: float,
                         intrusion=None, max_intrusion: float = 0.05) -> list[manifold3d.Manifold]:
    """Approximate convex decomposition of a closed solid by best-first plane cuts.

    Parameters
    ----------
    solid : manifold3d.Manifold
        One closed body.
    max_parts : int
        At most this many parts.
    concavity : float
        A part is final when its hull volume is at most ``(1 + concavity)``
        times its volume and its hull reaches into the neighbours' material
        by at most ``max_intrusion`` of its volume.
    intrusion : callable, optional
        ``intrusion(hull) -> float``: the volume of a part's hull inside other
        fragments (neighbours are ignored without it).
    max_intrusion : float, optional (default 0.05)
        See ``concavity``.

    Returns
    -------
    list of manifold3d.Manifold
        The (concave) pieces of material, in a deterministic order; each
        collision part is the hull of one (:func:`hull_corners`). One piece,
        the solid itself, when it is nearly convex.
    """
    def excess(part: manifold3d.Manifold) -> float:
        # How far a part is from acceptable, as a volume (> 0: cut it); the worst part is cut first.
        hull, volume = part.hull(), part.volume()
        own = hull.volume() - (1.0 + concavity) * volume
        if intrusion is None:
            return own
        return max(own, intrusion(hull) - max_intrusion * volume)

    leaves = _components(solid)
    waste = [excess(p) for p in leaves]
    while len(leaves) < max_parts:
        worst = int(np.argmax(waste))
        if waste[worst] <= 0:
            break
        pieces = _best_cut(leaves[worst])
        if pieces is None or len(leaves) - 1 + len(pieces) > max_parts:
            waste[worst] = -np.inf  # final: no cut helps, or no room for its pieces
            continue
        leaves[worst:worst + 1] = pieces
        waste[worst:worst + 1] = [excess(p) for p in pieces]
    return leaves


def _components(solid: manifold3d.Manifold) -> list[manifold3d.Manifold]:
    """Connected components of a solid with volume, largest first (ties by centre), deterministic."""
    parts = [p for p in solid.decompose() if p.volume() > _MIN_PART_VOLUME]
    return sorted(parts, key=lambda p: (-round(p.volume(), 15), tuple(np.round(p.bounding_box()[:3], 12))))


def _best_cut(part: manifold3d.Manifold):
    """Split ``part`` by the candidate plane with the smallest total hull volume; None if no cut helps."""
    V, F = _mesh(part)
    edges = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
    props = mass_properties(V, F)
    _, axes = props.principal()
    best, best_cost = None, part.hull().volume() * (1.0 - 1e-9)
    for normal in _cut_normals(axes):
        s = V @ normal
        lo, hi = float(s.min()), float(s.max())
        for offset in lo + (hi - lo) * _CUT_FRACTIONS:
            cost = _halves_hull_volume(V, edges, s, offset)
            if cost < best_cost:
                best, best_cost = (normal, offset), cost
    if best is None:
        return None
    above, below = part.split_by_plane(best[0], best[1])
    pieces = _components(above) + _components(below)
    return pieces if len(pieces) >= 2 else None


def _cut_normals(axes: np.ndarray) -> np.ndarray:
    """Candidate cut normals: the principal axes (columns of ``axes``), then each coordinate axis not within
    :data:`_SAME_AXIS` of one of them (an asset's own axes often follow its structure: legs, seat, walls)."""
    principal = axes.T
    extra = [e for e in np.eye(3) if np.abs(principal @ e).max() < _SAME_AXIS]
    return np.vstack([principal] + extra) if extra else principal


def _halves_hull_volume(V: np.ndarray, edges: np.ndarray, s: np.ndarray, offset: float) -> float:
    """Total hull volume of the two halves of a closed mesh cut at ``s == offset``.

    The corners of a half are the mesh vertices on its side plus the points
    where edges cross the plane, so each half's hull comes from points alone,
    without a boolean.
    """
    d = s - offset
    da, db = d[edges[:, 0]], d[edges[:, 1]]
    crossing = (da > 0) != (db > 0)
    t = da[crossing] / (da[crossing] - db[crossing])
    cut = V[edges[crossing, 0]] + t[:, None] * (V[edges[crossing, 1]] - V[edges[crossing, 0]])
    total = 0.0
    for side in (d > 0, d <= 0):
        points = np.vstack([V[side], cut])
        if len(points) >= 4:
            total += _hull(points).volume()
    return total


def simplify_hull(points: np.ndarray, max_vertices: int) -> np.ndarray:
    """At most ``max_vertices`` corners of a convex part, as a subset of its corners (so it only shrinks).

    Parameters
    ----------
    points : (k, 3) float
        Corners of a convex part (or any points: their hull is the part).
    max_vertices : int
        Cap on the number of corners (>= 4).

    Returns
    -------
    (k', 3) float64
        Hull corners of the simplified part, ``k' <= max_vertices``, sorted
        lexicographically; a subset of the input's hull corners.

    Notes
    -----
    Greedy farthest-point insertion: start from a large tetrahedron of
    corners, then repeatedly add the corner farthest outside the current hull
    (largest distance to a face plane) until the cap is reached or every corner
    is inside. Each step adds the point that removes the largest error of the
    current approximation, so the result covers the part well; ties go to the
    first corner in lexicographic order, so it is deterministic.
    """
    corners = hull_corners(_hull(points))
    if len(corners) <= max_vertices:
        return corners
    chosen = _initial_tetrahedron(corners)
    scale = float(np.linalg.norm(np.ptp(corners, axis=0)))
    while len(chosen) < max_vertices:
        V, F = hull_mesh(corners[chosen])
        normal = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        outside = (corners @ normal.T - np.einsum("ij,ij->i", normal, V[F[:, 0]])[None, :]).max(axis=1)
        outside[chosen] = -np.inf
        farthest = int(np.argmax(outside))
        if outside[farthest] <= 1e-12 * scale:
            break
        chosen.append(farthest)
    return hull_corners(_hull(corners[chosen]))


def _initial_tetrahedron(points: np.ndarray) -> list[int]:
    """Indices of four points spanning a large tetrahedron (the classic quickhull start)."""
    centre = points.mean(axis=0)
    a = int(np.argmax(np.linalg.norm(points - centre, axis=1)))
    b = int(np.argmax(np.linalg.norm(points - points[a], axis=1)))
    ab = points[b] - points[a]
    c = int(np.argmax(np.linalg.norm(np.cross(points - points[a], ab), axis=1)))
    normal = np.cross(ab, points[c] - points[a])
    d = int(np.argmax(np.abs((points - points[a]) @ normal)))
    return list(dict.fromkeys([a, b, c, d]))


def separate_parts(parts: list[np.ndarray], materials=None) -> list[np.ndarray]:
    """Clip every overlapping pair of convex parts by one plane so that they only touch.

    Parameters
    ----------
    parts : list of (k_i, 3) float
        Corners of convex parts.
    materials : list of (vertices (n_i, 3), faces (m_i, 3)), optional
        The closed piece of material each part stands for (a fragment, or a
        piece of one from :func:`convex_decomposition`); default the parts
        themselves.

    Returns
    -------
    list of (k_i', 3) float64
        Hull corners of each clipped part (an empty (0, 3) array if a part was
        clipped away entirely).

    Notes
    -----
    Pairs are clipped in the order ``(i, j)``, ``i < j``; ``a`` keeps the side
    of the plane below it, ``b`` the side above. The plane is the candidate
    that cuts off the least *material* (the pieces the parts stand for, as a
    fraction of each; a part only bulging over its neighbour loses its bulge,
    not its substance):
    normals are the interface's area-weighted normal where the two materials
    share faces, the thinnest direction of the overlap ``O = a ^ b`` (its
    second moment's smallest eigenvector) and the direction between the two
    materials' centroids; offsets span ``O`` along each normal. Material volume
    on the wrong side is exact (:func:`volume_beyond`). Clipping only shrinks parts and keeps
    them convex, so a pair once separated stays separated.
    """
    hulls = [_hull(p) for p in parts]
    corners = [np.asarray(p, dtype=np.float64) for p in parts]
    if materials is None:
        materials = [_mesh(h) for h in hulls]
    interfaces = _interface_normals(materials)
    masses = [mass_properties(V, F) for V, F in materials]
    solids = [_Material(V, F) for V, F in materials]
    n = len(hulls)
    boxes = np.array([h.bounding_box() for h in hulls]) if n else np.zeros((0, 6))
    lo, hi = boxes[:, :3], boxes[:, 3:]
    touching = np.all((lo[:, None, :] <= hi[None, :, :]) & (lo[None, :, :] <= hi[:, None, :]), axis=2)
    for i, j in zip(*np.nonzero(np.triu(touching, 1))):
        a, b = hulls[i], hulls[j]
        if a.is_empty() or b.is_empty() or _separated(corners[i], corners[j], masses[i].center, masses[j].center):
            continue
        overlap = a ^ b
        if overlap.is_empty() or overlap.volume() <= _TOUCH * min(a.volume(), b.volume()):
            continue
        normal, offset = _best_plane(overlap, solids[i], solids[j], masses[i], masses[j],
                                     interfaces.get((int(i), int(j))))
        hulls[i] = a.trim_by_plane(-normal, -offset)
        hulls[j] = b.trim_by_plane(normal, offset)
        corners[i], corners[j] = _mesh(hulls[i])[0], _mesh(hulls[j])[0]
    return [hull_corners(h) if not h.is_empty() and h.volume() > _MIN_PART_VOLUME else np.zeros((0, 3))
            for h in hulls]


class _Material:
    """A closed mesh as triangles (t, 3, 3) with the plane-independent terms of :func:`volume_beyond`."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.triangles = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
        a, b, c = self.triangles[:, 0], self.triangles[:, 1], self.triangles[:, 2]
        self.det = 6.0 * _cone_volume(self.triangles)
        self.twice_area = np.cross(a, b) + np.cross(b, c) + np.cross(c, a)


def volume_beyond(vertices: np.ndarray, faces: np.ndarray, normal: np.ndarray, offsets) -> np.ndarray:
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
    Divergence theorem with the apex ``p`` on the plane: each triangle is
    clipped to the half-space and its part coned to ``p``; the cap that closes
    the cut lies in the plane, so its cones are flat and need not be built.
    The cone of a whole triangle ``(a, b, c)`` is affine in ``p``
    (``det(a - p, b - p, c - p) = det(a, b, c) - p . (a x b + b x c + c x a)``),
    so triangles entirely beyond every plane are summed once; only those
    reaching between the planes are clipped.
    """
    return _volume_beyond(_Material(vertices, faces), normal, offsets)


def _volume_beyond(material: _Material, normal: np.ndarray, offsets) -> np.ndarray:
    normal = np.asarray(normal, dtype=np.float64)
    offsets = np.atleast_1d(np.asarray(offsets, dtype=np.float64))
    T = material.triangles
    d = T @ normal
    full = d.min(axis=1) > offsets.max()
    partial = ~full & (d.max(axis=1) > offsets.min())
    result = (material.det[full].sum() - offsets * (normal @ material.twice_area[full].sum(axis=0))) / 6.0
    # Triangles reaching between the planes, clipped against every plane at once (offset k, triangle t).
    shift = normal[None, :] * offsets[:, None]
    Tp = T[partial][None, :, :, :] - shift[:, None, None, :]
    dp = d[partial][None, :, :] - offsets[:, None, None]
    plane = np.broadcast_to(np.arange(len(offsets))[:, None], dp.shape[:2])
    result += np.bincount(plane.reshape(-1), weights=_clipped_cones(Tp.reshape(-1, 3, 3), dp.reshape(-1, 3)),
                          minlength=len(offsets))
    return result


def _clipped_cones(T: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Signed volumes (t,) of the cones from the origin (on the plane d = 0) to triangles (t, 3, 3) clipped to d > 0.

    ``d`` (t, 3) are the corners' signed distances to the plane.
    """
    above = d > 0
    count = above.sum(axis=1)
    # Rotate so the odd corner (the one above for one corner above, the one below for two) comes first.
    first = np.argmax(np.where((count == 1)[:, None], above, ~above), axis=1)
    order = (first[:, None] + np.arange(3)[None, :]) % 3
    rows = np.arange(len(T))[:, None]
    p, s = T[rows, order], d[rows, order]
    with np.errstate(divide="ignore", invalid="ignore"):
        x01 = p[:, 0] + (s[:, 0] / (s[:, 0] - s[:, 1]))[:, None] * (p[:, 1] - p[:, 0])
        x20 = p[:, 2] + (s[:, 2] / (s[:, 2] - s[:, 0]))[:, None] * (p[:, 0] - p[:, 2])
    volume = np.zeros(len(T))
    volume[count == 3] = _cone_volume(T[count == 3])
    one, two = count == 1, count == 2
    volume[one] = _cone_volume(np.stack([p[one, 0], x01[one], x20[one]], axis=1))
    volume[two] = (_cone_volume(np.stack([p[two, 1], p[two, 2], x20[two]], axis=1))
                   + _cone_volume(np.stack([p[two, 1], x20[two], x01[two]], axis=1)))
    return volume


def _cone_volume(triangles: np.ndarray) -> np.ndarray:
    """Signed volumes (t,) of the tetrahedra from the origin to triangles (t, 3, 3)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    return (a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1]) + a[:, 1] * (b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2])
            + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0])) / 6.0


def _separated(a: np.ndarray, b: np.ndarray, centre_a: np.ndarray, centre_b: np.ndarray) -> bool:
    """Whether the hulls of corner sets a and b are separated along the line between two centres (cheap test)."""
    axis = centre_b - centre_a
    return bool(len(a) == 0 or len(b) == 0 or (a @ axis).max() < (b @ axis).min())


def _interface_normals(materials) -> dict:
    """Unit area-weighted normal (from i to j) of the faces shared by every touching pair ``(i, j)``, i < j."""
    from fracture_cli.gameready.components import coincident_faces

    match = coincident_faces(materials)
    flip = np.where(match.owner < match.other, 1.0, -1.0)
    keys, group = np.unique(np.stack([np.minimum(match.owner, match.other), np.maximum(match.owner, match.other)],
                                     axis=1), axis=0, return_inverse=True)
    weighted = np.zeros((len(keys), 3))
    np.add.at(weighted, group.reshape(-1), (match.area * flip)[:, None] * match.normal)
    length = np.linalg.norm(weighted, axis=1)
    return {(i, j): weighted[k] / length[k] for k, (i, j) in enumerate(keys.tolist()) if length[k] > 0}


def _best_plane(overlap: manifold3d.Manifold, material_a, material_b, mass_a, mass_b, interface_normal):
    """The candidate plane ``(unit normal from a to b, offset)`` that leaves the least material on the wrong side."""
    corners, triangles = _mesh(overlap)
    towards_b = mass_b.center - mass_a.center
    # Largest principal moment of inertia = smallest second moment: the overlap's thinnest direction.
    moments, axes = mass_properties(corners, triangles).principal()
    candidates = [axes[:, int(np.argmax(moments))], towards_b]
    if interface_normal is not None:
        candidates.insert(0, interface_normal)
    volume_a, volume_b = max(mass_a.volume, 1e-300), max(mass_b.volume, 1e-300)
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
    return best


def max_overlap_fraction(parts_a, parts_b=None) -> float:
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
        intersection is exact (manifold3d booleans of the two hulls).
    """
    hulls_a = [_hull(p) for p in parts_a if len(p) >= 4]
    hulls_b = hulls_a if parts_b is None else [_hull(p) for p in parts_b if len(p) >= 4]
    worst = 0.0
    for i, a in enumerate(hulls_a):
        start = i + 1 if parts_b is None else 0
        box_a = np.asarray(a.bounding_box())
        for b in hulls_b[start:]:
            box_b = np.asarray(b.bounding_box())
            if np.any(box_a[:3] > box_b[3:]) or np.any(box_b[:3] > box_a[3:]):
                continue
            smaller = min(a.volume(), b.volume())
            if smaller > 0:
                worst = max(worst, (a ^ b).volume() / smaller)
    return worst
