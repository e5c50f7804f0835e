"""The three rules of the ``anchors`` stage: ground, boxes and painted vertex colour.

Each takes the baked fragments (normalized coordinates: the input's bounding-box
diagonal is 1) and returns which fragments it picks, ``(p,)`` bool. A fragment's
*outer* faces are those of the input's surface (any material but the interior one);
its faults (interior faces) never anchor it, so a cut that reaches the floor does not
glue the fragment above it to the world.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.boxlevels import LevelGrid
from fracture_cli.geometry.trigeom import closest_points
from fracture_cli.types import Fragments, SurfaceMesh

# Outer faces lie on the input's surface up to rounding; a colour sample looks for its triangle this far first
# (normalized units), then ten times farther until it finds one.
_NEAR = 1e-6
# Above this a channel counts as painted (colours in [0, 1]).
PAINTED = 0.5


def _outer(fragments: Fragments, index: int) -> np.ndarray:
    """The outer faces (m_o, 3) int64 of fragment ``index`` (every face not of the interior material)."""
    frag = fragments.fragments[index]
    return np.asarray(frag.faces, dtype=np.int64)[np.asarray(frag.material_ids) != fragments.interior_slot]


def on_ground(fragments: Fragments, up: str, tolerance: float) -> np.ndarray:
    """Fragments with an outer face on the lowest plane along ``up``, (p,) bool.

    Parameters
    ----------
    fragments : Fragments
    up : {"+x", "-x", "+y", "-y", "+z", "-z"}
        The up axis; heights are measured along it, and the ground is the lowest outer-surface point.
    tolerance : float
        A face is on the ground when all three of its corners lie at most this far above it (fraction of the
        bounding-box diagonal). One corner is not enough: a fragment whose outer surface only reaches the
        floor at a point or along an edge (beside a fault) does not rest on it.
    """
    axis, sign = "xyz".index(up[1]), (1.0 if up[0] == "+" else -1.0)
    # Height along up of the three corners of every outer face, per fragment: (m_o, 3) each.
    corners = [sign * np.asarray(f.vertices, dtype=np.float64)[_outer(fragments, j), axis]
               for j, f in enumerate(fragments.fragments)]
    lows = [float(c.min()) for c in corners if c.size]
    if not lows:
        return np.zeros(len(fragments.fragments), dtype=bool)
    ground = min(lows)
    return np.array([bool(c.size and np.any(c.max(axis=1) - ground <= tolerance)) for c in corners], dtype=bool)


def in_box(fragments: Fragments, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Fragments whose solid shares volume with the box ``[lo, hi]`` (input units), (p,) bool.

    A fragment with a vertex strictly inside the box shares volume with it (a solid has volume next to every
    point of its surface); otherwise the exact intersection (manifold3d) must hold more than
    :data:`~fracture_cli.geometry.tolerances.SLIVER_VOLUME` of the input's volume (a box that only touches a
    fragment's face shares ~0 there, up to rounding, and does not anchor it), which also catches a box inside a
    fragment or crossing it between its vertices.
    """
    # on first use: manifold3d only when a box is given
    import manifold3d

    from fracture_cli.geometry.hulls import solid_of

    norm = fragments.normalization
    box_lo, box_hi = norm.to_normalized(np.asarray(lo)[None])[0], norm.to_normalized(np.asarray(hi)[None])[0]
    everything = np.concatenate([np.asarray(f.vertices, dtype=np.float64) for f in fragments.fragments])
    # A box far larger than the asset would cost the boolean its precision: only the part near the asset matters.
    box_lo = np.maximum(box_lo, everything.min(axis=0) - 0.01)
    box_hi = np.minimum(box_hi, everything.max(axis=0) + 0.01)
    picked = np.zeros(len(fragments.fragments), dtype=bool)
    if np.any(box_lo >= box_hi):
        return picked
    box = manifold3d.Manifold.cube(tuple(float(x) for x in box_hi - box_lo)).translate(tuple(float(x) for x in box_lo))
    floor = tol.SLIVER_VOLUME * fragments.input_volume
    for j, frag in enumerate(fragments.fragments):
        V = np.asarray(frag.vertices, dtype=np.float64)
        if np.any(V.max(axis=0) <= box_lo) or np.any(V.min(axis=0) >= box_hi):
            continue  # their bounding boxes share no volume
        if np.any(np.all((V > box_lo) & (V < box_hi), axis=1)):
            picked[j] = True
            continue
        picked[j] = (solid_of(V, frag.faces) ^ box).volume() > floor
    return picked


def painted(fragments: Fragments, surface: SurfaceMesh, channel: int) -> np.ndarray:
    """Fragments whose outer surface carries vertex-colour ``channel`` above :data:`PAINTED`, (p,) bool.

    The colour of an outer face is the input's colour at its centroid: interpolated (barycentric) on the
    input triangle nearest to it, on which it lies (outer faces are pieces of the input's triangles).
    """
    centroids, owner = [], []
    for j, frag in enumerate(fragments.fragments):
        faces = _outer(fragments, j)
        centroids.append(np.asarray(frag.vertices, dtype=np.float64)[faces].mean(axis=1))
        owner.append(np.full(len(faces), j, dtype=np.int64))
    points = np.concatenate(centroids) if centroids else np.zeros((0, 3))
    owners = np.concatenate(owner) if owner else np.zeros(0, dtype=np.int64)
    values = surface_colour(surface, points)[:, channel]
    picked = np.zeros(len(fragments.fragments), dtype=bool)
    picked[np.unique(owners[values > PAINTED])] = True
    return picked


def surface_colour(surface: SurfaceMesh, points: np.ndarray) -> np.ndarray:
    """The surface's vertex colours interpolated at its points nearest to ``points`` (q, 3): (q, 4) float64.

    Points are meant to lie on the surface (within rounding); the nearest triangle is found among those whose
    bounding box comes within :data:`_NEAR` of the point, or ten times farther, and so on (ties: the smaller
    triangle index).
    """
    V = np.asarray(surface.vertices, dtype=np.float64)
    F = np.asarray(surface.faces, dtype=np.int64)
    colours = np.asarray(surface.colors, dtype=np.float64)
    T = V[F]  # (m, 3, 3)
    grid = LevelGrid(np.stack([T.min(axis=1), T.max(axis=1)], axis=1))
    nearest = np.full(len(points), -1, dtype=np.int64)
    todo = np.arange(len(points))
    pad = _NEAR
    while len(todo):
        q, j = grid.query(np.stack([points[todo], points[todo]], axis=1), pad=pad)
        if len(q):
            distance = np.linalg.norm(points[todo[q]] - closest_points(points[todo[q]], *T[j].transpose(1, 0, 2)),
                                      axis=1)
            order = np.lexsort((j, distance, q))  # per point: nearest first, then the smaller triangle index
            first = order[np.r_[True, q[order][1:] != q[order][:-1]]]
            nearest[todo[q[first]]] = j[first]
        todo = todo[nearest[todo] < 0]
        pad *= 10.0
    a, b, c = (T[nearest, k] for k in range(3))
    on = closest_points(points, a, b, c)
    weights = _barycentric(on, a, b, c)
    return np.einsum("qk,qkc->qc", weights, colours[F[nearest]])


def _barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric weights (q, 3) of points ``p`` in triangles ``(a, b, c)``; a degenerate one weighs its corners
    equally."""
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (np.einsum("ij,ij->i", x, y) for x, y in ((v0, v0), (v0, v1), (v1, v1)))
    d20, d21 = np.einsum("ij,ij->i", v2, v0), np.einsum("ij,ij->i", v2, v1)
    denom = d00 * d11 - d01 * d01
    ok = denom > 1e-30 * np.maximum(d00 * d11, tol.SMALLEST_DIVISOR)
    safe = np.where(ok, denom, 1.0)
    v = (d11 * d20 - d01 * d21) / safe
    w = (d00 * d21 - d01 * d20) / safe
    weights = np.stack([1.0 - v - w, v, w], axis=1)
    weights[~ok] = 1.0 / 3.0
    return np.clip(weights, 0.0, 1.0)
