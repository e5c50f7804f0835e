"""The ``runtime`` stage's work: contact sites, site-to-mode coefficients, piece modes, structure data.

:func:`fracture_cli.stages.runtime.runtime` and :func:`~fracture_cli.stages.runtime.with_structure` are the
stage's entry points (their docstrings say what is made); this module computes it, so that the package itself
loads nothing heavy.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Sequence

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.runtime.format import UNITS_NOTE, RuntimeData, check_runtime
from fracture_cli.stages.runtime.options import STAGE, RuntimeOptions
from fracture_cli.system import detmath
from fracture_cli.types import Anchors, Fragments, Modes, Pieces, TetMesh

log = logging.getLogger(__name__)


def precompute(tet_mesh: TetMesh, modes: Modes, pieces: Pieces, options: RuntimeOptions,
               fragment_pieces: Sequence[int] | np.ndarray | None, fragment_names: tuple[str, ...] | None,
               fragment_graph: tuple[np.ndarray, np.ndarray] | None) -> RuntimeData:
    """The stage's work (:func:`fracture_cli.stages.runtime.runtime`)."""
    started = time.perf_counter()
    U = np.asarray(modes.U, dtype=np.float64)
    W = np.asarray(pieces.W, dtype=np.float64)
    if U.ndim != 3 or U.shape[1] != tet_mesh.num_tets:
        raise StageError(f"modes have shape {U.shape}, expected (k, {tet_mesh.num_tets}, d) for this tet mesh",
                         stage=STAGE)
    k, t, d = U.shape
    if W.ndim != 3 or W.shape[0] != k or W.shape[2] != d:
        raise StageError(f"piece modes W have shape {W.shape}, expected ({k}, p, {d}) to match the modes",
                         stage=STAGE)
    W, edges, edge_areas = _restrict_to_fragments(W, pieces, fragment_pieces, fragment_graph)
    p = W.shape[1]
    if fragment_names is None:
        fragment_names = tuple(f"fragment_{j:03d}" for j in range(p))
    fragment_names = tuple(str(n) for n in fragment_names)
    if len(fragment_names) != p:
        raise StageError(f"{len(fragment_names)} fragment names for {p} fragments", stage=STAGE)
    if not options.radius > 0:
        raise StageError(f"radius must be > 0, got {options.radius}", stage=STAGE)

    volumes = tet_mesh.tet_volumes
    total_volume = float(volumes.sum())
    if not total_volume > 0:
        raise StageError("tet mesh has no volume", stage=STAGE)
    sites = tet_mesh.boundary_vertices
    scale = np.sqrt(total_volume)
    B = _site_coefficients(tet_mesh, U, detmath.square(float(options.radius)))[sites] * scale

    norm = tet_mesh.normalization
    data = RuntimeData(
        sites=norm.to_world(tet_mesh.vertices[sites]).astype(np.float32),
        B=B.astype(np.float32),
        W=(W * scale).astype(np.float32),
        edges=edges.astype(np.int32),
        edge_areas=(edge_areas * detmath.square(norm.scale)).astype(np.float32),
        fragment_names=fragment_names,
        transform=norm.matrix(),
        default_threshold=float(options.threshold),
        radius=float(options.radius),
        units=UNITS_NOTE,
    )
    problem = check_runtime(data)
    if problem:
        raise StageError(f"runtime data is inconsistent: {problem}", stage=STAGE)
    log.info("%s: %d sites, %d modes (d=%d), %d fragments, %d edges, radius %.3g, %.2fs", STAGE, len(sites), k, d,
             p, data.num_edges, options.radius, time.perf_counter() - started)
    return data


def structure_data(data: RuntimeData, anchors: Anchors | None, fragments: Fragments,
                   options: RuntimeOptions) -> RuntimeData:
    """What :func:`fracture_cli.stages.runtime.with_structure` returns."""
    if anchors is not None and anchors.any:
        if len(anchors.anchored) != data.p:
            raise StageError(f"{len(anchors.anchored)} anchor flags for {data.p} fragments: run 'anchors' on the "
                             "fragments the runtime stage gets", stage=STAGE)
        data = dataclasses.replace(data, anchored=np.asarray(anchors.anchored, dtype=np.int32),
                                   anchors_info=dict(anchors.info))
    if options.damage:
        # on first use: the fault matching loads only for a structure
        from fracture_cli.stages.fragments.cracks import crack_segments

        ptr, segments = crack_segments(fragments, data.edges)
        data = dataclasses.replace(data, damage={"crack_level": float(options.crack_level),
                                                 "damage_rate": float(options.damage_rate)},
                                   cracks={"crack_ptr": ptr, "crack_segments": segments})
        log.info("%s: damage c = %g, r = %g; %d crack segments on %d of %d bonds", STAGE, options.crack_level,
                 options.damage_rate, len(segments), int(np.count_nonzero(np.diff(ptr))), data.num_edges)
    problem = check_runtime(data)
    if problem:
        raise StageError(f"runtime data is inconsistent: {problem}", stage=STAGE)
    return data


def _site_coefficients(tet_mesh: TetMesh, U: np.ndarray, tau: float) -> np.ndarray:
    """``(M_V + tau K)^{-1} C^T M_T U_i`` at every vertex, (n, k, d): the unit-mass spread of ALGORITHM.md s. 4."""
    # on first use: scipy (0.5-1 s to import) loads in the bake that needs it, not with the runtime file format
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    k, t, d = U.shape
    volumes = tet_mesh.tet_volumes
    C = sp.csr_matrix(tet_mesh.tet_from_vertex)
    # Lumped vertex mass built from C and M_T themselves (a quarter of each tet's
    # volume per corner), so 1^T M_T C = 1^T M_V holds exactly and the impulse
    # density has unit mass whatever TetMesh.vertex_mass does.
    vertex_mass = sp.diags(np.asarray(C.T @ volumes).ravel())
    system = (vertex_mass + tau * tet_mesh.stiffness).tocsc()
    try:
        lu = spla.splu(system, permc_spec="MMD_AT_PLUS_A")
    except RuntimeError as exc:
        raise StageError(f"cannot factor M_V + tau K ({exc}); is the tet mesh valid?", stage=STAGE) from None
    # Right-hand sides C^T M_T U_i, one column per (mode, component).
    weighted = (U * volumes[None, :, None]).transpose(1, 0, 2).reshape(t, k * d)
    rhs = np.asarray(C.T @ weighted)
    return lu.solve(np.asfortranarray(rhs)).reshape(-1, k, d)  # (n, k, d)


# Public: the levels stage computes every refined fragment's ``B`` on its own tets the same way.
site_coefficients = _site_coefficients


def _restrict_to_fragments(W: np.ndarray, pieces: Pieces, fragment_pieces: Sequence[int] | np.ndarray | None,
                           fragment_graph: tuple[np.ndarray, np.ndarray] | None = None,
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Piece modes in the fragments' order (a piece's column repeated for each of its fragments) and their bonds."""
    p = W.shape[1]
    edges = np.asarray(pieces.edges, dtype=np.int64).reshape(-1, 2)
    areas = np.asarray(pieces.edge_areas, dtype=np.float64).reshape(-1)
    if fragment_pieces is None and fragment_graph is None:
        return W, edges, areas
    order = np.arange(p) if fragment_pieces is None else np.asarray(fragment_pieces, dtype=np.int64).reshape(-1)
    if len(order) == 0 or order.min() < 0 or order.max() >= p:
        raise StageError(f"fragment_pieces must list pieces in 0..{p - 1}, got {len(order)} entries", stage=STAGE)
    if len(np.unique(order)) < p:
        log.info("%s: %d piece(s) without a fragment left out of the runtime file", STAGE, p - len(np.unique(order)))
    if fragment_graph is not None:
        edges = np.asarray(fragment_graph[0], dtype=np.int64).reshape(-1, 2)
        areas = np.asarray(fragment_graph[1], dtype=np.float64).reshape(-1)
        if len(edges) and (edges.min() < 0 or edges.max() >= len(order) or np.any(edges[:, 0] >= edges[:, 1])):
            raise StageError(f"fragment graph edges must be pairs P < Q of fragments 0..{len(order) - 1}",
                             stage=STAGE)
        sort = np.lexsort((edges[:, 1], edges[:, 0]))
        return W[:, order], edges[sort], areas[sort]
    if len(np.unique(order)) != len(order):
        raise StageError("several fragments share a piece: the runtime needs their graph (fragment_graph)",
                         stage=STAGE)
    fragment_of_piece = np.full(p, -1, dtype=np.int64)
    fragment_of_piece[order] = np.arange(len(order))
    mapped = fragment_of_piece[edges]
    kept = np.all(mapped >= 0, axis=1)
    mapped, areas = np.sort(mapped[kept], axis=1), areas[kept]
    sort = np.lexsort((mapped[:, 1], mapped[:, 0]))
    return W[:, order], mapped[sort], areas[sort]
