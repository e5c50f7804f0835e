"""The work of the ``tetra`` stage: TetGen runs with quality bounds, their checks and the flat tets peeled off."""

from __future__ import annotations

import logging
import time

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry import tetgeom, trigeom
from fracture_cli.geometry import tolerances as tol
from fracture_cli.stages.tetra import tetgen as _tetgen
from fracture_cli.stages.tetra.options import STAGE, TetraOptions
from fracture_cli.system import detmath
from fracture_cli.types import Cage, TetMesh

log = logging.getLogger(__name__)



def tetgen_switches(options: TetraOptions, cage_volume: float) -> str:
    """TetGen switches for ``options``: PLC, boundary kept (``Y``), quality, optional volume bound,
    optimization level, quiet."""
    switches = f"pYq{options.radius_edge_ratio:.6g}/{options.min_dihedral:.6g}"
    if options.max_volume > 0:
        switches += f"a{options.max_volume * cage_volume:.6e}"
    return switches + f"O{options.optimization}Q"


def _run_tetgen(vertices: np.ndarray, faces: np.ndarray, switches: str, timeout: float) -> tuple[
        str | None, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """One TetGen run and its checks: ``(problem or None, nodes, tets, volumes)``."""
    try:
        nodes, tets = _tetgen.tetrahedralize(vertices, faces, switches, timeout=timeout)
    except _tetgen.TetGenFailure as failure:
        return failure.reason, None, None, None
    tets = tetgeom.orient_positive(nodes, tets)
    volumes = tetgeom.tet_volumes(nodes, tets)
    if np.any(volumes <= 0):
        return f"TetGen returned {int(np.sum(volumes <= 0))} flat tetrahedra", None, None, None
    if len(nodes) < len(vertices) or not np.array_equal(nodes[:len(vertices)], vertices):
        return "TetGen moved or dropped cage vertices", None, None, None
    _, _, boundary, _ = tetgeom.tet_faces(tets)
    if not _same_triangles(boundary, faces):
        # TetGen may split a near-degenerate cage face with a Steiner point on it: the boundary is then
        # a refinement of the cage, the same surface. Accept only that: same enclosed volume, same area.
        cage_area = tetgeom.triangle_areas(vertices, faces).sum()
        cage_volume = np.einsum("ij,ij->i", vertices[faces[:, 0]],
                                np.cross(vertices[faces[:, 1]], vertices[faces[:, 2]])).sum() / 6.0
        same_area = abs(tetgeom.triangle_areas(nodes, boundary).sum() - cage_area) <= tol.TIE * cage_area
        same_volume = abs(volumes.sum() - cage_volume) <= tol.TIE * cage_volume
        if not (same_area and same_volume):
            return "the tet mesh boundary differs from the cage surface (TetGen changed it)", None, None, None
        log.info("tetra: TetGen refined %d cage faces with points on them (same surface)",
                 len(_face_set(faces) - _face_set(boundary)))
    return None, nodes, tets, volumes


def _face_set(F: np.ndarray) -> set[tuple[int, ...]]:
    return set(map(tuple, np.sort(np.asarray(F), axis=1).tolist()))


def build_tet_mesh(cage: Cage, options: TetraOptions) -> TetMesh:
    """The body of :func:`fracture_cli.stages.tetra.tetra` (parameters, results and notes there)."""
    vertices = np.asarray(cage.vertices, dtype=np.float64)
    faces = np.asarray(cage.faces, dtype=np.int64)
    if len(faces) < 4:
        raise StageError(f"the cage has {len(faces)} faces; a closed surface needs at least 4", stage=STAGE)
    cage_volume = trigeom.signed_volume(vertices, faces)
    if cage_volume <= 0:
        raise StageError("the cage encloses no volume (inside-out or open); rebuild it with the cage stage",
                         stage=STAGE)
    started = time.perf_counter()
    # The quality run first; if TetGen fails or alters the boundary on it (rare: seen on box-like cages),
    # a plain boundary-preserving run that also keeps coplanar cage faces apart (M: no facet merging).
    attempts = [tetgen_switches(options, cage_volume), "pYMO0Q"]
    for attempt, switches in enumerate(attempts):
        problem, nodes, tets, volumes = _run_tetgen(vertices, faces, switches, options.timeout)
        if problem is None:
            break
        if attempt + 1 < len(attempts):
            log.warning("tetra: %s with switches %s; retrying without quality refinement (%s)", problem, switches,
                        attempts[attempt + 1])
    else:
        raise StageError(f"{problem} (switches {', '.join(attempts)}); try a looser --radius-edge-ratio or "
                         "--min-dihedral, or rebuild the cage with a larger offset", stage=STAGE)
    assert nodes is not None and tets is not None  # problem is None: _run_tetgen returned the mesh
    # Shape measure: volume / longest edge^3 (0.118 for a regular tet). Flat
    # tets can remain where four cage vertices are nearly coplanar, because the
    # boundary may not be split; report the worst so later stages can be judged.
    tets, peeled = _peel_flat_boundary_tets(nodes, tets)
    if peeled:
        log.info("tetra: removed %d flat tet(s) lying on the cage surface (the surface keeps its shape)", peeled)
    shape = _shape(nodes, tets)
    log.info("tetra: %d tets, %d vertices (%d inside) in %.2f s, switches %s, worst shape %.2e (%d below 1e-6)",
             len(tets), len(nodes), len(nodes) - len(vertices), time.perf_counter() - started, switches,
             float(shape.min()), int(np.sum(shape < 1e-6)))
    return TetMesh(vertices=nodes, tets=tets, normalization=cage.normalization)


def _shape(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Volume / longest edge^3 of every tet (0.118 for a regular tet, 0 for a flat one)."""
    return tetgeom.tet_volumes(nodes, tets) / detmath.cube(tetgeom.tet_edge_lengths(nodes, tets).max(axis=1))


def _peel_flat_boundary_tets(nodes: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, int]:
    """Remove tets flat to rounding (shape <= ``tol.ROUNDOFF``) that have a face on the boundary.

    Four coplanar cage vertices can form such a tet (TetGen ``Y`` may not split
    the boundary). Removing it swaps its boundary faces for its other faces,
    which lie in the same plane: the surface keeps its shape, the enclosed
    volume does not change, and every later stage gets tets with usable
    gradients. One at a time (flattest first), each only if the boundary stays
    closed, edge-manifold and consistently oriented and no vertex is left
    without a tet.

    Returns the remaining tets (t', 4) and how many were removed.
    """
    removed = 0
    blocked: set[tuple[int, ...]] = set()
    while True:
        shape = _shape(nodes, tets)
        boundary_tets = set(TetMesh(vertices=nodes, tets=tets).boundary_face_tets.tolist())
        candidates = [int(i) for i in np.argsort(shape, kind="stable")
                      if shape[i] <= tol.ROUNDOFF and int(i) in boundary_tets and tuple(tets[i]) not in blocked]
        if not candidates:
            return tets, removed
        i = candidates[0]
        kept = np.delete(tets, i, axis=0)
        orphan = np.setdiff1d(tets[i], kept.reshape(-1)).size > 0
        if orphan or not trigeom.edge_manifold_closed(TetMesh(vertices=nodes, tets=kept).boundary_faces):
            blocked.add(tuple(tets[i]))
            continue
        tets = kept
        removed += 1


def _same_triangles(F: np.ndarray, G: np.ndarray) -> bool:
    """Whether two triangle lists hold the same triangles, ignoring order and corner rotation."""
    if len(F) != len(G):
        return False

    def canonical(T: np.ndarray) -> np.ndarray:
        T = np.asarray(T, dtype=np.int64)
        k = np.argmin(T, axis=1)
        r = np.arange(len(T))
        rotated = np.stack([T[r, k], T[r, (k + 1) % 3], T[r, (k + 2) % 3]], axis=1)
        return rotated[np.lexsort(rotated.T[::-1])]

    return bool(np.array_equal(canonical(F), canonical(G)))
