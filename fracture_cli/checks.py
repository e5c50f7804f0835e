"""What the bake report says about fragments: invariants (closed, volumes, overlap) and fault shape.

Not a stage: measurements on the fragments stage's output (ALGORITHM.md section 6), used by the
pipeline's report and by the tests.
"""

from __future__ import annotations

import dataclasses
import logging

import manifold3d
import numpy as np
from scipy.spatial import cKDTree

from fracture_cli import parallel, trigeom
from fracture_cli.errors import StageError
from fracture_cli.meshfix.weld_check import MeshCheck, as_written, check_mesh, collapsed, weld_by_position
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Fragments, Regions, SurfaceMesh

log = logging.getLogger(__name__)

# A bake fails when the fragments' volumes differ from the input solid's by more than this fraction
# (they are exact booleans of it: the error is rounding, ~1e-9, plus zero-volume slivers dropped).
VOLUME_TOLERANCE = 1e-5


def written_fragments(fragments: Fragments, pivot: str = "center_of_mass") -> tuple[Fragments, list[MeshCheck]]:
    """Check every fragment on its positions exactly as the GLB stores them, dropping faces rounding collapses.

    Parameters
    ----------
    fragments : Fragments
    pivot : {"center_of_mass", "bbox"}, optional
        The fragment nodes' origins, as the writer will use them.

    Returns
    -------
    fragments : Fragments
        The same fragments, except that faces with two corners at one position
        once written (float32, relative to the fragment's pivot, as
        :func:`~fracture_cli.io.write.write_fragments_glb` does) are left out:
        they have no area, and removing them collapses their short edge as the
        writer's rounding already did (the vertices one written position joins
        then share the float64 position of the first of them, so the fragment
        stays closed in its own coordinates too).
    checks : list of MeshCheck
        One per fragment, welded by exact written position (see
        :func:`~fracture_cli.meshfix.weld_check.check_mesh`).
    """
    from fracture_cli.gameready.stage import fragment_physics

    out, checks = [], []
    for frag, body in zip(fragments.fragments, fragment_physics(fragments, pivot=pivot)):
        world = fragments.normalization.to_world(frag.vertices)
        stored = as_written(world, body.origin)
        _, index = weld_by_position(stored)
        degenerate = collapsed(index[frag.faces])
        if degenerate.any():
            # Corners one written position joins take one float64 position too (the first's): without the
            # faces, the later stages (collision: welded by exact float64 position) would find a hole there.
            first = np.full(int(index.max()) + 1, len(index))
            np.minimum.at(first, index, np.arange(len(index)))
            frag = dataclasses.replace(frag, vertices=frag.vertices[first[index]], faces=frag.faces[~degenerate],
                                       material_ids=frag.material_ids[~degenerate])
        out.append(frag)
        checks.append(check_mesh(stored, frag.faces))
    return dataclasses.replace(fragments, fragments=tuple(out)), checks


def written_summary(checks: list[MeshCheck]) -> dict:
    """The report's verdict on the written fragments (:func:`written_fragments`).

    Returns
    -------
    dict
        ``watertight`` (every fragment: every edge in exactly two faces of
        opposite orientation, no degenerate face, positive volume),
        ``connected`` (every fragment one body: faces connected across
        two-face edges), ``open_edges``, ``pinched_edges`` (more than two
        faces), ``misoriented_edges`` and ``degenerate_faces`` summed over the
        fragments, and ``fragment_bodies_max``.
    """
    return {
        "watertight": bool(all(c.watertight for c in checks)),
        "connected": bool(all(c.bodies == 1 for c in checks)),
        "open_edges": int(sum(c.open_edges for c in checks)),
        "pinched_edges": int(sum(c.pinched_edges for c in checks)),
        "misoriented_edges": int(sum(c.misoriented_edges for c in checks)),
        "degenerate_faces": int(sum(c.degenerate_faces for c in checks)),
        "fragment_bodies_max": int(max((c.bodies for c in checks), default=0)),
    }


def require_sound(checks: list[MeshCheck]) -> None:
    """Raise unless every written fragment is watertight; warn about fragments of several bodies.

    Raises
    ------
    StageError
        Naming the first fragment that is not watertight (``fragment_NNN``, as
        written) and what is wrong with it. Nothing has been written yet, so
        earlier outputs stay as they were.
    """
    from fracture_cli.io.write import fragment_name

    bad = [i for i, c in enumerate(checks) if not c.watertight]
    if bad:
        i = bad[0]
        more = f" (and {len(bad) - 1} more fragments)" if len(bad) > 1 else ""
        raise StageError(f"{fragment_name(i)} would be written as a broken mesh: {', '.join(checks[i].problems())}"
                         f"{more}; the input may have parts touching along an edge or too thin to cut; rerun with "
                         "-v for the repair log", stage="fragments")
    multi = [i for i, c in enumerate(checks) if c.bodies > 1]
    if multi:
        log.warning("fragments: %d fragment(s) consist of several separate bodies (up to %d, e.g. %s)", len(multi),
                    max(checks[i].bodies for i in multi), fragment_name(multi[0]))


def require_volume(report: dict) -> None:
    """Raise when the fragments' volumes differ from the input's by more than :data:`VOLUME_TOLERANCE`."""
    error = report.get("volume_error", 0.0)
    if not error <= VOLUME_TOLERANCE:
        raise StageError(f"the fragments' volumes add up to the input's only within {error:.3g} (tolerance "
                         f"{VOLUME_TOLERANCE:g}): some of the input is missing from the fragments", stage="fragments")


def fragment_invariants(surface: SurfaceMesh, fragments: Fragments, *, max_pairs: int = 2000,
                        written: list[MeshCheck] | None = None, jobs: int | None = None) -> dict:
    """Measure what ALGORITHM.md section 6 promises of the fragments.

    Parameters
    ----------
    surface : SurfaceMesh
        The input the fragments were cut from (normalized coordinates).
    fragments : Fragments
        The fragments.
    max_pairs : int, optional (default 2000)
        At most this many neighbouring fragment pairs are intersected for the
        overlap estimate (closest centroids first).
    jobs : int, optional (default :func:`fracture_cli.parallel.current_jobs`)
        Processes for the pairwise booleans; the result does not depend on it.
    written : list of MeshCheck, optional
        The checks of :func:`written_fragments` (computed when not given).

    Returns
    -------
    dict
        ``fragments`` count; the keys of :func:`written_summary`
        (``watertight``, ``connected``, edge counts: checked on the positions
        as written); ``volume_error`` (|sum of fragment volumes - input volume|
        / input volume, input volume = ``fragments.input_volume``);
        ``max_outer_distance`` (largest distance from a vertex of a non-interior
        face to the input surface, in units of the bounding-box diagonal);
        ``max_overlap`` (largest intersection volume of two neighbouring
        fragments, those sharing a fault (:func:`fragment_neighbours`), relative
        to the smaller one); the fragment volumes relative to the input:
        ``min_fragment_volume`` (= ``fragment_volume_min``),
        ``fragment_volume_median``, ``fragment_volume_max``.

    Notes
    -----
    Overlaps are measured between neighbours only: fragments that share no
    fault are kept apart by the regions between them, so an overlap there
    would also show as a volume error (the volumes sum to more than the
    input's) or a fragment reaching outside the input (``max_outer_distance``).
    """
    if written is None:
        written = written_fragments(fragments)[1]
    interior = [i for i, m in enumerate(fragments.materials) if m.name == INTERIOR_MATERIAL_NAME]
    interior_id = interior[-1] if interior else -1
    volume_list: list[float] = []
    outer_points = []
    for frag in fragments.fragments:
        volume_list.append(trigeom.signed_volume(frag.vertices, frag.faces))
        outer = frag.faces[frag.material_ids != interior_id]
        outer_points.append(frag.vertices[np.unique(outer)])
    volumes = np.array(volume_list)
    reference = fragments.input_volume
    points = np.concatenate(outer_points) if outer_points else np.zeros((0, 3))
    relative = np.sort(volumes) / reference if len(volumes) and reference > 0 else np.zeros(1)
    return {
        "fragments": len(fragments.fragments),
        **written_summary(written),
        "volume_error": float(abs(volumes.sum() - reference) / reference) if reference > 0 else float("nan"),
        "max_outer_distance": float(_max_distance_to_surface(points, surface.vertices, surface.faces)),
        "max_overlap": float(_max_overlap(fragments, volumes, max_pairs, jobs)),
        "min_fragment_volume": float(relative[0]),
        "fragment_volume_min": float(relative[0]),
        "fragment_volume_median": float(np.median(relative)),
        "fragment_volume_max": float(relative[-1]),
    }


# Degenerate-triangle threshold for fault_roughness: a triangle whose area is below
# this fraction of its longest edge squared has a normal dominated by rounding
# (marching-tet corners that land almost on a tet vertex); it is ignored with its edges.
_SLIVER = 1e-8
# Vertices closer than this (unit bbox diagonal) are one vertex for fault_roughness.
_WELD = 1e-9


# Faults measured by :func:`fault_shape`: an edge bending more than this is a visible crease under flat shading.
CREASE_DEGREES = 30.0
# ... and an edge bending less than this is flat (a fanned planar polygon), not counted in the mean dihedral.
_FLAT_DEGREES = 1.0


def _fault_edges(vertices: np.ndarray, faces: np.ndarray, fault: np.ndarray):
    """Dihedral angles (radians) and lengths of the edges inside one fault, and the measured fault area."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    fault = np.asarray(fault, dtype=np.int64)
    on_fault = fault >= 0
    faces, fault = faces[on_fault], fault[on_fault]
    nothing = (np.zeros(0), np.zeros(0), 0.0)
    if len(faces) == 0:
        return nothing
    _, weld = np.unique(np.round(vertices / _WELD), axis=0, return_inverse=True)
    F = weld.reshape(-1)[faces]
    P = vertices[faces]
    normal = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    area2 = np.linalg.norm(normal, axis=1)
    longest2 = np.max([np.sum((P[:, a] - P[:, b]) ** 2, axis=1) for a, b in ((0, 1), (1, 2), (2, 0))], axis=0)
    good = (area2 > 2 * _SLIVER * longest2) & (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])
    F, P, normal, area2, fault = F[good], P[good], normal[good], area2[good], fault[good]
    if len(F) == 0:
        return nothing
    normal = normal / area2[:, None]
    ends = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    lengths = np.concatenate([np.linalg.norm(P[:, b] - P[:, a], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))])
    face = np.tile(np.arange(len(F)), 3)
    key = np.column_stack([fault[face], np.sort(ends, axis=1)])
    order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
    key, face, lengths = key[order], face[order], lengths[order]
    # Edges of one fault with exactly two faces: a run of length 2 in the sorted keys.
    same = np.all(key[1:] == key[:-1], axis=1)
    start = np.r_[True, ~same]
    run_id = np.cumsum(start) - 1
    run_len = np.bincount(run_id)
    first = np.flatnonzero(start[:-1] & same & (run_len[run_id[:-1]] == 2))
    cosine = np.clip(np.einsum("ij,ij->i", normal[face[first]], normal[face[first + 1]]), -1.0, 1.0)
    return np.arccos(cosine), lengths[first], float(area2.sum() / 2.0)


def fault_roughness(vertices: np.ndarray, faces: np.ndarray, fault: np.ndarray) -> tuple[float, float]:
    """Turning of fault surfaces: sum over edges inside one fault of length x dihedral angle, and their area.

    Parameters
    ----------
    vertices : (n, 3) float
        Normalized coordinates (unit bounding-box diagonal).
    faces : (m, 3) int
    fault : (m,) int
        Which fault each face belongs to (e.g. an id of the pair of pieces it
        separates); -1 for faces that are on no fault (the outer surface).

    Returns
    -------
    turning : float
        ``sum(edge_length * angle_between_normals)`` over the edges shared by
        exactly two faces of the same fault (vertices welded by position).
    area : float
        Total area of the fault faces that were measured.

    Notes
    -----
    ``turning / area`` (units 1/diagonal) is the mean absolute bending of the
    faults: 0 for flat faults, about ``2 / R`` for faults curved with radius
    ``R``, and about ``c / h`` for stair-stepped faults that follow tets of edge
    ``h``. It measures curvature at every scale: a fault that curves smoothly
    across a thin part scores as high as a jagged one (see :func:`fault_shape`
    for what the eye sees). It is robust to triangulation: how a flat polygon
    is fanned does not matter (coplanar faces contribute 0), edges on a fault's
    boundary (where it meets the outer surface or other faults at a junction)
    are not counted, since the corner there is the fracture's shape, not its
    roughness, and degenerate faces (area below 1e-8 of their longest edge
    squared), whose normals are rounding noise, are ignored. Use
    :func:`region_fault_roughness` or :func:`fragment_fault_roughness` to label
    the faults.
    """
    angle, length, area = _fault_edges(vertices, faces, fault)
    return float((length * angle).sum()), area


def fault_shape(vertices: np.ndarray, faces: np.ndarray, fault: np.ndarray) -> dict:
    """How jagged faults look: mean dihedral angle, crease density and bending.

    Parameters are those of :func:`fault_roughness`.

    Returns
    -------
    dict
        ``mean_dihedral_degrees``: length-weighted mean dihedral angle of the
        edges inside a fault that bend by more than 1 degree (flat fans of one
        planar polygon do not dilute it); ``crease_density``: length of those
        edges bending by more than :data:`CREASE_DEGREES` (30) per unit fault
        area (1/diagonal), the creases flat shading shows as steps;
        ``bending``: ``turning / area`` of :func:`fault_roughness`;
        ``area``: the measured fault area.

    Notes
    -----
    The first two measure what the eye sees: a stair-stepped fault has few
    edges bending by tens of degrees, a smooth one many edges bending by a
    few. Both are independent of how flat polygons are triangulated, so tet-
    aligned faults and faults cut along a refined mesh compare fairly.
    """
    angle, length, area = _fault_edges(vertices, faces, fault)
    degrees = np.degrees(angle)
    bent = degrees > _FLAT_DEGREES
    crease = degrees > CREASE_DEGREES
    return {
        "mean_dihedral_degrees": float((degrees * length)[bent].sum() / length[bent].sum()) if bent.any() else 0.0,
        "crease_density": float(length[crease].sum() / area) if area > 0 else 0.0,
        "bending": float((angle * length).sum() / area) if area > 0 else 0.0,
        "area": area,
    }


def region_faults(regions: Regions):
    """All region triangles labelled by fault, each fault once.

    A fault is the surface between two pieces' regions: the triangles that
    both regions have (with opposite orientation; the smoothing stage emits
    each fault triangle once per side with shared vertices). The copy owned by
    the lower piece is labelled ``lo * p + hi``; everything else is -1.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    fault : (m,) int64
    """
    owners, tris = [], []
    offset = 0
    all_vertices = []
    for P, (V, F) in enumerate(regions.meshes):
        all_vertices.append(V)
        tris.append(F + offset)
        owners.append(np.full(len(F), P, dtype=np.int64))
        offset += len(V)
    if not tris:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    V = np.concatenate(all_vertices)
    F = np.concatenate(tris)
    owner = np.concatenate(owners)
    _, weld = np.unique(np.round(V / _WELD), axis=0, return_inverse=True)
    W = np.sort(weld.reshape(-1)[F], axis=1)
    _, inverse, counts = np.unique(W, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    # Per triangle (by welded corners): the lowest and highest owner; a fault triangle has two.
    lo = np.full(len(counts), np.iinfo(np.int64).max)
    hi = np.full(len(counts), -1)
    np.minimum.at(lo, inverse, owner)
    np.maximum.at(hi, inverse, owner)
    shared = (counts == 2) & (lo != hi)
    p = len(regions.meshes)
    keep = shared[inverse] & (owner == lo[inverse])
    return V, F, np.where(keep, lo[inverse] * p + hi[inverse], -1)


def region_fault_roughness(regions: Regions) -> float:
    """Mean bending of the faults between piece regions (1/diagonal; 0 = flat), see :func:`fault_roughness`.

    Each fault (see :func:`region_faults`) is measured once; the result is the
    area-weighted mean over all faults, ``sum(turning) / sum(area)``.
    """
    turning, area = fault_roughness(*region_faults(regions))
    return turning / area if area > 0 else 0.0


def fragment_faults(fragments: Fragments):
    """All fragment triangles, the interior ones labelled by fault.

    The interior faces of fragment ``i`` are grouped into faults by the
    fragment on their other side (the fragment owning the nearest interior
    face centroid), labelled ``i * q + j``; each side of a fault is a
    separate label. Outer faces are -1.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    fault : (m,) int64
    """
    interior = [i for i, m in enumerate(fragments.materials) if m.name == INTERIOR_MATERIAL_NAME]
    interior_id = interior[-1] if interior else -1
    centres, owners = [], []
    for j, frag in enumerate(fragments.fragments):
        inner = frag.faces[frag.material_ids == interior_id]
        centres.append(frag.vertices[inner].mean(axis=1))
        owners.append(np.full(len(inner), j, dtype=np.int64))
    empty = np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    if not centres or sum(len(c) for c in centres) == 0:
        return empty
    centres_all, owner_all = np.concatenate(centres), np.concatenate(owners)
    tree = cKDTree(centres_all)
    q = len(fragments.fragments)
    Vs, Fs, labels = [], [], []
    offset = 0
    for j, frag in enumerate(fragments.fragments):
        mask = frag.material_ids == interior_id
        fault = np.full(len(frag.faces), -1, dtype=np.int64)
        if mask.any():
            k = min(len(centres_all), 16)
            _, idx = tree.query(centres[j], k=k)
            other = owner_all[idx.reshape(len(centres[j]), k)]
            hit = other != j
            first = np.argmax(hit, axis=1)
            neighbour = np.where(hit.any(axis=1), other[np.arange(len(other)), first], -1)
            fault[mask] = np.where(neighbour >= 0, j * q + neighbour, -1)
        Vs.append(frag.vertices)
        Fs.append(frag.faces + offset)
        labels.append(fault)
        offset += len(frag.vertices)
    return np.concatenate(Vs), np.concatenate(Fs), np.concatenate(labels)


def fragment_fault_roughness(fragments: Fragments) -> float:
    """Mean bending of the fragments' interior faces (1/diagonal; 0 = flat), see :func:`fault_roughness`.

    Faults as in :func:`fragment_faults`; the result is the area-weighted mean
    over all faults, ``sum(turning) / sum(area)``, counting each side of a fault.
    """
    turning, area = fault_roughness(*fragment_faults(fragments))
    return turning / area if area > 0 else 0.0


def fragment_fault_shape(fragments: Fragments) -> dict:
    """:func:`fault_shape` of the fragments' interior faces (what a player sees of the faults)."""
    return fault_shape(*fragment_faults(fragments))


def _solid(V: np.ndarray, F: np.ndarray):
    _, first, pos = np.unique(V, axis=0, return_index=True, return_inverse=True)
    pos = pos.reshape(-1)
    target = first[pos]
    src = np.flatnonzero(target != np.arange(len(V)))
    mesh = manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(V, dtype=np.float64),
        tri_verts=np.ascontiguousarray(F, dtype=np.uint64),
        merge_from_vert=src.astype(np.uint64),
        merge_to_vert=target[src].astype(np.uint64),
    )
    return manifold3d.Manifold(mesh)


def fragment_neighbours(fragments: Fragments) -> np.ndarray:
    """Pairs ``(i, j)``, ``i < j`` (e, 2) int64, of fragments that share a fault (the fragment graph).

    Measured on the meshes: ``j`` owns the interior face nearest to some
    interior face of ``i`` (or the other way round), as in :func:`fragment_faults`.
    """
    q = len(fragments.fragments)
    fault = fragment_faults(fragments)[2]
    labels = np.unique(fault[fault >= 0])
    pairs = np.sort(np.column_stack([labels // max(q, 1), labels % max(q, 1)]), axis=1)
    return np.unique(pairs, axis=0) if len(pairs) else np.zeros((0, 2), dtype=np.int64)


def _max_overlap(fragments: Fragments, volumes: np.ndarray, max_pairs: int, jobs: int | None) -> float:
    frags = fragments.fragments
    if len(frags) < 2:
        return 0.0
    lo = np.array([f.vertices.min(axis=0) for f in frags])
    hi = np.array([f.vertices.max(axis=0) for f in frags])
    pairs = fragment_neighbours(fragments)
    i, j = pairs[:, 0], pairs[:, 1]
    touching = np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)
    i, j = i[touching], j[touching]
    centres = (lo + hi) / 2
    order = np.argsort(np.linalg.norm(centres[i] - centres[j], axis=1), kind="stable")[:max_pairs]
    todo = list(zip(i[order].tolist(), j[order].tolist()))
    # Each solid built once here (the workers inherit them), then one boolean per pair, independent: on worker
    # processes, results in order (the same max either way).
    used = set(i[order].tolist()) | set(j[order].tolist())
    solids = {k: _solid(frags[k].vertices, frags[k].faces) for k in sorted(used)}
    overlaps = parallel.ordered_map(_pair_overlap, todo, solids, jobs=jobs)
    worst = 0.0
    for (a, b), overlap in zip(todo, overlaps):
        smaller = min(volumes[a], volumes[b])
        if smaller > 0:
            worst = max(worst, overlap / smaller)
    return worst


def _pair_overlap(solids: dict, pair: tuple[int, int]) -> float:
    return float((solids[pair[0]] ^ solids[pair[1]]).volume())


def _max_distance_to_surface(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> float:
    """Largest distance (float64) from ``points`` to the triangles ``F`` over ``V``.

    open3d's ray-casting scene finds the closest triangle (float32); the
    distance to that triangle is then recomputed in float64.
    """
    if len(points) == 0:
        return 0.0
    from fracture_cli._open3d import open3d as _import_open3d
    o3d = _import_open3d()

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    result = scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
    tri = result["primitive_ids"].numpy().astype(np.int64)
    distance = trigeom.point_triangle_distance(points, V[F[tri]])
    # In float32 a point on an edge or corner can pick a neighbour of its triangle (at a fold, 1e-6 away):
    # measure such points against every triangle sharing a vertex with the one found.
    far = np.flatnonzero(distance > 1e-12)
    if len(far):
        from scipy.sparse import csr_matrix

        # All (point, triangle) pairs at once: each far point against the triangles around its triangle's corners.
        incidence = csr_matrix((np.ones(F.size), (F.reshape(-1), np.repeat(np.arange(len(F)), 3))),
                               shape=(len(V), len(F)))
        corners = F[tri[far]].reshape(-1)  # (3 * far,)
        count = np.diff(incidence.indptr)[corners]
        start = np.repeat(incidence.indptr[corners] - np.cumsum(count) + count, count)
        near = incidence.indices[start + np.arange(int(count.sum()))]
        point = np.repeat(np.repeat(far, 3), count)
        pair_distance = trigeom.point_triangle_distance(points[point], V[F[near]])
        best = np.full(len(points), np.inf)
        np.minimum.at(best, point, pair_distance)
        distance[far] = best[far]
    return float(distance.max())
