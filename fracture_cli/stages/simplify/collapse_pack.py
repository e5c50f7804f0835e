"""A :class:`.decimate.SurfaceComplex` as the arrays of :func:`.collapse_loop.collapse_loop`, and back.

:func:`decimate` packs the complex (faces, the faces around each vertex, the
removed points kept with each face, what earlier tries refused), runs the
compiled loop, then applies its collapses to the complex one by one, with the
points and faces the loop chose, and records its refusals: the complex ends as
the Python loop (:meth:`.SurfaceComplex.decimate_python`) leaves it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.stages.simplify.collapse_loop import collapse_loop
from fracture_cli.stages.simplify.collapse_replay import replay_loop
from fracture_cli.stages.simplify.decimate_faces import MIN_NORMAL_COS, MIN_NORMAL_COS_OUTER, MIN_SHAPE, merged

if TYPE_CHECKING:
    from fracture_cli.stages.simplify.decimate import SurfaceComplex


def static_arrays(complex_: SurfaceComplex) -> tuple:
    """What never changes in a complex, as the loop's ``geo`` tuple: (positions, positions, homogeneous,
    groups, owners (m, 2; -1 pads), fault, locked, damp, min cos, min cos outer, min shape); locked and
    damp (and two scratch arrays) are filled per call."""
    owners = complex_.owners
    own = np.full((len(owners), 2), -1, dtype=np.int64)
    pairs = np.fromiter((len(o) == 2 for o in owners), dtype=bool, count=len(owners))
    own[:, 0] = np.fromiter((o[0] for o in owners), dtype=np.int64, count=len(owners))
    own[pairs, 1] = np.fromiter((o[1] for o, two in zip(owners, pairs.tolist()) if two), dtype=np.int64,
                                count=int(pairs.sum()))
    return (complex_._positions, complex_._positions, complex_._homogeneous,
            np.asarray(complex_.groups, dtype=np.int64), own, np.asarray(complex_.fault, dtype=np.bool_), None, None,
            MIN_NORMAL_COS, MIN_NORMAL_COS_OUTER, MIN_SHAPE, None, None)


def _mask(n: int, items: object) -> np.ndarray:
    out = np.zeros(n, dtype=np.bool_)
    out[np.fromiter(items, dtype=np.int64)] = True  # type: ignore[call-overload]
    return out


def _faces(complex_: SurfaceComplex, m: int, n: int) -> tuple:
    """Corners (m, 3) of the faces (dead ones zero), and the faces around every vertex as a pool."""
    ids = np.fromiter(complex_.faces.keys(), dtype=np.int64, count=len(complex_.faces))
    F = np.zeros((m, 3), dtype=np.int64)
    if len(ids):
        F[ids] = np.array(list(complex_.faces.values()), dtype=np.int64)
    # A face once per distinct corner (the Python sets), grouped by vertex.
    pairs = np.unique(F[ids].ravel() * m + np.repeat(ids, 3))
    corner, face = pairs // m, pairs % m
    length = np.bincount(corner, minlength=n).astype(np.int64)
    start = np.concatenate([[0], np.cumsum(length)[:-1]]).astype(np.int64)
    return F, (start, length, length.copy()), face.astype(np.int64)


def _assigned(complex_: SurfaceComplex, m: int) -> tuple:
    """The removed points kept with each face, as a pool."""
    length = np.zeros(m, dtype=np.int64)
    items = [(t, p) for t, p in complex_.assigned.items() if p]
    if items:
        length[[t for t, _ in items]] = [len(p) for _, p in items]
    start = np.concatenate([[0], np.cumsum(length)[:-1]]).astype(np.int64)
    pool = np.array([x for _, p in items for x in p], dtype=np.int64) if items else np.zeros(0, dtype=np.int64)
    # (faces without points start at 0 with no room: their first point moves them to the pool's end)
    return (start, length, length.copy()), pool


def _earlier(complex_: SurfaceComplex, n: int) -> tuple:
    """The earlier try's refusals (:meth:`.SurfaceComplex.replay`) as (has, bound, start, length, pool)."""
    has, bound = np.zeros(n, dtype=np.bool_), np.zeros(n)
    start, length = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    regions = []
    at = 0
    for u, (b, region) in complex_._refusals.items():
        r = np.sort(np.fromiter(region, dtype=np.int64, count=len(region)))
        has[u], bound[u], start[u], length[u] = True, b, at, len(r)
        regions.append(r)
        at += len(r)
    pool = np.concatenate(regions) if regions else np.zeros(0, dtype=np.int64)
    return has, bound, start, length, pool


def _packed(complex_: SurfaceComplex, tolerance: dict[int, float] | float) -> tuple:
    """The arguments the compiled loops share: geo, grid, quadric (a copy), faces, vertices with faces, the
    bounds (per fragment, one, which), the faces around each vertex, the points kept with each face, the
    clock of each face, the clock."""
    n, m = len(complex_.points), len(complex_.groups)
    geo = list(complex_.static)
    geo[6] = _mask(n, complex_.locked)
    damp = np.ones(n)
    if complex_.damp:
        damp[np.fromiter(complex_.damp.keys(), dtype=np.int64)] = np.fromiter(complex_.damp.values(), dtype=float)
    geo[7] = damp
    geo[11], geo[12] = np.zeros(n, dtype=np.int64), np.zeros(1, dtype=np.int64)  # scratch of the link checks
    per_fragment = isinstance(tolerance, dict)
    tol = (np.array([tolerance[k] for k in range(len(tolerance))], dtype=float) if isinstance(tolerance, dict)
           else np.zeros(1))
    scalar = 0.0 if isinstance(tolerance, dict) else float(tolerance)
    F, vf, vpool = _faces(complex_, m, n)
    asg, apool = _assigned(complex_, m)
    modified = np.zeros(m, dtype=np.int64)
    if complex_.modified:
        modified[np.fromiter(complex_.modified.keys(), dtype=np.int64)] = np.fromiter(complex_.modified.values(),
                                                                                        dtype=np.int64)
    grid = (complex_.reference, complex_._centroids, *complex_._grid, complex_._cell, complex_._candidates)
    return (tuple(geo), grid, complex_.quadric.copy(), F, _mask(n, complex_.vertex_faces.keys()), tol, scalar,
            per_fragment, vf, vpool, asg, apool, modified, complex_.clock)


def decimate(complex_: SurfaceComplex, tolerance: dict[int, float] | float, vertices: list[int] | None) -> int:
    """:meth:`.SurfaceComplex.decimate_python`, compiled; returns how many collapses were done."""
    n, m = len(complex_.points), len(complex_.groups)
    seeds = np.array(sorted(complex_.vertex_faces) if vertices is None else sorted(vertices), dtype=np.int64)
    packed = _packed(complex_, tolerance)
    collapses, refusals, clock = collapse_loop(*packed, _mask(m, complex_._changed), complex_._replayed,
                                               _earlier(complex_, n), seeds)
    _replay_onto(complex_, collapses, packed[2])
    _record_refusals(complex_, refusals)
    assert complex_.clock == clock
    return len(collapses[1])


def replay(complex_: SurfaceComplex, collapses: list[tuple[int, int, float, list[int], list[int]]],
           tolerance: dict[int, float] | float) -> None:
    """The collapses of :meth:`.SurfaceComplex.replay_python`, compiled (it sets the refusals and the clock)."""
    m = len(complex_.groups)
    at = np.cumsum([0] + [len(c[3]) for c in collapses]).astype(np.int64)
    earlier = (np.array([c[0] for c in collapses], dtype=np.int64), np.array([c[1] for c in collapses], dtype=np.int64),
               np.array([c[2] for c in collapses], dtype=float), at,
               np.array([p for c in collapses for p in c[3]], dtype=np.int64),
               np.array([t for c in collapses for t in c[4]], dtype=np.int64))
    changed = _mask(m, complex_._changed)
    packed = _packed(complex_, tolerance)
    made, clock = replay_loop(*packed, changed, earlier)
    complex_._changed = set(np.flatnonzero(changed).tolist())
    _replay_onto(complex_, made, packed[2])
    assert complex_.clock == clock


def _replay_onto(complex_: SurfaceComplex, collapses: tuple, quadric: np.ndarray) -> None:
    """Apply the loop's collapses (:func:`.collapse_loop.logged`) to the complex, as
    :meth:`.SurfaceComplex._apply` does, with the points and faces the loop chose; ``quadric``: the loop's."""

    log, bounds = collapses[0].tolist(), collapses[1].tolist()
    faces, vertex_faces, assigned, history = complex_.faces, complex_.vertex_faces, complex_.assigned, complex_.history
    modified, fault, done = complex_.modified, complex_.fault, complex_.done
    clock, at = complex_.clock, 0
    for bound in bounds:
        u, v, p, r, k = log[at:at + 5]
        at += 5
        points, nearest, removed, kept = (log[at:at + p], log[at + p:at + 2 * p], log[at + 2 * p:at + 2 * p + r],
                                          log[at + 2 * p + r:at + 2 * p + r + k])
        at += 2 * p + r + k
        touched = (u, tuple(h for t in removed if (h := history[t])))
        clock += 1
        for t in removed:
            modified[t] = clock
            for x in faces.pop(t):
                vertex_faces[x].discard(t)
            del assigned[t], history[t]
        for t in kept:
            modified[t] = clock
            a, b, c = faces[t]
            faces[t] = (v if a == u else a, v if b == u else b, v if c == u else c)
            history[t] = merged(history[t], touched)
            if fault[t]:
                assigned[t] = []
        for point, t in zip(points, nearest):
            assigned[t].append(point)
        vertex_faces[v].update(kept)
        del vertex_faces[u]
        done.append((u, v, bound, points, nearest))
    complex_.clock = clock
    complex_.quadric = quadric


def _record_refusals(complex_: SurfaceComplex, refusals: tuple) -> None:
    """Each vertex's last refusal in the loop, as :attr:`.SurfaceComplex.refused` keeps it."""
    clock, bound, start, length, pool = refusals
    for u in np.flatnonzero(clock >= 0).tolist():
        region = pool[start[u]:start[u] + length[u]].tolist()
        complex_.refused[u] = (int(clock[u]), float(bound[u]), frozenset(region))
