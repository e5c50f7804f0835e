"""Thicken an open sheet inward: the visible side stays where it is, the thickness goes behind it.

A sheet's visible side is the side its face normals point to. The solid is
the sheet, a copy offset behind it along the (area-weighted) vertex normals,
and a rim strip joining the two along the sheet's boundary. The offset at a
vertex is the requested thickness, but at most:

* a fraction (``max_free_fraction``) of the free distance behind it (a ray
  cast to the opposite wall or the next fold), so the back never reaches
  another part of the surface;
* inside the input's bounding box: a back point that would leave it is moved
  onto the box (so it slides along the box where the sheet meets it at a
  grazing angle, as at the rim of an awning), and nothing pokes out of the box
  the user modelled;

and it is halved where an offset face would flip. A sheet whose thickness
must drop below ``min_fraction`` of the request somewhere (its back side lies
on its bounding box, or it folds onto itself) is refused rather than made
into a zero-thickness solid.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.edges import edge_table
from fracture_cli.geometry.tetgeom import triangle_areas
from fracture_cli.stages.repair.records import RepairRecord

# Rounds of halving the offset where an offset face flips.
_FLIP_ROUNDS = 12
# Rays start this far behind the sheet (relative to its bounding-box diagonal), so they do not hit their own
# faces: far above the rounding of the float64 ray test, and what the open3d (float32) scene needed.
_RAY_START = 1e-5


@dataclass(frozen=True)
class ThickenedSheet:
    """A closed solid made from a sheet.

    Attributes
    ----------
    vertices : (n2, 3) float64
        The sheet's vertices (unchanged, same ids), then the offset copies, then
        the rim's own copies (one per boundary vertex on each side).
    faces : (m2, 3) int64
        The sheet's faces (unchanged), then the back faces, then the rim strip.
    kind : (m2,) int8
        0 sheet (the visible side), 1 back, 2 rim.
    source_vertex : (n2,) int64
        The sheet vertex every output vertex copies (for attributes).
    thickness : (n,) float64
        The offset at every input vertex (0 where unused).
    records : list of RepairRecord
    """

    vertices: np.ndarray
    faces: np.ndarray
    kind: np.ndarray
    source_vertex: np.ndarray
    thickness: np.ndarray
    records: list[RepairRecord] = field(default_factory=list)


def free_distance(V: np.ndarray, F: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance (k,) along each ray (origins (k, 3), unit directions (k, 3)) to the first face hit (inf if none)."""
    from fracture_cli.geometry.surface_query import build, first_hits  # compiled (numba): imported when first needed

    return first_hits(build(V, F), origins, directions)


def _back_positions(V: np.ndarray, F: np.ndarray, normal: np.ndarray, thickness: float, box: np.ndarray | None,
                    max_free_fraction: float) -> np.ndarray:
    """Back-side position (n, 3) of every vertex: behind it by the request, limited by free space and the box.

    A back point outside the box is moved onto it (it slides along the box
    where the normal is nearly parallel to a box face, as at the rim of an
    awning). The offset is halved where a back face would flip.
    """
    used = np.unique(F)
    t = np.zeros(len(V))
    gap = _RAY_START * float(np.linalg.norm(np.ptp(V[used], axis=0)))
    free = free_distance(V, F, V[used] - gap * normal[used], -normal[used]) + gap
    t[used] = np.minimum(thickness, max_free_fraction * free)
    front = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    for _ in range(_FLIP_ROUNDS):
        back = V - t[:, None] * normal
        if box is not None:
            back = np.clip(back, box[0], box[1])
        fn = np.cross(back[F[:, 1]] - back[F[:, 0]], back[F[:, 2]] - back[F[:, 0]])
        bad = np.einsum("ij,ij->i", fn, front) <= 0
        if not bad.any():
            break
        t[np.unique(F[bad])] *= 0.5
    return back


def thicken_inward(V: np.ndarray, F: np.ndarray, thickness: float, *, box: np.ndarray | None = None,
                   max_free_fraction: float = 0.45, min_fraction: float = 1e-3) -> ThickenedSheet:
    """Make a closed solid of an open sheet by giving it thickness behind its visible side.

    Parameters
    ----------
    V : (n, 3) float
        Positions (welded).
    F : (m, 3) int
        The sheet's faces: edge-manifold, consistently oriented, normals
        towards the visible side; open (a closed body has nothing to thicken).
    thickness : float
        Requested thickness, in the units of ``V``.
    box : (2, 3) float, optional
        The input's bounding box; the solid stays inside it.
    max_free_fraction : float, optional (default 0.45)
        At most this fraction of the free distance behind a vertex.
    min_fraction : float, optional (default 1e-3)
        Refuse when the offset must drop below this fraction of ``thickness``.

    Returns
    -------
    ThickenedSheet

    Raises
    ------
    StageError
        When the sheet cannot be thickened inward by at least
        ``min_fraction * thickness`` everywhere.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    normal = trigeom.vertex_normals(V, F)
    if box is not None:
        box = np.asarray(box, dtype=np.float64)
    back = _back_positions(V, F, normal, thickness, box, max_free_fraction)
    t = np.linalg.norm(back - V, axis=1)
    used = np.unique(F)
    thin = used[t[used] < min_fraction * thickness]
    if len(thin):
        where = ", ".join(f"({x:.4g}, {y:.4g}, {z:.4g})" for x, y, z in V[thin[:3]])
        raise StageError(f"cannot thicken the open sheet inward by {thickness:.3g}: at {len(thin)} vertices (e.g. "
                         f"{where}) there is less than {min_fraction:g} of that behind it before the sheet folds onto "
                         "itself or leaves its bounding box; give it thickness in your modelling tool", stage="repair")
    return _build(V, F, back, t, thickness)


def _build(V: np.ndarray, F: np.ndarray, offset: np.ndarray, t: np.ndarray, thickness: float) -> ThickenedSheet:
    """Assemble sheet, back and rim into one closed mesh."""
    n = len(V)
    used = np.unique(F)
    back_id = np.full(n, -1, dtype=np.int64)
    back_id[used] = n + np.arange(len(used))
    table = edge_table(F)
    boundary = table.sides[table.count[table.edge] == 1]  # directed as in the sheet faces: a -> b
    ends = np.unique(boundary)
    m0 = n + len(used)
    rim_front = np.full(n, -1, dtype=np.int64)
    rim_front[ends] = m0 + np.arange(len(ends))
    rim_back = np.full(n, -1, dtype=np.int64)
    rim_back[ends] = m0 + len(ends) + np.arange(len(ends))
    a, b = boundary[:, 0], boundary[:, 1]
    # The rim runs each boundary edge backwards on the front side (b -> a) and forwards on the back.
    rim = np.concatenate([np.column_stack([rim_front[b], rim_front[a], rim_back[a]]),
                          np.column_stack([rim_front[b], rim_back[a], rim_back[b]])])
    back = back_id[F][:, ::-1]
    vertices = np.vstack([V, offset[used], V[ends], offset[ends]])
    source = np.concatenate([np.arange(n), used, ends, ends])
    faces = np.vstack([F, back, rim])
    kind = np.concatenate([np.zeros(len(F)), np.ones(len(back)), np.full(len(rim), 2)]).astype(np.int8)
    thinned = int((t[used] < thickness * (1 - tol.TIE)).sum())
    area = float(triangle_areas(V, F).sum())
    records = [RepairRecord("thickened_sheet", f"thickened an open sheet of {len(F)} faces behind its visible side"
                            + (f" (thinner at {thinned} vertices, down to {t[used].min() / thickness:.2g} of the "
                               "thickness)" if thinned else ""),
                            count=len(F), area=area, where=tuple(float(x) for x in V[used].mean(axis=0)),
                            extra={"thickness": float(thickness), "min_thickness": float(t[used].min()),
                                   "thinned_vertices": thinned, "direction": "inward"})]
    return ThickenedSheet(vertices=vertices, faces=faces, kind=kind, source_vertex=source, thickness=t,
                          records=records)
