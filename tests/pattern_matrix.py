"""Issue 32's matrix: every pattern kind on every sample asset, faults with and without noise, checked independently.

Shared by tests/test_pattern_matrix.py (half the matrix in ``make test``, every asset and every kind with noise
on and off; the whole with ``--full-matrix``) and bench/bench_patterns.py (the whole matrix, a table in
bench/RESULTS.md).

Each cell is one bake (:func:`bake_cell`, in this process) of a sample asset with the recipe it is made for
(:data:`ASSETS`), the pattern kind set by ``--set`` with a few cells (:data:`KINDS`), small settings
(:data:`SMALL`: a 500-face cage, 4 modes, one field refinement) and, with noise, :data:`NOISE`. The checks
(:func:`check_cell`) read the files as written and share no geometry code with the library
(tests/invariants.py reads the GLB; the overlaps of the collision parts are intersections of half-spaces by
scipy, not manifold3d's booleans):

* closed: every fragment welded by its stored float32 positions is a closed, consistently oriented
  2-manifold (no open, pinched or misoriented edge, no degenerate face);
* one body: each fragment's faces are connected through two-face edges;
* volume: the fragments' volumes sum to the input solid's (the report's ``input_volume``) within
  :data:`VOLUME_TOLERANCE`; for a closed input that volume is also the input file's own, within the same;
* overlap: every two convex collision parts of the GLB (``OMI_physics_shape``), of one fragment or of two,
  share less than :data:`OVERLAP_LIMIT` of the smaller one's volume;
* budget: the GLB's render triangles are at most twice the triangles of the solid that was cut plus 64 per
  fragment (the report's ``triangle_budget``, the README's definition).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np
from invariants import check_glb, input_box, read_collision_parts, read_triangles
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(REPO, "sample_assets")

# Each sample asset with the recipe it is made for (the manifest's, and the pane's and the wall's own).
ASSETS = {"chair.glb": "wood", "pillar.glb": "stone", "vase.obj": "ceramic", "pane.glb": "glass_pane",
          "wall.glb": "brick_wall"}
# A few cells of each kind (lengths are fractions of the diagonal, so they fit every asset).
KINDS = {
    "voronoi": ("pattern.count=8",),
    "clustered": ("pattern.clusters=2", "pattern.count=3", "pattern.spread=0.1"),
    "radial": ("pattern.rings=2", "pattern.spokes=5"),
    "slices": ("pattern.slice_axes=xy", "pattern.slices=2", "pattern.angle_jitter=10.0"),
    "bricks": ("pattern.brick_size=[0.3, 0.15, 1.0]",),
    "profile": ("pattern.cuts=4", "pattern.profiles=[{ points = [[0.0, 0.0], [0.3, 0.06], [0.6, -0.06], "
                "[1.0, 0.0]], weight = 1.0 }, { rotation = 90.0, weight = 1.0 }]"),
}
SMALL = ("cage.target_faces=500", "modes.num_modes=4", "smooth.refine=1", "pieces.min_fragment_fraction=0.002")
NOISE = ("faults.noise=0.003", "faults.noise_octaves=2", "faults.noise_subdivisions=1")
VOLUME_TOLERANCE = 1e-6
OVERLAP_LIMIT = 0.01


@dataclass
class CellResult:
    """One bake of the matrix and what the checks found."""

    asset: str
    kind: str
    noise: bool
    fragments: int = 0
    triangles: int = 0
    budget: int = 0
    volume_error: float = float("nan")
    overlap: float = float("nan")
    parts: int = 0
    seconds: float = 0.0
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Every check passed."""
        return not self.problems


def cell_settings(asset: str, kind: str, noise: bool) -> list[str]:
    """The ``--set`` values of one cell (after the asset's recipe)."""
    return [*SMALL, f"pattern.kind={kind}", *KINDS[kind], *(NOISE if noise else ())]


def bake_cell(asset: str, kind: str, noise: bool, out: str, cache_dir: str | None = None) -> CellResult:
    """Bake one cell into ``out`` (this process, ``cache_dir``: a stage cache) and check it; a failed bake is a
    problem, not an exception."""
    from fracture_cli.errors import FractureError
    from fracture_cli.pipeline.bake import bake
    from fracture_cli.pipeline.recipe import load_recipe

    result = CellResult(asset, kind, noise)
    started = time.perf_counter()
    try:
        report = bake(os.path.join(SAMPLES, asset), out,
                      load_recipe(ASSETS[asset], cell_settings(asset, kind, noise)), cache_dir=cache_dir).report
    except FractureError as error:
        result.seconds = time.perf_counter() - started
        result.problems.append(f"bake failed: {str(error).splitlines()[0][:300]}")
        return result
    result.seconds = time.perf_counter() - started
    return check_cell(result, out, report)


def check_cell(result: CellResult, out: str, report: dict) -> CellResult:
    """The module docstring's checks on a bake's files in ``out``, into ``result``."""
    stem = os.path.splitext(result.asset)[0]
    glb = os.path.join(out, f"{stem}.glb")
    source = os.path.join(SAMPLES, result.asset)
    solid_volume = float(report["checks"]["input_volume"])
    written = check_glb(glb, reference_volume=solid_volume, volume_tolerance=VOLUME_TOLERANCE,
                        reference_box=input_box(source))
    result.problems += written.problems[:5]
    result.fragments = len(written.fragments)
    result.volume_error = float(written.volume_error or 0.0)
    file_volume = _closed_volume(read_triangles(source))
    if file_volume is not None and abs(file_volume - solid_volume) > VOLUME_TOLERANCE * abs(file_volume):
        result.problems.append(f"the solid cut has volume {solid_volume:.9g}, the closed input {file_volume:.9g}")
    result.triangles = sum(f.triangles for f in written.fragments)
    result.budget = int(report["checks"]["triangle_budget"])
    if result.triangles > result.budget:
        result.problems.append(f"{result.triangles} triangles written, over the budget of {result.budget}")
    parts = read_collision_parts(glb)
    result.parts = len(parts)
    result.overlap = max_part_overlap([points for _, points in parts])
    if not parts:
        result.problems.append("no collision parts")
    if result.overlap >= OVERLAP_LIMIT:
        result.problems.append(f"collision parts overlap by {100 * result.overlap:.1f}% of the smaller one")
    return result


def _closed_volume(triangles: np.ndarray) -> float | None:
    """The volume a triangle soup (m, 3, 3) encloses when every edge (by exact position) has two faces, else None."""
    corners = triangles.reshape(-1, 3)
    _, ids = np.unique(corners, axis=0, return_inverse=True)
    W = ids.reshape(-1, 3)
    edges = np.sort(np.concatenate([W[:, [0, 1]], W[:, [1, 2]], W[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    if np.any(counts != 2):
        return None
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def max_part_overlap(parts: list[np.ndarray]) -> float:
    """Largest ``vol(A ^ B) / min(vol A, vol B)`` over pairs of convex parts (corners (k, 3)) whose boxes meet."""
    hulls = []
    for points in parts:
        try:
            hulls.append(ConvexHull(points))
        except QhullError:
            hulls.append(None)
    boxes = np.array([[*p.min(axis=0), *p.max(axis=0)] for p in parts]).reshape(-1, 6)
    worst = 0.0
    for i in range(len(parts)):
        meet = np.flatnonzero(np.all(boxes[i + 1:, :3] < boxes[i, 3:], axis=1)
                              & np.all(boxes[i + 1:, 3:] > boxes[i, :3], axis=1)) + i + 1
        for j in meet.tolist():
            a, b = hulls[i], hulls[j]
            if a is None or b is None:
                continue
            shared = convex_intersection_volume(a.equations, b.equations)
            worst = max(worst, shared / max(min(a.volume, b.volume), 1e-300))
    return worst


def convex_intersection_volume(planes_a: np.ndarray, planes_b: np.ndarray) -> float:
    """Volume of the intersection of two convex polytopes given as half-spaces ``n . x + d <= 0`` (rows (n, d)).

    The deepest point (the centre of the largest inscribed ball, a linear program) is the interior point qhull's
    half-space intersection needs; a ball radius below 1e-9 of the polytopes' size counts as no overlap.
    """
    planes = np.vstack([planes_a, planes_b])
    norms = np.linalg.norm(planes[:, :3], axis=1)
    # maximise r subject to n . x + r |n| <= -d
    solution = linprog(c=[0.0, 0.0, 0.0, -1.0], A_ub=np.column_stack([planes[:, :3], norms]), b_ub=-planes[:, 3],
                       bounds=[(None, None)] * 3 + [(0.0, None)], method="highs")
    if solution.status != 0:
        return 0.0
    size = float(np.abs(planes[:, 3]).max() / max(norms.min(), 1e-300))
    if solution.x[3] <= 1e-9 * max(size, 1e-300):
        return 0.0
    try:
        corners = HalfspaceIntersection(planes, solution.x[:3]).intersections
        return float(ConvexHull(corners).volume)
    except QhullError:
        return 0.0


def table(results: list[CellResult]) -> list[str]:
    """A markdown table of the matrix: one row per asset and kind, noise off | on in each cell."""
    lines = ["| asset (recipe) | kind | fragments | triangles / budget | volume error | parts | overlap | s | "
             "noise: fragments | triangles / budget | volume error | overlap | s | problems |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    by = {(r.asset, r.kind, r.noise): r for r in results}
    for asset in ASSETS:
        for kind in KINDS:
            off, on = by.get((asset, kind, False)), by.get((asset, kind, True))
            if off is None and on is None:
                continue
            cells = [f"{asset} ({ASSETS[asset]})", kind]
            for r, full in ((off, True), (on, False)):
                if r is None:
                    cells += ["-"] * (7 if full else 5)
                    continue
                cells += [str(r.fragments), f"{r.triangles} / {r.budget}", f"{r.volume_error:.1e}"]
                if full:
                    cells.append(str(r.parts))
                cells += [f"{100 * r.overlap:.2f}%", f"{r.seconds:.1f}"]
            problems = [f"{'noise: ' if r.noise else ''}{p}" for r in (off, on) if r is not None for p in r.problems]
            cells.append("; ".join(problems) if problems else "none")
            lines.append("| " + " | ".join(cells) + " |")
    return lines
