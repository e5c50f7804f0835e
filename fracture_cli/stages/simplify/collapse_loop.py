"""The collapse loop of :meth:`.decimate.SurfaceComplex.decimate`, compiled (numba).

Python's sets and dicts cost most of a collapse once its arithmetic was compiled
(:mod:`.collapse_kernels`): here the whole loop (queue, fan, link and polygon
checks, turn and error bounds, the collapse itself) runs on arrays, in the order
the Python loop takes, with its tie-breaks, so it makes the same collapses and
refusals (tests/test_simplify_kernels.py runs both). :mod:`.collapse_pack` packs a
complex into these arrays and replays what the loop did on the complex.

Lists that grow (the faces around a vertex, the removed points kept with a face)
live in one pool each: item ``x`` is ``pool[start[x]:start[x] + length[x]]`` with
room for ``cap[x]``; a full list moves to the pool's end with twice the room.
Orders inside such a list differ from Python's set orders; nothing that decides
a collapse depends on them (sets compare as sorted arrays, candidates are sorted).

Squares are ``x * x`` with ``two`` = 2.0 passed at run time: CPython's
``x ** 2`` calls the C library's ``pow``, which rounds differently from ``x * x``
about once in a thousand, and a constant 2.0 would let LLVM turn the call into a
product.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.stages.simplify.collapse_kernels import fault_bound, quadric_costs
from fracture_cli.system.jit import njit


@njit(cache=True)
def grown(pool: np.ndarray, top: int, need: int) -> np.ndarray:  # pragma: no cover (compiled)
    """``pool`` with room for ``need`` more items after ``top`` (a larger copy when it has none)."""
    if top + need <= len(pool):
        return pool
    new = np.empty(max(2 * len(pool), top + need), dtype=pool.dtype)
    new[:top] = pool[:top]
    return new


@njit(cache=True)
def append(pool: np.ndarray, top: int, start: np.ndarray, length: np.ndarray, cap: np.ndarray, x: int,
           value: float) -> tuple:  # pragma: no cover (compiled)
    """Append ``value`` to list ``x`` of ``pool`` (moved to the end when full); the pool and its new top."""
    if length[x] == cap[x]:
        room = max(4, 2 * cap[x])
        pool = grown(pool, top, room)
        pool[top:top + length[x]] = pool[start[x]:start[x] + length[x]]
        start[x], cap[x] = top, room
        top += room
    pool[start[x] + length[x]] = value
    length[x] += 1
    return pool, top


@njit(cache=True)
def _discard(pool: np.ndarray, start: np.ndarray, length: np.ndarray, x: int,
             value: int) -> None:  # pragma: no cover (compiled)
    """Remove ``value`` from list ``x`` (last item moved into its place), if there."""
    s, n = start[x], length[x]
    for i in range(s, s + n):
        if pool[i] == value:
            pool[i] = pool[s + n - 1]
            length[x] = n - 1
            return


@njit(cache=True)
def has_key(items: np.ndarray, value: int) -> bool:  # pragma: no cover (compiled)
    for i in range(len(items)):
        if items[i] == value:
            return True
    return False


@njit(cache=True)
def _same(a: np.ndarray, b: np.ndarray) -> bool:  # pragma: no cover (compiled)
    """Whether two sorted arrays hold the same items."""
    return len(a) == len(b) and bool(np.all(a == b))


@njit(cache=True)
def _before(c1: float, u1: int, s1: int, c2: float, u2: int, s2: int) -> bool:  # pragma: no cover (compiled)
    """Whether (c1, u1, s1) < (c2, u2, s2) as Python compares tuples."""
    return c1 < c2 if c1 != c2 else u1 < u2 if u1 != u2 else s1 < s2


@njit(cache=True)
def _heap_push(heap: tuple, size: int, cost: float, u: int, stamp: int) -> tuple:  # pragma: no cover (compiled)
    """Push (cost, u, stamp) on the binary heap ``heap`` (costs, vertices, stamps) of ``size`` entries."""
    hc, hu, hs = heap
    if size == len(hc):
        hc, hu, hs = grown(hc, size, 1), grown(hu, size, 1), grown(hs, size, 1)
    i = size
    while i > 0:
        p = (i - 1) // 2
        if not _before(cost, u, stamp, hc[p], hu[p], hs[p]):
            break
        hc[i], hu[i], hs[i] = hc[p], hu[p], hs[p]
        i = p
    hc[i], hu[i], hs[i] = cost, u, stamp
    return (hc, hu, hs), size + 1


@njit(cache=True)
def _heap_pop(heap: tuple, size: int) -> tuple:  # pragma: no cover (compiled)
    """Remove the least (cost, u, stamp) of ``heap``; it and the new size."""
    hc, hu, hs = heap
    cost, u, stamp = hc[0], hu[0], hs[0]
    size -= 1
    lc, lu, ls = hc[size], hu[size], hs[size]
    i = 0
    while True:
        c = 2 * i + 1
        if c >= size:
            break
        if c + 1 < size and _before(hc[c + 1], hu[c + 1], hs[c + 1], hc[c], hu[c], hs[c]):
            c += 1
        if not _before(hc[c], hu[c], hs[c], lc, lu, ls):
            break
        hc[i], hu[i], hs[i] = hc[c], hu[c], hs[c]
        i = c
    if size > 0:
        hc[i], hu[i], hs[i] = lc, lu, ls
    return cost, u, stamp, size


@njit(cache=True)
def turns_little(P: np.ndarray, old: np.ndarray, new: np.ndarray, limit: float,
                 min_shape: float) -> bool:  # pragma: no cover (compiled)
    """:func:`.decimate_faces.turns_little` on arrays: the same operations in the same order."""
    ax, ay, az = P[old[0], 0], P[old[0], 1], P[old[0], 2]
    bx, by, bz = P[old[1], 0], P[old[1], 1], P[old[1], 2]
    cx, cy, cz = P[old[2], 0], P[old[2], 1], P[old[2], 2]
    ux, uy, uz, vx, vy, vz = bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az
    ox, oy, oz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    ax, ay, az = P[new[0], 0], P[new[0], 1], P[new[0], 2]
    bx, by, bz = P[new[1], 0], P[new[1], 1], P[new[1], 2]
    cx, cy, cz = P[new[2], 0], P[new[2], 1], P[new[2], 2]
    ux, uy, uz, vx, vy, vz = bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    length2 = nx * nx + ny * ny + nz * nz
    e0 = (ax - bx) * (ax - bx) + (ay - by) * (ay - by) + (az - bz) * (az - bz)
    e1 = (bx - cx) * (bx - cx) + (by - cy) * (by - cy) + (bz - cz) * (bz - cz)
    e2 = (cx - ax) * (cx - ax) + (cy - ay) * (cy - ay) + (cz - az) * (cz - az)
    longest = e0
    if e1 > longest:
        longest = e1
    if e2 > longest:
        longest = e2
    if length2 == 0.0 or length2 <= (min_shape * longest) * (min_shape * longest):
        return False
    dot = ox * nx + oy * ny + oz * nz
    old2 = ox * ox + oy * oy + oz * oz
    return dot > 0 and dot * dot >= limit * limit * old2 * length2


@njit(cache=True)
def neighbours(F: np.ndarray, fan: np.ndarray, u: int, mark: np.ndarray,
               epoch: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    """Sorted corners of the faces ``fan`` around ``u``, other than ``u`` (``mark``, ``epoch``: see :func:`_link`)."""
    epoch[0] += 1
    e = epoch[0]
    mark[u] = e
    out = np.empty(3 * len(fan), dtype=np.int64)
    count = 0
    for t in fan:
        for x in F[t]:
            if mark[x] != e:
                mark[x] = e
                out[count] = x
                count += 1
    return np.sort(out[:count])


@njit(cache=True)
def fan_of(vf: tuple, vpool: np.ndarray, x: int) -> np.ndarray:  # pragma: no cover (compiled)
    """The faces around vertex ``x`` (a view: valid until the next collapse)."""
    start, length = vf[0], vf[1]
    return vpool[start[x]:start[x] + length[x]]


@njit(cache=True)
def _region(F: np.ndarray, vf: tuple, vpool: np.ndarray, u: int,
            targets: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    """Sorted faces around ``u`` and around each of ``targets`` (:meth:`.SurfaceComplex._region`)."""
    parts = [fan_of(vf, vpool, u)]
    for v in targets:
        parts.append(fan_of(vf, vpool, v))
    total = 0
    for part in parts:
        total += len(part)
    out = np.empty(total, dtype=np.int64)
    at = 0
    for part in parts:
        out[at:at + len(part)] = part
        at += len(part)
    return np.unique(out)


@njit(cache=True)
def _link(F: np.ndarray, own: np.ndarray, fan: np.ndarray, v_fan: np.ndarray, removed: np.ndarray, u: int, v: int,
          k: int, mark: np.ndarray, epoch: np.ndarray) -> bool:  # pragma: no cover (compiled)
    """The link condition of the collapse of ``u`` into ``v`` in fragment ``k`` (-1: over every face): the edge
    has two faces there, and the corners the faces around ``u`` and ``v`` share are the far corners of those
    two. Sets are stamps in ``mark`` (n,) (``epoch`` (1,): the last stamp), to allocate nothing."""
    o0, o1, count = -1, -1, 0
    for t in removed:
        if k >= 0 and own[t, 0] != k and own[t, 1] != k:
            continue
        count += 1
        for x in F[t]:
            if x != u and x != v and x != o0 and x != o1:
                if o0 < 0:
                    o0 = x
                else:
                    o1 = x  # (two faces with u and v: at most two far corners)
    if count != 2:
        return False
    epoch[0] += 1
    first = epoch[0]
    for t in fan:
        if k < 0 or own[t, 0] == k or own[t, 1] == k:
            for x in F[t]:
                mark[x] = first
    epoch[0] += 1
    shared = epoch[0]
    found = 0
    for t in v_fan:
        if k < 0 or own[t, 0] == k or own[t, 1] == k:
            for x in F[t]:
                if x != u and x != v and mark[x] == first:
                    mark[x] = shared
                    found += 1
    if found != (o0 >= 0) + (o1 >= 0):
        return False
    return (o0 < 0 or mark[o0] == shared) and (o1 < 0 or mark[o1] == shared)


@njit(cache=True)
def _topology(F: np.ndarray, own: np.ndarray, fan: np.ndarray, v_fan: np.ndarray, removed: np.ndarray, u: int,
              v: int, fragments: np.ndarray, single: bool, mark: np.ndarray,
              epoch: np.ndarray) -> bool:  # pragma: no cover (compiled)
    """The link conditions of :meth:`.SurfaceComplex._allowed` (``single``: every face of ``fan`` bounds the same
    fragments): over every face when those of ``v_fan`` bound them too, else in each fragment of both."""
    if single:
        t0 = fan[0]
        for t in v_fan:
            if own[t, 0] != own[t0, 0] or own[t, 1] != own[t0, 1]:
                single = False
                break
    if single:
        return _link(F, own, fan, v_fan, removed, u, v, -1, mark, epoch)
    for k in fragments:
        both = False
        for t in v_fan:
            both = both or own[t, 0] == k or own[t, 1] == k
        if both and not _link(F, own, fan, v_fan, removed, u, v, k, mark, epoch):
            return False  # link condition in fragment k: the collapse would pinch its surface
    return True


@njit(cache=True)
def _points(asg: tuple, apool: np.ndarray, fan: np.ndarray, u: int) -> np.ndarray:  # pragma: no cover (compiled)
    """``u`` and the removed points kept with the faces ``fan``."""
    start, length = asg[0], asg[1]
    total = 1
    for t in fan:
        total += length[t]
    out = np.empty(total, dtype=np.int64)
    out[0] = u
    at = 1
    for t in fan:
        out[at:at + length[t]] = apool[start[t]:start[t] + length[t]]
        at += length[t]
    return out


@njit(cache=True)
def _moved(f: np.ndarray, u: int, v: int) -> np.ndarray:  # pragma: no cover (compiled)
    g = f.copy()
    for i in range(3):
        if g[i] == u:
            g[i] = v
    return g


@njit(cache=True)
def try_collapse(geo: tuple, grid: tuple, F: np.ndarray, vf: tuple, vpool: np.ndarray, asg: tuple, apool: np.ndarray,
         u: int, v: int, bound: float, fan: np.ndarray, ctx: tuple) -> tuple:  # pragma: no cover (compiled)
    """:meth:`.SurfaceComplex._collapse` up to its apply: (allowed, removed, kept (ascending), points, nearest
    faces). Its tests in another order, cheapest first: a collapse is made only when all of them pass."""
    P, groups, own, fault, min_shape = geo[0], geo[3], geo[4], geo[5], geo[10]
    polygons, fragments, single, limit, on_fault = ctx
    empty = fan[:0]
    v_fan = fan_of(vf, vpool, v)
    inside = np.empty(len(fan), dtype=np.bool_)
    for i in range(len(fan)):
        inside[i] = has_key(v_fan, fan[i])
    removed = fan[inside]
    for p in polygons:
        on = False
        for t in removed:
            on = on or groups[t] == p
        if not on:
            return False, empty, empty, empty, empty  # v is not on every input polygon u is on
    kept = np.sort(fan[~inside])
    new = np.empty((len(kept), 3), dtype=np.int64)
    for i in range(len(kept)):
        for j in range(3):
            x = F[kept[i], j]
            new[i, j] = v if x == u else x
        if not turns_little(P, F[kept[i]], new[i], limit, min_shape):
            return False, empty, empty, empty, empty
    if not _topology(F, own, fan, v_fan, removed, u, v, fragments, single, geo[11], geo[12]):
        return False, empty, empty, empty, empty
    if not on_fault:
        return True, removed, kept, empty, empty
    on = fault[kept]
    if not np.any(on):
        return False, empty, empty, empty, empty
    points = _points(asg, apool, fan, u)
    reference, centroids, origin, dims, starts, order, cell, k = grid
    found = fault_bound(geo[1], points, new[on], reference, centroids, origin, dims, starts, order, cell, k, bound)
    if len(found) == 0:
        return False, empty, empty, empty, empty
    return True, removed, kept, points, kept[on][found]


@njit(cache=True)
def apply_collapse(F: np.ndarray, quadric: np.ndarray, fault: np.ndarray, vkey: np.ndarray, modified: np.ndarray,
           clock: int, vf: tuple, vpool: np.ndarray, vtop: int, asg: tuple, apool: np.ndarray, atop: int, u: int,
           v: int, removed: np.ndarray, kept: np.ndarray, points: np.ndarray,
           nearest: np.ndarray) -> tuple:  # pragma: no cover (compiled)
    """:meth:`.SurfaceComplex._apply` on the arrays; the pools and their tops."""
    for t in removed:
        modified[t] = clock
        for x in F[t]:
            _discard(vpool, vf[0], vf[1], x, t)
        asg[1][t] = 0
    for t in kept:
        modified[t] = clock
        F[t] = _moved(F[t], u, v)
        if fault[t]:
            asg[1][t] = 0
    for i in range(len(points)):
        apool, atop = append(apool, atop, asg[0], asg[1], asg[2], nearest[i], points[i])
    for t in kept:
        vpool, vtop = append(vpool, vtop, vf[0], vf[1], vf[2], v, t)
    vkey[u] = False
    vf[1][u] = 0
    quadric[v] = quadric[v] + quadric[u]
    return vpool, vtop, apool, atop


@njit(cache=True)
def _distinct(values: np.ndarray, skip: int) -> np.ndarray:  # pragma: no cover (compiled)
    """The distinct ``values`` other than ``skip``, first seen first (a few: quadratic is fine)."""
    out = np.empty(len(values), dtype=np.int64)
    count = 0
    for x in values:
        if x != skip and not has_key(out[:count], x):
            out[count] = x
            count += 1
    return out[:count]


@njit(cache=True)
def logged(log: np.ndarray, top: int, u: int, v: int, points: np.ndarray, nearest: np.ndarray, removed: np.ndarray,
           kept: np.ndarray) -> tuple:  # pragma: no cover (compiled)
    """Append a collapse to ``log`` at ``top``: u, v, the counts of points, removed and kept faces, then those
    points, their nearest faces, the removed and the kept faces. The log and its new top."""
    log = grown(log, top, 5 + 2 * len(points) + len(removed) + len(kept))
    log[top], log[top + 1], log[top + 2], log[top + 3], log[top + 4] = u, v, len(points), len(removed), len(kept)
    at = top + 5
    for part in (points, nearest, removed, kept):
        log[at:at + len(part)] = part
        at += len(part)
    return log, at


@njit(cache=True)
def collapse_context(geo: tuple, F: np.ndarray, fan: np.ndarray) -> tuple:  # pragma: no cover (compiled)
    """:meth:`.SurfaceComplex._fan` of a vertex with faces ``fan``: (polygons, fragments, single, limit, on_fault);
    polygons and fragments in no order (they are only looked up and maxed)."""
    groups, own, fault = geo[3], geo[4], geo[5]
    polygons = _distinct(groups[fan], -1)
    fragments = _distinct(own[fan].ravel(), -1)
    single = len(fan) > 0
    outer = False
    on_fault = False
    for t in fan:
        single = single and own[t, 0] == own[fan[0], 0] and own[t, 1] == own[fan[0], 1]
        outer = outer or not fault[t]
        on_fault = on_fault or fault[t]
    return polygons, fragments, single, geo[9] if outer else geo[8], on_fault


@njit(cache=True)
def collapse_bound(damp: np.ndarray, tol: np.ndarray, scalar: float, per_fragment: bool, u: int,
           fragments: np.ndarray) -> float:  # pragma: no cover (compiled)
    """:meth:`.SurfaceComplex._tolerance` of ``u``."""
    if not per_fragment:
        return scalar * damp[u]
    best = tol[fragments[0]]
    for k in fragments:
        if tol[k] > best:
            best = tol[k]
    return damp[u] * best


@njit(cache=True)
def collapse_loop(geo: tuple, grid: tuple, quadric: np.ndarray, F: np.ndarray, vkey: np.ndarray, tol: np.ndarray,
                  scalar: float, per_fragment: bool, vf: tuple, vpool: np.ndarray, asg: tuple, apool: np.ndarray,
                  modified: np.ndarray, clock: int, changed: np.ndarray, replayed: int, earlier: tuple,
                  seeds: np.ndarray) -> tuple:  # pragma: no cover (compiled)
    """:meth:`.SurfaceComplex.decimate` on arrays (see :mod:`.collapse_pack` for what each holds).

    Returns
    -------
    collapses : tuple
        The collapses made, in order: their :func:`logged` records, and their bounds (c,).
    refusals : tuple
        Per vertex its last refusal here: (clock (n,), -1 for none; bound (n,); region start (n,), length (n,),
        pool).
    clock : int
    """
    H, locked, damp = geo[2], geo[6], geo[7]
    n = len(vkey)
    vtop, atop = len(vpool), len(apool)
    vpool, apool = grown(vpool, vtop, vtop + 16), grown(apool, atop, atop + 16)
    stamp = np.zeros(n, dtype=np.int64)
    q_start, q_len = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    qpool, qcost, qtop = np.empty(1024, dtype=np.int64), np.empty(1024), 0
    heap = (np.empty(1024), np.empty(1024, dtype=np.int64), np.empty(1024, dtype=np.int64))
    size = 0
    log, ltop, bounds = np.empty(4096, dtype=np.int64), 0, [0.0]
    ref_clock, ref_bound = np.full(n, -1, dtype=np.int64), np.zeros(n)
    ref_start, ref_len, refpool, rtop = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64), np.empty(
        1024, dtype=np.int64), 0
    rf_has, rf_bound, rf_start, rf_len, rfpool = earlier
    pending = seeds
    while True:
        for w in pending:  # queue each at the cost of its cheapest collapse (:meth:`.SurfaceComplex._push`)
            if locked[w] or not vkey[w]:
                continue
            stamp[w] += 1
            targets = neighbours(F, fan_of(vf, vpool, w), w, geo[11], geo[12])
            costs = quadric_costs(H, quadric, w, targets)
            qpool, qcost = grown(qpool, qtop, len(targets)), grown(qcost, qtop, len(targets))
            qpool[qtop:qtop + len(targets)] = targets
            qcost[qtop:qtop + len(targets)] = costs
            q_start[w], q_len[w] = qtop, len(targets)
            qtop += len(targets)
            if len(costs):
                heap, size = _heap_push(heap, size, costs.min(), w, stamp[w])
        if size == 0:
            break
        _, u, s, size = _heap_pop(heap, size)
        pending = np.empty(0, dtype=np.int64)
        if stamp[u] != s or not vkey[u]:
            continue
        fan = fan_of(vf, vpool, u)
        ctx = collapse_context(geo, F, fan)
        bound = collapse_bound(damp, tol, scalar, per_fragment, u, ctx[1])
        queued = qpool[q_start[u]:q_start[u] + q_len[u]]
        targets = queued[np.argsort(qcost[q_start[u]:q_start[u] + q_len[u]], kind="mergesort")]
        region = np.empty(0, dtype=np.int64)
        if rf_has[u]:
            region = _region(F, vf, vpool, u, targets)
            earlier_region = rfpool[rf_start[u]:rf_start[u] + rf_len[u]]
            if (rf_bound[u] == bound and _same(earlier_region, region) and not np.any(changed[region])
                    and np.all(modified[region] <= replayed)):
                continue  # as refused in the earlier try: same faces, same tolerance
        done = False
        for v in targets:
            ok, removed, kept, points, nearest = try_collapse(geo, grid, F, vf, vpool, asg, apool, u, v, bound, fan,
                                                              ctx)
            if not ok:
                continue
            clock += 1
            vpool, vtop, apool, atop = apply_collapse(F, quadric, geo[5], vkey, modified, clock, vf, vpool, vtop, asg,
                                              apool, atop, u, v, removed, kept, points, nearest)
            log, ltop = logged(log, ltop, u, v, points, nearest, removed, kept)
            bounds.append(bound)
            near = neighbours(F, fan_of(vf, vpool, v), v, geo[11], geo[12])
            pending = np.unique(np.append(near, v))
            done = True
            break
        if not done:
            if not rf_has[u]:
                region = _region(F, vf, vpool, u, targets)
            refpool = grown(refpool, rtop, len(region))
            refpool[rtop:rtop + len(region)] = region
            ref_clock[u], ref_bound[u], ref_start[u], ref_len[u] = clock, bound, rtop, len(region)
            rtop += len(region)
    collapses = (log[:ltop].copy(), np.array(bounds[1:]))
    return collapses, (ref_clock, ref_bound, ref_start, ref_len, refpool[:rtop].copy()), clock
