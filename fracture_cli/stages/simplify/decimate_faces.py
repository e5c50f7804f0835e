"""Plain-Python face helpers of :class:`fracture_cli.stages.simplify.decimate.SurfaceComplex`'s reference loops.

The compiled loops (:mod:`.collapse_loop`) repeat these operations in the same
order on arrays; these are the Python statements they follow, on tuples.
"""

from __future__ import annotations

# A face is degenerate when twice its area is below this fraction of its longest edge squared.
MIN_SHAPE = 1e-6
# A collapse may not turn a triangle by more than this (cosine of the angle between old and new normal): inside a
# fault 30 degrees, so a smooth fault stays smooth under flat shading; 60 degrees for a vertex on the outer
# surface, where a fault curve straightens or snaps to input vertices across a thin wall.
MIN_NORMAL_COS = 0.85
MIN_NORMAL_COS_OUTER = 0.5


def merged(a: tuple, b: tuple) -> tuple:
    """The history of a face changed by the collapses of both ``a`` and ``b`` (:meth:`SurfaceComplex.behind`)."""
    return b if not a else a if not b or a is b else (-1, (a, b))


def turns_little(points: list, old: tuple, new: tuple, limit: float) -> bool:
    """Whether face ``new`` is not degenerate and its normal's cosine with ``old``'s is ``limit`` or more.

    Corners are ids into ``points``, a list of (x, y, z): plain floats, as numpy is slow on single triangles
    (normals written out: a call for each cost a fifth of the test).
    """
    (ax, ay, az), (bx, by, bz), (cx, cy, cz) = points[old[0]], points[old[1]], points[old[2]]
    ux, uy, uz, vx, vy, vz = bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az
    ox, oy, oz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    (ax, ay, az), (bx, by, bz), (cx, cy, cz) = points[new[0]], points[new[1]], points[new[2]]
    ux, uy, uz, vx, vy, vz = bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    length2 = nx * nx + ny * ny + nz * nz
    # Written out, in the order sum() adds them (0 + x is x exactly).
    longest = max((ax - bx) * (ax - bx) + (ay - by) * (ay - by) + (az - bz) * (az - bz),
                  (bx - cx) * (bx - cx) + (by - cy) * (by - cy) + (bz - cz) * (bz - cz),
                  (cx - ax) * (cx - ax) + (cy - ay) * (cy - ay) + (cz - az) * (cz - az))
    if length2 == 0.0 or length2 <= (MIN_SHAPE * longest) * (MIN_SHAPE * longest):
        return False
    dot = ox * nx + oy * ny + oz * nz
    old2 = ox * ox + oy * oy + oz * oz
    return dot > 0 and dot * dot >= limit * limit * old2 * length2


def moved(f: tuple, u: int, v: int) -> tuple[int, int, int]:
    """Face ``f`` with corner ``u`` replaced by ``v``."""
    a, b, c = f
    return (v if a == u else a, v if b == u else b, v if c == u else c)


class Fan:
    """The faces around a vertex and what its collapses check on them (see :meth:`.decimate.SurfaceComplex._fan`)."""

    __slots__ = ("fan", "polygons", "fragments", "limit", "on_fault", "around", "single", "corners")

    def __init__(self, fan: set[int], polygons: set[int], fragments: set[int], limit: float, on_fault: bool,
                 single: tuple[int, ...] | None):
        self.fan, self.polygons, self.fragments, self.limit, self.on_fault = fan, polygons, fragments, limit, on_fault
        self.around: dict[int, set[int]] = {}
        # The fragments every face of the fan bounds, when they all bound the same ones; and then their corners.
        self.single = single
        self.corners: set[int] | None = None
