"""The ``cage`` stage's work: the binary search on the offset (paper Algorithm 2) and its checks.

:func:`fracture_cli.stages.cage.cage` is the stage's entry point (its docstring says what is made);
this module does it, so that the package itself loads nothing heavy.
"""

from __future__ import annotations

import logging
import math
import time
from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.edgelengths import longest_edges
from fracture_cli.geometry.rows import group_rows, used_vertices
from fracture_cli.geometry.scenes import surface_scene
from fracture_cli.stages.cage.options import STAGE, CageOptions
from fracture_cli.stages.tetra import tetgen as _tetgen
from fracture_cli.types import Cage, SurfaceMesh

if TYPE_CHECKING:
    from fracture_cli.geometry.surface_query import SurfaceQuery

log = logging.getLogger(__name__)

# Input triangles whose distance to a cage, bounded below from their corners' clearance, exceeds this
# cannot touch it (the bound is exact up to float64 rounding; the margin dates from float32 distances).
_REACH_MARGIN = 1e-5

# Accepted deviation of the decimated face count from the target.
FACE_COUNT_TOLERANCE = 0.10

# PLC, keep the boundary (without Y tet counts explode), no mesh optimization
# (-O0: it only improves tet quality, which the tetra stage does once, and it
# can take minutes on some cages), quiet.
SEARCH_SWITCHES = "pYO0Q"

def auto_grid_resolution(target_faces: int) -> int:
    """Distance-grid cells along the diagonal for a cage of ``target_faces`` triangles.

    The grid must resolve features a few times smaller than a cage edge, and
    cage edges shrink like ``1 / sqrt(target_faces)``.
    """
    return int(np.clip(round(2.2 * math.sqrt(target_faces)), 48, 256))


class _DistanceField:
    """Unsigned distance to the input on a regular grid, computed lazily in narrow bands.

    Exact distances (:func:`fracture_cli.geometry.surface_query.distances`) are expensive
    far from the surface and only needed near the level set being extracted. A
    cheap bracket ``lower <= D <= upper`` for every grid point comes from a
    Euclidean distance transform of surface samples rasterized onto the grid;
    exact values are computed only where the bracket overlaps ``[d - h, d + h]``
    (each search bounded by the point's ``upper``), and cached across offsets.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, query: SurfaceQuery, spacing: float,
                 max_offset: float):
        from scipy import ndimage

        self.query = query
        self.spacing = h = float(spacing)
        self.max_offset = float(max_offset)
        pad = self.max_offset + 3.0 * h
        # The fractional shift keeps grid planes off the input's own planes
        # (axis-aligned assets), avoiding exact ties in the level set.
        lo = vertices.min(axis=0) - pad - 0.3183 * h
        hi = vertices.max(axis=0) + pad
        self.shape = tuple(int(k) for k in np.ceil((hi - lo) / h).astype(np.int64) + 1)
        self.origin = lo
        samples = _surface_samples(vertices, faces, h)
        index = np.rint((samples - lo) / h).astype(np.int64)
        index = np.clip(index, 0, np.array(self.shape) - 1)
        free = np.ones(self.shape, dtype=bool)
        free[index[:, 0], index[:, 1], index[:, 2]] = False
        edt = ndimage.distance_transform_edt(free, sampling=h)
        rounding = 0.5 * math.sqrt(3.0) * h
        # Every surface point is within h of a sample, every sample within `rounding` of its node.
        self.lower = edt - h - rounding
        self.upper = edt + rounding
        self.exact = np.full(self.shape, np.nan)
        self.exact_count = 0

    def covers(self, d: float) -> bool:
        return d <= self.max_offset

    def values(self, d: float) -> np.ndarray:
        """Grid values whose level set ``d`` equals that of the true distance (cells straddling it are exact)."""
        from fracture_cli.geometry.surface_query import distances  # compiled (numba): imported when first needed

        h = self.spacing
        need = (self.lower <= d + h) & (self.upper >= d - h) & np.isnan(self.exact)
        idx = np.flatnonzero(need)
        if len(idx):
            ijk = np.stack(np.unravel_index(idx, self.shape), axis=1)
            points = self.origin + ijk * h
            # `upper` bounds the distance (up to the rounding of the samples): it only prunes the search.
            dist = distances(self.query, points, self.upper.flat[idx])
            beyond = np.flatnonzero(np.isinf(dist))
            if len(beyond):
                dist[beyond] = distances(self.query, points[beyond])
            self.exact.flat[idx] = dist
            self.exact_count += len(idx)
        known = ~np.isnan(self.exact)
        return np.where(known, self.exact, np.where(self.lower > d, self.lower, self.upper))


def _surface_samples(vertices: np.ndarray, faces: np.ndarray, spacing: float) -> np.ndarray:
    """Points on the surface such that every surface point is within ``spacing`` of one."""
    longest = longest_edges(vertices, faces)
    parts = [vertices]
    # Triangles with edges <= spacing are covered by their corners; split the others.
    n_split = np.ceil(longest / spacing).astype(np.int64)
    for n in np.unique(n_split[n_split > 1]):
        tri = vertices[faces[n_split == n]]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = (i + j) <= n
        u = (i[keep] / n)[:, None]
        v = (j[keep] / n)[:, None]
        bary = np.concatenate([1.0 - u - v, u, v], axis=1)  # (k, 3)
        parts.append(np.einsum("kc,tcd->tkd", bary, tri).reshape(-1, 3))
    return np.concatenate(parts, axis=0)


def _outer_level_set(values: np.ndarray, d: float, origin: np.ndarray,
                     spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes of the outer sheet of ``{values = d}``.

    The level set of an unsigned distance has an inner sheet inside solid inputs
    and sheets around cavities; keeping only the boundary of the region reached
    from the grid border fills them all without needing a sign.
    """
    from scipy import ndimage
    from skimage.measure import marching_cubes

    outside = values > d
    labels, _ = ndimage.label(outside)
    border = np.unique(np.concatenate([
        labels[0].ravel(), labels[-1].ravel(), labels[:, 0].ravel(),
        labels[:, -1].ravel(), labels[:, :, 0].ravel(), labels[:, :, -1].ravel()]))
    border = border[border > 0]
    reached = np.isin(labels, border)
    field = np.where(reached | ~outside, values, d - spacing)
    verts, faces, _, _ = marching_cubes(field, level=d, spacing=(spacing,) * 3, allow_degenerate=False)
    return verts.astype(np.float64) + origin, faces.astype(np.int64)


def _decimate(vertices: np.ndarray, faces: np.ndarray, target: int, decimator: str) -> tuple[np.ndarray, np.ndarray]:
    """Quadric decimation to ``target`` faces; unreferenced vertices removed."""
    if len(faces) > target:
        if decimator == "fast-simplification":
            try:
                import fast_simplification
            except ImportError:
                raise StageError("decimator 'fast-simplification' needs the fast-simplification package "
                                 "(pip install fast-simplification), or use decimator 'open3d'", stage=STAGE) from None
            # agg 4 (default 7) keeps the offset surface about as faithfully as
            # open3d's decimation at a tenth of its cost; it sometimes stalls
            # above the target, and a more aggressive pass then finishes the job.
            for agg in (4.0, 7.0, 10.0):
                vertices, faces = fast_simplification.simplify(vertices, np.asarray(faces, dtype=np.int32),
                                                               target_count=int(target), agg=agg)
                if len(faces) <= (1.0 + FACE_COUNT_TOLERANCE) * target:
                    break
        else:
            # open3d loads only for the optional open3d decimator
            from fracture_cli.geometry.open3d_bridge import open3d as _import_open3d
            o3d = _import_open3d()

            mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices),
                                             o3d.utility.Vector3iVector(faces.astype(np.int32)))
            mesh = mesh.simplify_quadric_decimation(target_number_of_triangles=int(target))
            vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    used, inverse = np.unique(faces, return_inverse=True)
    return vertices[used], inverse.reshape(-1, 3).astype(np.int64)


class _ContainmentCheck:
    """Strict containment of the input in a candidate cage, independent of how the cage was built.

    Passes when (1) every input vertex is at least :data:`~fracture_cli.geometry.tolerances.WELD`
    from the cage surface (normalized units: a clearance that any later rounding, TetGen's or the tetra
    stage's, keeps positive), (2) every input vertex is inside the cage by a ray-parity
    vote (:func:`fracture_cli.geometry.surface_query.inside`), and (3) no input triangle
    intersects or touches a cage triangle (exact separating-axis tests in
    float64, after a broad phase). (1)+(3) mean no part of the input surface
    meets the cage; with (2) every connected part of the input is inside.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, query: SurfaceQuery, cell: float):
        self.vertices = vertices
        self.faces = faces
        self.query = query
        self.cell = cell
        # Only vertices of triangles count; loaders may leave unreferenced ones.
        used = used_vertices(faces, len(vertices))
        # One query per position (UV seams split vertices); the queries' order does not matter, only which
        # corners share one.
        inverse = group_rows(vertices[used])
        first = np.empty(int(inverse.max()) + 1 if len(inverse) else 0, dtype=np.int64)
        first[inverse] = np.arange(len(inverse))  # any vertex of a position stands for it
        self.query_vertices = vertices[used][first]
        # Query point of every corner, and every triangle's longest edge: no point of a triangle is farther
        # than that from any of its corners.
        position = np.zeros(len(vertices), dtype=np.int64)
        position[used] = inverse
        self.corner_query = position[faces]
        self.longest_edge = longest_edges(vertices, faces)
        # A position's clearance matters only up to its triangles' longest edge plus the margin (beyond it none
        # of them can reach the cage, see __call__): the distance searches stop there.
        self.reach_bound = np.zeros(len(self.query_vertices))
        np.maximum.at(self.reach_bound, self.corner_query.reshape(-1), np.repeat(self.longest_edge, 3))
        self.reach_bound += _REACH_MARGIN

    def __call__(self, cage_vertices: np.ndarray, cage_faces: np.ndarray) -> str | None:
        """Return why the cage does not strictly contain the input, or None if it does."""
        from fracture_cli.geometry.surface_query import build, distances, inside  # compiled: imported when first needed

        cage_query = build(cage_vertices, cage_faces)
        points = self.query_vertices
        # Exact up to reach_bound (inf beyond: such a position is far enough for both tests below).
        clearance = distances(cage_query, points, self.reach_bound)
        too_close = int(np.sum(clearance < tol.WELD))
        if too_close:
            return f"{too_close} input vertices touch the cage"
        outside = int(np.sum(~inside(cage_query, points)))
        if outside:
            return f"{outside} input vertices outside"
        # Only cage triangles whose bounding sphere reaches the input can cross it.
        corners = cage_vertices[cage_faces]
        centre = corners.mean(axis=1)
        radius = np.linalg.norm(corners - centre[:, None, :], axis=2).max(axis=1)
        reach = radius + tol.WELD
        near = np.flatnonzero(distances(self.query, centre, reach) <= reach)
        # Likewise only input triangles that may reach the cage: a triangle is at least its farthest corner's
        # clearance minus its longest edge away from it (most of a million-triangle input is not, and
        # testing it against the cage triangles took most of the stage). The triangles left out do not touch
        # the cage; the separating-axis test could have reported them only through a degenerate axis.
        reach = clearance[self.corner_query].max(axis=1) - self.longest_edge
        close = np.flatnonzero(reach <= _REACH_MARGIN)
        if len(close) == 0 or len(near) == 0:
            return None
        faces = self.faces[close]
        boxes = trigeom.triangle_boxes(self.vertices, faces)
        grid = trigeom.BoxGrid(boxes, max(trigeom.default_cell(boxes), self.cell))
        pairs = trigeom.mesh_intersections(cage_vertices, cage_faces, self.vertices, faces, grid_b=grid,
                                           candidates_a=near)
        if len(pairs):
            return f"{len(np.unique(pairs[:, 0]))} cage triangles cross the input"
        return None


def nested_cage(surface: SurfaceMesh, options: CageOptions) -> Cage:
    """The stage's work (:func:`fracture_cli.stages.cage.cage`)."""
    vertices = np.asarray(surface.vertices, dtype=np.float64)
    faces = np.asarray(surface.faces, dtype=np.int64)
    if len(faces) == 0 or len(vertices) == 0:
        raise StageError("the input has no triangles", stage=STAGE)
    if not np.all(np.isfinite(vertices)):
        raise StageError("the input has non-finite vertex coordinates", stage=STAGE)
    diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    if diagonal <= 0:
        raise StageError("the input is a single point; nothing to enclose", stage=STAGE)

    started = time.perf_counter()
    _tetgen.prestart()  # its start-up runs beside the first try's distance field and marching cubes
    resolution = options.grid_resolution or auto_grid_resolution(options.target_faces)
    spacing = diagonal / resolution
    query = surface_scene(surface.vertices, surface.faces)  # the pieces stage and the checks query it again
    # About the edge length of the target cage on a unit-area surface: the broad-phase cell.
    cage_edge = diagonal * math.sqrt(4.0 / (math.sqrt(3.0) * options.target_faces))
    check = _ContainmentCheck(vertices, faces, query, 0.5 * cage_edge)
    log.info("cage: %d input triangles, grid spacing %.4g (resolution %d), target %d faces",
             len(faces), spacing / diagonal, resolution, options.target_faces)
    search = _Search(vertices, faces, query, spacing, diagonal, options, check)
    d, cage_vertices, cage_faces = search.run()
    log.info("cage: offset %.4f, %d faces, %d tries, %.2f s (%d exact distances)", d / diagonal,
             len(cage_faces), len(search.entries), time.perf_counter() - started,
             search.field.exact_count if search.field else 0)
    return Cage(vertices=cage_vertices, faces=cage_faces, offset=d / diagonal, log=tuple(search.entries),
                normalization=surface.normalization)


class _Search:
    """The offset search of :func:`cage`: bracket upward from the initial offset, then bisect."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, query: SurfaceQuery, spacing: float,
                 diagonal: float, options: CageOptions, check: _ContainmentCheck):
        self.vertices, self.faces, self.query = vertices, faces, query
        self.spacing, self.diagonal, self.options, self.check = spacing, diagonal, options, check
        self.field: _DistanceField | None = None
        self.entries: list[dict] = []
        self.best: tuple[float, np.ndarray, np.ndarray] | None = None  # (d, vertices, faces)

    def attempt(self, d: float) -> bool:
        """Try offset ``d`` (logged in :attr:`entries`); whether it gave a valid cage."""
        seconds = {"distance": 0.0, "marching_cubes": 0.0, "decimation": 0.0,
                   "self_intersection": 0.0, "check": 0.0, "tetgen": 0.0}
        entry = {"offset": d / self.diagonal, "faces": 0, "tets": 0, "ok": False, "reason": "", "seconds": seconds}
        tick = time.perf_counter()
        if self.field is None or not self.field.covers(d):
            # Large offsets give smooth surfaces: a coarser grid (at most d / 4)
            # keeps the padded grid's memory bounded.
            field_spacing = self.spacing if self.field is None else max(self.spacing, 0.25 * d)
            self.field = _DistanceField(self.vertices, self.faces, self.query, field_spacing,
                                        max(4.0 * d, 8.0 * field_spacing))
        values = self.field.values(d)
        seconds["distance"] = time.perf_counter() - tick
        result = None
        try:
            result = _try_offset(d, values, self.field, self.options, self.check, seconds, entry)
        finally:
            self.entries.append(entry)
            log.info("cage: iteration %d offset %.4f faces %d tets %d %s", len(self.entries), d / self.diagonal,
                     entry["faces"], entry["tets"], "ok" if entry["ok"] else f"failed: {entry['reason']}")
        if result is not None and (self.best is None or d < self.best[0]):
            self.best = (d, result[0], result[1])
        return result is not None

    def run(self) -> tuple[float, np.ndarray, np.ndarray]:
        """The tightest offset that passed, and its cage's vertices and faces.

        Containment is not monotone in ``d``, so the search brackets upward
        (doubling) until something works, then bisects between the largest
        failure and the smallest success, keeping the tightest success seen.
        """
        options, diagonal = self.options, self.diagonal
        d = options.initial_offset * diagonal
        lo = None  # largest offset known to fail below the best success
        while len(self.entries) < options.max_iterations and d <= options.max_offset * diagonal:
            if self.attempt(d):
                break
            lo = d
            d *= 2.0
        if self.best is None:
            reasons = "; ".join(f"{e['offset']:.4f}: {e['reason']}" for e in self.entries)
            raise StageError(
                f"no valid cage found in {len(self.entries)} tries (offset: reason) {reasons}. "
                "Try a larger target_faces, initial_offset or max_offset, or repair the input", stage=STAGE)
        if lo is None:
            # The first offset worked: halve until one fails (or the grid cannot resolve smaller offsets).
            d = self.best[0] / 2.0
            while len(self.entries) < options.max_iterations and d >= 0.25 * self.spacing:
                if not self.attempt(d):
                    lo = d
                    break
                d /= 2.0
            if lo is None:
                lo = self.best[0]  # nothing failed down to the grid's limit: no bisection
        hi = self.best[0]
        while len(self.entries) < options.max_iterations and hi - lo > options.tolerance * diagonal:
            mid = 0.5 * (lo + hi)
            if self.attempt(mid):
                hi = mid
            else:
                lo = mid
        return self.best


def _try_offset(d: float, values: np.ndarray, field: _DistanceField, options: CageOptions, check: _ContainmentCheck,
                seconds: dict[str, float], entry: dict[str, object]) -> tuple[np.ndarray, np.ndarray] | None:
    """One try of the search at offset ``d``; returns ``(vertices, faces)`` or None (reason in ``entry``)."""
    tick = time.perf_counter()
    mc_vertices, mc_faces = _outer_level_set(values, d, field.origin, field.spacing)
    seconds["marching_cubes"] = time.perf_counter() - tick
    if len(mc_faces) == 0:
        entry["reason"] = "empty offset surface"
        return None

    tick = time.perf_counter()
    V, F = _decimate(mc_vertices, mc_faces, options.target_faces, options.decimator)
    seconds["decimation"] = time.perf_counter() - tick
    entry["faces"] = len(F)
    if abs(len(F) - options.target_faces) > FACE_COUNT_TOLERANCE * options.target_faces:
        entry["reason"] = f"{len(F)} faces after decimation (offset surface had {len(mc_faces)})"
        return None

    tick = time.perf_counter()
    reason = None
    if not trigeom.edge_manifold_closed(F):
        reason = "decimation left open or non-manifold edges"
    elif not trigeom.vertex_manifold(F):
        reason = "decimation left non-manifold vertices"
    else:
        if trigeom.signed_volume(V, F) < 0:
            F = F[:, ::-1].copy()
        crossing = trigeom.self_intersections(V, F)
        if len(crossing):
            reason = f"decimation made {len(crossing)} self-intersecting face pairs"
    seconds["self_intersection"] = time.perf_counter() - tick
    if reason:
        entry["reason"] = reason
        return None

    tick = time.perf_counter()
    reason = check(V, F)
    seconds["check"] = time.perf_counter() - tick
    if reason:
        entry["reason"] = reason
        return None

    tick = time.perf_counter()
    try:
        _, tets = _tetgen.tetrahedralize(V, F, SEARCH_SWITCHES, timeout=options.tetgen_timeout)
    except _tetgen.TetGenFailure as failure:
        entry["reason"] = failure.reason
        return None
    finally:
        seconds["tetgen"] = time.perf_counter() - tick
    entry["tets"] = len(tets)
    entry["ok"] = True
    return V, F
