"""Aligned fracture at runtime (seed 001): cut the asset's convex pieces with a pattern placed at the hit.

:func:`aligned_fracture` is the reference of docs/FORMAT.md sections 13.3-13.4 that the C and JavaScript
readers follow (engines/c/fracture_aligned.c, engines/web/fracture_aligned.js), checked against the
same conformance vectors (tests/data/aligned_conformance/). A pattern's unit-volume Voronoi sites are
placed at the hit (``world = point + scale * R * site``, ``R`` taking the pattern's +z to the impulse
direction); every convex piece of the file lying in one cell stays whole, every other piece is clipped
by the cells it meets (convex with convex stays convex); the pieces and parts in one cell form a new
fragment, with the visual triangles of its pieces, cut along the cells, and the interior material on
the new faces.

Notes
-----
Müller, Chentanez, Kim 2013, *Real Time Dynamic Fracture with Volumetric Approximate Convex
Decompositions*, sections 3-5 (fracture patterns aligned at the impact, convex-with-cell intersection,
per-cell compounds, and the visual mesh cut with them).

Depends on numpy and the standard library only (see :mod:`fracture_cli.runtime`).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import UsageError
from fracture_cli.runtime.aligned_clip import (
    Corner,
    Polyhedron,
    box_uv,
    clip_polygon,
    clip_polyhedron,
    dot,
    plane_basis,
    polyhedron_mass,
)
from fracture_cli.runtime.aligned_data import AlignedData

# Clipping tolerance, per piece: vertices within this fraction of the piece's sphere radius of a plane are on it.
EPS_RELATIVE = 1e-9
# A clipped part is kept when its volume exceeds this fraction of its piece's volume.
KEEP_RELATIVE = 1e-9


@dataclass(frozen=True, eq=False)
class AlignedPart:
    """One convex part of a new fragment: a stored piece kept whole, or a piece clipped by one cell.

    Attributes
    ----------
    piece : int
        The stored piece it comes from.
    whole : bool
        True: the piece unchanged (its vertices, faces and triangles are those of the file).
    vertices : (n, 3) float64
        Corners, model space.
    loops : tuple of tuple of int
        Face loops (indices into ``vertices``), counter-clockwise seen from outside.
    planes : (f, 4) float64
        Each face's outward unit normal and offset (``n . x <= h`` inside).
    new : (f,) bool
        Faces made by the cut (they carry the interior material).
    volume : float
    centroid : (3,) float64
    """

    piece: int
    whole: bool
    vertices: np.ndarray
    loops: tuple[tuple[int, ...], ...]
    planes: np.ndarray
    new: np.ndarray
    volume: float
    centroid: np.ndarray


@dataclass(frozen=True, eq=False)
class AlignedFragment:
    """One new fragment: the parts of the pieces inside one cell, and what it looks like.

    Attributes
    ----------
    cell : int
        The pattern cell (site index) that made it.
    parts : tuple of AlignedPart
        In piece order: convex, closed, ready as collision shapes.
    whole_pieces : tuple of int
        Pieces kept whole: their stored triangles (``piece_triangle_offsets``) belong to this fragment unchanged.
    positions, normals : (t, 3, 3) float64
        The fragment's other triangles (from cut pieces, and the new faces), model space.
    uvs : (t, 3, 2) float64
    materials : (t,) int32
        Material of each of those triangles (the interior material on new faces).
    volume : float
        Sum of the parts' volumes (the mass at unit density).
    center_of_mass : (3,) float64
    """

    cell: int
    parts: tuple[AlignedPart, ...]
    whole_pieces: tuple[int, ...]
    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    materials: np.ndarray
    volume: float
    center_of_mass: np.ndarray


@dataclass(frozen=True)
class _Piece:
    """A stored piece as Python floats (built once per file)."""

    polyhedron: Polyhedron
    centre: tuple[float, float, float]
    radius: float
    volume: float
    centroid: tuple[float, float, float]
    triangles: range


_PREPARED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _pieces(data: AlignedData) -> list[_Piece]:
    cached = _PREPARED.get(data)
    if cached is not None:
        return cached
    a = data.arrays
    pv, pf, fl, pt = (a[k].tolist() for k in ("piece_vertex_offsets", "piece_face_offsets", "face_loop_offsets",
                                                "piece_triangle_offsets"))
    vertices = [tuple(v) for v in a["piece_vertices"].astype(np.float64).tolist()]
    planes = [tuple(p) for p in a["face_planes"].astype(np.float64).tolist()]
    loops = a["face_loops"].tolist()
    spheres = a["piece_sphere"].astype(np.float64).tolist()
    pieces = []
    for k in range(data.num_pieces):
        faces = [(loops[fl[f]:fl[f + 1]], planes[f], False) for f in range(pf[k], pf[k + 1])]
        poly: Polyhedron = (vertices[pv[k]:pv[k + 1]], faces)
        volume, centroid = polyhedron_mass(poly)
        pieces.append(_Piece(poly, tuple(spheres[k][:3]), spheres[k][3], volume, centroid, range(pt[k], pt[k + 1])))
    _PREPARED[data] = pieces
    return pieces


def piece_volumes(data: AlignedData) -> list[float]:
    """The volume of every stored piece (the divergence-theorem sum of sections 13.3-13.4, in the readers' order)."""
    return [piece.volume for piece in _pieces(data)]


def pattern_frame(direction) -> tuple[tuple[float, float, float], ...]:
    """The columns ``(u, v, d)`` of ``R`` for an impulse direction (finite, not zero).

    ``d`` is the direction divided by its largest absolute component, then normalized; ``(u, v)`` are
    :func:`~fracture_cli.runtime.aligned_clip.plane_basis` of ``d`` (so ``u x v = d``).
    """
    m = max(abs(float(direction[0])), abs(float(direction[1])), abs(float(direction[2])))
    if not (math.isfinite(m) and m > 0.0):
        raise UsageError(f"aligned fracture: direction {list(direction)} must be finite and not zero")
    s = (float(direction[0]) / m, float(direction[1]) / m, float(direction[2]) / m)
    length = math.sqrt((s[0] * s[0] + s[1] * s[1]) + s[2] * s[2])
    d = (s[0] / length, s[1] / length, s[2] / length)
    u, v = plane_basis(d)
    return u, v, d


def place_sites(data: AlignedData, pattern: int, point, direction, scale: float) -> list[tuple[float, ...]]:
    """World positions of pattern ``pattern``'s sites: ``point + scale * (x0 u + x1 v + x2 d)``, component-wise
    ``p + (((scale x0) u + (scale x1) v) + (scale x2) d)``."""
    u, v, d = pattern_frame(direction)
    p = [float(x) for x in point]
    lo, hi = (int(x) for x in data["pattern_site_offsets"][pattern:pattern + 2])
    out = []
    for x in data["pattern_sites"][lo:hi].astype(np.float64).tolist():
        t0, t1, t2 = scale * x[0], scale * x[1], scale * x[2]
        out.append(tuple(p[c] + ((t0 * u[c] + t1 * v[c]) + t2 * d[c]) for c in range(3)))
    return out


def bisector(sites: list, i: int, j: int) -> tuple[float, float, float, float]:
    """The plane between sites ``i`` and ``j``, keeping ``i``'s side: unit normal towards ``j`` and offset."""
    wi, wj = sites[i], sites[j]
    n = (wj[0] - wi[0], wj[1] - wi[1], wj[2] - wi[2])
    length = math.sqrt((n[0] * n[0] + n[1] * n[1]) + n[2] * n[2])
    if length == 0.0:
        raise UsageError("aligned fracture: scale is too small for this pattern (two sites coincide)")
    unit = (n[0] / length, n[1] / length, n[2] / length)
    mid = ((wi[0] + wj[0]) * 0.5, (wi[1] + wj[1]) * 0.5, (wi[2] + wj[2]) * 0.5)
    return unit[0], unit[1], unit[2], dot(unit, mid)


def _nearest(x, sites: list, cells: list[int]) -> int:
    """The cell of ``cells`` whose site is nearest to ``x`` (squared distances; the first on ties)."""
    best, best_d = cells[0], math.inf
    for c in cells:
        w = sites[c]
        dx, dy, dz = x[0] - w[0], x[1] - w[1], x[2] - w[2]
        dd = (dx * dx + dy * dy) + dz * dz
        if dd < best_d:
            best, best_d = c, dd
    return best


def _candidates(piece: _Piece, sites: list) -> list[int]:
    """Cells that may meet the piece's sphere: ``|c - w_i| <= |c - w_n| + 2 r`` (``w_n`` nearest to the centre)."""
    c = piece.centre
    dists = []
    for w in sites:
        dx, dy, dz = c[0] - w[0], c[1] - w[1], c[2] - w[2]
        dists.append(math.sqrt((dx * dx + dy * dy) + dz * dz))
    bound = min(dists) + 2.0 * piece.radius
    return [i for i, dist in enumerate(dists) if dist <= bound]


@dataclass(frozen=True)
class _Hit:
    """A pattern placed at a hit: sites, each cell's neighbours and planes, the boundary's planes (model space)."""

    sites: list
    neighbors: list
    planes: dict
    boundary: list
    walls: list  # per cell, the boundary planes that bound it


def place_boundary(data: AlignedData, point, frame, scale: float) -> list[tuple[float, float, float, float]]:
    """The pattern's boundary planes in model space: ``n' = (n0 u + n1 v) + n2 d``, ``h' = scale h + n' . point``."""
    u, v, d = frame
    p = [float(x) for x in point]
    out = []
    for plane in data["boundary_planes"].astype(np.float64).tolist():
        n = tuple((plane[0] * u[c] + plane[1] * v[c]) + plane[2] * d[c] for c in range(3))
        out.append((n[0], n[1], n[2], scale * plane[3] + dot(n, p)))
    return out


class _Output:
    """Parts and triangles per cell, in the order they are made."""

    def __init__(self) -> None:
        self.parts: dict[int, list[AlignedPart]] = {}
        self.whole: dict[int, list[int]] = {}
        self.triangles: dict[int, list[tuple[Corner, Corner, Corner, int]]] = {}

    def add_whole(self, cell: int, k: int, piece: _Piece) -> None:
        vertices, faces = piece.polyhedron
        self.parts.setdefault(cell, []).append(_part(k, True, (vertices, faces), piece.volume, piece.centroid))
        self.whole.setdefault(cell, []).append(k)

    def add_polygon(self, cell: int, corners: list[Corner], material: int) -> None:
        tris = self.triangles.setdefault(cell, [])
        for q in range(1, len(corners) - 1):
            tris.append((corners[0], corners[q], corners[q + 1], material))


def _part(k: int, whole: bool, poly: Polyhedron, volume: float, centroid) -> AlignedPart:
    vertices, faces = poly
    return AlignedPart(piece=k, whole=whole, vertices=np.array(vertices, dtype=np.float64).reshape(-1, 3),
                       loops=tuple(tuple(loop) for loop, _, _ in faces),
                       planes=np.array([plane for _, plane, _ in faces], dtype=np.float64).reshape(-1, 4),
                       new=np.array([new for _, _, new in faces], dtype=bool), volume=volume,
                       centroid=np.array(centroid, dtype=np.float64))


def _clip_by(poly: Polyhedron | None, planes, centre, radius: float, eps: float) -> Polyhedron | None:
    """``poly`` clipped by ``planes`` in order, skipping those the piece's sphere lies inside (``t < -r``)."""
    for plane in planes:
        if poly is None:
            return None
        if dot(plane, centre) - plane[3] < -radius:
            continue
        poly = clip_polyhedron(poly, plane, eps)
    return poly


def _flipped(plane):
    return -plane[0], -plane[1], -plane[2], -plane[3]


def _cut_piece(data: AlignedData, k: int, piece: _Piece, hit: _Hit, out: _Output, rows: dict) -> None:
    """Piece ``k`` against the placed pattern: whole in one cell, or parts in the cells it meets (section 13.4)."""
    vertices, (centre, radius) = piece.polyhedron[0], (piece.centre, piece.radius)
    sites, outer = hit.sites, len(hit.sites)
    ts = [dot(plane, centre) - plane[3] for plane in hit.boundary]
    if any(t > radius for t in ts):  # 2a: beyond the pattern's boundary: the rest of the object
        out.add_whole(outer, k, piece)
        return
    straddle = any(t >= -radius for t in ts)
    cells = _candidates(piece, sites)
    if not straddle:  # 2c
        if len(cells) > 1:
            first = _nearest(vertices[0], sites, cells)
            if all(_nearest(x, sites, cells) == first for x in vertices[1:]):
                cells = [first]
        if len(cells) == 1:
            out.add_whole(cells[0], k, piece)
            return
    eps, keep = EPS_RELATIVE * radius, KEEP_RELATIVE * piece.volume
    parts: list[tuple[int, Polyhedron, float, tuple]] = []
    for i in cells:  # 2d: one part per cell the piece meets
        cell_planes = [hit.planes[(i, j)] for j in hit.neighbors[i]]
        if any(dot(plane, centre) - plane[3] > radius for plane in cell_planes):
            continue  # the piece's sphere lies beyond a plane of cell i
        if any(min(dot(plane, x) - plane[3] for x in vertices) > eps for plane in cell_planes):
            continue  # or every corner does
        poly = _clip_by(piece.polyhedron, cell_planes, centre, radius, eps)
        if straddle:
            poly = _clip_by(poly, [hit.boundary[b] for b in hit.walls[i]], centre, radius, eps)
        if poly is not None:
            volume, centroid = polyhedron_mass(poly)
            if volume > keep:
                parts.append((i, poly, volume, centroid))
    if straddle:  # and the parts beyond each boundary plane in turn, for the rest of the object
        rest: Polyhedron | None = piece.polyhedron
        for plane, t in zip(hit.boundary, ts):
            if t < -radius:
                continue
            beyond = clip_polyhedron(rest, _flipped(plane), eps)  # type: ignore[arg-type]
            if beyond is not None:
                volume, centroid = polyhedron_mass(beyond)
                if volume > keep:
                    parts.append((outer, beyond, volume, centroid))
            rest = clip_polyhedron(rest, plane, eps)  # type: ignore[arg-type]
            if rest is None:
                break
    if len(parts) <= 1:  # 2e
        cell = parts[0][0] if parts else _nearest(vertices[0], sites, cells)
        out.add_whole(cell, k, piece)
        return
    for i, poly, volume, centroid in parts:
        out.parts.setdefault(i, []).append(_part(k, False, poly, volume, centroid))
    inner = sorted({i for i, _, _, _ in parts if i != outer})
    has_outer = any(i == outer for i, _, _, _ in parts)
    positions, normals, uvs, materials = rows["positions"], rows["normals"], rows["uvs"], rows["materials"]
    for t in piece.triangles:  # 2f
        polygon: list[Corner] = [(*positions[t][c], *normals[t][c], *uvs[t][c]) for c in range(3)]
        if has_outer:
            for plane in hit.boundary:
                outside = clip_polygon(polygon, _flipped(plane), eps)
                if len(outside) >= 3:
                    out.add_polygon(outer, outside, materials[t])
                polygon = clip_polygon(polygon, plane, eps)
                if not polygon:
                    break
        if len(polygon) < 3:
            continue
        if not inner:
            out.add_polygon(outer, polygon, materials[t])
            continue
        _split_polygon(polygon, sites, inner, eps, out, materials[t])
    for i, poly, _, _ in parts:  # 2g: the new faces
        cap_vertices, faces = poly
        for loop, plane, new in faces:
            if new:
                normal = (plane[0], plane[1], plane[2])
                corners = [(*cap_vertices[v], *normal, *box_uv(cap_vertices[v], normal, data.uv_scale))
                           for v in loop]
                out.add_polygon(i, corners, data.interior_material)


def _split_polygon(polygon: list[Corner], sites: list, cells: list[int], eps: float, out: _Output,
                   material: int) -> None:
    """A convex polygon into the Voronoi cells of ``cells``' sites (section 13.4, step 7).

    When every corner has the same nearest site (the first on ties), the polygon lies in that cell. Otherwise
    with ``a`` the cell of corner 0 and ``b`` the first other corner cell, the polygon is split by their
    bisector; the side of ``a`` goes on without ``b`` (no point of it is nearer to ``b``), the other side
    without ``a``.
    """
    first = _nearest(polygon[0], sites, cells)
    other = -1
    for corner in polygon[1:]:
        cell = _nearest(corner, sites, cells)
        if cell != first:
            other = cell
            break
    if other < 0:
        out.add_polygon(first, polygon, material)
        return
    plane = bisector(sites, first, other)
    near = clip_polygon(polygon, plane, eps)
    far = clip_polygon(polygon, _flipped(plane), eps)
    if len(near) >= 3:
        _split_polygon(near, sites, [c for c in cells if c != other], eps, out, material)
    if len(far) >= 3:
        _split_polygon(far, sites, [c for c in cells if c != first], eps, out, material)


def _triangle_rows(data: AlignedData) -> dict:
    a = data.arrays
    return {"positions": a["triangle_positions"].astype(np.float64).tolist(),
            "normals": a["triangle_normals"].astype(np.float64).tolist(),
            "uvs": a["triangle_uvs"].astype(np.float64).tolist(), "materials": a["triangle_materials"].tolist()}


def aligned_fracture(data: AlignedData, point, direction, scale: float | None = None,
                     pattern: int = 0) -> tuple[AlignedFragment, ...]:
    """New fragments for a hit at ``point`` with an impulse along ``direction`` (docs/FORMAT.md sections 13.3-13.4).

    Parameters
    ----------
    data : AlignedData
        An aligned-fracture file (:func:`~fracture_cli.runtime.aligned_data.load_aligned`).
    point : (3,) float
        The hit, model space.
    direction : (3,) float
        The impulse (its direction only: finite, not zero).
    scale : float, optional (default the file's ``default_scale``)
        Model units per pattern unit: the pattern's unit ball becomes a ball of this radius.
    pattern : int, optional (default 0)
        Which pattern of the file.

    Returns
    -------
    tuple of AlignedFragment
        One per cell that holds any material, in increasing cell order.

    Raises
    ------
    UsageError
        Non-finite point, zero or non-finite direction, ``scale`` not finite and > 0, unknown pattern.
    """
    scale = data.default_scale if scale is None else float(scale)
    if not (math.isfinite(scale) and scale > 0.0):
        raise UsageError(f"aligned fracture: scale {scale!r} must be finite and > 0")
    if not all(math.isfinite(float(x)) for x in point) or len(point) != 3:
        raise UsageError(f"aligned fracture: point {list(point)} must be 3 finite numbers")
    if not 0 <= pattern < data.num_patterns:
        raise UsageError(f"aligned fracture: pattern {pattern} does not exist (the file has {data.num_patterns})")
    sites = place_sites(data, pattern, point, direction, scale)
    lo = int(data["pattern_site_offsets"][pattern])
    offsets = data["cell_neighbor_offsets"]
    neighbors = [data["cell_neighbors"][offsets[lo + i]:offsets[lo + i + 1]].tolist() for i in range(len(sites))]
    # Each cell's planes, once per hit: the bisector of its site and each neighbour's.
    planes = {(i, j): bisector(sites, i, j) for i in range(len(sites)) for j in neighbors[i]}
    bo = data["cell_boundary_offsets"]
    walls = [data["cell_boundary"][bo[lo + i]:bo[lo + i + 1]].tolist() for i in range(len(sites))]
    hit = _Hit(sites, neighbors, planes, place_boundary(data, point, pattern_frame(direction), scale), walls)
    out = _Output()
    rows = _triangle_rows(data)
    for k, piece in enumerate(_pieces(data)):
        _cut_piece(data, k, piece, hit, out, rows)
    return tuple(_fragment(cell, out) for cell in sorted(out.parts))


def _fragment(cell: int, out: _Output) -> AlignedFragment:
    parts = tuple(out.parts[cell])
    volume = 0.0
    moment = [0.0, 0.0, 0.0]
    for part in parts:
        volume += part.volume
        for c in range(3):
            moment[c] += part.volume * float(part.centroid[c])
    tris = out.triangles.get(cell, [])
    corners = np.array([[list(c) for c in tri[:3]] for tri in tris], dtype=np.float64).reshape(-1, 3, 8)
    return AlignedFragment(cell=cell, parts=parts, whole_pieces=tuple(out.whole.get(cell, [])),
                           positions=corners[:, :, 0:3], normals=corners[:, :, 3:6], uvs=corners[:, :, 6:8],
                           materials=np.array([tri[3] for tri in tris], dtype=np.int32),
                           volume=volume,
                           center_of_mass=np.array([m / volume for m in moment]) if volume > 0 else np.zeros(3))
