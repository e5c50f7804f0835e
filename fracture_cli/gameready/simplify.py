"""Lean fragment meshes: the fault (interior) surfaces simplified, every fragment still closed and exact.

The faults between fragments and the curves where they cut the outer surface
are most of a bake's triangles (chair, wood: 32,000 for a 2,500-triangle input).
:func:`simplify_faults` works on the finished fragments, all at once:

1. **One shared complex.** Vertices of all fragments are welded (within
   :data:`WELD_TOLERANCE`); every interior face is matched with the opposite
   face of the fragment on the other side and kept once, for both. Outer faces
   are labelled with the input polygon (coplanar input triangles) they lie in. Faces that are neither
   (a fault face without a twin) keep their corners locked.
2. **Collapses** (:mod:`.decimate`): half-edge collapses, cheapest first by
   the fault's quadric error, each kept only if every fault vertex removed so
   far stays within ``tolerance`` of the new fault, no face turns over, no
   fragment is pinched, and a vertex moves only within the patch, along the
   curve or inside the input triangle it lies on. Flat fault regions collapse
   to a few triangles, curved ones to the tolerance, and a fault curve across
   an input triangle becomes one straight segment. Both sides of a fault get
   the same faces, so the fragments still partition the input exactly: their
   volumes sum to the input's, and the outer surface is the input's, with its
   UVs and normals.
3. **Budget.** With ``max_triangles``, fragments still above it get their
   tolerance doubled, a few times, and are simplified further.
4. **Rebuild and check.** Each fragment is rebuilt (fault vertices split per
   plane, flat normals, box-projected UVs as the fragments stage makes them)
   and checked closed, manifold and free of self-intersections; when one is
   not, everything is simplified again with the vertices whose collapses made
   its bad faces held to a quarter of the tolerance, then locked, at last with
   every vertex of that fragment locked (which leaves it as it was cut).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fracture_cli import parallel
from fracture_cli.gameready.decimate import SurfaceComplex
from fracture_cli.gameready.faultmatch import (
    WELD_TOLERANCE,
    bad_faces,
    closed_when_welded,
    share_unmatched,
    source_groups,
    twins,
    valid,
    weld,
)
from fracture_cli.stages.fragments import _box_uvs
from fracture_cli.types import Fragment, Fragments, SurfaceMesh

__all__ = ["FaultReport", "simplify_faults", "valid"]

log = logging.getLogger(__name__)

# Tries after the first when a fragment comes out invalid: the vertices whose collapses made its bad faces get
# a quarter of the tolerance (cumulative), the next to last try locks them, the last one its whole fragment.
_RETRIES = 4
# Times a fragment above its triangle budget gets its tolerance doubled.
_BUDGET_ROUNDS = 6


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
        Interior faces with no opposite twin and not on the input (left as they were).
    patches : int
        Shared fault patches (pairs of touching fragments).
    retries : int
        Times the simplification was redone with more vertices locked.
    over_budget : int
        Fragments still above ``max_triangles`` (0 without a budget).
    """

    triangles_before: int
    triangles_after: int
    fault_before: int
    fault_after: int
    unmatched: int
    patches: int
    retries: int = 0
    over_budget: int = 0


@dataclass(frozen=True)
class _Classified:
    """The fragments' faces as one complex (see :class:`~fracture_cli.gameready.decimate.SurfaceComplex`)."""

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


def simplify_faults(fragments: Fragments, surface: SurfaceMesh, tolerance: float = 1e-3,
                    max_triangles: int = 0) -> tuple[Fragments, FaultReport]:
    """Simplify the fault surfaces of all fragments to ``tolerance``.

    Parameters
    ----------
    fragments : Fragments
        Closed fragments cut from ``surface``, normalized coordinates (unit bounding-box diagonal).
    surface : SurfaceMesh
        The (repaired) input they were cut from: outer faces are found in its triangles.
    tolerance : float, optional (default 1e-3)
        Largest distance of any original fault vertex from the simplified
        fault, as a fraction of the bounding-box diagonal; 0 changes nothing.
    max_triangles : int, optional (default 0: no budget)
        Triangles per fragment to aim for: fragments above it are simplified
        with up to 64 times the tolerance.

    Returns
    -------
    fragments : Fragments
        Same fragments, order and pieces.
    report : FaultReport
    """
    interior = fragments.interior_slot
    offsets = np.cumsum([0] + [len(f.vertices) for f in fragments.fragments])
    positions = np.vstack([f.vertices for f in fragments.fragments])
    owner = np.repeat(np.arange(len(fragments.fragments)), np.diff(offsets))
    gid, welded = weld(positions, owner, WELD_TOLERANCE)
    original = fragments
    fragments = share_unmatched(fragments, gid, offsets, interior)
    classified = _classify(fragments, surface, gid, offsets, welded, interior)
    results, retries, over = _valid_simplification(fragments, surface, classified, gid, offsets, welded, interior,
                                                   tolerance, max_triangles)
    before = sum(len(f.faces) for f in original.fragments)
    after = sum(len(f.faces) for f in results)
    report = FaultReport(before, after, sum(int(np.sum(f.material_ids == interior)) for f in original.fragments),
                         sum(int(np.sum(f.material_ids == interior)) for f in results), classified.unmatched,
                         classified.patches, retries, over)
    log.info("faults: %d -> %d triangles (interior %d -> %d) at tolerance %.3g", before, after,
             report.fault_before, report.fault_after, tolerance)
    new = dataclasses.replace(fragments, fragments=tuple(results))
    return new, report


def _valid_simplification(fragments: Fragments, surface: SurfaceMesh, classified: _Classified, gid: np.ndarray,
                          offsets: np.ndarray, welded: np.ndarray, interior: int, tolerance: float,
                          max_triangles: int) -> tuple[list[Fragment], int, int]:
    """The simplified fragments, every one valid; how many retries that took and how many stay over budget.

    Fragments not closed and manifold once their vertices are welded by position even as cut (bodies touching
    along an edge, which only the fragments' own vertex copies keep apart), or that intersect where no
    collapse changed a face (the weld moved a vertex), are returned as they were cut (all their vertices
    locked). The first try is checked whole, later ones only where their faces differ from the first's;
    after :data:`_RETRIES` tries every fragment still invalid is locked whole, and one still invalid then is
    returned as it was cut.
    """
    uv_scale = _uv_scale(fragments, interior)
    locked = set(classified.locked)
    count = len(fragments.fragments)
    as_cut = {k for k, f in enumerate(fragments.fragments) if not closed_when_welded(f)}
    known: dict[int, set] = {}  # faces (corner ids) of fragments that intersected themselves before
    whole: set[int] = set()  # fragments locked whole
    for k in sorted(as_cut):
        locked.update(np.unique(gid[fragments.fragments[k].faces + offsets[k]]).tolist())
    damp: dict[int, float] = {}  # tolerance factors of the vertices behind faces that intersected
    earlier: SurfaceComplex | None = None
    first: dict[int, tuple] | None = None  # the faces of the first try, all checked
    valid_faces: set[bytes] = set()
    attempt = 0
    while True:
        complex_, over = _decimate(welded, classified, locked, damp, tolerance, max_triangles, count, earlier)
        earlier = complex_
        if tolerance > 0:
            complex_.flip_needles(as_cut)
        ids, faces = complex_.face_arrays()
        results, face_ids = zip(*[_rebuild(fragments, k, welded, classified, ids, faces, interior, uv_scale)
                                  for k in range(count)])
        bad = {}
        # A fragment whose faces are those of a fragment found valid in an earlier try is valid again.
        signatures = {k: np.sort(np.sort(faces[np.isin(ids, face_ids[k])], axis=1), axis=0).tobytes()
                      for k in range(len(results)) if k not in as_cut}
        todo = [k for k, signature in signatures.items() if signature not in valid_faces]
        # The first try is checked whole; later ones only where a face differs from the first try's (pairs of
        # faces as they were then were checked then).
        changed = [None if first is None else
                   np.flatnonzero([first.get(t) != complex_.faces[t] for t in face_ids[k].tolist()]) for k in todo]
        first = dict(complex_.faces) if first is None else first
        # The fragments are checked on their own, in parallel; what was bad before is judged here.
        found_all = parallel.ordered_map(_bad_faces_item, [(results[k], c) for k, c in zip(todo, changed)])
        for k, found in zip(todo, found_all):
            b = _new_bad_faces(found, results[k], face_ids[k], complex_, known, k, fragments, gid, offsets)
            if b is None:
                valid_faces.add(signatures[k])
            else:
                bad[k] = b
        if not bad or tolerance <= 0:
            return [fragments.fragments[k] if k in as_cut else f for k, f in enumerate(results)], attempt, over
        log.debug("faults: try %d, %d fragment(s) invalid; simplifying again with more held back", attempt, len(bad))
        for k, b in sorted(bad.items()):
            behind = set().union(*[complex_.history[t] for t in face_ids[k][b].tolist()])
            if not behind:  # faces no collapse made (the weld moved them): locking cannot mend them
                as_cut.add(k)
                locked.update(np.unique(gid[fragments.fragments[k].faces + offsets[k]]).tolist())
            elif attempt + 1 >= _RETRIES:
                (as_cut if k in whole else whole).add(k)
                locked.update(np.unique(gid[fragments.fragments[k].faces + offsets[k]]).tolist())
            elif attempt + 2 >= _RETRIES:
                locked.update(behind)
            else:
                damp.update({u: damp.get(u, 1.0) / 4.0 for u in behind})
        attempt += 1


def _decimate(welded: np.ndarray, classified: _Classified, locked: set, damp: dict, tolerance: float,
              max_triangles: int, count: int, earlier: SurfaceComplex | None = None) -> tuple[SurfaceComplex, int]:
    """The complex after collapses to ``tolerance``, then to the budget; and how many fragments stay above it.

    ``earlier``: the complex of an earlier try, whose collapses are redone first where still allowed.
    """
    complex_ = SurfaceComplex(welded, classified.faces, classified.groups, classified.owners, classified.fault,
                              locked, damp)
    if tolerance <= 0:
        return complex_, 0
    bound = {k: tolerance for k in range(count)}
    if earlier is not None:
        complex_.replay(earlier.done, bound, earlier.final_refusals())
    complex_.decimate(bound)
    over: list[int] = []
    for _ in range(_BUDGET_ROUNDS + 1):
        if max_triangles <= 0:
            break
        sizes = np.zeros(count, dtype=np.int64)
        for t in complex_.faces:
            for k in classified.owners[t]:
                sizes[k] += 1
        over = np.flatnonzero(sizes > max_triangles).tolist()
        if not over or bound[over[0]] >= tolerance * 2**_BUDGET_ROUNDS:
            break
        for k in over:
            bound[k] *= 2.0
        todo = {x for t, f in complex_.faces.items() if set(classified.owners[t]) & set(over) for x in f}
        complex_.decimate(bound, sorted(todo))
    return complex_, len(over)


def _bad_faces_item(_: None, item: tuple[Fragment, np.ndarray | None]) -> np.ndarray | None:
    fragment, changed = item
    return bad_faces(fragment, changed)


def _new_bad_faces(bad: np.ndarray | None, fragment: Fragment, ids: np.ndarray, complex_: SurfaceComplex,
                   known: dict, k: int, fragments: Fragments, gid: np.ndarray,
                   offsets: np.ndarray) -> np.ndarray | None:
    """Of the faces ``bad`` making a rebuilt fragment invalid (:func:`bad_faces`), those not so before.

    A fragment cut with faces that already intersect (rare: folds the booleans left) is not held against
    the simplification: faces of it that no collapse touched, and that were bad before, are let through.
    """
    if bad is None or len(bad) == len(fragment.faces):
        return bad
    was = _known_bad(fragments, k, known, gid, offsets)
    new = [i for i, t in zip(bad.tolist(), ids[bad].tolist()) if tuple(sorted(complex_.faces[t])) not in was]
    return np.array(new, dtype=np.int64) if new else None


def _known_bad(fragments: Fragments, k: int, known: dict, gid: np.ndarray, offsets: np.ndarray) -> set:
    """The faces (sorted global corner ids) of fragment ``k`` that intersect as cut (memoized in ``known``)."""
    if k not in known:
        before = fragments.fragments[k]
        was = bad_faces(before)
        known[k] = set() if was is None else {tuple(sorted(f)) for f in gid[before.faces[was] + offsets[k]].tolist()}
    return known[k]



def _uv_scale(fragments: Fragments, interior: int) -> float:
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
        unit = _box_uvs(fragments.normalization.to_world(frag.vertices[used]), frag.normals[used], 1.0)
        num += float(np.sum(unit * frag.uvs[used]))
        den += float(np.sum(frag.uvs[used] ** 2))
    return num / den if den > 0 and num > 0 else 1.0


def _classify(fragments: Fragments, surface: SurfaceMesh, gid: np.ndarray, offsets: np.ndarray, welded: np.ndarray,
              interior: int) -> _Classified:
    """Every face of every fragment as a face of the complex: a shared fault face, an outer face, or a locked one."""
    G = np.vstack([gid[f.faces + offsets[k]] for k, f in enumerate(fragments.fragments)])
    owner = np.concatenate([np.full(len(f.faces), k) for k, f in enumerate(fragments.fragments)])
    local = np.vstack([f.faces for f in fragments.fragments])
    material = np.concatenate([f.material_ids for f in fragments.fragments]).astype(np.int32)
    twin = twins(G, owner, material == interior)
    paired = twin >= 0
    source = np.full(len(G), -1, dtype=np.int64)
    source[~paired] = source_groups(surface, welded[G[~paired]], material[~paired] != interior)
    loose = ~paired & (source < 0)
    groups = np.where(paired, -1, np.where(loose, -2 - np.arange(len(G)), source))
    keep = ~paired | (owner < owner[np.maximum(twin, 0)])  # one face per twin pair: the lower fragment's
    rows = np.flatnonzero(keep)
    owners = [(int(owner[i]), int(owner[twin[i]])) if paired[i] else (int(owner[i]),) for i in rows.tolist()]
    corner: dict = {}
    for i in np.flatnonzero(~paired).tolist():
        for g, v in zip(G[i].tolist(), local[i].tolist()):
            corner.setdefault((int(groups[i]), g), (int(owner[i]), v))
    # The input's own vertices stay: the outer surface keeps its triangulation's corners, only cuts move.
    near, _ = cKDTree(surface.vertices).query(welded, distance_upper_bound=WELD_TOLERANCE)
    on_input = np.flatnonzero(np.isfinite(near))
    owner_pair = np.column_stack([owner[rows], np.where(paired[rows], owner[np.maximum(twin[rows], 0)], -1)])
    return _Classified(faces=G[rows], groups=groups[rows], owners=owners, owner_pair=owner_pair, fault=paired[rows],
                       material=material[rows],
                       corner=corner, locked=set(np.unique(G[loose]).tolist()) | set(on_input.tolist()),
                       unmatched=int(np.sum(loose & (material == interior))),
                       patches=len({o for o in owners if len(o) == 2}))


def _rebuild(fragments: Fragments, k: int, welded: np.ndarray, classified: _Classified, ids: np.ndarray,
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
    _, first, local = np.unique(corner, axis=0, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))  # vertices in the order of first use
    first, local = np.sort(first), rank[local.reshape(-1)]
    flat_vertices, flat_normals, flat_faces = _flat(welded, faces[fault])
    all_uvs = None
    if frag.uvs is not None:
        world = fragments.normalization.to_world(flat_vertices)
        all_uvs = np.vstack([uvs[first], _box_uvs(world, flat_normals, uv_scale)])
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
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    key = np.column_stack([np.round(normal * 1e6), np.round(np.einsum("ij,ij->i", normal, a) * 1e9)])
    _, plane = np.unique(key.astype(np.int64), axis=0, return_inverse=True)
    plane = plane.reshape(-1)
    plane_normal = np.zeros((plane.max() + 1, 3))
    np.add.at(plane_normal, plane, normal)
    plane_normal /= np.maximum(np.linalg.norm(plane_normal, axis=1, keepdims=True), 1e-300)
    uniq, corner = np.unique(np.column_stack([faces.reshape(-1), np.repeat(plane, 3)]), axis=0, return_inverse=True)
    return V[uniq[:, 0]], plane_normal[uniq[:, 1]], corner.reshape(-1, 3)
