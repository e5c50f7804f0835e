"""The compiled (numba) kernels of :mod:`fracture_cli.geometry.surface_query`: its hierarchy, distances and ray casts.

Every kernel works on one point or one ray per loop iteration, in float64,
with only ``+ - * /``, comparisons and ``sqrt``; no fastmath. The rules they
follow (the split rule, the per-triangle tests, the sign of an edge function
that is exactly zero) are stated in :mod:`fracture_cli.geometry.surface_query`.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.system.jit import njit


@njit(error_model="numpy")
def _area(lo: np.ndarray, hi: np.ndarray) -> float:  # pragma: no cover (compiled)
    """Half the surface area of the box ``lo``-``hi`` (3,) (0 for an empty one)."""
    dx, dy, dz = hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]
    if dx < 0.0:
        return 0.0
    return dx * dy + dy * dz + dz * dx


@njit(error_model="numpy")
def sah_tree(corners: np.ndarray, leaf_size: int, bins: int, max_level: int):  # pragma: no cover (compiled)
    """Leaf order (m,) of the triangles and the nodes (right, start, count, depth): binned SAH splits.

    A node of more than ``leaf_size`` triangles is split along the longest axis of its triangles' box
    centres, into ``bins`` equal bins, between the two bins that minimize the surface-area cost (the
    first such place); with all centres equal, or from level ``max_level`` on, in the middle of its range.
    """
    m = corners.shape[0]
    tlo = np.empty((m, 3))
    thi = np.empty((m, 3))
    centre = np.empty((m, 3))
    for t in range(m):
        for k in range(3):
            tlo[t, k] = min(corners[t, 0, k], corners[t, 1, k], corners[t, 2, k])
            thi[t, k] = max(corners[t, 0, k], corners[t, 1, k], corners[t, 2, k])
            centre[t, k] = 0.5 * tlo[t, k] + 0.5 * thi[t, k]
    order = np.arange(m)
    cap = 2 * m
    right = np.full(cap, -1, dtype=np.int64)
    start = np.zeros(cap, dtype=np.int64)
    count = np.zeros(cap, dtype=np.int64)
    bin_count = np.zeros(bins, dtype=np.int64)
    bin_lo = np.empty((bins, 3))
    bin_hi = np.empty((bins, 3))
    right_area = np.empty(bins)
    right_count = np.zeros(bins, dtype=np.int64)
    lo, hi = np.empty(3), np.empty(3)
    # Pending ranges: (first, end, parent, is right child, level). A range is numbered when taken, and the left
    # one is taken right after its parent: preorder. At most one range waits per level.
    pending = np.empty((max_level + 72, 5), dtype=np.int64)
    pending[0, 0], pending[0, 1], pending[0, 2], pending[0, 3], pending[0, 4] = 0, m, -1, 0, 1
    top = 1
    n = 0
    depth = 1
    while top > 0:
        top -= 1
        s, e, parent, is_right, level = pending[top, 0], pending[top, 1], pending[top, 2], pending[top, 3], \
            pending[top, 4]
        node = n
        n += 1
        depth = max(depth, level)
        if is_right:
            right[parent] = node
        if e - s <= leaf_size:
            start[node] = s
            count[node] = e - s
            continue
        # The longest axis of the centres.
        axis, extent, low = 0, -1.0, 0.0
        for k in range(3):
            c0, c1 = np.inf, -np.inf
            for i in range(s, e):
                c0 = min(c0, centre[order[i], k])
                c1 = max(c1, centre[order[i], k])
            if c1 - c0 > extent:
                axis, extent, low = k, c1 - c0, c0
        split = (s + e) // 2
        if extent > 0.0 and level < max_level:
            scale = bins * (1.0 - tol.TIE) / extent
            bin_count[:] = 0
            bin_lo[:] = np.inf
            bin_hi[:] = -np.inf
            for i in range(s, e):
                t = order[i]
                b = min(int((centre[t, axis] - low) * scale), bins - 1)
                bin_count[b] += 1
                for k in range(3):
                    bin_lo[b, k] = min(bin_lo[b, k], tlo[t, k])
                    bin_hi[b, k] = max(bin_hi[b, k], thi[t, k])
            # Sweep from the right: area and count of bins b.. ; then from the left, the cost of each place.
            lo[:] = np.inf
            hi[:] = -np.inf
            total = 0
            for b in range(bins - 1, 0, -1):
                for k in range(3):
                    lo[k] = min(lo[k], bin_lo[b, k])
                    hi[k] = max(hi[k], bin_hi[b, k])
                total += bin_count[b]
                right_area[b] = _area(lo, hi)
                right_count[b] = total
            lo[:] = np.inf
            hi[:] = -np.inf
            total = 0
            best_cost, best_bin = np.inf, -1
            for b in range(bins - 1):
                for k in range(3):
                    lo[k] = min(lo[k], bin_lo[b, k])
                    hi[k] = max(hi[k], bin_hi[b, k])
                total += bin_count[b]
                if total == 0 or right_count[b + 1] == 0:
                    continue
                cost = _area(lo, hi) * total + right_area[b + 1] * right_count[b + 1]
                if cost < best_cost:
                    best_cost, best_bin = cost, b
            if best_bin >= 0:
                # Partition the range in place: bins up to best_bin first.
                i, j = s, e - 1
                while i <= j:
                    if min(int((centre[order[i], axis] - low) * scale), bins - 1) <= best_bin:
                        i += 1
                    else:
                        order[i], order[j] = order[j], order[i]
                        j -= 1
                split = i
        pending[top, 0], pending[top, 1], pending[top, 2], pending[top, 3], pending[top, 4] = \
            split, e, node, 1, level + 1
        pending[top + 1, 0], pending[top + 1, 1], pending[top + 1, 2], pending[top + 1, 3], pending[top + 1, 4] = \
            s, split, node, 0, level + 1
        top += 2
    return order, right[:n].copy(), start[:n].copy(), count[:n].copy(), depth


@njit(error_model="numpy")
def node_boxes(corners: np.ndarray, right: np.ndarray, start: np.ndarray, count: np.ndarray,
           margin: float) -> np.ndarray:  # pragma: no cover (compiled)
    """Widened boxes (n, 2, 3) of the nodes, children before parents (preorder numbers them after)."""
    n = right.shape[0]
    box = np.empty((n, 2, 3))
    for node in range(n - 1, -1, -1):
        for k in range(3):
            if right[node] < 0:
                lo = np.inf
                hi = -np.inf
                for t in range(start[node], start[node] + count[node]):
                    for c in range(3):
                        lo = min(lo, corners[t, c, k])
                        hi = max(hi, corners[t, c, k])
            else:
                lo = min(box[node + 1, 0, k], box[right[node], 0, k])
                hi = max(box[node + 1, 1, k], box[right[node], 1, k])
            box[node, 0, k] = lo
            box[node, 1, k] = hi
    for node in range(n):
        for k in range(3):
            box[node, 0, k] -= margin
            box[node, 1, k] += margin
    return box


@njit(error_model="numpy", inline="always")
def _segment_d2(px, py, pz, ax, ay, az, bx, by, bz) -> float:  # pragma: no cover (compiled)
    """Squared distance from p to the segment a-b (a point when a = b)."""
    ex, ey, ez = bx - ax, by - ay, bz - az
    dx, dy, dz = px - ax, py - ay, pz - az
    along = dx * ex + dy * ey + dz * ez
    length2 = ex * ex + ey * ey + ez * ez
    if along <= 0.0 or length2 == 0.0:
        return dx * dx + dy * dy + dz * dz
    if along >= length2:
        fx, fy, fz = px - bx, py - by, pz - bz
        return fx * fx + fy * fy + fz * fz
    t = along / length2
    dx -= t * ex
    dy -= t * ey
    dz -= t * ez
    return dx * dx + dy * dy + dz * dz


@njit(error_model="numpy")
def _triangle_d2(corners: np.ndarray, t: int, px: float, py: float, pz: float) -> float:  # pragma: no cover
    """Squared distance from p to triangle ``t`` of ``corners``."""
    ax, ay, az = corners[t, 0, 0], corners[t, 0, 1], corners[t, 0, 2]
    bx, by, bz = corners[t, 1, 0], corners[t, 1, 1], corners[t, 1, 2]
    cx, cy, cz = corners[t, 2, 0], corners[t, 2, 1], corners[t, 2, 2]
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    nx = aby * acz - abz * acy
    ny = abz * acx - abx * acz
    nz = abx * acy - aby * acx
    nn = nx * nx + ny * ny + nz * nz
    apx, apy, apz = px - ax, py - ay, pz - az
    if nn > 0.0:
        # p projects inside the triangle when it is strictly on the inner side of all three edges (on an edge
        # or corner the segments below give 0 exactly where the plane distance would give rounding).
        bcx, bcy, bcz = cx - bx, cy - by, cz - bz
        cax, cay, caz = ax - cx, ay - cy, az - cz
        bpx, bpy, bpz = px - bx, py - by, pz - bz
        cpx, cpy, cpz = px - cx, py - cy, pz - cz
        s_ab = (aby * apz - abz * apy) * nx + (abz * apx - abx * apz) * ny + (abx * apy - aby * apx) * nz
        s_bc = (bcy * bpz - bcz * bpy) * nx + (bcz * bpx - bcx * bpz) * ny + (bcx * bpy - bcy * bpx) * nz
        s_ca = (cay * cpz - caz * cpy) * nx + (caz * cpx - cax * cpz) * ny + (cax * cpy - cay * cpx) * nz
        if s_ab > 0.0 and s_bc > 0.0 and s_ca > 0.0:
            h = apx * nx + apy * ny + apz * nz
            return h * h / nn
    # Otherwise the nearest point is on the boundary (and a degenerate triangle is only its edges).
    d2 = _segment_d2(px, py, pz, ax, ay, az, bx, by, bz)
    d2 = min(d2, _segment_d2(px, py, pz, bx, by, bz, cx, cy, cz))
    return min(d2, _segment_d2(px, py, pz, cx, cy, cz, ax, ay, az))


@njit(error_model="numpy", inline="always")
def _box_d2(box: np.ndarray, node: int, px: float, py: float, pz: float) -> float:  # pragma: no cover
    gx = max(box[node, 0, 0] - px, px - box[node, 1, 0], 0.0)
    gy = max(box[node, 0, 1] - py, py - box[node, 1, 1], 0.0)
    gz = max(box[node, 0, 2] - pz, pz - box[node, 1, 2], 0.0)
    return gx * gx + gy * gy + gz * gz


@njit(error_model="numpy")
def closest_d2(corners, box, right, start, count, depth, points, bound2):  # pragma: no cover (compiled)
    """Smallest squared distance (k,) of each point to a triangle, if at most ``bound2`` (k,), else inf."""
    k = points.shape[0]
    out = np.empty(k)
    stack = np.empty(depth + 1, dtype=np.int64)
    stack_d2 = np.empty(depth + 1)
    for i in range(k):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        best = bound2[i]
        found = False
        stack[0] = 0
        stack_d2[0] = _box_d2(box, 0, px, py, pz)
        top = 1
        while top > 0:
            top -= 1
            node = stack[top]
            if stack_d2[top] > best:
                continue
            if right[node] < 0:
                for t in range(start[node], start[node] + count[node]):
                    d2 = _triangle_d2(corners, t, px, py, pz)
                    if d2 <= best:
                        best = d2
                        found = True
                continue
            left, other = node + 1, right[node]
            d_left, d_other = _box_d2(box, left, px, py, pz), _box_d2(box, other, px, py, pz)
            if d_other < d_left:  # the nearer child is taken first (on top)
                left, other, d_left, d_other = other, left, d_other, d_left
            if d_other <= best:
                stack[top], stack_d2[top] = other, d_other
                top += 1
            if d_left <= best:
                stack[top], stack_d2[top] = left, d_left
                top += 1
        out[i] = best if found else np.inf
    return out


@njit(error_model="numpy", inline="always")
def _positive(e: float, px: float, py: float, qx: float, qy: float) -> bool:  # pragma: no cover (compiled)
    """Sign of the edge function ``e`` of edge p -> q; when it is 0, its sign for the origin moved by
    ``(e1, e2)``, ``e1 >> e2 > 0``: that adds ``e1 (py - qy) + e2 (qx - px)``."""
    if e != 0.0:
        return e > 0.0
    return qy < py or (qy == py and qx > px)


@njit(error_model="numpy")
def _ray_triangle(corners: np.ndarray, t: int, o: np.ndarray, kx: int, ky: int, kz: int,
                  sx: float, sy: float, sz: float) -> float:  # pragma: no cover (compiled)
    """Hit distance along the sheared ray (origin ``o`` (3,)) on triangle ``t``, in units of the direction's
    length; inf if none. Every corner is sheared by the same operations in every triangle that has it."""
    az = corners[t, 0, kz] - o[kz]
    bz = corners[t, 1, kz] - o[kz]
    cz = corners[t, 2, kz] - o[kz]
    ax = (corners[t, 0, kx] - o[kx]) - sx * az
    ay = (corners[t, 0, ky] - o[ky]) - sy * az
    bx = (corners[t, 1, kx] - o[kx]) - sx * bz
    by = (corners[t, 1, ky] - o[ky]) - sy * bz
    cx = (corners[t, 2, kx] - o[kx]) - sx * cz
    cy = (corners[t, 2, ky] - o[ky]) - sy * cz
    u = bx * cy - by * cx  # edge b -> c
    v = cx * ay - cy * ax  # edge c -> a
    w = ax * by - ay * bx  # edge a -> b
    su = _positive(u, bx, by, cx, cy)
    if _positive(v, cx, cy, ax, ay) != su or _positive(w, ax, ay, bx, by) != su:
        return np.inf
    det = u + v + w
    if det == 0.0:
        return np.inf
    hit = (u * (sz * az) + v * (sz * bz) + w * (sz * cz)) / det
    return hit if hit > 0.0 else np.inf


@njit(error_model="numpy", inline="always")
def _ray_box(box: np.ndarray, node: int, o: np.ndarray, d: np.ndarray, inv: np.ndarray,
             far: float) -> float:  # pragma: no cover (compiled)
    """Entry distance (>= 0) of the ray into the node's box before ``far``; inf if it misses."""
    near = 0.0
    for k in range(3):
        lo, hi = box[node, 0, k], box[node, 1, k]
        if d[k] == 0.0:
            if o[k] < lo or o[k] > hi:
                return np.inf
            continue
        t0, t1 = (lo - o[k]) * inv[k], (hi - o[k]) * inv[k]
        near = max(near, min(t0, t1))
        far = min(far, max(t0, t1))
    return near if near <= far else np.inf


@njit(error_model="numpy", inline="always")
def _shear(d: np.ndarray):  # pragma: no cover (compiled)
    """The axes (kx, ky, kz) and shear (sx, sy, sz) that make direction ``d`` (3,) run along +z."""
    kz = 0
    for axis in (1, 2):
        if abs(d[axis]) > abs(d[kz]):
            kz = axis
    kx, ky = (kz + 1) % 3, (kz + 2) % 3
    sz = 1.0 / d[kz]
    return kx, ky, kz, d[kx] * sz, d[ky] * sz, sz


@njit(error_model="numpy")
def cast_rays(corners, box, right, start, count, depth, origins, directions, first):  # pragma: no cover (compiled)
    """Per ray: the nearest hit distance (``first``) or the number of hits (as float), over all triangles."""
    k = origins.shape[0]
    out = np.empty(k)
    stack = np.empty(depth + 1, dtype=np.int64)
    stack_t = np.empty(depth + 1)
    inv = np.empty(3)
    for i in range(k):
        o, d = origins[i], directions[i]
        kx, ky, kz, sx, sy, sz = _shear(d)
        for axis in range(3):
            inv[axis] = 1.0 / d[axis] if d[axis] != 0.0 else 0.0
        best = np.inf
        hits = 0
        stack[0] = 0
        stack_t[0] = _ray_box(box, 0, o, d, inv, np.inf)
        top = 1 if stack_t[0] < np.inf else 0
        while top > 0:
            top -= 1
            node = stack[top]
            if first and stack_t[top] > best:
                continue
            if right[node] < 0:
                for t in range(start[node], start[node] + count[node]):
                    hit = _ray_triangle(corners, t, o, kx, ky, kz, sx, sy, sz)
                    if hit < np.inf:
                        hits += 1
                        best = min(best, hit)
                continue
            far = best if first else np.inf
            left, other = node + 1, right[node]
            t_left, t_other = _ray_box(box, left, o, d, inv, far), _ray_box(box, other, o, d, inv, far)
            if t_other < t_left:
                left, other, t_left, t_other = other, left, t_other, t_left
            if t_other < np.inf:
                stack[top], stack_t[top] = other, t_other
                top += 1
            if t_left < np.inf:
                stack[top], stack_t[top] = left, t_left
                top += 1
        out[i] = best if first else float(hits)
    return out


@njit(error_model="numpy")
def count_parallel(corners: np.ndarray, origins: np.ndarray, d: np.ndarray, margin: float,
                   cells: int) -> np.ndarray:  # pragma: no cover (compiled)
    """Hits (k,) int64 of rays from ``origins`` (k, 3) along one direction ``d`` (3,), through a 2D grid.

    Every triangle is entered into the cells of the plane across the rays that its sheared rectangle
    (widened by ``margin``, which is far more than the rounding between the shear of a corner and the
    shear of the corner relative to a ray's origin) overlaps; a ray tests the triangles of its own cell with
    :func:`_ray_triangle`, as the hierarchy's traversal does, so the counts are the same. A cell holds the
    triangles in ascending order. The grid has about ``cells`` square cells over the rectangles' box, fewer
    when large triangles would make more than 16 entries per triangle or per cell.
    """
    m, k = corners.shape[0], origins.shape[0]
    kx, ky, kz, sx, sy, sz = _shear(d)
    rect = np.empty((m, 4))  # x0, x1, y0, y1 of each sheared triangle
    for t in range(m):
        x0, x1, y0, y1 = np.inf, -np.inf, np.inf, -np.inf
        for c in range(3):
            x = corners[t, c, kx] - sx * corners[t, c, kz]
            y = corners[t, c, ky] - sy * corners[t, c, kz]
            x0, x1, y0, y1 = min(x0, x), max(x1, x), min(y0, y), max(y1, y)
        rect[t, 0], rect[t, 1], rect[t, 2], rect[t, 3] = x0 - margin, x1 + margin, y0 - margin, y1 + margin
    gx0, gx1 = rect[:, 0].min(), rect[:, 1].max()
    gy0, gy1 = rect[:, 2].min(), rect[:, 3].max()
    width, height = gx1 - gx0, gy1 - gy0
    side = np.sqrt(width * height / cells)
    nx = min(int(width / side) + 1, cells)
    ny = min(int(height / side) + 1, cells)
    lo = np.empty((m, 2), dtype=np.int64)
    hi = np.empty((m, 2), dtype=np.int64)
    while True:
        fx, fy = nx / width, ny / height
        entries = 0
        for t in range(m):
            lo[t, 0] = min(int((rect[t, 0] - gx0) * fx), nx - 1)
            hi[t, 0] = min(int((rect[t, 1] - gx0) * fx), nx - 1)
            lo[t, 1] = min(int((rect[t, 2] - gy0) * fy), ny - 1)
            hi[t, 1] = min(int((rect[t, 3] - gy0) * fy), ny - 1)
            entries += (hi[t, 0] - lo[t, 0] + 1) * (hi[t, 1] - lo[t, 1] + 1)
        if entries <= 16 * max(m, nx * ny) or (nx == 1 and ny == 1):
            break
        nx, ny = max(nx // 2, 1), max(ny // 2, 1)
    first = np.zeros(nx * ny + 1, dtype=np.int64)
    for t in range(m):
        for iy in range(lo[t, 1], hi[t, 1] + 1):
            for ix in range(lo[t, 0], hi[t, 0] + 1):
                first[iy * nx + ix + 1] += 1
    for c in range(nx * ny):
        first[c + 1] += first[c]
    fill = first[:-1].copy()
    members = np.empty(entries, dtype=np.int32)
    for t in range(m):
        for iy in range(lo[t, 1], hi[t, 1] + 1):
            for ix in range(lo[t, 0], hi[t, 0] + 1):
                members[fill[iy * nx + ix]] = t
                fill[iy * nx + ix] += 1
    out = np.zeros(k, dtype=np.int64)
    for i in range(k):
        o = origins[i]
        px, py = o[kx] - sx * o[kz], o[ky] - sy * o[kz]
        if not (gx0 <= px <= gx1 and gy0 <= py <= gy1):
            continue
        c = min(int((py - gy0) * fy), ny - 1) * nx + min(int((px - gx0) * fx), nx - 1)
        hits = 0
        for e in range(first[c], first[c + 1]):
            t = members[e]
            if rect[t, 0] <= px <= rect[t, 1] and rect[t, 2] <= py <= rect[t, 3]:
                if _ray_triangle(corners, t, o, kx, ky, kz, sx, sy, sz) < np.inf:
                    hits += 1
        out[i] = hits
    return out
