"""Matching the two sides of every fault, and where outer faces lie on the input (see :mod:`.simplify`).

The fragments stage cuts each fragment on its own, so the two sides of a fault
are two sets of faces: :func:`weld` makes their corners one set of points,
:func:`twins` pairs opposite faces, :func:`share_unmatched` gives both sides
the same triangles where the booleans triangulated one polygon two ways, and
:func:`source_groups` finds the input polygon each outer face lies in.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.exactgeom import real_pairs
from fracture_cli.geometry.meshtopo import manifold_patches, undirected_edges
from fracture_cli.geometry.rows import group_rows, unique_rows
from fracture_cli.geometry.trigeom import (
    BoxGrid,
    default_cell,
    edge_manifold_closed,
    point_triangle_distance,
    self_intersections,
    self_intersections_among,
    vertex_manifold,
)
from fracture_cli.system import parallel
from fracture_cli.types import Fragment, Fragments, SurfaceMesh

# Input triangles tried per outer face (nearest centroids first) before all of them are.
_CANDIDATES = 16


def closed_when_welded(fragment: Fragment) -> bool:
    """Whether the fragment is closed and manifold once vertices at one position are welded."""
    W = group_rows(fragment.vertices)[fragment.faces]  # any ids: the verdicts do not depend on their order
    return bool(edge_manifold_closed(W) and vertex_manifold(W))


def valid(fragment: Fragment) -> bool:
    """Closed, manifold and free of self-intersections once vertices at one position are welded."""
    return bad_faces(fragment) is None


def bad_faces(fragment: Fragment, changed: np.ndarray | None = None,
              pinches: np.ndarray | None = None) -> np.ndarray | None:
    """None if the fragment is valid (see :func:`valid`); else the faces (k,) at fault, all if it is not closed.

    ``changed`` (c,): only intersections involving one of these faces count (the others are as they were
    checked before); None checks every pair. ``pinches`` (p, 3): positions where the fragment may touch
    itself at a vertex (several fans of faces, as it was cut: :func:`pinched_positions`); None allows none.
    Pairs the floating-point test reports are tested again exactly
    (:func:`~fracture_cli.geometry.exactgeom.real_pairs`): needles the booleans leave (height ~1e-10 of their edges)
    "intersect" the faces they share a corner with by rounding alone, and would keep fragments as cut.
    """
    V, weld = unique_rows(fragment.vertices, return_inverse=True)
    W = weld.reshape(-1)[fragment.faces]
    if not edge_manifold_closed(W):
        return np.arange(len(W))
    if not vertex_manifold(W) and not _pinched_within(V, W, pinches):
        return np.arange(len(W))
    pairs = self_intersections(V, W) if changed is None else self_intersections_among(V, W, changed)
    pairs = real_pairs(V, W, pairs)
    return np.unique(pairs) if len(pairs) else None


def pinched_positions(fragment: Fragment) -> np.ndarray | None:
    """Positions (p, 3) where the fragment, welded by position, touches itself at a vertex; None if it is not
    even closed and edge-manifold so welded."""
    V, weld = unique_rows(fragment.vertices, return_inverse=True)
    W = weld.reshape(-1)[fragment.faces]
    if not edge_manifold_closed(W):
        return None
    return V[_fan_counts(W, len(V)) > 1]


def _pinched_within(V: np.ndarray, W: np.ndarray, pinches: np.ndarray | None) -> bool:
    """Whether every vertex of ``W`` (m, 3) (positions ``V``) with several fans is at one of ``pinches`` (p, 3)
    (within :data:`~fracture_cli.geometry.tolerances.WELD`: the welded complex may hold a pinch one weld apart)."""
    if pinches is None or len(pinches) == 0:
        return False
    pinched = np.flatnonzero(_fan_counts(W, len(V)) > 1)
    distance, _ = cKDTree(pinches).query(V[pinched])
    return bool(np.all(distance <= tol.WELD))


def _fan_counts(W: np.ndarray, n: int) -> np.ndarray:
    """Fans of faces (n,) around each vertex of a closed, edge-manifold ``W`` (m, 3) (0 for unused vertices).

    Corners are joined across every edge: the corner at ``a`` of the face with half-edge (a, b) and that of
    the face with (b, a), likewise at ``b``; a vertex has as many fans as its corners have components.
    """
    m = len(W)
    corner = np.arange(3 * m).reshape(m, 3)
    a, b = W.reshape(-1), np.roll(W, -1, axis=1).reshape(-1)  # half-edge (a, b) starts at corner i
    at_a, at_b = corner.reshape(-1), np.roll(corner, -1, axis=1).reshape(-1)
    key = a * n + b
    order = np.argsort(key)
    twin = order[np.searchsorted(key[order], b * n + a)]  # closed and edge-manifold: every half-edge has one
    graph = sp.coo_matrix((np.ones(2 * len(a)), (np.concatenate([at_a, at_b]), np.concatenate([at_b[twin],
                                                                                              at_a[twin]]))),
                          shape=(3 * m, 3 * m))
    _, label = connected_components(graph, directed=False)
    owner = W.reshape(-1)
    pairs = np.unique(np.column_stack([owner, label]), axis=0)
    return np.bincount(pairs[:, 0], minlength=n)


def weld(positions: np.ndarray, owner: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Global id (n,) of every vertex and one position (g, 3) per id.

    Vertices of one fragment are one point only at the same exact position;
    vertices of different fragments are joined when closer than
    ``tolerance``, closest pairs first, never so that two distinct points of
    one fragment end up as one (which would collapse a sliver edge).
    """
    _, exact = unique_rows(np.column_stack([owner, positions]), return_inverse=True)
    exact = exact.reshape(-1)
    m = exact.max() + 1
    first = np.full(m, len(positions))
    np.minimum.at(first, exact, np.arange(len(positions)))
    points, point_owner = positions[first], owner[first]
    pairs = cKDTree(points).query_pairs(tolerance, output_type="ndarray")
    pairs = pairs[point_owner[pairs[:, 0]] != point_owner[pairs[:, 1]]]
    distance = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    parent = list(range(m))
    members = [{int(point_owner[i])} for i in range(m)]

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for i, j in pairs[np.lexsort((pairs[:, 1], pairs[:, 0], distance))].tolist():
        a, b = find(i), find(j)
        if a != b and not (members[a] & members[b]):
            a, b = min(a, b), max(a, b)
            parent[b] = a
            members[a] |= members[b]
    root = np.array([find(i) for i in range(m)])
    _, gid = np.unique(root, return_inverse=True)
    gid = gid.reshape(-1)
    rep = np.full(gid.max() + 1, m)
    np.minimum.at(rep, gid, np.arange(m))
    return gid[exact], points[rep]


def twins(G: np.ndarray, owner: np.ndarray, candidate: np.ndarray) -> np.ndarray:
    """For each face (n,) the index of its opposite twin in another fragment, or -1 (only ``candidate`` faces)."""
    twin = np.full(len(G), -1, dtype=np.int64)
    rows = np.flatnonzero(candidate)
    _, group, counts = unique_rows(np.sort(G[rows], axis=1), return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    order = np.argsort(group, kind="stable")
    starts = np.searchsorted(group[order], np.arange(len(counts)))
    pair = np.flatnonzero(counts == 2)
    i, j = rows[order[starts[pair]]], rows[order[starts[pair] + 1]]
    ok = (owner[i] != owner[j]) & _opposite(G[i], G[j])
    twin[i[ok]], twin[j[ok]] = j[ok], i[ok]
    return twin


def _opposite(f: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Whether triangles f (p, 3) and g (p, 3), with the same corners, have them in opposite cyclic order."""
    k = np.argmax(g == f[:, :1], axis=1)  # the first corner of g at f's first corner
    return g[np.arange(len(g)), (k + 1) % 3] == f[:, 2]


def coplanar_groups(surface: SurfaceMesh) -> np.ndarray:
    """Group id (t,) of every input triangle: triangles in one plane joined across edges with no seam.

    The booleans merge such triangles into one polygon and triangulate it anew, so an outer face may span
    several of them; UVs and normals are continuous inside a group (its edges join vertex ids, not positions).
    """
    V, F = surface.vertices, surface.faces
    normal = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    plane = np.column_stack([np.round(normal * 1e6), np.round(np.einsum("ij,ij->i", normal, V[F[:, 0]]) * 1e9)])
    _, plane_id = unique_rows(plane.astype(np.int64), return_inverse=True)
    plane_id = plane_id.reshape(-1)
    _, edge_id, face = undirected_edges(F)
    order = np.argsort(edge_id, kind="stable")
    pair = order[np.bincount(edge_id)[edge_id[order]] == 2].reshape(-1, 2)
    a, b = face[pair[:, 0]], face[pair[:, 1]]
    same = plane_id[a] == plane_id[b]
    graph = sp.coo_matrix((np.ones(int(same.sum())), (a[same], b[same])), shape=(len(F), len(F)))
    return connected_components(graph, directed=False)[1]


def source_groups(surface: SurfaceMesh, points: np.ndarray, thorough: np.ndarray) -> np.ndarray:
    """For triangles (m, 3, 3) the coplanar group (m,) of input triangles holding them, or -1 if none does.

    A face belongs to the group of the input triangle nearest to its centroid (those with the nearest
    centroids are tried, all of them for the ``thorough`` (m,) faces not placed so) when its centroid is on
    that triangle and its corners on the group's plane.
    """
    S = surface.vertices[surface.faces]
    group = coplanar_groups(surface)
    centroid = points.mean(axis=1)
    k = min(_CANDIDATES, len(S))
    _, near = cKDTree(S.mean(axis=1)).query(centroid, k=k)
    near = near.reshape(len(points), k)
    best = np.full(len(points), -1, dtype=np.int64)
    best_distance = np.full(len(points), np.inf)
    for j in range(k):
        distance = point_triangle_distance(centroid, S[near[:, j]])
        better = distance < best_distance
        best[better], best_distance[better] = near[better, j], distance[better]
    far = np.flatnonzero((best_distance > tol.ON_SURFACE) & thorough)  # beside a big input triangle
    if len(far):
        best[far], best_distance[far] = _nearest_within(S, centroid[far], tol.ON_SURFACE)
    T = S[np.maximum(best, 0)]
    normal = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    off_plane = np.abs(np.einsum("mcj,mj->mc", points - T[:, :1], normal)).max(axis=1)
    return np.where((best_distance <= tol.ON_SURFACE) & (off_plane <= tol.ON_SURFACE), group[np.maximum(best, 0)], -1)


def _nearest_within(S: np.ndarray, points: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """For points (q, 3) the nearest of triangles S (t, 3, 3) (lowest index on ties) and its distance (q,).

    Only triangles whose boxes come within ``reach`` of a point are measured (a box grid, not all t): a point
    with none of them gets -1 and infinity, whatever lies farther.
    """
    boxes = np.stack([S.min(axis=1), S.max(axis=1)], axis=1)
    qi, j = BoxGrid(boxes, default_cell(boxes)).query(np.stack([points, points], axis=1), pad=reach)
    best = np.full(len(points), -1, dtype=np.int64)
    distance = np.full(len(points), np.inf)
    if len(qi):
        d = point_triangle_distance(points[qi], S[j])
        order = np.lexsort((j, d, qi))
        first = order[np.r_[True, qi[order][1:] != qi[order][:-1]]]
        best[qi[first]], distance[qi[first]] = j[first], d[first]
    return best, distance


def share_unmatched(fragments: Fragments, gid: np.ndarray, offsets: np.ndarray, interior: int) -> Fragments:
    """Fragments whose untwinned fault faces, where both sides triangulate one polygon differently, agree.

    Untwinned fault faces of one fragment are grouped in clusters (joined across edges); when a cluster of
    fragment B has the same vertices and boundary as one of fragment A (A < B), B takes A's faces, reversed.
    A fragment this would make invalid keeps its own faces.
    """
    G = np.vstack([gid[f.faces + offsets[k]] for k, f in enumerate(fragments.fragments)])
    owner = np.concatenate([np.full(len(f.faces), k) for k, f in enumerate(fragments.fragments)])
    material = np.concatenate([f.material_ids for f in fragments.fragments])
    start = np.cumsum([0] + [len(f.faces) for f in fragments.fragments])
    untwinned = (material == interior) & (twins(G, owner, material == interior) < 0)
    clusters: dict = {}
    for k in np.unique(owner[untwinned]).tolist():
        rows = np.flatnonzero(untwinned[start[k]:start[k + 1]])
        patch = manifold_patches(G[start[k] + rows])[0]
        for p in np.unique(patch).tolist():
            faces = rows[patch == p]
            clusters.setdefault(_cluster_key(G[start[k] + faces]), []).append((k, faces))
    swaps: dict[int, list] = {}
    for key in sorted(clusters, key=lambda c: min(k for k, _ in clusters[c])):
        found = clusters[key]
        if len(found) == 2 and found[0][0] != found[1][0]:
            (a, fa), (b, fb) = sorted(found, key=lambda x: x[0])
            swaps.setdefault(b, []).append((gid[fragments.fragments[a].faces[fa] + offsets[a]][:, ::-1], fb))
    out = list(fragments.fragments)
    candidates: list[tuple[int, Fragment]] = []
    counts: list[int] = []  # new faces per candidate
    for b, items in sorted(swaps.items()):
        frag = fragments.fragments[b]
        local = {int(g): v for g, v in zip(gid[offsets[b]:offsets[b + 1]].tolist(), range(len(frag.vertices)))}
        drop = np.concatenate([fb for _, fb in items])
        new = np.vstack([np.vectorize(local.__getitem__, otypes=[np.int64])(faces) for faces, _ in items])
        keep = np.setdiff1d(np.arange(len(frag.faces)), drop)
        candidate = Fragment(vertices=frag.vertices, faces=np.vstack([frag.faces[keep], new]), uvs=frag.uvs,
                             normals=frag.normals,
                             material_ids=np.concatenate([frag.material_ids[keep],
                                                          np.full(len(new), interior, dtype=np.int32)]),
                             piece=frag.piece)
        candidates.append((b, candidate))
        counts.append(len(new))
    # The candidates are checked on their own, in parallel: closed and manifold, and their new faces (last)
    # free of intersections (an intersection the fragment had as cut is not the swap's doing).
    items = [(c, np.arange(len(c.faces) - n, len(c.faces))) for (_, c), n in zip(candidates, counts)]
    for (b, candidate), bad in zip(candidates, parallel.ordered_map(_bad_faces_item, items)):
        if bad is None:
            out[b] = candidate
    return dataclasses.replace(fragments, fragments=tuple(out))


def _bad_faces_item(_: None, item: tuple[Fragment, np.ndarray]) -> np.ndarray | None:
    return bad_faces(*item)


def _cluster_key(G: np.ndarray) -> tuple:
    """What two triangulations of one polygon share: their vertices and their boundary's (undirected) edges."""
    directed, edge_id, _ = undirected_edges(G)
    boundary = np.sort(directed[np.bincount(edge_id)[edge_id] == 1], axis=1)
    return tuple(np.unique(G).tolist()), tuple(map(tuple, unique_rows(boundary).tolist()))
