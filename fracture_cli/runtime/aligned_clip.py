"""Convex clipping for aligned fracture, with the exact arithmetic of docs/FORMAT.md sections 13.3-13.4.

Plain Python floats (IEEE doubles), every sum and product in the order the format states, so the
C and JavaScript readers (engines/c/fracture_aligned.c, engines/web/fracture_aligned.js), which
follow the same order, give the same numbers up to the last bit on the conformance vectors.

* :func:`clip_polyhedron`: a convex polyhedron (vertices and face loops) cut by one half-space; the
  new face (the *cap*) gets the plane and the flag ``new``.
* :func:`clip_polygon`: a convex polygon with attributes (position, normal, UV) cut by one half-space
  (Sutherland-Hodgman).
* :func:`polyhedron_mass`: volume and centroid (divergence theorem, tetrahedra fanned from vertex 0).
* :func:`plane_basis`, :func:`box_uv`: the in-plane axes and the box-projected UVs of new faces.
"""

from __future__ import annotations

import math

Vec = tuple[float, float, float]
# A polyhedron: vertices, and per face (loop of vertex indices, plane (nx, ny, nz, h), new face?).
Face = tuple[list[int], tuple[float, float, float, float], bool]
Polyhedron = tuple[list[Vec], list[Face]]
# A polygon corner: x, y, z, nx, ny, nz, u, v.
Corner = tuple[float, float, float, float, float, float, float, float]
_UV_AXIS_TIE = 1e-9  # as the bake's box projection (fracture_cli.geometry.uvs)


def dot(a, b) -> float:
    """``(a0 b0 + a1 b1) + a2 b2``: every dot product of the format, in this order."""
    return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]


def smallest_axis(n) -> int:
    """The coordinate axis along which ``|n_i|`` is smallest (the lowest index on ties)."""
    axis = 0
    if abs(n[1]) < abs(n[axis]):
        axis = 1
    if abs(n[2]) < abs(n[axis]):
        axis = 2
    return axis


def plane_basis(n: Vec) -> tuple[Vec, Vec]:
    """Unit axes ``(a, b)`` with ``a x b = n`` for a unit vector ``n`` (docs/FORMAT.md sections 13.3-13.4).

    ``a`` is the coordinate axis of :func:`smallest_axis` with its ``n`` component removed, normalized;
    ``b = n x a``.
    """
    axis = smallest_axis(n)
    k = n[axis]
    a = [-k * n[0], -k * n[1], -k * n[2]]
    a[axis] = 1.0 - k * n[axis]
    length = math.sqrt((a[0] * a[0] + a[1] * a[1]) + a[2] * a[2])
    ax = (a[0] / length, a[1] / length, a[2] / length)
    b = (n[1] * ax[2] - n[2] * ax[1], n[2] * ax[0] - n[0] * ax[2], n[0] * ax[1] - n[1] * ax[0])
    return ax, b


def box_uv(position: Vec, normal: Vec, uv_scale: float) -> tuple[float, float]:
    """The bake's box projection of a point on a new face (fracture_cli.geometry.uvs.box_uvs), one point."""
    mx = max(abs(normal[0]), abs(normal[1]), abs(normal[2]))
    axis = 0 if abs(normal[0]) >= mx - _UV_AXIS_TIE else (1 if abs(normal[1]) >= mx - _UV_AXIS_TIE else 2)
    sign = -1.0 if normal[axis] < 0 else 1.0
    u_axis, v_axis = (1, 0, 0)[axis], (2, 2, 1)[axis]
    u = position[u_axis] * sign * (-1.0 if axis == 1 else 1.0)
    return u / uv_scale, position[v_axis] / uv_scale


def _side(s: float, eps: float) -> int:
    return 1 if s > eps else (-1 if s < -eps else 0)


def _before(p: tuple[float, float, int], q: tuple[float, float, int]) -> bool:
    """Whether 2-D point ``p`` comes before ``q`` counter-clockwise from the +x axis (ties: nearer, lower index)."""
    hp = 1 if (p[1] < 0.0 or (p[1] == 0.0 and p[0] < 0.0)) else 0
    hq = 1 if (q[1] < 0.0 or (q[1] == 0.0 and q[0] < 0.0)) else 0
    if hp != hq:
        return hp < hq
    cross = p[0] * q[1] - p[1] * q[0]
    if cross != 0.0:
        return cross > 0.0
    dp, dq = p[0] * p[0] + p[1] * p[1], q[0] * q[0] + q[1] * q[1]
    if dp != dq:
        return dp < dq
    return p[2] < q[2]


def cap_loop(vertices: list[Vec], points: list[int], n: Vec) -> list[int]:
    """The indices ``points`` (on one plane, normal ``n``) ordered counter-clockwise around ``n``.

    Sorted by angle around their mean in the axes of :func:`plane_basis` (insertion sort with
    :func:`_before`, a total order, so every correct sort gives the same loop).
    """
    count = len(points)
    cx = cy = cz = 0.0
    for i in points:
        cx, cy, cz = cx + vertices[i][0], cy + vertices[i][1], cz + vertices[i][2]
    cx, cy, cz = cx / count, cy / count, cz / count
    a, b = plane_basis(n)
    keyed = []
    for i in points:
        d = (vertices[i][0] - cx, vertices[i][1] - cy, vertices[i][2] - cz)
        keyed.append((dot(d, a), dot(d, b), i))
    for j in range(1, count):
        item, k = keyed[j], j - 1
        while k >= 0 and _before(item, keyed[k]):
            keyed[k + 1] = keyed[k]
            k -= 1
        keyed[k + 1] = item
    return [p[2] for p in keyed]


def clip_polyhedron(poly: Polyhedron, plane: tuple[float, float, float, float], eps: float) -> Polyhedron | None:
    """The part of a convex polyhedron where ``n . x - h <= 0``; None when nothing is left.

    Parameters
    ----------
    poly : (vertices, faces)
        Vertices (list of (x, y, z)) and faces (loop of vertex indices, counter-clockwise seen from
        outside; plane; new flag).
    plane : (nx, ny, nz, h)
        Unit normal and offset.
    eps : float
        Vertices within ``eps`` of the plane count as on it.

    Returns
    -------
    (vertices, faces) or None
        ``poly`` itself when no vertex lies beyond ``eps`` outside. Otherwise the kept vertices in order,
        then one new vertex per crossed edge (in the order the faces meet them), the kept faces (fewer
        than 3 corners: dropped) in order, and the cap: the plane's face, flag new, its loop of
        :func:`cap_loop`.
    """
    vertices, faces = poly
    n = (plane[0], plane[1], plane[2])
    dist = [dot(n, x) - plane[3] for x in vertices]
    sides = [_side(s, eps) for s in dist]
    if 1 not in sides:
        return poly
    if -1 not in sides:
        return None
    renumber = [-1] * len(vertices)
    out_vertices: list[Vec] = []
    for i, side in enumerate(sides):
        if side <= 0:
            renumber[i] = len(out_vertices)
            out_vertices.append(vertices[i])
    crossings: dict[tuple[int, int], int] = {}
    out_faces: list[Face] = []
    for loop, face_plane, new in faces:
        out: list[int] = []
        count = len(loop)
        for t in range(count):
            a, b = loop[t], loop[t + 1 if t + 1 < count else 0]
            if sides[a] <= 0:
                out.append(renumber[a])
            if sides[a] * sides[b] == -1:
                key = (a, b) if a < b else (b, a)
                index = crossings.get(key)
                if index is None:
                    lo, hi = vertices[key[0]], vertices[key[1]]
                    t_cut = dist[key[0]] / (dist[key[0]] - dist[key[1]])
                    index = len(out_vertices)
                    out_vertices.append((lo[0] + (hi[0] - lo[0]) * t_cut, lo[1] + (hi[1] - lo[1]) * t_cut,
                                         lo[2] + (hi[2] - lo[2]) * t_cut))
                    crossings[key] = index
                out.append(index)
        if len(out) >= 3:
            out_faces.append((out, face_plane, new))
    used = [False] * len(out_vertices)
    for loop, _, _ in out_faces:
        for i in loop:
            used[i] = True
    on_plane = [renumber[i] for i, side in enumerate(sides) if side == 0 and used[renumber[i]]]
    on_plane += [i for i in sorted(crossings.values()) if used[i]]
    if len(on_plane) >= 3:
        out_faces.append((cap_loop(out_vertices, on_plane, n), (plane[0], plane[1], plane[2], plane[3]), True))
    return out_vertices, out_faces


def clip_polygon(corners: list[Corner], plane: tuple[float, float, float, float], eps: float) -> list[Corner]:
    """The part of a convex polygon where ``n . x - h <= 0`` (Sutherland-Hodgman); ``[]`` when nothing is left.

    New corners interpolate position, normal (then normalized) and UV linearly along the crossed edge,
    from its first corner (in loop order) to its second.
    """
    n = (plane[0], plane[1], plane[2])
    dist = [dot(n, c) - plane[3] for c in corners]
    sides = [_side(s, eps) for s in dist]
    if 1 not in sides:
        return corners
    if -1 not in sides:
        return []
    out: list[Corner] = []
    count = len(corners)
    for t in range(count):
        u = t + 1 if t + 1 < count else 0
        if sides[t] <= 0:
            out.append(corners[t])
        if sides[t] * sides[u] == -1:
            a, b = corners[t], corners[u]
            w = dist[t] / (dist[t] - dist[u])
            p = [a[c] + (b[c] - a[c]) * w for c in range(8)]
            length = math.sqrt((p[3] * p[3] + p[4] * p[4]) + p[5] * p[5])
            if length > 0.0:
                p[3], p[4], p[5] = p[3] / length, p[4] / length, p[5] / length
            out.append((p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]))
    return out


def polyhedron_mass(poly: Polyhedron) -> tuple[float, Vec]:
    """Volume and centroid of a closed polyhedron (faces counter-clockwise seen from outside).

    Each face loop ``l0 .. l(k-1)`` is fanned into triangles ``(l0, lq, lq+1)``; with ``o`` vertex 0 and
    ``a, b, c`` the triangle's corners minus ``o``, ``det = a . (b x c)`` adds to ``6 V`` and
    ``det * ((a + b) + c)`` to ``24 V (centroid - o)``.
    """
    vertices, faces = poly
    o = vertices[0]
    six_volume = sx = sy = sz = 0.0
    for loop, _, _ in faces:
        p0 = vertices[loop[0]]
        a = (p0[0] - o[0], p0[1] - o[1], p0[2] - o[2])
        for q in range(1, len(loop) - 1):
            p1, p2 = vertices[loop[q]], vertices[loop[q + 1]]
            b = (p1[0] - o[0], p1[1] - o[1], p1[2] - o[2])
            c = (p2[0] - o[0], p2[1] - o[1], p2[2] - o[2])
            det = (a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2])) \
                + a[2] * (b[0] * c[1] - b[1] * c[0])
            six_volume += det
            sx += det * ((a[0] + b[0]) + c[0])
            sy += det * ((a[1] + b[1]) + c[1])
            sz += det * ((a[2] + b[2]) + c[2])
    volume = six_volume / 6.0
    if six_volume == 0.0:
        return 0.0, o
    quad = 4.0 * six_volume
    return volume, (o[0] + sx / quad, o[1] + sy / quad, o[2] + sz / quad)
