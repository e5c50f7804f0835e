"""Exact triangle intersection tests, for the few pairs a floating-point test cannot decide.

:func:`fracture_cli.geometry.trigeom.self_intersections` counts faces closer than
1e-12 as touching and computes with rounding, so it reports pairs that do not
meet: a needle triangle (height ~1e-10 of its edges, left by the booleans
where a fault grazes a tet corner) next to a face it shares a corner with,
or two faces meeting at a corner at a grazing angle. :func:`real_pairs` tests
such reported pairs again in exact arithmetic: every float is a dyadic
rational, so scaled to one common power of two the corners are Python
integers, and orientation signs computed on them have no rounding at all.
"""

from __future__ import annotations

import numpy as np

# Reported pairs retested per call at most (a few hundred microseconds each, in Python); any further ones stay
# reported, as the floating-point test found them.
MAX_EXACT_PAIRS = 2000

_Point = tuple[int, int, int]


def real_pairs(V: np.ndarray, F: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Of the face pairs ``pairs`` (k, 2) reported as intersecting, those that do, in exact arithmetic.

    Pairs with no common corner meet if their closed triangles do; pairs with one common corner if they
    meet anywhere else. Pairs sharing an edge (reported for folding onto each other, a matter of angle) or
    all three corners are kept, and so is every pair beyond the first :data:`MAX_EXACT_PAIRS`.

    Parameters
    ----------
    V : (n, 3) float
        Vertices.
    F : (m, 3) int
        Triangles.
    pairs : (k, 2) int
        Face pairs, as :func:`~fracture_cli.geometry.trigeom.self_intersections` returns them.

    Returns
    -------
    pairs : (k', 2) int64
        The rows of ``pairs`` that are real intersections (or not retested), in their order.
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    keep = np.ones(len(pairs), dtype=bool)
    for row, (f, g) in enumerate(pairs[:MAX_EXACT_PAIRS].tolist()):
        a, b = F[f].tolist(), F[g].tolist()
        shared = set(a) & set(b)
        if len(shared) <= 1:
            keep[row] = _meet(_integers(V[a + b]), a, b, shared)
    return pairs[keep]


def _integers(points: np.ndarray) -> list[_Point]:
    """Points (k, 3) as integer triples on one common scale (a power of two): their exact values, scaled."""
    ratios = [float(x).as_integer_ratio() for x in np.asarray(points, dtype=np.float64).reshape(-1)]
    scale = max(d for _, d in ratios)  # every denominator is a power of two, so each divides the largest
    flat = [n * (scale // d) for n, d in ratios]
    return [(flat[i], flat[i + 1], flat[i + 2]) for i in range(0, len(flat), 3)]


def _meet(P: list[_Point], a: list[int], b: list[int], shared: set) -> bool:
    """Whether triangles ``P[0:3]`` (corner ids ``a``) and ``P[3:6]`` (ids ``b``) meet beyond their common corner.

    Two closed triangles meet iff an edge of one meets the other. With a common corner v, a point other
    than v in both lies on an edge opposite v (their intersection is convex and contains v), so only the
    two opposite edges are tested; they do not pass through v unless a triangle has no area, and a
    triangle with no area is reported (it meets its neighbour at v in a segment).
    """
    A, B = P[:3], P[3:]
    if shared:
        v = next(iter(shared))
        i, j = a.index(v), b.index(v)
        return (_segment_meets(A[(i + 1) % 3], A[(i + 2) % 3], B)
                or _segment_meets(B[(j + 1) % 3], B[(j + 2) % 3], A))
    return (any(_segment_meets(A[k], A[(k + 1) % 3], B) for k in range(3))
            or any(_segment_meets(B[k], B[(k + 1) % 3], A) for k in range(3)))


def _sub(p: _Point, q: _Point) -> _Point:
    return p[0] - q[0], p[1] - q[1], p[2] - q[2]


def _cross(p: _Point, q: _Point) -> _Point:
    return p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2], p[0] * q[1] - p[1] * q[0]


def _sign(x: int) -> int:
    return (x > 0) - (x < 0)


def _orient(a: _Point, b: _Point, c: _Point, d: _Point) -> int:
    """Sign of the volume of tet (a, b, c, d): which side of plane (a, b, c) d is on; 0 in the plane."""
    n = _cross(_sub(b, a), _sub(c, a))
    e = _sub(d, a)
    return _sign(n[0] * e[0] + n[1] * e[1] + n[2] * e[2])


def _segment_meets(p: _Point, q: _Point, T: list[_Point]) -> bool:
    """Whether the closed segment pq meets the closed triangle T (3 points)."""
    sp, sq = _orient(T[0], T[1], T[2], p), _orient(T[0], T[1], T[2], q)
    if sp * sq > 0:
        return False
    if sp == 0 and sq == 0:
        return _coplanar_segment_meets(p, q, T)
    # pq crosses T's plane (or ends on it): at a point of T iff it passes every edge of T on one side.
    s = [_orient(p, q, T[k], T[(k + 1) % 3]) for k in range(3)]
    return all(x >= 0 for x in s) or all(x <= 0 for x in s)


def _coplanar_segment_meets(p: _Point, q: _Point, T: list[_Point]) -> bool:
    """:func:`_segment_meets` for a segment in T's plane: projected along the normal's largest axis, in 2D."""
    n = _cross(_sub(T[1], T[0]), _sub(T[2], T[0]))
    if n == (0, 0, 0):
        return True  # T has no area: no plane to decide in; reported, as the floating-point test does
    drop = max(range(3), key=lambda k: abs(n[k]))
    x, y = [k for k in range(3) if k != drop]
    p2, q2 = (p[x], p[y]), (q[x], q[y])
    t2 = [(t[x], t[y]) for t in T]
    return (_inside2(p2, t2) or _inside2(q2, t2)
            or any(_segments_meet2(p2, q2, t2[k], t2[(k + 1) % 3]) for k in range(3)))


def _orient2(a: tuple[int, int], b: tuple[int, int], c: tuple[int, int]) -> int:
    return _sign((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def _inside2(p: tuple[int, int], t: list[tuple[int, int]]) -> bool:
    s = [_orient2(t[k], t[(k + 1) % 3], p) for k in range(3)]
    return all(x >= 0 for x in s) or all(x <= 0 for x in s)


def _on_segment2(p: tuple[int, int], a: tuple[int, int], b: tuple[int, int]) -> bool:
    return (_orient2(a, b, p) == 0 and min(a[0], b[0]) <= p[0] <= max(a[0], b[0])
            and min(a[1], b[1]) <= p[1] <= max(a[1], b[1]))


def _segments_meet2(p: tuple[int, int], q: tuple[int, int], a: tuple[int, int], b: tuple[int, int]) -> bool:
    if _orient2(a, b, p) * _orient2(a, b, q) < 0 and _orient2(p, q, a) * _orient2(p, q, b) < 0:
        return True
    return _on_segment2(p, a, b) or _on_segment2(q, a, b) or _on_segment2(a, p, q) or _on_segment2(b, p, q)
