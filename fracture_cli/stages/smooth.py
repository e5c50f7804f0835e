"""Laplacian fault smoothing: closed piece regions that partition the cage (ALGORITHM.md section 5)."""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass

import manifold3d
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from fracture_cli import tetgeom, trigeom
from fracture_cli.errors import StageError
from fracture_cli.options import option
from fracture_cli.stages._solids import shell_mask
from fracture_cli.types import Pieces, Regions, SurfaceMesh, TetMesh

log = logging.getLogger(__name__)

STAGE = "smooth"

# Barycentric feasibility tolerance when enumerating cell corners; the fields
# are O(1) (smoothed one-hot values), so an absolute tolerance is meaningful.
_FEASIBLE_TOL = 1e-12
# Below this |det| (rows are O(1)) three planes are treated as not meeting in a point.
_SINGULAR_TOL = 1e-13
# Connected parts of a region below this fraction of its volume are union artefacts.
_SHELL_VOLUME = 1e-9
# Fallback (union) path only: how far apart (unit bbox diagonal) the copies of
# a vertex where a region touches itself are moved.
_PINCH_SEPARATION = 1e-7
# Pieces with at least this margin below the best guaranteed value are never
# candidates in a simplex (field values are O(1)).
_CANDIDATE_TOL = 1e-12
# Field method: smallest weight of a tet (fraction of the mean tet volume) in the lumped mass of the smoothing.
_MIN_TET_WEIGHT = 1e-12
# Field method: the most a vanishing piece's field (values in [0, 1]) may be raised to keep its volume.
_MAX_BIAS = 0.5
# Relative width of the spindle carved around an edge where a tet-aligned region
# touches itself: its notches sit this fraction of the way from the edge's
# midpoint to the opposite vertices (volume change eps^2 of the tets around it).
_PINCH_SPINDLE = 0.02
# Rounds of making tets tet-aligned where a region touches itself along a line.
_MAX_REPAIRS = 12
# Geometric method: weight of a fault-sheet edge in the surface Laplacian, the cotangent weight of an
# equilateral triangulation, so that (M_f + lambda L_f) approximates the continuous operator and lambda
# keeps units of length^2 (uniform weights are an M-matrix: no overshoot on stair-stepped faults).
_SHEET_WEIGHT = 1.0 / np.sqrt(3.0)
# Geometric method: a tet may shrink to this fraction of its volume (never invert or flatten).
_MIN_VOLUME_RATIO = 0.05
# Geometric method: rounds of freezing fault vertices of flattened tets, then halvings of the displacement.
_MAX_FREEZE_ROUNDS = 12
_MIN_DAMPING = 1.0 / 8.0
_MIN_ALPHA = 1.0 / 64.0
# Sliding (geometric method with the input given): the boundary fault curves take the implicit step in this
# many sub-steps of lambda / _SLIDE_STEPS, each followed by a projection onto the original cage surface, so a
# curve flows along the cage instead of cutting through it.
_SLIDE_STEPS = 4
# Sliding: a cage triangle next to a slid vertex must stay this far (unit bbox diagonal) from the input; the
# triangle test is conservative (a separating-axis gap), so the true distance is at least this.
_SLIDE_CLEARANCE = 1e-3


@dataclass(frozen=True)
class SmoothOptions:
    """Options of :func:`smooth`."""

    smoothing: float = option(
        1e-3,
        "fault smoothing lambda in units of (bbox diagonal)^2, about the square of the radius over which faults "
        "are rounded; 0 = faults follow tet faces",
        min=0.0,
    )
    method: str = option(
        "geometric",
        "geometric: move the tet vertices so the tet-aligned faults become smooth surfaces (pieces keep their "
        "tets); field: smooth the piece membership field and cut tets along its level sets",
        choices=("geometric", "field"),
    )
    refine: int = option(
        2,
        "field method: levels of regular 1:8 tet refinement before smoothing, so faults are cut along a finer "
        "mesh than the cage tets (fewer levels when the refined mesh would exceed max_refined_tets); it pays off "
        "when sqrt(smoothing) is at least about the refined tet edge, else the faults zigzag at the fine scale",
        min=0,
        max=3,
    )
    max_refined_tets: int = option(
        400_000,
        "field method: the most tets refinement may create (memory and time grow with it)",
        min=1,
    )
    vanish_fraction: float = option(
        0.01,
        "field method: a piece whose smoothed region is below this fraction of its own volume gets its field "
        "raised to keep about its volume, and if that fails keeps its own tets",
        min=0.0,
        max=1.0,
    )


def smooth(tet_mesh: TetMesh, pieces: Pieces, options: SmoothOptions = SmoothOptions(),
           surface: SurfaceMesh | None = None) -> Regions:
    """Closed regions of space, one per atomic piece, with smoothed faults.

    Parameters
    ----------
    tet_mesh : TetMesh
        The tet mesh of the cage (``n`` vertices, ``t`` tets).
    pieces : Pieces
        Atomic pieces; ``pieces.tet_piece`` (t,) assigns every tet to a piece.
    options : SmoothOptions, optional
        ``smoothing`` (lambda, default 1e-3), ``method`` (default
        ``"geometric"``); field method only: ``refine`` (default 2),
        ``max_refined_tets`` (default 400000) and ``vanish_fraction``
        (default 0.01).
    surface : SurfaceMesh, optional (default None)
        The (repaired) input the cage contains, in the same normalized
        coordinates. Geometric method only: when given, fault vertices on the
        cage boundary may slide along the cage wherever the moved cage still
        strictly contains it; without it cage-boundary vertices never move.

    Returns
    -------
    Regions
        For each piece a closed, edge-manifold, outward-oriented triangle mesh
        (vertices (n_i, 3) float64, faces (m_i, 3) int64) of its region; the
        regions partition the cage. ``vanished`` lists the pieces that kept
        their own tets.

    Raises
    ------
    StageError
        If ``pieces`` does not match ``tet_mesh`` or a region cannot be built.

    Notes
    -----
    ALGORITHM.md section 5. ``lambda`` has units of length^2 in normalized
    coordinates (unit bounding-box diagonal) for both methods: ``sqrt(lambda)``
    is roughly the radius over which faults are rounded, so the same value
    gives the same shapes at any asset scale. ``lambda = 0`` gives tet-aligned
    faults with either method.

    Geometric method (default): every piece keeps exactly its own tets, so no
    piece can vanish and the regions partition the cage by construction; the
    tet vertices move so that the faults (interior faces between tets of
    different pieces) become smooth. Junction curves (fault edges where three
    or more pieces meet) are smoothed first as 1-D curves, ``(M_c + lambda
    L_c) X = M_c X`` (linear-element stiffness, lumped lengths, curve ends
    fixed); then the fault sheets, ``(M_f + lambda L_f) X = M_f X`` (uniform
    edge weights 1/sqrt(3), the cotangent weight of an equilateral mesh, and
    lumped fault areas), with the curves, the cage boundary and points where
    fault sheets touch as Dirichlet data. Without ``surface``, cage-boundary
    vertices never move, so the cage still contains the input. With it, the
    curves where a fault sheet meets the cage boundary are smoothed first, as
    1-D curves (same system, ends at boundary junctions fixed) in
    ``_SLIDE_STEPS`` sub-steps of ``lambda / 4``, each moved vertex projected
    back onto the closest point of the original cage surface, so the cage
    shape barely changes while the faults meet it along smooth curves. The
    moved cage is then checked against the input: a cage triangle next to a
    slid vertex that comes within ``_SLIDE_CLEARANCE`` (1e-3) of an input
    triangle or crosses another cage triangle, and an input vertex near a slid
    vertex that is no longer inside the moved cage (winding number), send the
    slid vertices involved back to where they were, and everything is solved
    again; if that does not settle, no vertex slides (with a warning). The
    other interior vertices follow by harmonic extension (``K d = 0``). A tet may not shrink below 5% of its
    volume: the free fault vertices of offending tets are held at half their
    displacement (repeatedly, then at none) and everything is solved again;
    as a last resort the whole displacement is scaled down, with a warning.
    The regions are then the unions of each piece's deformed tets, built as
    for ``lambda = 0``. Faults can only be as smooth as the vertices that may
    move allow: where pieces are one or two tets thick, most fault vertices
    lie on the cage boundary and stay where they are.

    Field method: the tet mesh is first refined ``refine`` times by regular
    1:8 refinement (:func:`~fracture_cli.tetgeom.refine_red`; fewer levels if
    the result would exceed ``max_refined_tets``), every child keeping its
    parent's piece, so the tet-aligned starting point is unchanged and the
    level sets below are cut along a mesh fine enough to follow the smoothed
    field. Then the one-hot piece field is averaged onto vertices
    (lumped-mass weighted) and smoothed by one implicit diffusion step
    ``Z <- (M_V + lambda K)^-1 M_V Z`` (one sparse factorization, ``p``
    right-hand sides); useful values are around the squared cage-tet edge
    length (1e-4 .. 1e-2). Without refinement, on coarse tet meshes (pieces a
    few tets across), the per-tet gradients of ``Z`` zigzag and faults can get
    rougher, not smoother; refinement pays off when ``sqrt(lambda)`` is at
    least about the refined edge.

    Inside a tet ``Z`` is linear, so the set where piece ``P`` wins is the tet
    clipped by the half-spaces ``Z_P >= Z_Q``: a convex cell. The boundary of
    every region is built directly (multi-label marching tetrahedra): each
    output vertex is identified by the simplex it lies in and the pieces that
    tie there, so neighbouring tets and neighbouring regions share vertices
    bit for bit, and every fault polygon is triangulated once and used by
    both of its sides. ``lambda = 0`` skips the field entirely: averaging the
    one-hot field onto vertices already rounds faults, so "no smoothing"
    means each region is exactly the union of its piece's tets.

    Where a tet-aligned region would touch itself along a tet edge (pieces
    alternating around the edge), importers that weld vertices by position
    would see an edge with four faces. A thin spindle around such an edge
    (width 2% of the surrounding tets) goes to the piece with the most volume
    around it, so regions then touch themselves at isolated points at most.
    A region that still fails the closed, edge-manifold check is rebuilt as a
    union of its cells (manifold3d), with a warning.

    Smoothing never creates or removes a piece. Field method: a piece whose region would
    shrink below ``vanish_fraction`` of its own volume first gets its field
    raised by the constant that gives its region about its own volume
    (estimated per tet, halfway between two ties, at most 0.5), so small pieces stay smooth
    blobs instead of disappearing. If it still vanishes, it is reported in
    ``Regions.vanished`` and keeps exactly its own tets; the field of that piece
    is then ignored everywhere and its tets are claimed by no other piece, so
    the regions still partition the cage. This repeats until no piece vanishes.
    """
    t = tet_mesh.num_tets
    tet_piece = np.asarray(pieces.tet_piece, dtype=np.int64)
    if tet_piece.shape != (t,):
        raise StageError(f"pieces cover {tet_piece.shape[0]} tets but the tet mesh has {t}", stage=STAGE)
    p = pieces.num_pieces
    lam = float(options.smoothing)
    if lam > 0.0 and options.method == "field":
        tet_mesh, tet_piece = _refined(tet_mesh, tet_piece, options.refine, options.max_refined_tets)
        t = tet_mesh.num_tets
    V, T = tet_mesh.vertices, tet_mesh.tets
    topo = _Topology(T, tet_mesh.num_vertices)

    vanished: list[int] = []
    Z = None
    if lam == 0.0 or options.method == "geometric":
        if lam > 0.0:
            V, moves = _smoothed_vertices(tet_mesh, topo, tet_piece, p, lam, surface)
            log.info("%s: geometric smoothing moved %d fault vertices (%d on junction curves, %d slid along the cage, "
                     "%d sent back to keep the cage around the input), %d held back in %d round(s) to keep tets from "
                     "flattening, displacement scale %g", STAGE, moves["moved"], moves["curve"], moves["slid"],
                     moves["reverted"], moves["frozen"], moves["rounds"], moves["alpha"])
        meshes, pinches, repaired = _repaired_regions(V, T, topo, None, np.ones(t, dtype=bool), tet_piece, p)
    else:
        Z, vanished = _winning_field(tet_mesh, topo, tet_piece, pieces, lam, options.vanish_fraction)
        forced, Zv = _forced_field(Z, tet_piece, vanished)
        meshes, pinches, repaired = _repaired_regions(V, T, topo, Zv, forced, tet_piece, p)

    broken = [P for P in range(p) if _region_defects(*meshes[P])]
    if broken:
        log.warning("%s: %d region(s) were not closed and edge-manifold when built directly (e.g. piece %d); "
                    "rebuilding them as unions of cells", STAGE, len(broken), broken[0])
        rebuilt = _union_regions(V, T, Z, tet_piece, p, vanished, broken)
        for P, mesh in zip(broken, rebuilt):
            meshes[P] = mesh
    log.info("%s: %d regions, lambda=%g, %d triangles, %d vanished, %d tet(s) made tet-aligned, %d pinched edge(s) "
             "given a spindle", STAGE, p, lam, sum(len(f) for _, f in meshes), len(vanished), repaired, pinches)
    return Regions(meshes=tuple(meshes), smoothing=lam, vanished=tuple(sorted(vanished)))


def _refined(tet_mesh: TetMesh, tet_piece: np.ndarray, levels: int, max_tets: int):
    """The tet mesh after up to ``levels`` regular refinements (at most ``max_tets`` tets) and its pieces.

    Children keep their parent's piece, so the tet-aligned regions do not
    change; only the field gets a finer mesh to be cut along.
    """
    done = 0
    while done < levels and 8 * tet_mesh.num_tets <= max_tets:
        V, T, parent = tetgeom.refine_red(tet_mesh.vertices, tet_mesh.tets)
        tet_mesh = TetMesh(vertices=V, tets=T, normalization=tet_mesh.normalization)
        tet_piece = tet_piece[parent]
        done += 1
    if done < levels:
        log.info("%s: %d of %d refinement level(s): one more would exceed %d tets", STAGE, done, levels, max_tets)
    if done:
        edge = float(tetgeom.tet_edge_lengths(tet_mesh.vertices, tet_mesh.tets).mean())
        log.info("%s: %d refinement level(s): %d tets, mean edge %.3g (diagonal units)", STAGE, done,
                 tet_mesh.num_tets, edge)
    return tet_mesh, tet_piece


def _repaired_regions(V, T, topo, Zv, forced, tet_piece, p):
    """Direct regions; where a region touches itself along a line, the tets there become tet-aligned (repeatedly).

    Returns the meshes, the number of spindles carved and of tets made tet-aligned.
    """
    forced = forced.copy()
    start = int(forced.sum())
    for _ in range(_MAX_REPAIRS):
        meshes, pinches, defects = _direct_regions(V, T, topo, Zv, forced, tet_piece, p)
        if not defects or forced.all():
            break
        # A defect edge lies in the simplex spanned by its end points' simplices: the tets around that
        # simplex's vertices keep their own pieces (whole stars, so that this converges in few rounds).
        before = int(forced.sum())
        corners = np.unique(np.concatenate([site[site >= 0] for site in defects]))
        forced |= np.isin(T, corners).any(axis=1)
        if int(forced.sum()) == before:
            break
    return meshes, pinches, int(forced.sum()) - start


def _winning_field(tet_mesh: TetMesh, topo, tet_piece: np.ndarray, pieces: Pieces, lam: float,
                   vanish_fraction: float):
    """Field method: the smoothed field ``Z`` (n, p), raised for pieces that would vanish, and the pieces that
    vanish anyway (they keep their own tets)."""
    V, T, p = tet_mesh.vertices, tet_mesh.tets, pieces.num_pieces
    Z = _smoothed_field(tet_mesh, tet_piece, p, lam)
    vanished: list[int] = []
    raised: list[int] = []
    while True:
        forced, Zv = _forced_field(Z, tet_piece, vanished)
        meshes, _, _ = _direct_regions(V, T, topo, Zv, forced, tet_piece, p, check=False)
        won = np.array([_mesh_volume(*m) for m in meshes])
        gone = [P for P in range(p) if P not in vanished and won[P] <= vanish_fraction * pieces.volumes[P]]
        if not gone:
            break
        fresh = [P for P in gone if P not in raised]
        if fresh:
            # First try to keep the piece smooth: raise its field until its region has about its volume.
            for P in fresh:
                Z[:, P] += _rescue_bias(tet_mesh, Zv, P, pieces.volumes[P])
            raised.extend(fresh)
            log.info("%s: %d piece(s) would (almost) vanish under smoothing lambda=%g; their fields are raised "
                     "to keep about their volume", STAGE, len(fresh), lam)
            continue
        log.warning(
            "%s: %d piece(s) would (almost) vanish under smoothing lambda=%g (e.g. piece %d keeps %.2g of its "
            "volume); they keep their own tets. A smaller lambda avoids this.",
            STAGE, len(gone), lam, gone[0], won[gone[0]] / pieces.volumes[gone[0]],
        )
        vanished.extend(gone)
    return Z, vanished


def _rescue_bias(tet_mesh: TetMesh, Z: np.ndarray, P: int, target: float) -> float:
    """The raise ``b`` of piece ``P``'s field (n, p) whose winning region has about ``target`` volume.

    The region's volume is estimated per tet from where ``Z_P + b`` wins at the
    four corners and the centroid (the exact regions are built afterwards).
    That estimate is a step function of ``b``, stepping where ``Z_P + b`` ties
    with another piece at a sample point; ``b`` is taken halfway between the
    step that reaches ``target`` and the next one, so that no corner of the
    mesh lies on the raised piece's fault (a tie exactly at a vertex would give
    degenerate, zero-area fault triangles). At most ``_MAX_BIAS``.
    """
    others = np.delete(Z, P, axis=1).max(axis=1) if Z.shape[1] > 1 else np.full(len(Z), -np.inf)
    margin = (Z[:, P] - others)[tet_mesh.tets]  # (t, 4): where P wins by how much, at the corners
    near = margin.max(axis=1) + _MAX_BIAS >= 0
    # The raise each sample point needs to be won by P, with the volume it stands for.
    need = -np.column_stack([margin[near], margin[near].mean(axis=1)]).reshape(-1)
    weight = np.repeat(np.abs(tet_mesh.tet_volumes[near]) / 5.0, 5)
    steps, inverse = np.unique(need, return_inverse=True)
    reached = np.cumsum(np.bincount(inverse.reshape(-1), weights=weight, minlength=len(steps)))
    k = int(np.searchsorted(reached, target))
    if k >= len(steps) or steps[k] >= _MAX_BIAS:
        return _MAX_BIAS
    following = steps[k + 1] if k + 1 < len(steps) else steps[k] + 1e-3
    return float(np.clip(0.5 * (steps[k] + min(following, _MAX_BIAS)), 0.0, _MAX_BIAS))


def _forced_field(Z: np.ndarray, tet_piece: np.ndarray, vanished: list[int]):
    """Tets (t,) bool that vanished pieces keep, and the field with those pieces never winning."""
    forced = np.isin(tet_piece, vanished)
    Zv = Z.copy()
    if vanished:
        Zv[:, vanished] = -1.0
    return forced, Zv


def _mesh_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _union_regions(V: np.ndarray, T: np.ndarray, Z, tet_piece: np.ndarray, p: int, vanished: list[int],
                   only: list[int]) -> list:
    """Regions of the pieces ``only`` as manifold3d unions of their convex cells (slow, independent path).

    ``Z`` (n, p) is the smoothed field, or None for tet-aligned regions.
    """
    if Z is None:
        cells = _CellList()
        cells.add_tets(np.arange(len(T)), tet_piece)
    else:
        forced, _ = _forced_field(Z, tet_piece, vanished)
        cells = _field_cells(V, T, Z, forced, tet_piece, vanished)
    return cells.union_by_piece(V, T, p, only)


def _smoothed_field(tet_mesh: TetMesh, tet_piece: np.ndarray, p: int, lam: float) -> np.ndarray:
    """Smoothed piece membership ``Z`` (n, p) at the vertices."""
    n = tet_mesh.num_vertices
    vol = np.abs(tet_mesh.tet_volumes)
    # Tets flat to rounding (a flat cage tet refined) still weigh a little, so that a vertex only they touch
    # has a mass and the value of their piece instead of making the system singular.
    vol = np.maximum(vol, _MIN_TET_WEIGHT * vol.mean()) if len(vol) else vol
    # M_V Z0 with Z0 the lumped-mass average of the one-hot tet field: each tet
    # gives a quarter of its volume to each of its vertices, in its piece's column.
    quarter = np.repeat(vol / 4.0, 4)
    mass_onehot = sp.coo_matrix(
        (quarter, (tet_mesh.tets.reshape(-1), np.repeat(tet_piece, 4))), shape=(n, p)
    ).toarray()
    mass = sp.diags(np.bincount(tet_mesh.tets.reshape(-1), weights=quarter, minlength=n))
    system = (mass + lam * tet_mesh.stiffness).tocsc()
    try:
        solve = spla.factorized(system)
    except RuntimeError as exc:  # singular: degenerate tets
        raise StageError(f"the smoothing system is singular ({exc}); check the tet mesh for flat tets",
                         stage=STAGE) from exc
    Z = np.column_stack([solve(mass_onehot[:, P]) for P in range(p)]) if p else np.zeros((n, 0))
    return Z


# ---------------------------------------------------------------------------
# Geometric method: move tet vertices so that tet-aligned faults become smooth.
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class _FaultGraph:
    """Fault faces of a tet-aligned partition and how each vertex may move.

    All vertex masks are (n,) bool; edge arrays are (e_i, 2) int64 vertex ids.
    """

    fault_vertex: np.ndarray  # on a fault face
    curve_free: np.ndarray  # interior point of a junction curve (degree 2, off the cage boundary)
    sheet_free: np.ndarray  # inside one fault sheet (one piece pair, a disc of faces, off junctions)
    curve_edges: np.ndarray  # junction edges: 3+ fault faces around them
    sheet_edges: np.ndarray  # fault edges with exactly 2 fault faces
    sheet_mass: np.ndarray  # (n,) lumped fault area
    curve_mass: np.ndarray  # (n,) lumped junction-curve length
    slide_free: np.ndarray  # cage-boundary vertex inside one boundary fault curve (may slide along the cage)
    slide_edges: np.ndarray  # boundary fault curves: cage-boundary edges with exactly 1 fault face
    slide_mass: np.ndarray  # (n,) lumped boundary-fault-curve length


def _fault_graph(tet_mesh: TetMesh, topo: _Topology, tet_piece: np.ndarray, p: int) -> _FaultGraph:
    """Classify the vertices of the faults (interior faces between tets of different pieces)."""
    V, n = tet_mesh.vertices, tet_mesh.num_vertices
    ft = topo.face_tets
    inner = ft[:, 1] >= 0
    pa = tet_piece[ft[:, 0]]
    pb = np.where(inner, tet_piece[np.maximum(ft[:, 1], 0)], -1)
    fault = np.flatnonzero(inner & (pa != pb))
    fault_faces = topo.faces[fault]  # (k, 3) sorted vertex ids
    boundary = np.zeros(n, dtype=bool)
    boundary[tet_mesh.boundary_vertices] = True
    fault_vertex = np.zeros(n, dtype=bool)
    fault_vertex[fault_faces.reshape(-1)] = True

    fe = topo.face_edges[fault]  # (k, 3); edge j of a face joins its corners _FACE_EDGE_PAIRS[j]
    edge_count = np.bincount(fe.reshape(-1), minlength=len(topo.edges))
    # Around an interior edge the tets form a cycle, so a fault edge has 2 fault faces inside a sheet and
    # 3+ where three pieces meet or a piece touches itself (a junction).
    curve_edges = topo.edges[edge_count >= 3]
    sheet_edges = topo.edges[edge_count == 2]
    on_curve = np.zeros(n, dtype=bool)
    on_curve[curve_edges.reshape(-1)] = True
    curve_degree = np.bincount(curve_edges.reshape(-1), minlength=n)
    curve_free = on_curve & ~boundary & (curve_degree == 2)

    # A sheet vertex must see one piece pair and one disc of fault faces (not two sheets touching at a point).
    pair = np.minimum(pa, pb)[fault] * p + np.maximum(pa, pb)[fault]
    corner_vertex = fault_faces.reshape(-1)
    corner_pair = np.repeat(pair, 3)
    lo = np.full(n, np.iinfo(np.int64).max)
    hi = np.full(n, -1, dtype=np.int64)
    np.minimum.at(lo, corner_vertex, corner_pair)
    np.maximum.at(hi, corner_vertex, corner_pair)
    k = len(fault)
    rows = np.repeat(np.arange(k), 3)
    local = np.tile(np.arange(3), k)
    edge = fe.reshape(-1)
    order = np.lexsort((rows, edge))
    edge, rows, local = edge[order], rows[order], local[order]
    twice = np.flatnonzero((edge[1:] == edge[:-1]) & (edge_count[edge[:-1]] == 2))
    a, b = twice, twice + 1
    # Corners (face, local corner) that see the same vertex across a sheet edge are linked.
    links = []
    for end in range(2):
        ca = 3 * rows[a] + _FACE_EDGE_PAIRS[local[a], end]
        cb = 3 * rows[b] + _FACE_EDGE_PAIRS[local[b], end]
        links.append(np.column_stack([ca, cb]))
    links = np.concatenate(links) if links else np.zeros((0, 2), np.int64)
    graph = sp.coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(3 * k, 3 * k))
    _, component = connected_components(graph, directed=False)
    vertex_component = np.unique(np.column_stack([corner_vertex, component]), axis=0)
    discs = np.bincount(vertex_component[:, 0], minlength=n)

    single_sheet = fault_vertex & ~on_curve & (lo == hi) & (discs == 1)
    sheet_free = single_sheet & ~boundary

    # Where a sheet meets the cage boundary: around a boundary edge the tets form an open fan, so one fault
    # face means the two boundary faces at the edge belong to different pieces (a boundary fault curve), two
    # or more mean a junction on the boundary.
    on_cage = np.zeros(len(topo.edges), dtype=bool)
    on_cage[topo.face_edges[ft[:, 1] < 0].reshape(-1)] = True
    slide_edges = topo.edges[on_cage & (edge_count == 1)]
    cage_junction = np.zeros(n, dtype=bool)
    cage_junction[topo.edges[on_cage & (edge_count >= 2)].reshape(-1)] = True
    slide_degree = np.bincount(slide_edges.reshape(-1), minlength=n)
    slide_free = single_sheet & boundary & ~cage_junction & (slide_degree == 2)

    areas = tetgeom.triangle_areas(V, fault_faces)
    sheet_mass = np.bincount(corner_vertex, weights=np.repeat(areas / 3.0, 3), minlength=n)
    mass = []
    for E in (curve_edges, slide_edges):
        lengths = np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1)
        mass.append(np.bincount(E.reshape(-1), weights=np.repeat(lengths / 2.0, 2), minlength=n))
    return _FaultGraph(fault_vertex, curve_free, sheet_free, curve_edges, sheet_edges, sheet_mass, mass[0],
                       slide_free, slide_edges, mass[1])


def _implicit_smooth(X: np.ndarray, edges: np.ndarray, weights: np.ndarray, mass: np.ndarray, free: np.ndarray,
                     lam: float) -> np.ndarray:
    """One implicit Laplacian step ``(M + lam L) X_free = M X_free`` with the other vertices as Dirichlet data.

    ``L`` is the graph Laplacian of ``edges`` (e, 2) with positive ``weights`` (e,) (PSD, an M-matrix), ``M``
    the diagonal ``mass`` (n,). Returns a copy of ``X`` (n, 3) with the rows ``free`` (n,) bool replaced.
    """
    out = X.copy()
    idx = np.flatnonzero(free)
    if len(idx) == 0 or len(edges) == 0:
        return out
    n = len(X)
    i, j = edges[:, 0], edges[:, 1]
    W = sp.coo_matrix((np.r_[weights, weights], (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
    L = (sp.diags(np.asarray(W.sum(axis=1)).reshape(-1)) - W).tocsr()
    known = np.flatnonzero(~free)
    L_rows = L[idx]
    system = (sp.diags(mass[idx]) + lam * L_rows[:, idx]).tocsc()
    rhs = mass[idx, None] * X[idx] - lam * (L_rows[:, known] @ X[known])
    out[idx] = spla.splu(system).solve(np.ascontiguousarray(rhs))
    return out


def _harmonic_extension(tet_mesh: TetMesh, displacement: np.ndarray, known: np.ndarray, solver=None):
    """Displacements (n, 3) of the vertices not ``known`` (n,) bool with ``K d = 0`` there.

    Returns the full displacement field and the (reusable) factorization of ``K`` on the unknown vertices.
    """
    out = displacement.copy()
    idx = np.flatnonzero(~known)
    if len(idx) == 0:
        return out, solver
    K = tet_mesh.stiffness.tocsr()
    rows = K[idx]
    if solver is None:
        solver = spla.splu(rows[:, idx].tocsc())
    rhs = -(rows[:, np.flatnonzero(known)] @ displacement[known])
    out[idx] = solver.solve(np.ascontiguousarray(rhs))
    return out, solver


def _smoothed_vertices(tet_mesh: TetMesh, topo: _Topology, tet_piece: np.ndarray, p: int, lam: float,
                       surface: SurfaceMesh | None = None):
    """Tet vertex positions (n, 3) with smoothed faults, and counts for the log.

    With ``surface`` (the input inside the cage) the boundary fault curves slide along the cage (see
    :func:`_deform`); if the moved cage cannot be made to contain the input that way, nothing slides.
    """
    graph = _fault_graph(tet_mesh, topo, tet_piece, p)
    n = tet_mesh.num_vertices
    if not graph.fault_vertex.any():
        return tet_mesh.vertices.copy(), {"moved": 0, "curve": 0, "slid": 0, "reverted": 0, "frozen": 0,
                                          "rounds": 0, "alpha": 1.0}
    if surface is not None and graph.slide_free.any():
        cage = _CageSurface(tet_mesh.vertices, tet_mesh.boundary_faces)
        guard = _Containment(surface, tet_mesh.vertices, tet_mesh.boundary_faces)
        X, stats = _deform(tet_mesh, graph, lam, graph.slide_free, cage, guard)
        if X is not None:
            return X, stats
        log.warning("%s: sliding the faults along the cage kept flattening tets or bringing the cage too close to "
                    "the input after %d rounds; cage-boundary vertices stay where they are", STAGE, stats["rounds"])
    return _deform(tet_mesh, graph, lam, np.zeros(n, dtype=bool), None, None)


def _deform(tet_mesh: TetMesh, graph: _FaultGraph, lam: float, slide: np.ndarray, cage, guard):
    """Smoothed tet vertex positions (n, 3) (None if sliding did not settle) and counts for the log.

    Boundary fault curves (vertices ``slide`` (n,) bool) are smoothed first, along the cage (``cage`` a
    :class:`_CageSurface`); then junction curves (1-D, their ends fixed), then the fault sheets with the curves,
    the cage boundary and the non-manifold fault points as Dirichlet data; the other interior vertices follow
    harmonically. Where a tet would flatten (volume below ``_MIN_VOLUME_RATIO`` of its own), the free fault
    vertices of the offending tets are held back and everything is solved again; a slid vertex that ``guard``
    (a :class:`_Containment`) blames for the cage no longer containing the input goes back where it was. Without
    sliding, if holding back does not help, the displacement is scaled down.
    """
    V, T = tet_mesh.vertices, tet_mesh.tets
    n = len(V)
    stats = {"moved": 0, "curve": 0, "slid": 0, "reverted": 0, "frozen": 0, "rounds": 0, "alpha": 1.0}
    sliding = bool(slide.any())
    boundary = np.zeros(n, dtype=bool)
    boundary[tet_mesh.boundary_vertices] = True
    known = graph.fault_vertex | boundary  # Dirichlet data of the harmonic extension
    curve_lengths = np.linalg.norm(V[graph.curve_edges[:, 1]] - V[graph.curve_edges[:, 0]], axis=1)
    curve_weights = 1.0 / curve_lengths  # 1-D linear-element stiffness: units match lambda * length^-1
    slide_lengths = np.linalg.norm(V[graph.slide_edges[:, 1]] - V[graph.slide_edges[:, 0]], axis=1)
    slide_weights = 1.0 / slide_lengths
    sheet_weights = np.full(len(graph.sheet_edges), _SHEET_WEIGHT)
    volume0 = tet_mesh.tet_volumes
    movable = graph.curve_free | graph.sheet_free | slide
    # Vertices of flattened tets are held at a fraction ``damping`` of their first-round displacement (halved
    # each round they are still to blame) and become Dirichlet data for the next round.
    damping = np.ones(n)
    reverted = np.zeros(n, dtype=bool)
    target = V
    solver = None
    settled = False
    for round_ in range(_MAX_FREEZE_ROUNDS + 1):
        held = damping < 1.0
        start = V + damping[:, None] * (target - V)
        # A slid vertex held part of the way is put back onto the cage (a vertex sent back is exactly on it).
        partway = np.flatnonzero(slide & held & (damping > 0.0))
        if len(partway):
            start[partway] = cage.project(start[partway])
        X = start
        if sliding:
            X = _slide_smooth(X, graph.slide_edges, slide_weights, graph.slide_mass, slide & ~held, lam, cage)
        X = _implicit_smooth(X, graph.curve_edges, curve_weights, graph.curve_mass, graph.curve_free & ~held, lam)
        X = _implicit_smooth(X, graph.sheet_edges, sheet_weights, graph.sheet_mass, graph.sheet_free & ~held, lam)
        if round_ == 0:
            target = X
        D, solver = _harmonic_extension(tet_mesh, X - V, known, solver)
        bad = tetgeom.tet_volumes(V + D, T) < _MIN_VOLUME_RATIO * volume0
        stats["rounds"] = round_
        offenders = np.zeros(0, dtype=np.int64)
        if sliding:
            moved = slide & np.any(D != 0.0, axis=1)
            offenders = guard.offenders(V + D, moved)
        if not bad.any() and len(offenders) == 0:
            settled = True
            break
        if round_ == _MAX_FREEZE_ROUNDS:
            break
        damping[offenders] = 0.0
        reverted[offenders] = True
        if bad.any():
            culprits = np.unique(T[bad])
            culprits = culprits[(movable & (damping > 0.0))[culprits]]
            if len(culprits) == 0:
                # The extension itself flattens the tets: hold the fault vertices around them.
                ring = np.unique(T[np.isin(T, T[bad]).any(axis=1)])
                culprits = ring[(movable & (damping > 0.0))[ring]]
            if len(culprits) == 0 and len(offenders) == 0:
                break
            damping[culprits] = np.where(damping[culprits] > _MIN_DAMPING, damping[culprits] / 2.0, 0.0)
    stats.update(moved=int((movable & (damping > 0.0)).sum()), curve=int((graph.curve_free & (damping > 0.0)).sum()),
                 slid=int((slide & np.any(D != 0.0, axis=1)).sum()), reverted=int(reverted.sum()),
                 frozen=int((damping < 1.0).sum()))
    if sliding:
        # Scaling a displacement along the cage would take slid vertices off it: no partial answers here.
        return (V + D if settled else None), stats
    alpha = 1.0
    while bad.any() and alpha > _MIN_ALPHA:
        alpha /= 2.0
        bad = tetgeom.tet_volumes(V + alpha * D, T) < _MIN_VOLUME_RATIO * volume0
    if bad.any():
        alpha = 0.0
    if alpha < 1.0:
        log.warning("%s: smoothed faults would flatten %d tet(s); the fault displacement is scaled by %g", STAGE,
                    int((tetgeom.tet_volumes(V + D, T) < _MIN_VOLUME_RATIO * volume0).sum()), alpha)
    stats["alpha"] = alpha
    return V + alpha * D, stats


def _slide_smooth(X: np.ndarray, edges: np.ndarray, weights: np.ndarray, mass: np.ndarray, free: np.ndarray,
                  lam: float, cage) -> np.ndarray:
    """Boundary fault curves smoothed along the cage: implicit sub-steps, each followed by a projection onto it."""
    idx = np.flatnonzero(free)
    for _ in range(_SLIDE_STEPS):
        X = _implicit_smooth(X, edges, weights, mass, free, lam / _SLIDE_STEPS)
        X[idx] = cage.project(X[idx])
    return X


def _closest_points(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest points (k, 3) to ``p`` on triangles ``(a, b, c)`` (each (k, 3)), by Voronoi regions (Ericson)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp, cp = p - b, p - c
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        out = a + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        t_ac = d2 / (d2 - d6)
        t_ab = d1 / (d1 - d3)
    # Later regions override earlier ones (vertex regions last); degenerate triangles fall back to a corner.
    out = np.where(np.isfinite(out), out, a)
    out = np.where(((va <= 0) & (d4 >= d3) & (d5 >= d6))[:, None], b + (c - b) * t_bc[:, None], out)
    out = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[:, None], a + ac * t_ac[:, None], out)
    out = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[:, None], a + ab * t_ab[:, None], out)
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    return out


class _CageSurface:
    """Closest points on the original cage surface (triangles ``F`` (b, 3) over ``V`` (n, 3))."""

    def __init__(self, V: np.ndarray, F: np.ndarray):
        self.V = V
        self.F = np.asarray(F, dtype=np.int64)
        self.tree = cKDTree(V[np.unique(self.F)])
        boxes = trigeom.triangle_boxes(V, self.F)
        self.grid = trigeom.BoxGrid(boxes, trigeom.default_cell(boxes))

    def project(self, points: np.ndarray) -> np.ndarray:
        """Closest points (k, 3) on the cage to ``points`` (k, 3) (lowest face id on ties)."""
        if len(points) == 0:
            return points.copy()
        # The closest point is no farther than the nearest cage vertex: only triangles whose boxes come that
        # near can hold it.
        d0, _ = self.tree.query(points)
        reach = d0 * (1.0 + 1e-9) + 1e-12
        row, face = self.grid.query(np.stack([points - reach[:, None], points + reach[:, None]], axis=1))
        tri = self.V[self.F[face]]
        closest = _closest_points(points[row], tri[:, 0], tri[:, 1], tri[:, 2])
        dist = np.sum((closest - points[row]) ** 2, axis=1)
        best = np.lexsort((face, dist, row))
        first = best[np.r_[True, row[best][1:] != row[best][:-1]]]
        return closest[first]


def _solid_angles(points: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Sums (k,) over triangles ``(A, B, C)`` (each (m, 3)) of their signed solid angles at ``points`` / 4 pi.

    For a closed, outward mesh this is the generalized winding number (Van Oosterom and Strackee).
    """
    out = np.zeros(len(points))
    chunk = max(1, 2_000_000 // max(len(A), 1))
    for s in range(0, len(points), chunk):
        q = points[s:s + chunk, None, :]
        a, b, c = A[None] - q, B[None] - q, C[None] - q
        la, lb, lc = (np.sqrt(np.sum(x * x, axis=2)) for x in (a, b, c))
        det = np.sum(a * np.cross(b, c), axis=2)
        dot = (la * lb * lc + np.sum(a * b, axis=2) * lc + np.sum(b * c, axis=2) * la
               + np.sum(c * a, axis=2) * lb)
        out[s:s + chunk] = np.arctan2(det, dot).sum(axis=1) / (2.0 * np.pi)
    return out


def _pair_solid_angles(P: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Signed solid angle / 4 pi (k,) of triangle ``(A[i], B[i], C[i])`` seen from ``P[i]`` (all (k, 3))."""
    a, b, c = A - P, B - P, C - P
    la, lb, lc = (np.sqrt(np.sum(x * x, axis=1)) for x in (a, b, c))
    det = np.einsum("ij,ij->i", a, np.cross(b, c))
    dot = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", b, c) * la
           + np.einsum("ij,ij->i", c, a) * lb)
    return np.arctan2(det, dot) / (2.0 * np.pi)


def _prism_winding(P: np.ndarray, V0: np.ndarray, X: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Winding numbers (k,) of points ``P`` (k, 3) w.r.t. the prisms swept by triangles ``faces`` (k, 3).

    Each triangle moves from ``V0`` to ``X``; its prism is the new triangle, the old one reversed and one
    side quad per edge. Each quad is split along the diagonal from the edge's lower vertex id (old) to its
    higher one (new), so the two triangles sharing an edge build the same wall with opposite orientations
    and their walls cancel exactly in a sum.
    """
    total = _pair_solid_angles(P, X[faces[:, 0]], X[faces[:, 1]], X[faces[:, 2]])
    total -= _pair_solid_angles(P, V0[faces[:, 0]], V0[faces[:, 1]], V0[faces[:, 2]])
    for i, j in ((0, 1), (1, 2), (2, 0)):
        p, q = faces[:, i], faces[:, j]
        p0, q0, p1, q1 = V0[p], V0[q], X[p], X[q]
        low_first = (p < q)[:, None]
        # Quad (p0, q0, q1, p1), outward for a counter-clockwise triangle moving along its normal.
        # Diagonal p0-q1 when p < q, else q0-p1.
        t1 = (p0, q0, np.where(low_first, q1, p1))
        t2 = (np.where(low_first, p0, q0), np.where(low_first, q1, q1), p1)
        total += _pair_solid_angles(P, *t1)
        total += _pair_solid_angles(P, *t2)
    return total


class _Containment:
    """Checks that a moved cage (same triangles ``F`` (b, 3), outward) still strictly contains ``surface``."""

    def __init__(self, surface: SurfaceMesh, V0: np.ndarray, F: np.ndarray):
        self.SV = np.asarray(surface.vertices, dtype=np.float64)
        self.SF = np.asarray(surface.faces, dtype=np.int64)
        boxes = trigeom.triangle_boxes(self.SV, self.SF)
        self.grid = trigeom.BoxGrid(boxes, trigeom.default_cell(boxes))
        self.V0 = V0
        self.F = np.asarray(F, dtype=np.int64)

    def offenders(self, X: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """Moved vertices (ascending ids) to send back: the cage over ``X`` (n, 3) near ``moved`` (n,) is unsafe.

        Unsafe: a cage triangle at a moved vertex within ``_SLIDE_CLEARANCE`` of an input triangle (which also
        catches crossings) or crossing another cage triangle; an input vertex near a moved vertex that the
        moved cage no longer encloses (its triangles swept past it).
        """
        blame = np.zeros(len(X), dtype=bool)
        touched = moved[self.F].any(axis=1)
        if not touched.any():
            return np.zeros(0, dtype=np.int64)
        faces = self.F[touched]
        qi, j = self.grid.query(trigeom.triangle_boxes(X, faces), pad=_SLIDE_CLEARANCE)
        hit = trigeom.triangles_intersect(X[faces[qi]], self.SV[self.SF[j]], eps=_SLIDE_CLEARANCE)
        blame[faces[np.unique(qi[hit])].reshape(-1)] = True
        pairs = trigeom.self_intersections(X, self.F)
        crossing = pairs[touched[pairs].any(axis=1)]
        blame[self.F[crossing.reshape(-1)].reshape(-1)] = True
        # Moving each touched triangle straight from its old to its new corners, the cage sweeps over a point
        # (changing its winding number) only inside the box of some triangle's old and new corners.
        swept = np.concatenate([self.V0[faces], X[faces]], axis=1)
        boxes = np.stack([swept.min(axis=1), swept.max(axis=1)], axis=1)
        grid = trigeom.BoxGrid(boxes, trigeom.default_cell(boxes))
        qi, box = grid.query(np.stack([self.SV, self.SV], axis=1))
        if len(qi):
            # The input is strictly inside the original cage (winding number 1) and only the touched
            # triangles changed: the winding number w.r.t. the moved cage is 1 plus the winding numbers of
            # the prisms the touched triangles swept (their side walls cancel between neighbours), and a
            # prism's winding number is 0 outside its box: only (point, box) pairs contribute.
            change = np.bincount(qi, weights=_prism_winding(self.SV[qi], self.V0, X, faces[box]),
                                 minlength=len(self.SV))
            points = np.unique(qi)
            outside = points[1.0 + change[points] < 0.5]
            blame[faces[box[np.isin(qi, outside)]].reshape(-1)] = True
        return np.flatnonzero(blame & moved)


class _CellList:
    """Convex cells (whole tets or clipped corner sets) tagged with their piece."""

    def __init__(self):
        self.tets: list[np.ndarray] = []
        self.tet_pieces: list[np.ndarray] = []
        self.clipped: list[tuple[int, int, np.ndarray]] = []  # (tet, piece, corners (c, 3))
        self.clipped_volumes: list[float] = []

    def add_tets(self, tets: np.ndarray, pieces: np.ndarray) -> None:
        self.tets.append(np.asarray(tets, dtype=np.int64))
        self.tet_pieces.append(np.asarray(pieces, dtype=np.int64))

    def add_clipped(self, tet: int, piece: int, corners: np.ndarray) -> None:
        hull = manifold3d.Manifold.hull_points(corners)
        volume = hull.volume()
        if volume <= 0.0:
            return
        self.clipped.append((tet, piece, hull))
        self.clipped_volumes.append(volume)

    @property
    def count(self) -> int:
        return sum(len(x) for x in self.tets) + len(self.clipped)

    @property
    def clipped_count(self) -> int:
        return len(self.clipped)

    def piece_array(self) -> np.ndarray:
        whole = np.concatenate(self.tet_pieces) if self.tets else np.zeros(0, np.int64)
        return np.concatenate([whole, np.array([c[1] for c in self.clipped], dtype=np.int64)])

    def volume_array(self, tet_volumes: np.ndarray) -> np.ndarray:
        whole = tet_volumes[np.concatenate(self.tets)] if self.tets else np.zeros(0)
        return np.concatenate([whole, np.array(self.clipped_volumes, dtype=np.float64)])

    def union_by_piece(self, V: np.ndarray, T: np.ndarray, p: int, only: list[int]):
        """Closed, edge-manifold meshes (vertices, faces) of the union of the cells of each piece in ``only``."""
        parts: list[list] = [[] for _ in range(p)]
        tets = np.concatenate(self.tets) if self.tets else np.zeros(0, np.int64)
        owners = np.concatenate(self.tet_pieces) if self.tets else np.zeros(0, np.int64)
        order = np.argsort(owners, kind="stable")
        tets, owners = tets[order], owners[order]
        bounds = np.searchsorted(owners, np.arange(p + 1))
        for P in only:
            parts[P].extend(_whole_tets_solids(V, T, tets[bounds[P]:bounds[P + 1]]))
        for _, P, hull in self.clipped:
            parts[P].append(hull)
        meshes = []
        for P in only:
            if not parts[P]:
                raise StageError(f"piece {P} has no cells; this is a bug in the smoothing stage", stage=STAGE)
            region = manifold3d.Manifold.batch_boolean(parts[P], manifold3d.OpType.Add)
            if region.status() != manifold3d.Error.NoError or region.is_empty():
                raise StageError(f"the region of piece {P} could not be built ({region.status()})", stage=STAGE)
            mesh = region.to_mesh64()
            vertices = np.array(mesh.vert_properties[:, :3], dtype=np.float64)
            faces = np.array(mesh.tri_verts, dtype=np.int64)
            # Coplanar cell faces can leave zero-volume shells in a union; drop them (not cavities).
            faces = faces[shell_mask(mesh, _SHELL_VOLUME * region.volume())]
            meshes.append(_separate_pinches(*_compact(vertices, faces)))
        return meshes


def _whole_tets_solids(V: np.ndarray, T: np.ndarray, tets: np.ndarray) -> list:
    """Manifolds whose union is the union of ``tets``: one boundary mesh plus single tets.

    The boundary faces of a tet set form a closed surface, but it is not
    edge-manifold where the set touches itself along an edge; manifold3d
    accepts such a mesh without an error and can then get volumes wrong. So the
    tets around every such edge are taken out (repeatedly, as removing tets can
    create new ones) and passed on as single-tet solids, whose union is
    edge-manifold by construction.
    """
    local_faces = np.ascontiguousarray(tetgeom.TET_FACES.astype(np.uint64))

    def tet_solid(tet):
        corners = np.ascontiguousarray(V[T[tet]], dtype=np.float64)
        return manifold3d.Manifold(manifold3d.Mesh64(vert_properties=corners, tri_verts=local_faces))

    singles: list[int] = []
    body = np.asarray(tets, dtype=np.int64)
    for _ in range(8):
        if len(body) == 0:
            break
        faces = T[body][:, tetgeom.TET_FACES].reshape(-1, 3)
        owner = np.repeat(body, 4)
        _, inverse, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
        outer = counts[inverse.reshape(-1)] == 1
        faces, owner = faces[outer], owner[outer]
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        _, e_inverse, e_counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
        bad = e_counts[e_inverse.reshape(-1)] > 2
        if not bad.any():
            used, local = np.unique(faces, return_inverse=True)
            mesh = manifold3d.Mesh64(
                vert_properties=np.ascontiguousarray(V[used], dtype=np.float64),
                tri_verts=np.ascontiguousarray(local.reshape(-1, 3), dtype=np.uint64),
            )
            solid = manifold3d.Manifold(mesh)
            if solid.status() != manifold3d.Error.NoError:
                raise StageError(f"a piece's tet boundary is not a closed mesh ({solid.status()})", stage=STAGE)
            return [solid] + [tet_solid(t) for t in singles]
        # Tets owning a face on a non-manifold edge become single solids.
        moving = np.unique(np.tile(owner, 3)[bad])
        singles.extend(moving.tolist())
        body = body[~np.isin(body, moving)]
    return [tet_solid(t) for t in singles + body.tolist()]


def _separate_pinches(vertices: np.ndarray, faces: np.ndarray, distance: float = _PINCH_SEPARATION):
    """Move apart the vertex copies where a region touches itself.

    A union of cells is edge-manifold by index, but where a region touches
    itself along an edge or at a point (e.g. a tet-aligned piece wrapping
    around another piece's edge) it keeps two vertices at one position. Tools
    that weld by position (and the fragments cut from such a region) would see
    an edge with four faces. Each copy is moved ``distance`` into its own part
    of the solid (against the mean normal of its faces), which opens a gap far
    below any modelling tolerance but above position-welding tolerances.
    """
    _, first, pos = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    pos = pos.reshape(-1)
    shared = np.bincount(pos, minlength=len(first))[pos] > 1
    if not shared.any():
        return vertices, faces
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    face_normal = np.cross(b - a, c - a)
    vertex_normal = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(vertex_normal, faces[:, k], face_normal)
    length = np.linalg.norm(vertex_normal, axis=1, keepdims=True)
    step = np.where(length > 0, vertex_normal / np.maximum(length, 1e-300), 0.0) * distance
    moved = vertices.copy()
    moved[shared] -= step[shared]
    log.debug("%s: separated %d vertex copies where a region touches itself", STAGE, int(shared.sum()))
    return moved, faces


def _compact(vertices: np.ndarray, faces: np.ndarray):
    """Drop unreferenced vertices (keeps the order of the rest)."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.reshape(-1)] = True
    if used.all():
        return vertices, faces
    remap = np.cumsum(used) - 1
    return vertices[used], remap[faces]


def _field_cells(V, T, Z, forced, tet_piece, vanished) -> _CellList:
    """Cells of the pieces that win in each tet under the smoothed field ``Z`` (n, p)."""
    cells = _CellList()
    Zv = Z.copy()
    if vanished:
        # A vanished piece keeps its own tets and wins nowhere else.
        Zv[:, vanished] = -1.0
    Zt = Zv[T]  # (t, 4, p)
    # Piece P can win somewhere in the tet only if its largest corner value
    # reaches the best guaranteed value max_Q min_corners Z_Q (a necessary test).
    floor = Zt.min(axis=1).max(axis=1)  # (t,)
    candidate = Zt.max(axis=1) >= floor[:, None]
    counts = candidate.sum(axis=1)
    counts[forced] = 1
    single = np.flatnonzero(counts == 1)
    whole_piece = np.where(forced[single], tet_piece[single], np.argmax(candidate[single], axis=1))
    cells.add_tets(single, whole_piece)
    multi = np.flatnonzero(counts > 1)
    if len(multi) == 0:
        return cells
    # Group the mixed tets by candidate count so each group is one batched computation.
    pending = []  # (tet, piece, first corner, corner count) into the global corner list
    corner_blocks = [V]
    offset = len(V)
    for m in np.unique(counts[multi]):
        group = multi[counts[multi] == m]
        cand = np.stack([np.flatnonzero(candidate[i]) for i in group])  # (N, m) sorted piece ids
        G = np.take_along_axis(Zt[group], cand[:, None, :], axis=2).transpose(0, 2, 1)  # (N, m, 4)
        corners, valid = _cell_corners(G)  # (N, m, C, 4), (N, m, C)
        points = np.einsum("nmcj,njd->nmcd", corners, V[T[group]])
        counts_cell = valid.sum(axis=2)  # (N, m)
        flat = points[valid]  # cells' corners, cell by cell in (N, m) order
        corner_blocks.append(flat)
        starts = offset + np.concatenate([[0], np.cumsum(counts_cell.reshape(-1))[:-1]])
        tets_cell = np.repeat(group, int(m))
        for tet, piece, start, count in zip(tets_cell.tolist(), cand.reshape(-1).tolist(), starts.tolist(),
                                            counts_cell.reshape(-1).tolist()):
            if count >= 4:
                pending.append((tet, piece, start, count))
        offset += len(flat)
    # Corners that neighbouring cells share are computed from different plane
    # triples (and in different tets), so they differ in the last bits. Snap
    # every cluster of near-identical corners (tet vertices first) to one
    # point: cells then meet exactly and the unions leave no slivers.
    allpoints = _snap(np.concatenate(corner_blocks))
    for tet, piece, start, count in pending:
        cells.add_clipped(tet, piece, allpoints[start:start + count])
    return cells


def _snap(points: np.ndarray, tol: float = 1e-10) -> np.ndarray:
    """Replace each cluster of points closer than ``tol`` by its lowest-index member."""
    pairs = cKDTree(points).query_pairs(tol, output_type="ndarray")
    if len(pairs) == 0:
        return points
    n = len(points)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    # Lowest index per label: np.unique's return_index gives first occurrences.
    _, first = np.unique(labels, return_index=True)
    return points[first[labels]]


_COMBOS: dict = {}


def _cell_corners(G: np.ndarray):
    """Corners, in barycentric coordinates, of the cell of each candidate in each tet.

    Parameters
    ----------
    G : (N, m, 4) float
        Field values of the ``m`` candidate pieces at the 4 corners of ``N`` tets.

    Returns
    -------
    corners : (N, m, C, 4) float64
        Barycentric coordinates of every intersection of three bounding planes.
    valid : (N, m, C) bool
        Which of them are feasible (inside the tet and on the winning side of
        every other candidate).
    """
    N, m, _ = G.shape
    # Planes of cell j: b_i >= 0 (4 rows) and (G_j - G_q) . b >= 0 for q != j.
    others = np.array([[q for q in range(m) if q != j] for j in range(m)], dtype=np.int64).reshape(m, m - 1)
    diff = G[:, :, None, :] - G[:, others, :]  # (N, m, m-1, 4)
    eye = np.broadcast_to(np.eye(4), (N, m, 4, 4))
    H = np.concatenate([eye, diff], axis=2)  # (N, m, m+3, 4)
    planes = m + 3
    if planes not in _COMBOS:
        _COMBOS[planes] = np.array(list(itertools.combinations(range(planes), 3)), dtype=np.int64)
    combos = _COMBOS[planes]  # (C, 3)
    C = len(combos)
    A = np.empty((N, m, C, 4, 4))
    A[:, :, :, :3, :] = H[:, :, combos, :]
    A[:, :, :, 3, :] = 1.0
    rows = np.linalg.norm(A, axis=4).prod(axis=3)
    det = np.linalg.det(A)
    ok = np.abs(det) > _SINGULAR_TOL * rows
    A[~ok] = np.eye(4)
    rhs = np.zeros((N, m, C, 4, 1))
    rhs[..., 3, 0] = 1.0
    b = np.linalg.solve(A, rhs)[..., 0]  # (N, m, C, 4)
    # Corners on tet faces/edges: snap the coordinates that a chosen plane b_i = 0 forces to exactly 0.
    chosen_eye = combos < 4  # (C, 3)
    for s in range(3):
        idx = np.where(chosen_eye[:, s], combos[:, s], -1)
        for i in range(4):
            b[:, :, idx == i, i] = 0.0
    slack = np.einsum("nmpj,nmcj->nmcp", H, b)  # (N, m, C, planes)
    valid = ok & (slack >= -_FEASIBLE_TOL).all(axis=3)
    b = np.clip(b, 0.0, None)
    b /= b.sum(axis=3, keepdims=True)
    return b, valid


# ---------------------------------------------------------------------------
# Direct construction: multi-label marching tetrahedra with combinatorial keys.
# ---------------------------------------------------------------------------

_EDGE_PAIRS = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)
_FACE_EDGE_PAIRS = np.array([[0, 1], [0, 2], [1, 2]], dtype=np.int64)


class _Topology:
    """Unique edges and faces of a tet mesh and their incidences (all arrays int64)."""

    def __init__(self, T: np.ndarray, n: int):
        t = len(T)
        local = T[:, tetgeom.TET_FACES].reshape(-1, 3)  # (4t, 3) outward for positive tets
        ordered = np.sort(local, axis=1)
        face_key = (ordered[:, 0] * n + ordered[:, 1]) * n + ordered[:, 2]
        _, first, inverse = np.unique(face_key, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        owner = np.repeat(np.arange(t), 4)
        self.faces = ordered[first]  # (f, 3) sorted vertex ids
        self.face_oriented = local[first]  # (f, 3) outward from face_tets[:, 0]
        self.tet_faces = inverse.reshape(t, 4)
        self.face_tets = np.full((len(first), 2), -1, dtype=np.int64)
        self.face_tets[:, 0] = owner[first]
        second = np.ones(len(local), dtype=bool)
        second[first] = False
        self.face_tets[inverse[second], 1] = owner[second]
        edges = np.sort(T[:, _EDGE_PAIRS], axis=2).reshape(-1, 2)
        edge_key = edges[:, 0] * n + edges[:, 1]
        unique_keys, efirst, einverse = np.unique(edge_key, return_index=True, return_inverse=True)
        self.edges = edges[efirst]  # (e, 2) sorted
        self.tet_edges = einverse.reshape(t, 6)
        fe = self.faces[:, _FACE_EDGE_PAIRS]  # (f, 3, 2)
        self.face_edges = np.searchsorted(unique_keys, fe[..., 0] * n + fe[..., 1])  # (f, 3)
        self.ties = None  # cache: (field, edge ties, face ties, tet ties)


def _tie_points(V: np.ndarray, Zv: np.ndarray, S: np.ndarray):
    """Points inside simplices where ``k + 1`` pieces tie for the maximum of the field.

    Parameters
    ----------
    V : (n, 3) float64
    Zv : (n, p) float64
        Field at the vertices.
    S : (N, k + 1) int64
        Simplices (edges, faces or tets), vertex ids sorted ascending.

    Returns
    -------
    simplex : (r,) int64
        Row of ``S`` each point lies strictly inside, ascending.
    tie : (r, k + 1) int64
        The tied pieces, ascending.
    position : (r, 3) float64

    Notes
    -----
    Every point is computed from its simplex's own vertex values only (in a
    canonical vertex and piece order), so all tets that share the simplex see
    a bit-identical point.
    """
    k1 = S.shape[1]
    kept = np.arange(len(S))
    if Zv.shape[1] > 1 and len(S):
        # Most simplices lie inside one region: one piece wins at every corner, and even the runner-up at
        # any corner stays below its value at every corner, so no other piece is a candidate (the test
        # below would skip them). Dropping them first keeps the (N, k+1, p) arrays small.
        # (Which of tied best pieces argmax picks does not matter: a tie fails the margin test.)
        best = Zv.argmax(axis=1)
        z2, z1 = np.partition(Zv, -2, axis=1)[:, -2:].T
        clear = np.all(best[S] == best[S[:, :1]], axis=1) & (z2[S].max(axis=1) < z1[S].min(axis=1) - _CANDIDATE_TOL)
        kept = np.flatnonzero(~clear)
        S = S[kept]
    Zs = Zv[S]  # (N, k+1, p)
    floor = Zs.min(axis=1).max(axis=1)
    # Pieces that can win somewhere on the simplex (necessary test, with a margin for rounding).
    cand = Zs.max(axis=1) >= floor[:, None] - _CANDIDATE_TOL
    counts = cand.sum(axis=1)
    out_s, out_tie, out_pos = [], [], []
    for m in np.unique(counts).tolist():
        if m < k1:
            continue
        group = np.flatnonzero(counts == m)
        cidx = np.nonzero(cand[group])[1].reshape(-1, m)  # (N, m) sorted piece ids
        G = np.take_along_axis(Zs[group], cidx[:, None, :], axis=2)  # (N, k+1, m)
        combos = _combinations(m, k1)  # (C, k+1)
        Gc = G[:, :, combos].transpose(0, 2, 3, 1)  # (N, C, k+1 pieces, k+1 corners)
        A = np.empty(Gc.shape)
        A[:, :, :-1, :] = Gc[:, :, :1, :] - Gc[:, :, 1:, :]
        A[:, :, -1, :] = 1.0
        rows = np.linalg.norm(A, axis=3).prod(axis=2)
        ok = np.abs(np.linalg.det(A)) > _SINGULAR_TOL * rows
        A[~ok] = np.eye(k1)
        rhs = np.zeros(A.shape[:3] + (1,))
        rhs[:, :, -1, 0] = 1.0
        beta = np.linalg.solve(A, rhs)[..., 0]  # (N, C, k+1)
        values = np.einsum("nkm,nck->ncm", G, beta)  # every candidate's value at every point
        in_tie = np.zeros((len(combos), m), dtype=bool)
        in_tie[np.arange(len(combos))[:, None], combos] = True
        tie_value = np.where(in_tie, values, np.inf).min(axis=2)
        other = np.where(in_tie, -np.inf, values).max(axis=2)
        feasible = ok & (beta > 0.0).all(axis=2) & (tie_value >= other)
        ni, ci = np.nonzero(feasible)
        out_s.append(group[ni])
        out_tie.append(np.take_along_axis(cidx[ni], combos[ci], axis=1))
        out_pos.append(np.einsum("rk,rkd->rd", beta[ni, ci], V[S[group[ni]]]))
    if not out_s:
        return np.zeros(0, np.int64), np.zeros((0, k1), np.int64), np.zeros((0, 3))
    simplex = np.concatenate(out_s)
    order = np.argsort(simplex, kind="stable")
    return kept[simplex[order]], np.concatenate(out_tie)[order], np.concatenate(out_pos)[order]


def _combinations(m: int, k: int) -> np.ndarray:
    key = (m, k)
    if key not in _COMBOS:
        _COMBOS[key] = np.array(list(itertools.combinations(range(m), k)), dtype=np.int64).reshape(-1, k)
    return _COMBOS[key]


def _join(owners: np.ndarray, point_simplex: np.ndarray):
    """Pairs (owner row, point index) for every point whose simplex is ``owners[row]``.

    ``owners`` (q,) simplex ids (any order, repeats allowed), ``point_simplex`` sorted.
    """
    lo = np.searchsorted(point_simplex, owners, side="left")
    hi = np.searchsorted(point_simplex, owners, side="right")
    count = hi - lo
    rows = np.repeat(np.arange(len(owners)), count)
    offsets = np.repeat(lo - (np.cumsum(count) - count), count)
    return rows, np.arange(int(count.sum())) + offsets


def _fan(poly: np.ndarray, keys: np.ndarray, normals: np.ndarray, positions: np.ndarray, centre_ids=None,
         centre_pos=None):
    """Triangulate convex polygons given as unordered vertex sets.

    Parameters
    ----------
    poly : (r,) int64
        Polygon id of each incidence row (ids 0..q-1).
    keys : (r,) int64
        Global vertex id of each row.
    normals : (q, 3) float64
        Orientation of each polygon: its vertices are ordered counter-clockwise
        about it.
    positions : (v, 3) float64
        Global vertex positions.

    Returns
    -------
    triangles : (s, 3) int64 global vertex ids
    owner : (s,) int64 polygon of each triangle

    Notes
    -----
    Each polygon is fanned from its smallest vertex id, so a polygon computed
    once and emitted for both of its sides is triangulated identically.
    Polygons with fewer than three vertices are dropped. With ``centre_ids``
    (q,) and ``centre_pos`` (q, 3), polygons are star-shaped about their
    centres (e.g. triangles with extra vertices on their edges) and are fanned
    from them instead.
    """
    q = len(normals)
    if len(poly) == 0:
        return np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    count = np.bincount(poly, minlength=q)
    P = positions[keys]
    centre = np.zeros((q, 3))
    for d in range(3):
        centre[:, d] = np.bincount(poly, weights=P[:, d], minlength=q)
    centre /= np.maximum(count, 1)[:, None]
    if centre_pos is not None:
        centre = centre_pos
    nrm = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    helper = np.where(np.abs(nrm[:, :1]) < 0.6, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(nrm, helper)
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    w = np.cross(nrm, u)
    d = P - centre[poly]
    angle = np.arctan2(np.einsum("ij,ij->i", d, w[poly]), np.einsum("ij,ij->i", d, u[poly]))
    order = np.lexsort((keys, angle, poly))
    poly, keys = poly[order], keys[order]
    start = np.cumsum(count) - count
    # Rotate each cycle to start at its smallest vertex id.
    local = np.arange(len(poly)) - start[poly]
    smallest = np.full(q, np.iinfo(np.int64).max)
    np.minimum.at(smallest, poly, keys)
    first_local = np.zeros(q, np.int64)
    is_min = keys == smallest[poly]
    first_local[poly[is_min]] = local[is_min]
    L = count
    if centre_ids is not None:
        tri_poly = poly
        following = np.where(local + 1 < L[poly], np.arange(len(poly)) + 1, start[poly])
        tri = np.stack([centre_ids[poly], keys, keys[following]], axis=1)
        return tri, tri_poly
    ntri = np.maximum(L - 2, 0)
    tri_poly = np.repeat(np.arange(q), ntri)
    j = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1  # 1..L-2
    base = start[tri_poly]
    f0 = first_local[tri_poly]
    Lp = L[tri_poly]
    tri = np.stack([keys[base + f0], keys[base + (f0 + j) % Lp], keys[base + (f0 + j + 1) % Lp]], axis=1)
    return tri, tri_poly


def _direct_regions(V: np.ndarray, T: np.ndarray, topo: _Topology, Zv, forced: np.ndarray, tet_piece: np.ndarray,
                    p: int, check: bool = True):
    """Boundary meshes of every piece's region, built directly from keyed polygons.

    Parameters
    ----------
    V : (n, 3) float64
    T : (t, 4) int64
        Positively oriented tets.
    topo : _Topology
    Zv : (n, p) float64 or None
        Field deciding the winner in the tets that are not ``forced``.
    forced : (t,) bool
        Tets that belong wholly to ``tet_piece`` (all of them when ``Zv`` is None).
    tet_piece : (t,) int64
    p : int

    Returns
    -------
    meshes : list of (vertices (n_i, 3) float64, faces (m_i, 3) int64)
    pinches : int
        Edges where a tet-aligned region touched itself and a spindle was carved.

    Notes
    -----
    Every output vertex has a combinatorial identity: a tet vertex; a tie of
    two pieces on a tet edge, of three inside a face, of four inside a tet; a
    notch or centre of a face at a pinch. Its position is computed once from
    that simplex's data, so the polygons of neighbouring pieces share vertices
    exactly. Region boundaries consist of cage-boundary polygons, of face
    polygons where a forced tet meets another piece, and of the polygons
    between cells of different pieces inside a tet; each fault polygon is
    triangulated once and emitted for both sides with opposite orientation.
    """
    n = len(V)
    blocks = [V]
    sites = [np.column_stack([np.arange(n), np.full((n, 3), -1)])]  # tet vertices spanning each vertex's simplex
    next_id = n
    emitted_tris: list[np.ndarray] = []
    emitted_piece: list[np.ndarray] = []

    def emit(tris, pieces_, both=None):
        """Triangles for ``pieces_`` and, reversed, for ``both`` (where >= 0)."""
        emitted_tris.append(tris)
        emitted_piece.append(pieces_)
        if both is not None:
            keep = both >= 0
            emitted_tris.append(tris[keep][:, ::-1])
            emitted_piece.append(both[keep])

    face_tets = topo.face_tets
    has2 = face_tets[:, 1] >= 0
    side_forced = forced[face_tets]  # (f, 2); the value for a missing side is ignored
    side_forced[~has2, 1] = True
    field = ~forced
    es = np.zeros(0, np.int64)
    eid = np.zeros(0, np.int64)
    if field.any():
        win = np.argmax(Zv, axis=1)
        ftets = np.flatnonzero(field)
        # Tie points depend on the field only: computed once per field for all simplices, then selected.
        if topo.ties is None or topo.ties[0] is not Zv:
            topo.ties = (Zv, _tie_points(V, Zv, topo.edges), _tie_points(V, Zv, topo.faces),
                         _tie_points(V, Zv, np.sort(T, axis=1)))
        e_used = np.zeros(len(topo.edges), dtype=bool)
        e_used[topo.tet_edges[ftets]] = True
        f_used = np.zeros(len(topo.faces), dtype=bool)
        f_used[topo.tet_faces[ftets]] = True
        (es, etie, epos), (fs, ftie, fpos), (ts, ttie, tpos) = topo.ties[1:]
        keep_e, keep_f, keep_t = e_used[es], f_used[fs], field[ts]
        es, etie, epos = es[keep_e], etie[keep_e], epos[keep_e]
        fs, ftie, fpos = fs[keep_f], ftie[keep_f], fpos[keep_f]
        ts, ttie, tpos = ts[keep_t], ttie[keep_t], tpos[keep_t]
        eid = next_id + np.arange(len(es))
        fid = eid[-1] + 1 + np.arange(len(fs)) if len(es) else next_id + np.arange(len(fs))
        next_id += len(es) + len(fs)
        tid = next_id + np.arange(len(ts))
        next_id += len(ts)
        blocks += [epos, fpos, tpos]
        sites += [np.pad(topo.edges[es], ((0, 0), (0, 2)), constant_values=-1),
                  np.pad(topo.faces[fs], ((0, 0), (0, 1)), constant_values=-1), T[ts]]
        positions = np.concatenate(blocks)

        # Polygons between two pieces' cells inside a tet: all tie points with both pieces in the tie.
        f_tet, f_P, f_Q, f_key = [], [], [], []
        rows, idx = _join(topo.tet_edges[ftets].reshape(-1), es)
        f_tet.append(np.repeat(ftets, 6)[rows]), f_P.append(etie[idx, 0]), f_Q.append(etie[idx, 1])
        f_key.append(eid[idx])
        rows, idx = _join(topo.tet_faces[ftets].reshape(-1), fs)
        for a, b in ((0, 1), (0, 2), (1, 2)):
            f_tet.append(np.repeat(ftets, 4)[rows]), f_P.append(ftie[idx, a]), f_Q.append(ftie[idx, b])
            f_key.append(fid[idx])
        for a, b in itertools.combinations(range(4), 2):
            f_tet.append(ts), f_P.append(ttie[:, a]), f_Q.append(ttie[:, b]), f_key.append(tid)
        f_tet, f_P, f_Q, f_key = map(np.concatenate, (f_tet, f_P, f_Q, f_key))
        code = (f_tet * p + f_P) * p + f_Q
        ucode, poly = np.unique(code, return_inverse=True)
        u_tet, u_P, u_Q = ucode // (p * p), (ucode // p) % p, ucode % p
        grads = tetgeom.barycentric_gradients(V, T[u_tet])  # (q, 4, 3)
        dz = Zv[T[u_tet], u_Q[:, None]] - Zv[T[u_tet], u_P[:, None]]  # (q, 4)
        normals = np.einsum("qi,qid->qd", dz, grads)  # out of P's cell
        tri, owner = _fan(poly.reshape(-1), f_key, normals, positions)
        emit(tri, u_P[owner], u_Q[owner])

        # Face polygons of the field where the other side is the cage's outside or a forced tet.
        on_field = ~side_forced[:, 0] | ~side_forced[:, 1]
        shown = np.flatnonzero(on_field & (~has2 | side_forced[:, 0] | side_forced[:, 1]))
        if len(shown):
            field_side = np.where(side_forced[shown, 0], 1, 0)
            other_tet = face_tets[shown, 1 - field_side]
            other_piece = np.where(other_tet >= 0, tet_piece[np.maximum(other_tet, 0)], -1)
            p_face, p_piece, p_key = [], [], []
            corners = topo.faces[shown]
            p_face.append(np.repeat(np.arange(len(shown)), 3)), p_piece.append(win[corners].reshape(-1))
            p_key.append(corners.reshape(-1))
            rows, idx = _join(topo.face_edges[shown].reshape(-1), es)
            for a in range(2):
                p_face.append(rows // 3), p_piece.append(etie[idx, a]), p_key.append(eid[idx])
            rows, idx = _join(shown, fs)
            for a in range(3):
                p_face.append(rows), p_piece.append(ftie[idx, a]), p_key.append(fid[idx])
            p_face, p_piece, p_key = map(np.concatenate, (p_face, p_piece, p_key))
            code = p_face * p + p_piece
            ucode, poly = np.unique(code, return_inverse=True)
            u_face, u_piece = ucode // p, ucode % p
            oriented = topo.face_oriented[shown[u_face]]
            normals = np.cross(positions[oriented[:, 1]] - positions[oriented[:, 0]],
                               positions[oriented[:, 2]] - positions[oriented[:, 0]])
            normals[field_side[u_face] == 1] *= -1.0
            tri, owner = _fan(poly.reshape(-1), p_key, normals, positions)
            X = other_piece[u_face[owner]]
            keep = X != u_piece[owner]
            emit(tri[keep], u_piece[owner][keep], X[keep])

    # Tet-aligned parts: faces whose sides are both forced (or forced and outside).
    X1 = tet_piece[face_tets[:, 0]]
    X2 = np.where(has2, tet_piece[np.maximum(face_tets[:, 1], 0)], -1)
    aligned = side_forced[:, 0] & side_forced[:, 1]
    pinched, spindle_owner = _aligned_pinches(V, T, topo, forced, tet_piece, p, aligned, X1, X2)
    n_face, n_edge, n_pos = _notches(V, topo, pinched)
    nid = next_id + np.arange(len(n_face))
    blocks.append(n_pos)
    sites.append(np.pad(topo.faces[n_face], ((0, 0), (0, 1)), constant_values=-1))
    next_id += len(n_face)
    shown = aligned & (X1 != X2)
    # Faces with vertices on their edges (ties seen from field tets) or notches become polygons.
    extra = np.zeros(len(topo.faces), dtype=bool)
    if len(es):
        on_edge = np.zeros(len(topo.edges), dtype=bool)
        on_edge[es] = True
        extra |= on_edge[topo.face_edges].any(axis=1)
    extra[n_face] = True
    plain = np.flatnonzero(shown & ~extra)
    emit(topo.face_oriented[plain], X1[plain], X2[plain])
    busy = np.flatnonzero(shown & extra)
    if len(busy):
        centre_pos = V[topo.faces[busy]].mean(axis=1)
        centre_ids = next_id + np.arange(len(busy))
        blocks.append(centre_pos)
        sites.append(np.pad(topo.faces[busy], ((0, 0), (0, 1)), constant_values=-1))
        next_id += len(busy)
        positions = np.concatenate(blocks)
        b_poly = [np.repeat(np.arange(len(busy)), 3)]
        b_key = [topo.faces[busy].reshape(-1)]
        rows, idx = _join(topo.face_edges[busy].reshape(-1), es)
        b_poly.append(rows // 3), b_key.append(eid[idx])
        mine = np.isin(n_face, busy)
        b_poly.append(np.searchsorted(busy, n_face[mine])), b_key.append(nid[mine])
        oriented = topo.face_oriented[busy]
        normals = np.cross(V[oriented[:, 1]] - V[oriented[:, 0]], V[oriented[:, 2]] - V[oriented[:, 0]])
        tri, owner = _fan(np.concatenate(b_poly), np.concatenate(b_key), normals, positions,
                          centre_ids=centre_ids, centre_pos=centre_pos)
        emit(tri, X1[busy][owner], X2[busy][owner])
    if len(pinched):
        tris, pcs, others = _spindle_faces(V, T, topo, tet_piece, pinched, spindle_owner, n_face, n_edge, nid, X2)
        emit(tris, pcs, others)
    positions = np.concatenate(blocks)

    tris = np.concatenate(emitted_tris) if emitted_tris else np.zeros((0, 3), np.int64)
    owner = np.concatenate(emitted_piece) if emitted_piece else np.zeros(0, np.int64)
    order = np.argsort(owner, kind="stable")
    tris, owner = tris[order], owner[order]
    bounds = np.searchsorted(owner, np.arange(p + 1))
    meshes = []
    for P in range(p):
        faces = tris[bounds[P]:bounds[P + 1]]
        used, local = np.unique(faces, return_inverse=True)
        meshes.append((positions[used], local.reshape(-1, 3).astype(np.int64)))
    defects = _defect_edges(positions, tris, owner) if check else []
    site_table = np.concatenate(sites)
    return meshes, len(pinched), [site_table[list(edge)] for edge in defects]


def _aligned_pinches(V, T, topo, forced, tet_piece, p, aligned, X1, X2):
    """Edges, all of whose tets are forced, around which some piece's tets form two or more runs.

    Returns the pinched edge ids (ascending) and the piece that gets each edge's spindle (the piece with
    the most volume around the edge, lowest id on a tie).
    """
    E = len(topo.edges)
    not_all_forced = np.zeros(E, dtype=bool)
    not_all_forced[topo.tet_edges[~forced].reshape(-1)] = True
    te = topo.tet_edges.reshape(-1)
    tp = np.repeat(tet_piece, 6)
    keep = ~not_all_forced[te]
    code = te[keep] * p + tp[keep]
    vol = np.repeat(np.abs(tetgeom.tet_volumes(V, T)), 6)[keep]
    ucode, inverse, n_tets = np.unique(code, return_inverse=True, return_counts=True)
    # Faces around an edge that glue two tets of the same piece join consecutive runs.
    glued = np.flatnonzero(aligned & (X1 == X2))
    ge = topo.face_edges[glued].reshape(-1)
    gcode = ge * p + np.repeat(X1[glued], 3)
    gcode = gcode[np.isin(gcode, ucode)]
    n_glued = np.bincount(np.searchsorted(ucode, gcode), minlength=len(ucode))
    runs = n_tets - n_glued
    bad_edges = np.unique(ucode[runs >= 2] // p)
    if len(bad_edges) == 0:
        return bad_edges, bad_edges
    ring_vol = np.bincount(inverse.reshape(-1), weights=vol, minlength=len(ucode))
    edge_of = ucode // p
    sel = np.isin(edge_of, bad_edges)
    e_sel, piece_sel, vol_sel = edge_of[sel], ucode[sel] % p, ring_vol[sel]
    order = np.lexsort((piece_sel, -vol_sel, e_sel))  # per edge: largest volume, then lowest id
    e_sorted = e_sel[order]
    first = np.r_[True, e_sorted[1:] != e_sorted[:-1]]
    return e_sorted[first], piece_sel[order][first]


def _notches(V: np.ndarray, topo: _Topology, pinched: np.ndarray):
    """Notch vertices in every face next to a pinched edge.

    Returns, per notch, its face (ascending), its edge and its position
    ``m + eps (w - m)``: ``m`` the edge's midpoint, ``w`` the face's third
    vertex, computed from that face's vertices only.
    """
    face, local = np.nonzero(np.isin(topo.face_edges, pinched))
    edge = topo.face_edges[face, local]
    pair = _FACE_EDGE_PAIRS[local]
    verts = topo.faces[face]
    u = np.take_along_axis(verts, pair[:, :1], axis=1)[:, 0]
    v = np.take_along_axis(verts, pair[:, 1:], axis=1)[:, 0]
    w = verts.sum(axis=1) - u - v
    mid = (V[u] + V[v]) / 2.0
    return face, edge, mid + _PINCH_SPINDLE * (V[w] - mid)


def _spindle_faces(V, T, topo, tet_piece, pinched, owner, n_face, n_edge, nid, X2):
    """Triangles of the spindles carved around pinched tet-aligned edges.

    Around a pinched edge ``(a, b)`` each tet ``(a, b, c, d)`` loses the
    sliver tet ``(a, b, n_c, n_d)`` (``n_c``, ``n_d`` the notches of its two
    faces at the edge) to the edge's spindle piece. The spindle meets the rest
    of the mesh only at ``a`` and ``b``, so pieces that touched each other
    along the edge now touch at points at most, and the spindle's piece
    surrounds the edge. Volumes change by ``eps^2`` of the tets around the
    edge.

    Returns triangles (s, 3), their pieces (s,) and the pieces of their back
    sides (s,) (-1: none).
    """
    notch = {(f, e): i for f, e, i in zip(n_face.tolist(), n_edge.tolist(), nid.tolist())}
    npos = {i: x for i, x in zip(nid.tolist(), _notches(V, topo, pinched)[2])}
    rows: list[tuple] = []
    for f, e, i in zip(n_face.tolist(), n_edge.tolist(), nid.tolist()):
        if X2[f] < 0:  # the sliver's face on the cage boundary, oriented like the face
            u, v = [x for x in topo.face_oriented[f].tolist() if x in topo.edges[e]]
            oriented = topo.face_oriented[f].tolist()
            if (oriented.index(u) + 1) % 3 != oriented.index(v):
                u, v = v, u
            rows.append((u, v, i, int(owner[np.searchsorted(pinched, e)]), -1))
    for e, Q in zip(pinched.tolist(), owner.tolist()):
        a, b = topo.edges[e].tolist()
        for t in np.flatnonzero((topo.tet_edges == e).any(axis=1)).tolist():
            X = int(tet_piece[t])
            if X == Q:
                continue
            c, d = [int(x) for x in T[t] if x != a and x != b]
            nc, nd = notch[(_face_id(topo, t, (a, b, c)), e)], notch[(_face_id(topo, t, (a, b, d)), e)]
            xa, xb = V[a], V[b]
            if np.linalg.det(np.stack([xb - xa, npos[nc] - xa, npos[nd] - xa])) > 0:
                rows += [(b, nc, nd, Q, X), (a, nd, nc, Q, X)]
            else:
                rows += [(b, nd, nc, Q, X), (a, nc, nd, Q, X)]
    out = np.array(rows, dtype=np.int64).reshape(-1, 5)
    return out[:, :3], out[:, 3], out[:, 4]


def _local_edge(face: np.ndarray, u: int, v: int) -> int:
    """Index (into _FACE_EDGE_PAIRS) of edge (u, v) of a sorted face."""
    i, j = sorted((int(np.flatnonzero(face == u)[0]), int(np.flatnonzero(face == v)[0])))
    return {(0, 1): 0, (0, 2): 1, (1, 2): 2}[(i, j)]


def _face_id(topo, t: int, vertices) -> int:
    target = sorted(vertices)
    for f in topo.tet_faces[t].tolist():
        if topo.faces[f].tolist() == target:
            return f
    raise StageError("internal error: a tet does not contain its face", stage=STAGE)


def _defect_edges(positions: np.ndarray, tris: np.ndarray, owner: np.ndarray) -> list:
    """Global vertex pairs of region edges not shared by exactly two oppositely oriented faces.

    Checked per region (``owner`` (s,) piece of each triangle), by vertex id and by position.
    """
    found = set()
    if len(tris) == 0:
        return []
    _, weld = np.unique(positions, axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    N = len(positions)
    original = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    piece = np.tile(owner, 3)
    for ids in (original, weld[original]):
        lo, hi = ids.min(axis=1), ids.max(axis=1)
        code = (piece * N + lo) * N + hi
        forward = ids[:, 0] < ids[:, 1]
        _, inverse, counts = np.unique(code, return_inverse=True, return_counts=True)
        inverse = inverse.reshape(-1)
        n_forward = np.bincount(inverse, weights=forward, minlength=len(counts))
        bad = ((counts != 2) | (2 * n_forward != counts))[inverse] | (ids[:, 0] == ids[:, 1])
        for row in np.flatnonzero(bad).tolist():
            found.add(tuple(sorted(original[row].tolist())))
    return sorted(found)


def _region_defects(vertices: np.ndarray, faces: np.ndarray) -> int:
    """Edges of a mesh that are not shared by exactly two oppositely oriented faces (by index or position)."""
    if len(faces) == 0:
        return 1
    worst = 0
    _, weld = np.unique(vertices, axis=0, return_inverse=True)
    for F in (faces, weld.reshape(-1)[faces]):
        directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        m = int(directed.max()) + 1
        code = directed[:, 0] * m + directed[:, 1]
        reverse = directed[:, 1] * m + directed[:, 0]
        ucode, counts = np.unique(code, return_counts=True)
        pos = np.searchsorted(ucode, reverse)
        pos = np.minimum(pos, len(ucode) - 1)
        matched = ucode[pos] == reverse
        bad = int((counts > 1).sum()) + int((~matched).sum()) + int((directed[:, 0] == directed[:, 1]).sum())
        worst = max(worst, bad)
    return worst
