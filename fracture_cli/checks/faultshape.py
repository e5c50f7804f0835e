"""How jagged the faults look: dihedral angles, crease density and roughness of fault surfaces.

Not a stage: measurements on the smooth and fragments stages' output for the bake report, the
benchmarks and the tests (what smoothing is for, so a recipe change shows up in review).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.rows import unique_rows
from fracture_cli.system import detmath
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Fragments, Regions

# Degenerate-triangle threshold for fault_roughness: a triangle whose area is below
# this fraction of its longest edge squared has a normal dominated by rounding
# (marching-tet corners that land almost on a tet vertex); it is ignored with its edges.
_SLIVER = 1e-8


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
    # Vertices closer than SAME_POINT are one vertex.
    _, weld = unique_rows(np.round(vertices / tol.SAME_POINT), return_inverse=True)
    F = weld.reshape(-1)[faces]
    P = vertices[faces]
    normal = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    area2 = np.linalg.norm(normal, axis=1)
    longest2 = np.max([np.sum(np.square(P[:, a] - P[:, b]), axis=1) for a, b in ((0, 1), (1, 2), (2, 0))], axis=0)
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
    return detmath.acos(cosine), lengths[first], float(area2.sum() / 2.0)


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
    _, weld = unique_rows(np.round(V / tol.SAME_POINT), return_inverse=True)
    W = np.sort(weld.reshape(-1)[F], axis=1)
    _, inverse, counts = unique_rows(W, return_inverse=True, return_counts=True)
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
