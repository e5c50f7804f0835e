"""Holes: find boundary loops, decide from the mesh whether to fill them, and fill them.

The decision is made per body (faces connected across shared edges), from
the mesh alone, so an artist can predict it:

* A boundary loop can be filled when its fill patch is well defined: the loop
  is nearly planar (its largest distance to its best-fit plane at most
  :attr:`FillOptions.planarity` of its diameter), or it is small (its diameter
  at most :attr:`FillOptions.small_hole` of the body's bounding-box diagonal).
  The patch is a fan around the loop's centroid where the loop is star-shaped
  about it in its plane, otherwise an ear-clipped triangulation of the loop
  projected on its plane.
* A body is filled when every loop can be filled, the filled body encloses a
  positive volume (after turning it outward if it was inside out), and no
  patch crosses the body's surface. The share of the area that is filled does
  not matter up to a bound: the patches may be at most
  :attr:`FillOptions.max_fill_share` of the filled body's area, unless every
  patch lies inside another body of the mesh (hidden, like the rims of a
  teapot's spout and handle or Suzanne's eyes).
* Any other open body is a sheet: :func:`fracture_cli.stages.repair.thicken.thicken_inward`
  gives it a thickness behind its visible side.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.edges import edge_table, face_bodies, signed_volume
from fracture_cli.geometry.tetgeom import triangle_areas
from fracture_cli.stages.repair.patch import least_area_patch
from fracture_cli.stages.repair.records import RepairRecord

# Points per patch tested for being inside another body.
_HIDDEN_SAMPLES = 16
# How far (of its diagonal) a body may rise above the plane of a container's opening: a rim's lip.
_LIP = 0.02


@dataclass(frozen=True)
class FillOptions:
    """Thresholds of :func:`plan_fill` (lengths relative to the loop's or the body's size)."""

    planarity: float = 0.1
    """A loop is planar when its largest distance to its best-fit plane is at most this fraction of its diameter."""
    small_hole: float = 0.1
    """A loop is small when its diameter is at most this fraction of its body's bounding-box diagonal."""
    max_fill_share: float = 0.5
    """The patches of a body may be at most this fraction of the filled body's area (unless hidden)."""
    min_thickness: float = 1e-3
    """A filled body must enclose at least this volume per unit area, relative to its diagonal (not flat)."""
    container_opening: float = 0.5
    """A planar hole at the top of its body (the body on one side of its plane) at least this wide, relative to
    the body's width in that plane, is the opening of a container: the body is a thin wall, not filled (unless
    another body covers the opening, as a lid). Above 1: never."""


@dataclass(frozen=True)
class HoleLoop:
    """One boundary loop and its fill patch.

    Attributes
    ----------
    vertices : (k,) int64
        Loop vertex ids, in the direction of the surface's boundary edges.
    body : int
        The body (face group) the loop bounds.
    centroid : (3,) float64
        Mean of the loop's vertices.
    diameter : float
        Bounding-box diagonal of the loop's vertices.
    planarity : float
        Largest distance to the best-fit plane, relative to ``diameter``.
    patch : (p, 3) int64
        Fill triangles over the mesh's vertex ids, where id ``-1`` is the
        centroid (a new vertex) for a fan; oriented to close the surface.
    area : float
        Area of the patch.
    """

    vertices: np.ndarray
    body: int
    centroid: np.ndarray
    diameter: float
    planarity: float
    patch: np.ndarray
    area: float
    kind: str = "fan"
    """How the patch was made: ``fan`` (around the centroid), ``ear`` (ear clipping in the loop's plane),
    ``least_area`` (a non-planar patch over the loop's own vertices) or ``none``."""


@dataclass(frozen=True)
class BodyPlan:
    """What :func:`plan_fill` decided for one open body: ``fill`` or ``thicken``, and why."""

    body: int
    action: str
    reason: str
    loops: tuple[HoleLoop, ...]
    flip: bool = False
    hidden: bool = False
    container: bool = False


@dataclass(frozen=True)
class FillPlan:
    """Per-body decisions (open bodies only) and the body id of every face."""

    bodies: tuple[BodyPlan, ...]
    face_body: np.ndarray
    records: list[RepairRecord] = field(default_factory=list)

    def loops_to_fill(self) -> list[HoleLoop]:
        """The loops of every body decided ``fill``, in body order."""
        return [loop for b in self.bodies if b.action == "fill" for loop in b.loops]


def boundary_loops(F: np.ndarray) -> list[np.ndarray]:
    """Simple loops (vertex ids, in boundary-edge direction) of the edges of ``F`` (m, 3) used by one face.

    A vertex where two holes touch (two outgoing boundary edges) splits the
    walk into separate simple loops.
    """
    table = edge_table(F)
    boundary = table.sides[table.count[table.edge] == 1]
    outgoing: dict[int, list[int]] = {}
    for a, b in boundary.tolist():
        outgoing.setdefault(a, []).append(b)
    loops: list[np.ndarray] = []
    for start in sorted(outgoing):
        while outgoing.get(start):
            walk = [start]
            while True:
                nxt = outgoing[walk[-1]].pop(0)
                if nxt == start:
                    break
                if not outgoing.get(nxt):
                    walk = []  # an open chain: not a loop (cannot happen on an oriented surface)
                    break
                walk.append(nxt)
            loops.extend(_simple_loops(walk))
    return [loop for loop in loops if len(loop) >= 3]


def _simple_loops(walk: list[int]) -> list[np.ndarray]:
    """Split a closed walk that revisits vertices into simple loops."""
    out: list[np.ndarray] = []
    stack: list[int] = []
    position: dict[int, int] = {}
    for v in walk:
        if v in position:
            i = position[v]
            out.append(np.array(stack[i:], dtype=np.int64))
            for u in stack[i + 1:]:
                del position[u]
            del stack[i + 1:]
        else:
            position[v] = len(stack)
            stack.append(v)
    out.append(np.array(stack, dtype=np.int64))
    return out


def _plane(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Centroid, unit normal of the loop's winding (Newell) and largest distance to the best-fit plane."""
    c = P.mean(axis=0)
    newell = np.cross(P - c, np.roll(P, -1, axis=0) - c).sum(axis=0)
    normal = newell / max(np.linalg.norm(newell), tol.SMALLEST_DIVISOR)
    fit = np.linalg.svd(P - c, full_matrices=False)[2][-1]
    return c, normal, float(np.abs((P - c) @ fit).max())


def _fan(loop: np.ndarray, P: np.ndarray, c: np.ndarray, normal: np.ndarray) -> np.ndarray | None:
    """Fan patch around the centroid (id -1), or None when some fan triangle faces the wrong way."""
    nxt = np.roll(np.arange(len(loop)), -1)
    # The cap runs every boundary edge a -> b backwards: (b, a, centre); its normal is -normal.
    n = np.cross(P - P[nxt], c - P[nxt])
    if np.any(n @ -normal <= 0):
        return None
    return np.column_stack([loop[nxt], loop, np.full(len(loop), -1)])


def _ear_clip(loop: np.ndarray, P: np.ndarray, normal: np.ndarray) -> np.ndarray | None:
    """Ear-clipping triangulation of the loop projected on its plane, oriented as the cap; None if not simple."""
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    # The cap runs the loop backwards, so it is counter-clockwise about -normal: use (v, u) axes.
    Q = np.column_stack([P @ v, P @ u])
    ring = list(range(len(loop)))[::-1]
    tris = []

    def cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(ring) > 3 and guard < len(loop) * len(loop):
        guard += 1
        for i in range(len(ring)):
            a, b, c = ring[i - 1], ring[i], ring[(i + 1) % len(ring)]
            if cross(Q[a], Q[b], Q[c]) <= 0:
                continue
            others = [r for r in ring if r not in (a, b, c)]
            if others and _inside_triangle(Q[others], Q[a], Q[b], Q[c]).any():
                continue
            tris.append((loop[a], loop[b], loop[c]))
            del ring[i]
            break
        else:
            return None
    if len(ring) == 3:
        a, b, c = ring
        if cross(Q[a], Q[b], Q[c]) <= 0:
            return None
        tris.append((loop[a], loop[b], loop[c]))
    return np.array(tris, dtype=np.int64)


def _inside_triangle(R: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Whether 2-d points R (k, 2) lie in or on the counter-clockwise triangle (a, b, c)."""
    def side(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        return (q[0] - p[0]) * (R[:, 1] - p[1]) - (q[1] - p[1]) * (R[:, 0] - p[0])

    return (side(a, b) >= 0) & (side(b, c) >= 0) & (side(c, a) >= 0)


def measure_loop(V: np.ndarray, loop: np.ndarray, body: int) -> HoleLoop:
    """A :class:`HoleLoop` with its patch: a fan if star-shaped about the centroid, else ear clipping in the
    loop's plane, else (an outline that folds over itself in its plane) the least-area patch over its vertices.

    ``patch`` is empty (``kind`` ``none``) when none works (a loop longer than
    :data:`~fracture_cli.stages.repair.patch.MAX_LOOP` that crosses itself in its plane).
    """
    P = V[loop]
    c, normal, deviation = _plane(P)
    diameter = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
    kind = "fan"
    patch = _fan(loop, P, c, normal)
    if patch is None:
        kind, patch = "ear", _ear_clip(loop, P, normal)
    if patch is None:
        kind, patch = "least_area", least_area_patch(loop, P)
    if patch is None:
        kind, patch = "none", np.zeros((0, 3), dtype=np.int64)
    return _with_patch(HoleLoop(vertices=loop, body=body, centroid=c, diameter=diameter,
                                planarity=deviation / max(diameter, tol.SMALLEST_DIVISOR), patch=patch, area=0.0,
                                kind=kind), V)


def _with_patch(loop: HoleLoop, V: np.ndarray, patch: np.ndarray | None = None, kind: str | None = None) -> HoleLoop:
    """``loop`` with ``patch`` (default its own) and that patch's area."""
    patch = loop.patch if patch is None else patch
    W = np.vstack([V, loop.centroid[None]])
    area = float(triangle_areas(W, np.where(patch < 0, len(V), patch)).sum())
    return dataclasses.replace(loop, patch=patch, area=area, kind=loop.kind if kind is None else kind)


def _with_centroids(V: np.ndarray, loops: list[HoleLoop]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Vertices with every loop's centroid appended, and each loop's patch over those ids."""
    extra: list[np.ndarray] = []
    patches: list[np.ndarray] = []
    for loop in loops:
        centre = len(V) + len(extra)
        if (loop.patch < 0).any():
            extra.append(loop.centroid)
        patches.append(np.where(loop.patch < 0, centre, loop.patch))
    return (np.vstack([V] + [np.asarray(extra)]) if extra else np.asarray(V, dtype=np.float64)), patches


def _patch_samples(W: np.ndarray, patch: np.ndarray) -> np.ndarray:
    """Up to _HIDDEN_SAMPLES centroids of patch triangles (k, 3)."""
    pick = np.linspace(0, len(patch) - 1, min(_HIDDEN_SAMPLES, len(patch))).astype(np.int64)
    return W[patch[pick]].mean(axis=1)


def _patch_crosses(W: np.ndarray, surface: np.ndarray, patch: np.ndarray) -> bool:
    """Whether a patch triangle meets a surface or patch triangle it shares no vertex with."""
    faces = np.vstack([surface, patch])
    boxes = trigeom.triangle_boxes(W, faces)
    grid = trigeom.BoxGrid(boxes, trigeom.default_cell(boxes))
    i, j = grid.query(boxes[len(surface):])
    i = i + len(surface)
    keep = (i != j) & ~(faces[i][:, :, None] == faces[j][:, None, :]).any(axis=(1, 2))
    i, j = i[keep], j[keep]
    return bool(len(i)) and bool(trigeom.triangles_intersect(W[faces[i]], W[faces[j]]).any())


def _judge_body(b: int, loops: list[HoleLoop], W: np.ndarray, patches: list[np.ndarray], F: np.ndarray,
                face_body: np.ndarray, others: np.ndarray, options: FillOptions) -> BodyPlan:
    """Fill or thicken one open body (see the module docstring)."""
    body_faces = F[face_body == b]
    diag = float(np.linalg.norm(np.ptp(W[np.unique(body_faces)], axis=0)))
    for loop in loops:
        if len(loop.patch) == 0:
            return BodyPlan(b, "thicken", "a hole's outline crosses itself and is too long for a non-planar patch",
                            tuple(loops))
        if loop.planarity > options.planarity and loop.diameter > options.small_hole * diag:
            return BodyPlan(b, "thicken", f"a boundary loop is neither planar ({loop.planarity:.2g} of its diameter "
                            f"off its plane > {options.planarity:g}) nor small ({loop.diameter / diag:.2g} of the "
                            f"body > {options.small_hole:g}): an edge of a sheet, not a hole", tuple(loops))
    volume, area = _filled_measures(W, body_faces, patches)
    if abs(volume) <= options.min_thickness * diag * area:
        return BodyPlan(b, "thicken", "filling its holes encloses no volume (a flat or folded sheet)", tuple(loops))
    if _patch_crosses(W, body_faces, np.vstack(patches)):
        # A fan or flat patch of a non-planar outline can cut through the surface where the least-area one,
        # following the outline, does not.
        loops, patches = _least_area_instead(loops, W, patches)
        if _patch_crosses(W, body_faces, np.vstack(patches)):
            return BodyPlan(b, "thicken", "a fill patch would cross the surface", tuple(loops))
        volume, area = _filled_measures(W, body_faces, patches)
    share = float(sum(loop.area for loop in loops)) / area
    opening = _container_opening(W, body_faces, loops, volume > 0, options.planarity, options.container_opening)
    hidden = False
    if share > options.max_fill_share or opening:
        samples = np.vstack([_patch_samples(W, p) for p in patches])
        hidden = bool(len(others)) and bool(np.all(np.abs(trigeom.winding_numbers(samples, W, others)) > 0.5))
    if opening and not hidden:
        return BodyPlan(b, "thicken", f"a rim around a large opening ({opening:.2g} of the body's width, at its "
                        "top): an open container, kept hollow as a thin wall", tuple(loops), container=True)
    if share > options.max_fill_share and not hidden:
        return BodyPlan(b, "thicken", f"the holes would be {100 * share:.3g}% of the filled surface (more than "
                        f"{100 * options.max_fill_share:g}%) and are not inside another body", tuple(loops))
    non_planar = sum(loop.kind == "least_area" for loop in loops)
    reason = f"{len(loops)} hole(s) close into a solid ({100 * share:.3g}% of its surface" + (
        ", hidden inside another body" if hidden else "") + (
        f"; {non_planar} by a non-planar patch" if non_planar else "") + ")"
    return BodyPlan(b, "fill", reason, tuple(loops), flip=volume < 0, hidden=hidden)


def _filled_measures(W: np.ndarray, body_faces: np.ndarray, patches: list[np.ndarray]) -> tuple[float, float]:
    """Signed volume and area of a body closed by its patches."""
    filled = np.vstack([body_faces] + patches)
    return signed_volume(W, filled), float(triangle_areas(W, filled).sum())


def _least_area_instead(loops: list[HoleLoop], W: np.ndarray,
                        patches: list[np.ndarray]) -> tuple[list[HoleLoop], list[np.ndarray]]:
    """Every loop's least-area patch in place of its fan or flat one (where the loop is short enough)."""
    new_loops, new_patches = [], []
    for loop, patch in zip(loops, patches):
        other = least_area_patch(loop.vertices, W[loop.vertices]) if loop.kind != "least_area" else None
        if other is None:
            new_loops.append(loop)
            new_patches.append(patch)
        else:
            new_loops.append(_with_patch(loop, W, other, "least_area"))
            new_patches.append(other)
    return new_loops, new_patches


def _container_opening(W: np.ndarray, body_faces: np.ndarray, loops: list[HoleLoop], outward: bool,
                       planarity: float, threshold: float) -> float:
    """How wide the body's widest opening is relative to the body, when it is a container's opening; else 0.

    An opening of a container: a planar loop (within ``planarity`` of its
    diameter) with the whole body on the inner side of its plane (the rim is
    the top; 2% of the body's diagonal allowed for a lip) and, measured in
    that plane, at least ``threshold`` of the body's width.
    """
    verts = W[np.unique(body_faces)]
    diag = float(np.linalg.norm(np.ptp(verts, axis=0)))
    widest = 0.0
    for loop in loops:
        P = W[loop.vertices]
        c, newell, _ = _plane(P)
        # The cap runs the loop backwards: its outward normal is -newell on an outward body.
        n = -newell if outward else newell
        if loop.planarity > planarity or np.max((verts - c) @ n) > _LIP * diag:
            continue
        u = np.cross(n, np.eye(3)[int(np.argmin(np.abs(n)))])
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        width = max(float(np.ptp(verts @ u)), float(np.ptp(verts @ v)))
        ratio = max(float(np.ptp(P @ u)), float(np.ptp(P @ v))) / max(width, tol.SMALLEST_DIVISOR)
        if ratio >= threshold:
            widest = max(widest, ratio)
    return widest


def plan_fill(V: np.ndarray, F: np.ndarray, options: FillOptions = FillOptions()) -> FillPlan:
    """Decide, for every open body of an edge-manifold oriented mesh, whether to fill its holes or thicken it.

    Parameters
    ----------
    V : (n, 3) float
        Positions (welded).
    F : (m, 3) int
        Faces, edge-manifold (see :func:`~fracture_cli.stages.repair.nonmanifold.split_nonmanifold`)
        and consistently oriented within each body.
    options : FillOptions, optional

    Returns
    -------
    FillPlan
        One :class:`BodyPlan` per open body, with an ``open_surface`` record
        each saying what was decided and why.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    face_body = face_bodies(edge_table(F))
    vertex_body = np.full(len(V), -1, dtype=np.int64)
    vertex_body[F.reshape(-1)] = np.repeat(face_body, 3)
    loops = [measure_loop(V, loop, int(vertex_body[loop[0]])) for loop in boundary_loops(F)]
    W, patches = _with_centroids(V, loops)
    plans, records = [], []
    for b in sorted({loop.body for loop in loops}):
        mine = [i for i, loop in enumerate(loops) if loop.body == b]
        others = np.vstack([F[face_body != b]] + [patches[i] for i in range(len(loops)) if loops[i].body != b])
        plan = _judge_body(b, [loops[i] for i in mine], W, [patches[i] for i in mine], F, face_body, others, options)
        plans.append(plan)
        where = tuple(float(x) for x in V[np.unique(F[face_body == b])].mean(axis=0))
        records.append(RepairRecord("open_surface", f"open body {b}: {plan.action}: {plan.reason}", count=len(mine),
                                    area=float(sum(loop.area for loop in plan.loops)), where=where,
                                    extra={"action": plan.action}))
    return FillPlan(bodies=tuple(plans), face_body=face_body, records=records)


@dataclass(frozen=True)
class FilledMesh:
    """Result of :func:`fill_holes`: positions (n + c, 3) with the fan centroids appended, faces, patch mask."""

    vertices: np.ndarray
    faces: np.ndarray
    patch: np.ndarray
    flipped_faces: int
    records: list[RepairRecord] = field(default_factory=list)


def fill_holes(V: np.ndarray, F: np.ndarray, plan: FillPlan) -> FilledMesh:
    """Fill the holes of the bodies ``plan`` decided to fill (turning inside-out ones outward).

    Returns
    -------
    FilledMesh
        ``faces`` are the input faces (in order; reversed for flipped bodies)
        then the patches; ``patch`` (m2,) marks the new faces; one
        ``filled_hole`` record per hole with its area and share of the surface.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3).copy()
    loops = plan.loops_to_fill()
    W, patches = _with_centroids(V, loops)
    surface_area = float(triangle_areas(V, F).sum())
    flip_body = {b.body for b in plan.bodies if b.action == "fill" and b.flip}
    flip = np.isin(plan.face_body, sorted(flip_body))
    F[flip] = F[flip][:, ::-1]
    records = []
    for loop, patch in zip(loops, patches):
        if loop.body in flip_body:
            patch[:] = patch[:, ::-1]
        records.append(RepairRecord(
            "filled_hole", f"filled a hole of {len(loop.vertices)} edges in body {loop.body} "
            f"({100 * loop.area / surface_area:.3g}% of the surface"
            + (", a non-planar patch" if loop.kind == "least_area" else "") + ")", area=loop.area,
            where=tuple(float(x) for x in loop.centroid),
            extra={"share": loop.area / surface_area, "planarity": loop.planarity, "edges": len(loop.vertices),
                   "patch": loop.kind}))
    if flip.any():
        records.append(RepairRecord("flipped_winding", f"turned {len(flip_body)} inside-out bodies outward",
                                    count=int(flip.sum())))
    faces = np.vstack([F] + patches) if patches else F
    mask = np.zeros(len(faces), dtype=bool)
    mask[len(F):] = True
    return FilledMesh(vertices=W, faces=faces, patch=mask, flipped_faces=int(flip.sum()), records=records)
