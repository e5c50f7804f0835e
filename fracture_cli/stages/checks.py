"""Invariants of a set of fragments, for the bake report (ALGORITHM.md section 6)."""

from __future__ import annotations

import logging

import manifold3d
import numpy as np

from fracture_cli.types import INTERIOR_MATERIAL_NAME, Fragments, SurfaceMesh

log = logging.getLogger(__name__)


def fragment_invariants(surface: SurfaceMesh, fragments: Fragments, *, max_pairs: int = 2000) -> dict:
    """Measure what ALGORITHM.md section 6 promises of the fragments.

    Parameters
    ----------
    surface : SurfaceMesh
        The input the fragments were cut from (normalized coordinates).
    fragments : Fragments
        The fragments.
    max_pairs : int, optional (default 2000)
        At most this many bounding-box-overlapping fragment pairs are
        intersected for the overlap estimate (closest centroids first).

    Returns
    -------
    dict
        ``fragments`` count; ``watertight`` (every fragment, welded by
        position, has every edge in exactly two faces of opposite orientation,
        or in an even number of faces with balanced orientation where a
        fragment touches itself); ``pinched_edges`` (edges of the latter kind);
        ``volume_error`` (|sum of fragment volumes - input volume| / input
        volume, input volume = ``fragments.input_volume``);
        ``max_outer_distance`` (largest distance from a vertex of a non-interior
        face to the input surface, in units of the bounding-box diagonal);
        ``max_overlap`` (largest intersection volume of two fragments relative
        to the smaller one); ``min_fragment_volume`` relative to the input.
    """
    interior = [i for i, m in enumerate(fragments.materials) if m.name == INTERIOR_MATERIAL_NAME]
    interior_id = interior[-1] if interior else -1
    watertight = True
    pinched = 0
    volumes = []
    outer_points = []
    solids = []
    for frag in fragments.fragments:
        ok, pinch = _closed_by_position(frag.vertices, frag.faces)
        watertight &= ok
        pinched += pinch
        volumes.append(_volume(frag.vertices, frag.faces))
        outer = frag.faces[frag.material_ids != interior_id]
        outer_points.append(frag.vertices[np.unique(outer)])
        solids.append(_solid(frag.vertices, frag.faces))
    volumes = np.array(volumes)
    reference = fragments.input_volume
    points = np.concatenate(outer_points) if outer_points else np.zeros((0, 3))
    return {
        "fragments": len(fragments.fragments),
        "watertight": bool(watertight),
        "pinched_edges": int(pinched),
        "volume_error": float(abs(volumes.sum() - reference) / reference) if reference > 0 else float("nan"),
        "max_outer_distance": float(_max_distance_to_surface(points, surface.vertices, surface.faces)),
        "max_overlap": float(_max_overlap(solids, volumes, max_pairs)),
        "min_fragment_volume": float(volumes.min() / reference) if len(volumes) and reference > 0 else 0.0,
    }


def fault_roughness(vertices: np.ndarray, faces: np.ndarray, mask: np.ndarray) -> float:
    """Mean turning of a surface patch: sum over its inner edges of length x dihedral angle, per unit area.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
    mask : (m,) bool
        The faces of the patch (e.g. a fragment's interior faces).

    Returns
    -------
    float
        ``sum(edge_length * angle_between_normals) / patch_area`` over edges
        shared by two patch faces (vertices welded by position); 1/length
        units, 0 for a flat patch, independent of how flat parts are
        triangulated.
    """
    _, pos = np.unique(vertices, axis=0, return_inverse=True)
    F = pos.reshape(-1)[faces[mask]]
    P = vertices[faces[mask]]
    normal = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    area2 = np.linalg.norm(normal, axis=1)
    keep = area2 > 1e-300
    F, P, normal, area2 = F[keep], P[keep], normal[keep], area2[keep]
    normal = normal / area2[:, None]
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    lengths = np.concatenate([np.linalg.norm(P[:, 1] - P[:, 0], axis=1), np.linalg.norm(P[:, 2] - P[:, 1], axis=1),
                              np.linalg.norm(P[:, 0] - P[:, 2], axis=1)])
    face = np.tile(np.arange(len(F)), 3)
    key = np.sort(edges, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, face, lengths = key[order], face[order], lengths[order]
    same = np.all(key[1:] == key[:-1], axis=1)
    first = np.flatnonzero(same)
    cosine = np.clip(np.einsum("ij,ij->i", normal[face[first]], normal[face[first + 1]]), -1.0, 1.0)
    total_area = area2.sum() / 2.0
    return float((lengths[first] * np.arccos(cosine)).sum() / total_area) if total_area > 0 else 0.0


def _closed_by_position(vertices: np.ndarray, faces: np.ndarray):
    _, pos = np.unique(vertices, axis=0, return_inverse=True)
    F = pos.reshape(-1)[faces]
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    key = np.sort(directed, axis=1)
    forward = (directed[:, 0] < directed[:, 1]).astype(np.int64)
    uniq, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    n_forward = np.bincount(inverse.reshape(-1), weights=forward, minlength=len(uniq))
    balanced = 2 * n_forward == counts
    ok = bool(np.all(balanced & (counts >= 2)))
    return ok, int(np.sum(counts > 2))


def _volume(V: np.ndarray, F: np.ndarray) -> float:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


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


def _max_overlap(solids: list, volumes: np.ndarray, max_pairs: int) -> float:
    if len(solids) < 2:
        return 0.0
    boxes = np.array([s.bounding_box() for s in solids])  # (q, 6) min xyz, max xyz
    lo, hi = boxes[:, :3], boxes[:, 3:]
    touching = np.all((lo[:, None, :] <= hi[None, :, :]) & (lo[None, :, :] <= hi[:, None, :]), axis=2)
    i, j = np.nonzero(np.triu(touching, 1))
    centres = (lo + hi) / 2
    order = np.argsort(np.linalg.norm(centres[i] - centres[j], axis=1), kind="stable")[:max_pairs]
    worst = 0.0
    for a, b in zip(i[order].tolist(), j[order].tolist()):
        overlap = (solids[a] ^ solids[b]).volume()
        smaller = min(volumes[a], volumes[b])
        if smaller > 0:
            worst = max(worst, overlap / smaller)
    return worst


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
    return float(point_triangle_distance(points, V[F[tri]]).max())


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Distances (n,) from points (n, 3) to triangles (n, 3, 3), float64 (Ericson's closest-point regions)."""
    p = points
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = va + vb + vc
    with np.errstate(divide="ignore", invalid="ignore"):
        v = vb / denom
        w = vc / denom
        closest = a + ab * v[:, None] + ac * w[:, None]
        # Edge and vertex regions, checked in Ericson's order (later ones override).
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    closest = np.where(on_bc[:, None], b + (c - b) * t_bc[:, None], closest)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    closest = np.where(on_ac[:, None], a + ac * t_ac[:, None], closest)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    closest = np.where(on_ab[:, None], a + ab * t_ab[:, None], closest)
    closest = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, closest)
    closest = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, closest)
    closest = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, closest)
    closest = np.where(np.isfinite(closest), closest, a)
    return np.linalg.norm(p - closest, axis=1)
