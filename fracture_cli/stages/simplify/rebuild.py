"""Fragments rebuilt from the simplified complex (see :mod:`.simplify`): outer corners as cut, faults flat."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.rows import unique_rows
from fracture_cli.geometry.uvs import box_uvs
from fracture_cli.types import Fragment, Fragments


@dataclass(frozen=True)
class Classified:
    """The fragments' faces as one complex (see :class:`~fracture_cli.stages.simplify.decimate.SurfaceComplex`;
    made by :mod:`.simplify`)."""

    faces: np.ndarray  # (m, 3) global vertex ids, in the first owner's orientation
    groups: np.ndarray  # (m,) input polygon of an outer face; -1 on a fault; -2 - face for a loose face
    owners: list  # per face: (fragment,) or (fragment A, fragment B)
    owner_pair: np.ndarray  # (m, 2) the same as an array: (A, B), or (A, -1) for a face of one fragment
    fault: np.ndarray  # (m,) bool: a matched fault face (rebuilt flat); else the original corners are kept
    material: np.ndarray  # (m,) material slot
    corner: dict  # (group, global id) -> (fragment, its original vertex): the UV and normal of that corner
    locked: set  # vertices of faces that match nothing
    unmatched: int
    patches: int


def uv_scale(fragments: Fragments, interior: int) -> float:
    """World units per UV unit of the fragments stage's box projection, read back from its fault vertices.

    The projection is linear in the world position (``uv = world / uv_scale``), so one least-squares ratio
    recovers the recipe's ``fragments.uv_scale`` exactly; 1 without fault faces or UVs.
    """
    num = den = 0.0
    for frag in fragments.fragments:
        if frag.uvs is None:
            continue
        used = np.unique(frag.faces[frag.material_ids == interior])
        if len(used) == 0:
            continue
        unit = box_uvs(fragments.normalization.to_world(frag.vertices[used]), frag.normals[used], 1.0)
        num += float(np.sum(unit * frag.uvs[used]))
        den += float(np.sum(np.square(frag.uvs[used])))
    return num / den if den > 0 and num > 0 else 1.0


def fragment_rows(owner_pair: np.ndarray, count: int) -> list[np.ndarray]:
    """For each of ``count`` fragments, the rows (ascending) of ``owner_pair`` (m, 2) that name it.

    The rows :func:`rebuild` keeps of each fragment, found for all fragments in one sort (not one scan of
    every face per fragment).
    """
    rows = np.arange(len(owner_pair), dtype=np.int64)
    other = owner_pair[:, 1] != owner_pair[:, 0]
    key = np.concatenate([owner_pair[:, 0], owner_pair[:, 1][other]])
    row = np.concatenate([rows, rows[other]])
    order = np.lexsort((row, key))
    key, row = key[order], row[order]
    bounds = np.searchsorted(key, np.arange(count + 1))
    return [row[bounds[k]:bounds[k + 1]] for k in range(count)]


def rebuild(fragments: Fragments, k: int, welded: np.ndarray, classified: Classified, ids: np.ndarray,
             faces: np.ndarray, interior: int, uv_scale: float) -> tuple[Fragment, np.ndarray]:
    """Fragment ``k`` from the complex's faces ``ids`` (m',), ``faces`` (m', 3); and its faces' complex ids.

    Faces not on a fault keep the fragment's own corners (positions welded, UVs and normals as they were);
    fault faces get one vertex per (corner, plane): flat normals, box-projected UVs.
    """
    frag = fragments.fragments[k]
    mine = np.any(classified.owner_pair[ids] == k, axis=1)
    ids, faces = ids[mine], faces[mine].copy()
    flip = classified.owner_pair[ids, 0] != k
    faces[flip] = faces[flip][:, ::-1]
    fault = classified.fault[ids]
    kept_faces = faces[~fault]
    groups = classified.groups[ids[~fault]]
    # Every outer corner takes the UV and normal its input polygon has there (from whichever fragment had
    # that corner); corners with one position and the same attributes are one vertex.
    source = [classified.corner[(grp, g)] for grp, row in zip(groups.tolist(), kept_faces.tolist()) for g in row]
    normals = np.array([fragments.fragments[f].normals[v] for f, v in source]).reshape(-1, 3)
    uvs = np.array([fragments.fragments[f].uvs[v] if fragments.fragments[f].uvs is not None else (0.0, 0.0)
                    for f, v in source]).reshape(-1, 2)
    corner = np.column_stack([kept_faces.reshape(-1), normals, uvs])
    _, first, local = unique_rows(corner, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))  # vertices in the order of first use
    first, local = np.sort(first), rank[local.reshape(-1)]
    flat_vertices, flat_normals, flat_faces = _flat(welded, faces[fault])
    all_uvs = None
    if frag.uvs is not None:
        world = fragments.normalization.to_world(flat_vertices)
        all_uvs = np.vstack([uvs[first], box_uvs(world, flat_normals, uv_scale)])
    order = np.concatenate([np.flatnonzero(~fault), np.flatnonzero(fault)])
    rebuilt = Fragment(vertices=np.vstack([welded[kept_faces.reshape(-1)[first]], flat_vertices]),
                       faces=np.vstack([local.reshape(-1, 3), len(first) + flat_faces]),
                       uvs=all_uvs, normals=np.vstack([normals[first], flat_normals]),
                       material_ids=np.concatenate([classified.material[ids[~fault]],
                                                    np.full(int(fault.sum()), interior, dtype=np.int32)]),
                       piece=frag.piece)
    return rebuilt, ids[order]


def _flat(V: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fault faces (m, 3) with one vertex per (corner, plane): positions (n, 3), unit normals (n, 3), faces (m, 3).

    Faces in one plane (normal equal to 1e-6, offset to 1e-9) share vertices, so a flat region is one smooth
    patch with one normal, as the fragments stage splits them.
    """
    if len(faces) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    a, b, c = V[faces[:, 0]], V[faces[:, 1]], V[faces[:, 2]]
    normal = np.cross(b - a, c - a)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    key = np.column_stack([np.round(normal * 1e6), np.round(np.einsum("ij,ij->i", normal, a) * 1e9)])
    _, plane = unique_rows(key.astype(np.int64), return_inverse=True)
    plane = plane.reshape(-1)
    plane_normal = np.zeros((plane.max() + 1, 3))
    np.add.at(plane_normal, plane, normal)
    plane_normal /= np.maximum(np.linalg.norm(plane_normal, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    uniq, corner = unique_rows(np.column_stack([faces.reshape(-1), np.repeat(plane, 3)]), return_inverse=True)
    return V[uniq[:, 0]], plane_normal[uniq[:, 1]], corner.reshape(-1, 3)
