"""The geometric method: move tet vertices so tet-aligned faults become smooth surfaces (ALGORITHM.md section 5)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import connected_components

from fracture_cli.geometry import tetgeom
from fracture_cli.geometry.rows import unique_rows
from fracture_cli.stages.smooth.options import STAGE
from fracture_cli.stages.smooth.sliding import CageSurface, Containment
from fracture_cli.stages.smooth.topology import FACE_EDGE_PAIRS, Topology
from fracture_cli.types import SurfaceMesh, TetMesh

log = logging.getLogger(__name__)


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


@dataclass(frozen=True)
class FaultGraph:
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


def _fault_graph(tet_mesh: TetMesh, topo: Topology, tet_piece: np.ndarray, p: int) -> FaultGraph:
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

    fe = topo.face_edges[fault]  # (k, 3); edge j of a face joins its corners FACE_EDGE_PAIRS[j]
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
    link_blocks = []
    for end in range(2):
        ca = 3 * rows[a] + FACE_EDGE_PAIRS[local[a], end]
        cb = 3 * rows[b] + FACE_EDGE_PAIRS[local[b], end]
        link_blocks.append(np.column_stack([ca, cb]))
    links = np.concatenate(link_blocks)
    graph = sp.coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(3 * k, 3 * k))
    _, component = connected_components(graph, directed=False)
    vertex_component = unique_rows(np.column_stack([corner_vertex, component]))
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
    return FaultGraph(fault_vertex, curve_free, sheet_free, curve_edges, sheet_edges, sheet_mass, mass[0],
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


def _harmonic_extension(tet_mesh: TetMesh, displacement: np.ndarray, known: np.ndarray,
                        solver: spla.SuperLU | None = None) -> tuple[np.ndarray, spla.SuperLU]:
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


def smoothed_vertices(tet_mesh: TetMesh, topo: Topology, tet_piece: np.ndarray, p: int, lam: float,
                       surface: SurfaceMesh | None = None) -> tuple[np.ndarray, dict]:
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
        cage = CageSurface(tet_mesh.vertices, tet_mesh.boundary_faces)
        guard = Containment(surface, tet_mesh.vertices, tet_mesh.boundary_faces)
        X, stats = _deform(tet_mesh, graph, lam, graph.slide_free, cage, guard)
        if X is not None:
            return X, stats
        log.warning("%s: sliding the faults along the cage kept flattening tets or bringing the cage too close to "
                    "the input after %d rounds; cage-boundary vertices stay where they are", STAGE, stats["rounds"])
    X, stats = _deform(tet_mesh, graph, lam, np.zeros(n, dtype=bool), None, None)
    assert X is not None  # nothing slides: _deform has no partial answer to refuse
    return X, stats


def _deform(tet_mesh: TetMesh, graph: FaultGraph, lam: float, slide: np.ndarray, cage: CageSurface | None,
            guard: Containment | None) -> tuple[np.ndarray | None, dict]:
    """Smoothed tet vertex positions (n, 3) (None if sliding did not settle) and counts for the log.

    Boundary fault curves (vertices ``slide`` (n,) bool) are smoothed first, along the cage (``cage`` a
    :class:`CageSurface`); then junction curves (1-D, their ends fixed), then the fault sheets with the curves,
    the cage boundary and the non-manifold fault points as Dirichlet data; the other interior vertices follow
    harmonically. Where a tet would flatten (volume below ``_MIN_VOLUME_RATIO`` of its own), the free fault
    vertices of the offending tets are held back and everything is solved again; a slid vertex that ``guard``
    (a :class:`Containment`) blames for the cage no longer containing the input goes back where it was. Without
    sliding, if holding back does not help, the displacement is scaled down.
    """
    V, T = tet_mesh.vertices, tet_mesh.tets
    n = len(V)
    stats: dict[str, float] = {"moved": 0, "curve": 0, "slid": 0, "reverted": 0, "frozen": 0, "rounds": 0,
                               "alpha": 1.0}
    sliding = bool(slide.any())  # then ``cage`` and ``guard`` are given
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
        if len(partway) and cage is not None:
            start[partway] = cage.project(start[partway])
        X = start
        if cage is not None and sliding:
            X = _slide_smooth(X, graph.slide_edges, slide_weights, graph.slide_mass, slide & ~held, lam, cage)
        X = _implicit_smooth(X, graph.curve_edges, curve_weights, graph.curve_mass, graph.curve_free & ~held, lam)
        X = _implicit_smooth(X, graph.sheet_edges, sheet_weights, graph.sheet_mass, graph.sheet_free & ~held, lam)
        if round_ == 0:
            target = X
        D, solver = _harmonic_extension(tet_mesh, X - V, known, solver)
        bad = tetgeom.tet_volumes(V + D, T) < _MIN_VOLUME_RATIO * volume0
        stats["rounds"] = round_
        offenders = np.zeros(0, dtype=np.int64)
        if guard is not None and sliding:
            moved = slide & np.any(D != 0.0, axis=1)
            offenders = guard.offenders(V + D, moved)
        if not bad.any() and len(offenders) == 0:
            settled = True
            break
        if round_ == _MAX_FREEZE_ROUNDS or not _hold_back(damping, reverted, offenders, bad, T, movable):
            break
    stats.update(moved=int((movable & (damping > 0.0)).sum()), curve=int((graph.curve_free & (damping > 0.0)).sum()),
                 slid=int((slide & np.any(D != 0.0, axis=1)).sum()), reverted=int(reverted.sum()),
                 frozen=int((damping < 1.0).sum()))
    if sliding:
        # Scaling a displacement along the cage would take slid vertices off it: no partial answers here.
        return (V + D if settled else None), stats
    stats["alpha"] = _displacement_scale(V, T, D, volume0, bad)
    return V + stats["alpha"] * D, stats


def _hold_back(damping: np.ndarray, reverted: np.ndarray, offenders: np.ndarray, bad: np.ndarray, T: np.ndarray,
               movable: np.ndarray) -> bool:
    """Send ``offenders`` back and halve the damping (n,) of the movable vertices of flattened tets, in place.

    Returns False when no vertex is left to hold back (the rounds stop).
    """
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
            return False
        damping[culprits] = np.where(damping[culprits] > _MIN_DAMPING, damping[culprits] / 2.0, 0.0)
    return True


def _displacement_scale(V: np.ndarray, T: np.ndarray, D: np.ndarray, volume0: np.ndarray, bad: np.ndarray) -> float:
    """The largest of 1, 1/2, ... 1/64 (else 0) by which the displacement ``D`` (n, 3) flattens no tet."""
    alpha = 1.0
    while bad.any() and alpha > _MIN_ALPHA:
        alpha /= 2.0
        bad = tetgeom.tet_volumes(V + alpha * D, T) < _MIN_VOLUME_RATIO * volume0
    if bad.any():
        alpha = 0.0
    if alpha < 1.0:
        log.warning("%s: smoothed faults would flatten %d tet(s); the fault displacement is scaled by %g", STAGE,
                    int((tetgeom.tet_volumes(V + D, T) < _MIN_VOLUME_RATIO * volume0).sum()), alpha)
    return alpha


def _slide_smooth(X: np.ndarray, edges: np.ndarray, weights: np.ndarray, mass: np.ndarray, free: np.ndarray,
                  lam: float, cage: CageSurface) -> np.ndarray:
    """Boundary fault curves smoothed along the cage: implicit sub-steps, each followed by a projection onto it."""
    idx = np.flatnonzero(free)
    for _ in range(_SLIDE_STEPS):
        X = _implicit_smooth(X, edges, weights, mass, free, lam / _SLIDE_STEPS)
        X[idx] = cage.project(X[idx])
    return X

