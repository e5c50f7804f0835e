""":meth:`.decimate.SurfaceComplex.replay`, compiled (numba), on the arrays of :mod:`.collapse_loop`.

A retry redoes the collapses of the try before it, each only where still
allowed: those whose surroundings are as they were are applied without a check,
the others checked as :func:`.collapse_loop.collapse_loop` checks a collapse.
Same order, same tests as the Python method, so the same collapses.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.stages.simplify.collapse_loop import (
    apply_collapse,
    collapse_bound,
    collapse_context,
    fan_of,
    grown,
    has_key,
    logged,
    try_collapse,
)
from fracture_cli.system.jit import njit


@njit(cache=True)
def _mark_changed(F: np.ndarray, vf: tuple, vpool: np.ndarray, vkey: np.ndarray, u: int, v: int, faces: np.ndarray,
                  vertices: np.ndarray) -> None:  # pragma: no cover (compiled)
    """:meth:`.SurfaceComplex._mark_changed`: the faces around ``u`` and ``v`` and their corners."""
    for x in (u, v):
        if vkey[x]:
            for t in fan_of(vf, vpool, x):
                faces[t] = True
                for y in F[t]:
                    vertices[y] = True
    vertices[u] = vertices[v] = True


@njit(cache=True)
def _any(mask: np.ndarray, items: np.ndarray) -> bool:  # pragma: no cover (compiled)
    for t in items:
        if mask[t]:
            return True
    return False


@njit(cache=True)
def replay_loop(geo: tuple, grid: tuple, quadric: np.ndarray, F: np.ndarray, vkey: np.ndarray, tol: np.ndarray,
                scalar: float, per_fragment: bool, vf: tuple, vpool: np.ndarray, asg: tuple, apool: np.ndarray,
                modified: np.ndarray, clock: int, changed: np.ndarray, earlier: tuple) -> tuple:  # pragma: no cover
    """Redo the collapses ``earlier`` (u, v, bound, offsets (c + 1,), points, nearest faces) where allowed.

    ``changed`` (m,) bool, the faces where the tries part, is updated. Returns the collapses made, as
    :func:`.collapse_loop.collapse_loop` does, and the clock.
    """
    locked, damp = geo[6], geo[7]
    e_u, e_v, e_bound, e_at, e_points, e_nearest = earlier
    vtop, atop = len(vpool), len(apool)
    vpool, apool = grown(vpool, vtop, vtop + 16), grown(apool, atop, atop + 16)
    changed_vertices = np.zeros(len(vkey), dtype=np.bool_)
    log, ltop, bounds = np.empty(4096, dtype=np.int64), 0, [0.0]
    for i in range(len(e_u)):
        u, v, was = e_u[i], e_v[i], e_bound[i]
        if locked[u] or not vkey[u] or not vkey[v]:
            _mark_changed(F, vf, vpool, vkey, u, v, changed, changed_vertices)
            continue
        fan, v_fan = fan_of(vf, vpool, u), fan_of(vf, vpool, v)
        ctx = collapse_context(geo, F, fan)
        # (Python's max() of no fragments raises: an isolated vertex under per-fragment bounds; never seen.)
        bound = collapse_bound(damp, tol, scalar, per_fragment, u, ctx[1]) if len(fan) or not per_fragment else np.nan
        if (bound == was and not changed_vertices[u] and not changed_vertices[v] and not _any(changed, fan)
                and not _any(changed, v_fan)):
            keep = np.zeros(len(fan), dtype=np.bool_)
            for j in range(len(fan)):
                keep[j] = has_key(v_fan, fan[j])
            removed, kept = fan[keep], np.sort(fan[~keep])
            points, nearest = e_points[e_at[i]:e_at[i + 1]], e_nearest[e_at[i]:e_at[i + 1]]
        else:
            _mark_changed(F, vf, vpool, vkey, u, v, changed, changed_vertices)
            ok, removed, kept, points, nearest = try_collapse(geo, grid, F, vf, vpool, asg, apool, u, v, bound, fan,
                                                              ctx)
            if not ok:
                continue
        clock += 1
        vpool, vtop, apool, atop = apply_collapse(F, quadric, geo[5], vkey, modified, clock, vf, vpool, vtop, asg,
                                                  apool, atop, u, v, removed, kept, points, nearest)
        log, ltop = logged(log, ltop, u, v, points, nearest, removed, kept)
        bounds.append(bound)
    collapses = (log[:ltop].copy(), np.array(bounds[1:]))
    return collapses, clock
