"""Prototype: fewer fault (interior) triangles, with both sides of every fault kept identical.

The faults between fragments are most of a bake's triangles (chair, wood: 76%).
This prototype works on finished fragments:

1. **Shared faults.** Vertices of all fragments are welded (within a tolerance)
   and every interior face is matched with the opposite face of the fragment
   on the other side. Matched faces form one *patch* per pair of fragments;
   faces without a twin (the two sides triangulated differently, near the
   outer surface) are left alone.
2. **Locked curves.** Every vertex on a patch's boundary is locked: the
   curves where a fault meets the outer surface, another fault (a junction of
   three fragments) or an unmatched face. So are vertices of non-fault faces.
3. **Decimation.** Each patch is simplified once, by half-edge collapses
   (a vertex merges into a neighbour; no new positions), cheapest first by the
   quadric error, each accepted only if every original vertex removed so far
   stays within ``tolerance`` of the new surface, no triangle flips or
   degenerates, and the link condition holds. Flat regions collapse to a few
   triangles; curved ones to the tolerance.
4. **Rebuild.** Both fragments of a patch get the same simplified triangles
   (opposite orientation), so the fragments still partition the input exactly
   and stay closed. Interior vertices are split per face (flat normals) with
   box-projected UVs, as the fragments stage does.

The module is a research prototype: it is not wired into the pipeline (see
the report for where it belongs).
"""

from __future__ import annotations

import heapq
import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fracture_cli.stages.fragments import _box_uvs
from fracture_cli.trigeom import edge_manifold_closed, point_triangle_distance, self_intersections, vertex_manifold
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Fragment, Fragments

log = logging.getLogger(__name__)

# Vertices of different fragments closer than this (normalized units) are one point.
WELD_TOLERANCE = 1e-6
# Rounds of re-simplifying the patches of fragments that came out invalid (tolerance / 4 each, then none).
_RETRIES = 3
# A collapse may not turn a triangle by more than this (cosine of the angle between old and new normal).
_MIN_NORMAL_COS = 0.5


@dataclass(frozen=True)
class FaultReport:
    """What :func:`simplify_faults` did.

    Attributes
    ----------
    triangles_before, triangles_after : int
        Triangles of all fragments.
    fault_before, fault_after : int
        Interior (fault) triangles of all fragments.
    unmatched : int
        Interior faces with no opposite twin (left as they were).
    patches : int
        Shared fault patches simplified.
    """

    triangles_before: int
    triangles_after: int
    fault_before: int
    fault_after: int
    unmatched: int
    patches: int


def simplify_faults(fragments: Fragments, tolerance: float = 1e-3, uv_scale: float = 1.0):
    """Simplify the shared fault surfaces of all fragments to ``tolerance``.

    Parameters
    ----------
    fragments : Fragments
        Closed fragments, normalized coordinates (unit bounding-box diagonal).
    tolerance : float, optional (default 1e-3)
        Largest distance of any original fault vertex from the simplified
        fault, as a fraction of the bounding-box diagonal.
    uv_scale : float, optional (default 1)
        World units per UV unit of the rebuilt interior faces (the fragments
        stage's ``uv_scale``).

    Returns
    -------
    fragments : Fragments
        Same fragments, order and pieces; outer faces untouched.
    report : FaultReport
    """
    interior = _interior_slot(fragments)
    offsets = np.cumsum([0] + [len(f.vertices) for f in fragments.fragments])
    positions = np.vstack([f.vertices for f in fragments.fragments])
    owner = np.repeat(np.arange(len(fragments.fragments)), np.diff(offsets))
    gid, welded = _weld(positions, owner, WELD_TOLERANCE)
    faults = [gid[f.faces[f.material_ids == interior] + offsets[k]] for k, f in enumerate(fragments.fragments)]
    patches, unmatched = _match_patches(faults)
    locked = _locked_vertices(fragments, gid, offsets, interior, patches, faults, unmatched)
    tolerances = {key: tolerance for key in patches}
    simplified = dict(patches)
    taken = _LockedEdges(locked)
    for k, frag in enumerate(fragments.fragments):
        taken.add(gid[frag.faces[frag.material_ids != interior] + offsets[k]])
        taken.add(faults[k][unmatched[k]])
    for key in sorted(patches):
        taken.add(patches[key])

    def redo(key):
        taken.remove(simplified[key])
        simplified[key] = (_decimate(welded, patches[key], locked, tolerances[key], taken.count)
                           if tolerances[key] > 0 else patches[key])
        taken.add(simplified[key])

    for key in sorted(patches):
        redo(key)
    def rebuild(k: int) -> Fragment:
        return _rebuild(fragments.fragments[k], k, gid[offsets[k]:offsets[k + 1]], welded, faults[k], unmatched[k],
                        simplified, interior, fragments, uv_scale)

    # Fragments failing the check with every patch as it was (e.g. read back from float32, then welded) are
    # not held against the simplification.
    current = dict(simplified)
    simplified.update(patches)
    exempt = {k for k in range(len(fragments.fragments)) if not _valid(rebuild(k))}
    simplified.update(current)
    results = [rebuild(k) for k in range(len(fragments.fragments))]
    for attempt in range(_RETRIES + 1):
        culprits = set()
        for k, frag in enumerate(results):
            bad = None if k in exempt else _bad_faces(frag)
            if bad is not None:
                culprits.update(_patches_of(k, bad, frag, interior, unmatched[k], simplified))
        if not culprits:
            break
        log.debug("faults: attempt %d, %d patch(es) make a fragment invalid", attempt, len(culprits))
        # Simplify those patches again, more gently, the last time not at all (the original faces are valid).
        for key in sorted(culprits):
            tolerances[key] = tolerances[key] / 4.0 if attempt < _RETRIES else 0.0
            redo(key)
        for k in sorted({k for key in culprits for k in key}):
            results[k] = rebuild(k)
    before = sum(len(f.faces) for f in fragments.fragments)
    after = sum(len(f.faces) for f in results)
    fault_before = sum(len(t) for t in faults)
    fault_after = sum(int(np.sum(f.material_ids == interior)) for f in results)
    report = FaultReport(before, after, fault_before, fault_after, int(sum(int(u.sum()) for u in unmatched)),
                         len(patches))
    log.info("faults: %d -> %d interior triangles (%d -> %d in all) at tolerance %.3g", fault_before, fault_after,
             before, after, tolerance)
    new = Fragments(fragments=tuple(results), materials=fragments.materials, normalization=fragments.normalization,
                    input_volume=fragments.input_volume)
    return new, report


def _valid(fragment: Fragment) -> bool:
    """Closed, manifold and free of self-intersections once vertices at one position are welded."""
    return _bad_faces(fragment) is None


def _bad_faces(fragment: Fragment):
    """None if the fragment is valid (see :func:`_valid`); else the faces (k,) at fault, all if it is not closed."""
    V, weld = np.unique(fragment.vertices, axis=0, return_inverse=True)
    W = weld.reshape(-1)[fragment.faces]
    if not (edge_manifold_closed(W) and vertex_manifold(W)):
        return np.arange(len(W))
    pairs = self_intersections(V, W)
    return np.unique(pairs) if len(pairs) else None


def _interior_slot(fragments: Fragments) -> int:
    names = [m.name for m in fragments.materials]
    return names.index(INTERIOR_MATERIAL_NAME) if INTERIOR_MATERIAL_NAME in names else len(names) - 1


def _weld(positions: np.ndarray, owner: np.ndarray, tolerance: float):
    """Global id (n,) of every vertex and one position (g, 3) per id.

    Vertices of one fragment are one point only at the same exact position;
    vertices of different fragments are joined when closer than
    ``tolerance``, closest pairs first, never so that two distinct points of
    one fragment end up as one (which would collapse a sliver edge).
    """
    _, exact = np.unique(np.column_stack([owner, positions]), axis=0, return_inverse=True)
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


def _match_patches(faults: list[np.ndarray]):
    """Patches ``{(A, B): faces (m, 3) in A's orientation}`` of faces with an opposite twin, and the unmatched faces.

    Returns the patches and, per fragment, a bool mask of its fault faces that have no twin.
    """
    owner = np.concatenate([np.full(len(t), k) for k, t in enumerate(faults)]) if faults else np.zeros(0, int)
    local = np.concatenate([np.arange(len(t)) for t in faults]) if faults else np.zeros(0, int)
    T = np.vstack(faults) if faults else np.zeros((0, 3), int)
    _, group, counts = np.unique(np.sort(T, axis=1), axis=0, return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    unmatched = [np.ones(len(t), dtype=bool) for t in faults]
    patches: dict[tuple[int, int], list] = {}
    order = np.argsort(group, kind="stable")
    starts = np.searchsorted(group[order], np.arange(len(counts)))
    for g in np.flatnonzero(counts == 2).tolist():
        i, j = order[starts[g]], order[starts[g] + 1]
        a, b = (i, j) if owner[i] < owner[j] else (j, i)
        if owner[a] == owner[b] or not _opposite(T[a], T[b]):
            continue
        patches.setdefault((int(owner[a]), int(owner[b])), []).append(T[a])
        unmatched[owner[a]][local[a]] = unmatched[owner[b]][local[b]] = False
    return {key: np.array(faces) for key, faces in patches.items()}, unmatched


def _opposite(f: np.ndarray, g: np.ndarray) -> bool:
    """Whether triangles f and g have the same corners in opposite cyclic order."""
    k = int(np.flatnonzero(g == f[0])[0])
    return bool(g[(k + 1) % 3] == f[2])


def _locked_vertices(fragments, gid, offsets, interior, patches, faults, unmatched) -> set:
    """Vertices no collapse may move: on non-fault faces, unmatched faces, or a patch's boundary."""
    locked = set()
    for k, frag in enumerate(fragments.fragments):
        locked.update(np.unique(gid[frag.faces[frag.material_ids != interior] + offsets[k]]).tolist())
        locked.update(np.unique(faults[k][unmatched[k]]).tolist())
    for faces in patches.values():
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        uniq, counts = np.unique(edges, axis=0, return_counts=True)
        locked.update(np.unique(uniq[counts != 2]).tolist())
    return locked


class _LockedEdges:
    """How many faces use each edge between two locked vertices (a multiset, updated as patches change)."""

    def __init__(self, locked: set):
        self.locked = locked
        self.count: dict[tuple[int, int], int] = {}

    def _edges(self, faces: np.ndarray):
        for f in np.asarray(faces, dtype=np.int64).reshape(-1, 3).tolist():
            for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
                if a in self.locked and b in self.locked:
                    yield (min(a, b), max(a, b))

    def add(self, faces: np.ndarray) -> None:
        for edge in self._edges(faces):
            self.count[edge] = self.count.get(edge, 0) + 1

    def remove(self, faces: np.ndarray) -> None:
        for edge in self._edges(faces):
            self.count[edge] -= 1


def _decimate(V: np.ndarray, faces: np.ndarray, locked: set, tolerance: float, taken: dict) -> np.ndarray:
    """Half-edge-collapse decimation of one patch with its boundary locked; returns the new faces (m', 3).

    ``taken`` counts the edges between two locked vertices used by faces elsewhere (outer faces, other
    patches): a collapse may not create one of them again, or the fragment would get an edge of four faces.
    """
    mesh = _PatchMesh(V, faces, locked, taken)
    heap: list = []
    for u in sorted(mesh.vertex_faces):
        mesh.push(heap, u)
    while heap:
        _, _, u, v, stamp = heapq.heappop(heap)
        if mesh.stamp.get(u) != stamp or u not in mesh.vertex_faces:
            continue
        if mesh.collapse(u, v, tolerance):
            for w in sorted(mesh.neighbours(v) | {v}):
                mesh.push(heap, w)
    return mesh.faces_array()


class _PatchMesh:
    """A mutable triangle patch for half-edge collapses (vertex ids are global; positions never change)."""

    def __init__(self, V: np.ndarray, faces: np.ndarray, locked: set, taken: dict):
        self.V = V
        self.taken = taken
        self.faces = {t: tuple(int(x) for x in f) for t, f in enumerate(faces)}
        self.vertex_faces: dict[int, set] = {}
        for t, f in self.faces.items():
            for x in f:
                self.vertex_faces.setdefault(x, set()).add(t)
        self.locked = locked
        self.stamp: dict[int, int] = {}
        # Original vertices removed so far, kept with the face nearest to them (for the error bound).
        self.assigned: dict[int, list] = {t: [] for t in self.faces}
        self.quadric = {x: np.zeros((4, 4)) for x in self.vertex_faces}
        for f in self.faces.values():
            p = self._plane(f)
            for x in f:
                self.quadric[x] += np.outer(p, p)

    def _plane(self, f) -> np.ndarray:
        a, b, c = self.V[list(f)]
        n = np.cross(b - a, c - a)
        area = np.linalg.norm(n)
        n = n / area if area > 0 else n
        return np.sqrt(area) * np.append(n, -n @ a)

    def neighbours(self, u: int) -> set:
        return {x for t in self.vertex_faces.get(u, ()) for x in self.faces[t]} - {u}

    def push(self, heap: list, u: int) -> None:
        """Queue every collapse of ``u`` into a neighbour, by quadric error, if ``u`` may move.

        A new stamp makes the entries queued for ``u`` before obsolete; when the cheapest collapse is
        refused, the next one of the same stamp is tried.
        """
        if u in self.locked or u not in self.vertex_faces:
            return
        stamp = self.stamp[u] = self.stamp.get(u, 0) + 1
        for v in sorted(self.neighbours(u)):
            p = np.append(self.V[v], 1.0)
            heapq.heappush(heap, (float(p @ self.quadric[u] @ p), u, u, v, stamp))

    def collapse(self, u: int, v: int, tolerance: float) -> bool:
        """Merge ``u`` into ``v`` if topology, orientation and the error bound allow; True if done."""
        fan = self.vertex_faces[u]
        removed = [t for t in fan if v in self.faces[t]]
        if len(removed) != 2:
            return False
        opposite = {x for t in removed for x in self.faces[t]} - {u, v}
        if self.neighbours(u) & self.neighbours(v) != opposite:
            return False  # link condition: the collapse would pinch the surface
        if v in self.locked and any(self.taken.get((min(v, x), max(v, x)), 0) > 0
                                    for x in self.neighbours(u) - self.neighbours(v) - {v} if x in self.locked):
            return False  # the new edge between two locked vertices is already an edge of another surface
        kept = sorted(t for t in fan if t not in removed)
        new_faces = {t: tuple(v if x == u else x for x in self.faces[t]) for t in kept}
        for t, f in new_faces.items():
            old = self._normal(self.faces[t])
            new = self._normal(f)
            length = np.linalg.norm(new)
            if length <= 1e-14 or (old @ new) / (np.linalg.norm(old) * length) < _MIN_NORMAL_COS:
                return False
        points = [u] + [p for t in fan for p in self.assigned[t]]
        triangles = np.array([self.V[list(f)] for f in new_faces.values()])
        P = self.V[points]
        distance = np.stack([point_triangle_distance(P, np.repeat(tri[None], len(P), axis=0)) for tri in triangles])
        if distance.min(axis=0).max() > tolerance:
            return False
        nearest = np.argmin(distance, axis=0)
        for t in removed:
            for x in self.faces[t]:
                self.vertex_faces[x].discard(t)
            del self.faces[t], self.assigned[t]
        for t in kept:
            self.faces[t] = new_faces[t]
            self.assigned[t] = []
        for point, k in zip(points, nearest.tolist()):
            self.assigned[kept[k]].append(point)
        self.vertex_faces[v].update(kept)
        del self.vertex_faces[u]
        self.quadric[v] = self.quadric[v] + self.quadric[u]
        return True

    def _normal(self, f) -> np.ndarray:
        a, b, c = self.V[list(f)]
        return np.cross(b - a, c - a)

    def faces_array(self) -> np.ndarray:
        return np.array([self.faces[t] for t in sorted(self.faces)], dtype=np.int64).reshape(-1, 3)


def _patches_of(k: int, faces: np.ndarray, frag: Fragment, interior: int, unmatched: np.ndarray,
                simplified: dict) -> set:
    """The patches (keys) that faces of fragment ``k`` as built by :func:`_rebuild` belong to.

    Faces of no patch (outer, unmatched) do not name one; if only such faces are listed, every patch of the
    fragment is named (the fault of a topology failure is not local).
    """
    keys = [key for key in sorted(simplified) if k in key]
    start = int(np.sum(frag.material_ids != interior)) + int(unmatched.sum())
    bounds = start + np.cumsum([0] + [len(simplified[key]) for key in keys])
    index = np.searchsorted(bounds, faces, side="right") - 1
    named = {keys[i] for i in index[(index >= 0) & (index < len(keys))].tolist()}
    return named if named else set(keys)


def _rebuild(frag: Fragment, k: int, frag_gid: np.ndarray, welded: np.ndarray, fault: np.ndarray,
             unmatched: np.ndarray, simplified: dict, interior: int, fragments: Fragments, uv_scale: float) -> Fragment:
    """Fragment ``k`` with its matched fault faces replaced by the simplified patches (split, flat-shaded)."""
    outer = frag.material_ids != interior
    new_fault = [fault[unmatched]]
    for (a, b), faces in sorted(simplified.items()):
        if a == k:
            new_fault.append(faces)
        elif b == k:
            new_fault.append(faces[:, ::-1])
    T = np.vstack(new_fault)
    outer_faces = frag.faces[outer]
    used, local = np.unique(outer_faces, return_inverse=True)
    P = welded[T].reshape(-1, 3)
    normals = np.cross(P[1::3] - P[0::3], P[2::3] - P[0::3])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    corner_normals = np.repeat(normals, 3, axis=0)
    uvs = _box_uvs(fragments.normalization.to_world(P), corner_normals, uv_scale)
    # Outer vertices take their welded position too, so both sides of every locked curve are one point.
    vertices = np.vstack([welded[frag_gid[used]], P])
    all_normals = np.vstack([frag.normals[used], corner_normals])
    all_uvs = None if frag.uvs is None else np.vstack([frag.uvs[used], uvs])
    faces = np.vstack([local.reshape(-1, 3), len(used) + np.arange(3 * len(T)).reshape(-1, 3)])
    material = np.concatenate([frag.material_ids[outer], np.full(len(T), interior, dtype=np.int32)])
    return Fragment(vertices=vertices, faces=faces, uvs=all_uvs, normals=all_normals, material_ids=material,
                    piece=frag.piece)
