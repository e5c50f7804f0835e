"""Lean fragment meshes: the fault (interior) surfaces simplified, every fragment still closed and exact.

The faults between fragments and the curves where they cut the outer surface
are most of a bake's triangles (chair, wood: 32,000 for a 2,500-triangle input).
:func:`simplify_faults` works on the finished fragments, all at once:

1. **One shared complex.** Vertices of all fragments are welded (within
   :data:`~fracture_cli.geometry.tolerances.WELD`); every interior face is matched with the opposite
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
3. **Budget** (:mod:`.budget`). With ``max_triangles``, fragments still above
   it get their tolerance doubled, a few times, and are simplified further;
   with ``fit_budget``, likewise the fragments above their share of the
   asset's budget (twice the input's triangles plus 64 per fragment) while
   the asset is above it (:mod:`.fit`: a fragment that comes out invalid
   there first gets the vertices behind its bad faces pinned, and is held
   whole only if that does not mend it).
4. **Rebuild and check.** Each fragment is rebuilt (fault vertices split per
   plane, flat normals, box-projected UVs as the fragments stage makes them)
   and checked closed, manifold and free of self-intersections; when one is
   not, everything is simplified again with the vertices whose collapses made
   its bad faces held to a quarter of the tolerance, then locked, at last with
   every vertex of that fragment locked (which leaves it as it was cut). A
   fragment that touches itself at a vertex as cut may go on doing so there
   (those vertices are locked; the stage moves the copies apart after).
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import logging
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fracture_cli.geometry import tolerances as tol
from fracture_cli.stages.simplify.budget import Limits, shares, triangle_budget
from fracture_cli.stages.simplify.decimate import SurfaceComplex
from fracture_cli.stages.simplify.faultmatch import (
    bad_faces,
    closed_when_welded,
    pinched_positions,
    share_unmatched,
    source_groups,
    twins,
    valid,
    weld,
)
from fracture_cli.stages.simplify.fit import rounds, within_budget
from fracture_cli.stages.simplify.rebuild import Classified, fragment_rows, rebuild, uv_scale
from fracture_cli.system import parallel
from fracture_cli.types import Fragment, Fragments, SurfaceMesh

__all__ = ["FaultReport", "simplify_faults", "valid"]

log = logging.getLogger(__name__)

# Tries after the first when a fragment comes out invalid: the vertices whose collapses made its bad faces get
# a quarter of the tolerance (cumulative), the next to last try locks them, the last one its whole fragment.
_RETRIES = 4


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


def simplify_faults(fragments: Fragments, surface: SurfaceMesh, tolerance: float = 1e-3,
                    max_triangles: int = 0, fit_budget: bool = False) -> tuple[Fragments, FaultReport]:
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
    fit_budget : bool, optional (default False)
        Also simplify, up to 64 times the tolerance, the fragments above their share of
        :func:`~fracture_cli.stages.simplify.budget.triangle_budget` while the asset is above it.

    Returns
    -------
    fragments : Fragments
        Same fragments, order and pieces.
    report : FaultReport
    """
    with _no_cyclic_gc():
        return _simplify_faults(fragments, surface, tolerance, max_triangles, fit_budget)


@contextlib.contextmanager
def _no_cyclic_gc() -> Iterator[None]:
    """Python's cyclic garbage collector off meanwhile (as it was after).

    The complex makes and drops millions of small tuples, lists and sets, none in a reference cycle; the
    collector, triggered again and again as they pile up, only walked the complex's dicts: a sixth of the
    stage's time. Nothing is kept from collection: whatever cycles were made are found at its next run.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _simplify_faults(fragments: Fragments, surface: SurfaceMesh, tolerance: float, max_triangles: int,
                     fit_budget: bool) -> tuple[Fragments, FaultReport]:
    """:func:`simplify_faults`, the collector off."""
    interior = fragments.interior_slot
    offsets = np.cumsum([0] + [len(f.vertices) for f in fragments.fragments])
    positions = np.vstack([f.vertices for f in fragments.fragments])
    owner = np.repeat(np.arange(len(fragments.fragments)), np.diff(offsets))
    gid, welded = weld(positions, owner, tol.WELD)
    original = fragments
    fragments = share_unmatched(fragments, gid, offsets, interior)
    classified = _classify(fragments, surface, gid, offsets, welded, interior)
    count = len(fragments.fragments)
    limits = (Limits(max_triangles, triangle_budget(len(surface.faces), count),
                     shares(len(surface.faces), _outer_area(classified, welded, count)))
              if fit_budget else Limits(max_triangles))
    results, retries, over = _valid_simplification(fragments, surface, classified, gid, offsets, welded, interior,
                                                   tolerance, limits)
    before = sum(len(f.faces) for f in original.fragments)
    after = sum(len(f.faces) for f in results)
    report = FaultReport(before, after, sum(int(np.sum(f.material_ids == interior)) for f in original.fragments),
                         sum(int(np.sum(f.material_ids == interior)) for f in results), classified.unmatched,
                         classified.patches, retries, over)
    log.info("faults: %d -> %d triangles (interior %d -> %d) at tolerance %.3g", before, after,
             report.fault_before, report.fault_after, tolerance)
    new = dataclasses.replace(fragments, fragments=tuple(results))
    return new, report


def _valid_simplification(fragments: Fragments, surface: SurfaceMesh, classified: Classified, gid: np.ndarray,
                          offsets: np.ndarray, welded: np.ndarray, interior: int, tolerance: float,
                          limits: Limits) -> tuple[list[Fragment], int, int]:
    """The simplified fragments, every one valid; how many retries that took and how many stay over budget.

    First to ``tolerance`` and ``limits.max_triangles`` (:func:`_within_tolerance`), then, while the asset is
    above ``limits.budget``, further (:func:`~fracture_cli.stages.simplify.fit.within_budget`).
    """
    checker = _Checker(fragments, classified, welded, interior, gid, offsets)
    tried, results, attempt, over = _within_tolerance(checker, tolerance, Limits(limits.max_triangles))
    if tolerance > 0 and limits.budget > 0 and sum(len(f.faces) for f in results) > limits.budget:
        results = within_budget(checker, tried, tolerance, limits, results)
    return results, attempt, over


@dataclass(frozen=True)
class _Tried:
    """What the last try of :func:`_within_tolerance` held back, and its complex (all its fragments valid)."""

    complex_: SurfaceComplex
    locked: set
    damp: dict
    as_cut: frozenset


class _Checker:
    """Rebuilds the fragments of a complex and finds the invalid ones, remembering what was checked before."""

    def __init__(self, fragments: Fragments, classified: Classified, welded: np.ndarray, interior: int,
                 gid: np.ndarray, offsets: np.ndarray):
        self.fragments, self.classified, self.welded, self.interior = fragments, classified, welded, interior
        self.gid, self.offsets = gid, offsets
        self.uv_scale = uv_scale(fragments, interior)
        self.known: dict[int, set] = {}  # faces (corner ids) of fragments that intersected themselves as cut
        # Positions (p, 3) where a fragment touched itself at a vertex as cut: allowed to go on doing so.
        self.pinches: dict[int, np.ndarray] = {}
        self.first: dict[int, tuple] | None = None  # the faces of the first try, all checked
        self.valid_faces: set[bytes] = set()
        self._pristine: SurfaceComplex | None = None

    def pristine(self) -> SurfaceComplex:
        """The complex of the fragments as cut, nothing locked (built once: every try starts from a copy)."""
        if self._pristine is None:
            classified = self.classified
            self._pristine = SurfaceComplex(self.welded, classified.faces, classified.groups, classified.owners,
                                            classified.fault, set())
        return self._pristine

    def check(self, complex_: SurfaceComplex, as_cut: set | frozenset) -> tuple[list[Fragment], list, dict]:
        """The rebuilt fragments (those ``as_cut`` as they were cut), their faces' complex ids, and the bad
        faces (local indices) of each invalid fragment."""
        fragments, count = self.fragments, len(self.fragments.fragments)
        ids, faces = complex_.face_arrays()
        rows = fragment_rows(self.classified.owner_pair[ids], count)
        results, face_ids = zip(*[rebuild(fragments, k, self.welded, self.classified, ids[rows[k]], faces[rows[k]],
                                          self.interior, self.uv_scale) for k in range(count)])
        bad = {}
        # A fragment whose faces are those of a fragment found valid in an earlier try is valid again.
        signatures = {k: np.sort(np.sort(faces[rows[k]], axis=1), axis=0).tobytes()
                      for k in range(count) if k not in as_cut}
        todo = [k for k, signature in signatures.items() if signature not in self.valid_faces]
        # The first try is checked whole; later ones only where a face differs from the first try's (pairs of
        # faces as they were then were checked then).
        first = self.first
        changed = [None if first is None else
                   np.flatnonzero([first.get(t) != complex_.faces[t] for t in face_ids[k].tolist()]) for k in todo]
        self.first = dict(complex_.faces) if first is None else first
        # The fragments are checked on their own, in parallel; what was bad before is judged here.
        found_all = parallel.ordered_map(_bad_faces_item, [(results[k], c, self.pinches.get(k))
                                                           for k, c in zip(todo, changed)])
        # Where some faces are bad, which of the fragment as cut were bad already (:func:`_cut_faces`), in parallel.
        cut = [k for k, found in zip(todo, found_all)
               if found is not None and len(found) != len(results[k].faces) and k not in self.known]
        for k, was in zip(cut, parallel.ordered_map(_bad_faces_item, [(fragments.fragments[k], None,
                                                                       self.pinches.get(k)) for k in cut])):
            self.known[k] = _cut_faces(fragments, k, was, self.gid, self.offsets)
        for k, found in zip(todo, found_all):
            b = _new_bad_faces(found, results[k], face_ids[k], complex_, self.known.get(k, set()))
            if b is None:
                self.valid_faces.add(signatures[k])
            else:
                bad[k] = b
        return [fragments.fragments[k] if k in as_cut else f for k, f in enumerate(results)], list(face_ids), bad


def _pinched(checker: _Checker, locked: set) -> set[int]:
    """The fragments not closed and edge-manifold once welded by position, to keep as cut.

    A fragment that only touches itself at a vertex (cones of one body meeting at a point, as a region of the
    cut can) is simplified all the same: its vertices there are ``locked`` (updated) and the check lets them
    go on touching (:attr:`_Checker.pinches`; the simplify stage moves the copies apart after). Keeping it as
    cut would keep every fault it shares as cut.
    """
    fragments, gid, offsets = checker.fragments, checker.gid, checker.offsets
    as_cut = set()
    for k, fragment in enumerate(fragments.fragments):
        if closed_when_welded(fragment):
            continue
        pinches = pinched_positions(fragment)
        if pinches is None:
            as_cut.add(k)
            continue
        checker.pinches[k] = pinches
        at = np.flatnonzero(cKDTree(pinches).query(fragment.vertices)[0] == 0.0)
        locked.update(np.unique(gid[at + offsets[k]]).tolist())
    return as_cut


def _within_tolerance(checker: _Checker, tolerance: float,
                      limits: Limits) -> tuple[_Tried, list[Fragment], int, int]:
    """Simplify to ``tolerance`` (and ``limits``) until every fragment is valid.

    Fragments not closed and edge-manifold once their vertices are welded by position even as cut (bodies
    touching along an edge, which only the fragments' own vertex copies keep apart; :func:`_pinched`), or that
    intersect where no
    collapse changed a face (the weld moved a vertex), are returned as they were cut (all their vertices
    locked). The first try is checked whole, later ones only where their faces differ from the first's;
    after :data:`_RETRIES` tries every fragment still invalid is locked whole, and one still invalid then is
    returned as it was cut.

    Returns
    -------
    tried : _Tried
    fragments : list of Fragment
    retries, over : int
        Tries after the first; fragments above ``limits.max_triangles``.
    """
    fragments, gid, offsets = checker.fragments, checker.gid, checker.offsets
    locked = set(checker.classified.locked)
    count = len(fragments.fragments)
    as_cut = _pinched(checker, locked)
    whole: set[int] = set()  # fragments locked whole
    for k in sorted(as_cut):
        locked.update(np.unique(gid[fragments.fragments[k].faces + offsets[k]]).tolist())
    damp: dict[int, float] = {}  # tolerance factors of the vertices behind faces that intersected
    earlier: SurfaceComplex | None = None
    attempt = 0
    while True:
        complex_, over = _decimate(checker, locked, damp, tolerance, limits, count, earlier)
        earlier = complex_
        if tolerance > 0:
            complex_.flip_needles(as_cut)
        results, face_ids, bad = checker.check(complex_, as_cut)
        if not bad or tolerance <= 0:
            return _Tried(complex_, locked, damp, frozenset(as_cut)), results, attempt, over
        log.debug("faults: try %d, %d fragment(s) invalid; simplifying again with more held back", attempt, len(bad))
        for k, b in sorted(bad.items()):
            behind = complex_.behind(face_ids[k][b].tolist())
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


def _decimate(checker: _Checker, locked: set, damp: dict, tolerance: float, limits: Limits, count: int,
              earlier: SurfaceComplex | None = None) -> tuple[SurfaceComplex, int]:
    """The complex after collapses to ``tolerance``, then to the limits; and how many fragments stay above
    ``limits.max_triangles``.

    ``earlier``: the complex of an earlier try, whose collapses are redone first where still allowed.
    """
    complex_ = checker.pristine().copy()
    complex_.locked, complex_.damp = locked, damp or {}
    if tolerance <= 0:
        return complex_, 0
    bound = {k: tolerance for k in range(count)}
    if earlier is not None:
        complex_.replay(earlier.done, bound, earlier.final_refusals())
    complex_.decimate(bound)
    sizes = rounds(complex_, checker.classified, limits, bound, tolerance)
    over = int(np.sum(sizes > limits.max_triangles)) if limits.max_triangles > 0 else 0
    return complex_, over


def _outer_area(classified: Classified, welded: np.ndarray, count: int) -> np.ndarray:
    """Area (count,) of each fragment's outer surface (its faces on the input)."""
    outer = classified.groups >= 0
    T = welded[classified.faces[outer]]
    area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
    return np.bincount(classified.owner_pair[outer, 0], weights=area, minlength=count)


def _bad_faces_item(_: None, item: tuple[Fragment, np.ndarray | None, np.ndarray | None]) -> np.ndarray | None:
    fragment, changed, pinches = item
    return bad_faces(fragment, changed, pinches)


def _new_bad_faces(bad: np.ndarray | None, fragment: Fragment, ids: np.ndarray, complex_: SurfaceComplex,
                   was: set) -> np.ndarray | None:
    """Of the faces ``bad`` making a rebuilt fragment invalid (:func:`bad_faces`), those not so before.

    A fragment cut with faces that already intersect (rare: folds the booleans left) is not held against
    the simplification: faces of it that no collapse touched, and that were bad before (``was``: sorted
    global corner ids, :func:`_cut_faces`, found by :meth:`_Checker.check` for every fragment with some bad
    faces), are let through.
    """
    if bad is None or len(bad) == len(fragment.faces):
        return bad
    new = [i for i, t in zip(bad.tolist(), ids[bad].tolist()) if tuple(sorted(complex_.faces[t])) not in was]
    return np.array(new, dtype=np.int64) if new else None


def _cut_faces(fragments: Fragments, k: int, was: np.ndarray | None, gid: np.ndarray, offsets: np.ndarray) -> set:
    """The faces ``was`` (local indices, or None) of fragment ``k`` as cut, as sorted global corner ids."""
    before = fragments.fragments[k]
    return set() if was is None else {tuple(sorted(f)) for f in gid[before.faces[was] + offsets[k]].tolist()}



def _classify(fragments: Fragments, surface: SurfaceMesh, gid: np.ndarray, offsets: np.ndarray, welded: np.ndarray,
              interior: int) -> Classified:
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
    near, _ = cKDTree(surface.vertices).query(welded, distance_upper_bound=tol.WELD)
    on_input = np.flatnonzero(np.isfinite(near))
    owner_pair = np.column_stack([owner[rows], np.where(paired[rows], owner[np.maximum(twin[rows], 0)], -1)])
    return Classified(faces=G[rows], groups=groups[rows], owners=owners, owner_pair=owner_pair, fault=paired[rows],
                       material=material[rows],
                       corner=corner, locked=set(np.unique(G[loose]).tolist()) | set(on_input.tolist()),
                       unmatched=int(np.sum(loose & (material == interior))),
                       patches=len({o for o in owners if len(o) == 2}))
