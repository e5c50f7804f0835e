"""The ``runtime`` stage: precompute the impact-projection data a game needs (ALGORITHM.md section 4).

Named ``precompute`` so it is not confused with :mod:`fracture_cli.runtime`, the
game-side reader of what it writes; the recipe section keeps the name ``runtime``.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.options import option
from fracture_cli.runtime.format import UNITS_NOTE, RuntimeData, check_runtime
from fracture_cli.system import detmath
from fracture_cli.types import Anchors, Fragments, Modes, Pieces, TetMesh

log = logging.getLogger(__name__)
STAGE = "runtime"


@dataclass(frozen=True)
class RuntimeOptions:
    """Options of the runtime precomputation.

    Attributes
    ----------
    radius : float, optional (default 0.05)
        Impact radius ``r`` relative to the bounding-box diagonal; the impulse is
        spread by one implicit diffusion step of time ``tau = r^2``.
    criterion, youngs_modulus, poisson_ratio, tensile_strength, stress_keep, stress_reach, stress_max_bonds
        The stress criterion (:mod:`fracture_cli.stages.stress`); ``criterion = "modes"`` ignores the others
        and writes version 1 as before.
    threshold : float, optional (default 3.0)
        Default toughness written to the file (games may override it per hit).
        Dimensionless per unit of impulse: an impulse of magnitude ``m`` breaks
        the same edges as an impulse of magnitude 1 with threshold ``T / m``.
        With 3.0 a unit impulse typically splits an object into 2-3 groups
        (measured on two boxes joined by a neck, k = 6 and 12 modes).
    damage : bool, optional (default False)
        Write damage that adds up (feature ``"damage"``, docs/FORMAT.md section 12) with ``crack_level`` and
        ``damage_rate``, and the crack lines of every bond. Off: hits are judged alone (version 1, as before),
        whatever the two values say; a recipe keeps its material's values and a structure turns them on.
    crack_level, damage_rate : float, optional (default 0.6, 0.4)
        ``c`` and ``r`` of docs/FORMAT.md section 12.4: a hit that loads a bond above ``c`` of its strength
        cracks it and takes ``r (load - c) / (1 - c)`` of its health.
    """

    radius: float = option(0.05, "impact radius as a fraction of the bounding-box diagonal (diffusion time r^2)",
                           min=0.0, max=1.0, min_exclusive=True)
    threshold: float = option(3.0, "default toughness: an edge breaks when the fragments' displacement jump per "
                                   "unit impulse exceeds it (bigger = harder to break)", min=0.0)
    criterion: str = option("modes", "what breaks a bond: 'modes' (the projection's jump, format version 1) or "
                                     "'stress' (tensile traction of the elastic response, version 2)",
                            choices=("modes", "stress"))
    youngs_modulus: float = option(1.0e9, "stress criterion: Young's modulus E in Pa (a free body's stress under "
                                          "balanced loads does not depend on it)", min=0.0, min_exclusive=True)
    poisson_ratio: float = option(0.25, "stress criterion: Poisson ratio nu", min=-0.99, max=0.49)
    tensile_strength: float = option(1.0, "stress criterion: tensile strength per unit area of the asset scaled "
                                          "to a unit diagonal, in impulse units (with threshold: bigger = harder)",
                                     min=0.0, min_exclusive=True)
    stress_keep: float = option(0.05, "stress criterion: a site lists the bonds it loads to at least this fraction "
                                      "of its most loaded bond's load", min=0.0, max=1.0)
    stress_reach: float = option(0.05, "stress criterion: how far the impact's stress wave runs during the contact "
                                       "(fraction of the diagonal; small = local breaks, 0 = quasi-static)",
                                 min=0.0, max=100.0)
    stress_measure: str = option("tension_shear", "stress criterion: what loads a bond: 'tension' (normal traction) "
                                                  "or 'tension_shear' (traction without its compressive part)",
                                 choices=("tension_shear", "tension"))
    stress_max_bonds: int = option(48, "stress criterion: at most this many bonds per site (0 = no limit)",
                                   min=0, max=100000)
    damage: bool = option(False, "write damage that adds up (format version 2, feature 'damage'): a hit below a "
                                 "bond's strength cracks and weakens it, in a state the game keeps per object; "
                                 "with crack lines to draw")
    crack_level: float = option(0.6, "damage: a hit loading a bond above this fraction of its strength cracks it "
                                     "(1: any crack is a break)", min=0.0, max=1.0, min_exclusive=True)
    damage_rate: float = option(0.4, "damage: the health a hit just under a bond's strength takes (about 1/rate "
                                     "such hits break it; 0: cracks never weaken)", min=0.0, max=100.0)


def runtime(tet_mesh: TetMesh, modes: Modes, pieces: Pieces, options: RuntimeOptions = RuntimeOptions(),
            fragment_pieces: Sequence[int] | np.ndarray | None = None, fragment_names: tuple[str, ...] | None = None,
            fragment_graph: tuple[np.ndarray, np.ndarray] | None = None) -> RuntimeData:
    """Compute the contact sites, site-to-mode coefficients ``B`` and piece modes ``W``.

    Parameters
    ----------
    tet_mesh : TetMesh
        The mesh the modes live on (normalized coordinates); its boundary
        vertices are the contact sites.
    modes : Modes
        ``U : (k, t, d)`` M_T-orthonormal fracture modes.
    pieces : Pieces
        Atomic pieces: ``W : (k, p, d)``, ``edges : (e, 2)``, ``edge_areas : (e,)``.
    options : RuntimeOptions, optional
    fragment_pieces : (f,) int, optional (default ``0..p-1``)
        The piece of every exported fragment, in the fragments file's order
        (``[frag.piece for frag in fragments.fragments]``). Pieces without a
        fragment (regions that miss the input) are left out with their edges:
        there is no material there to hold fragments together. A piece may
        hold several fragments (a region cut into separate bodies): each gets
        the piece's column of ``W``; ``fragment_graph`` is then required.
    fragment_names : tuple of str, optional (default ``fragment_000``, ...)
        Node name of every fragment, in the same order.
    fragment_graph : ((e, 2) int, (e,) float), optional
        Bonds between fragments measured on their meshes (pairs ``P < Q`` in
        the fragments' order, sorted; shared fault area in normalized units
        squared, see :func:`fracture_cli.stages.fragments.interfaces.fragment_graph`).
        Default: the piece graph mapped to the fragments, which may bond
        fragments that touch only outside the input.

    Returns
    -------
    RuntimeData
        Sites and areas in the input's units; ``B`` and ``W`` scaled so the
        threshold is a dimensionless toughness (see Notes).

    Notes
    -----
    ALGORITHM.md section 4, with the two scalings of section 8 that make the
    result independent of the mesh and of the asset's size: the impulse is
    spread as a unit-mass density, and modes are rescaled to unit RMS over the
    volume. ``B`` for all sites costs ``k d`` solves with one factorization
    (``M_V + tau K`` is symmetric).
    """
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


def with_structure(data: RuntimeData, anchors: Anchors | None, fragments: Fragments,
                   options: RuntimeOptions) -> RuntimeData:
    """``data`` with what a structure needs (docs/FORMAT.md section 12), where the recipe asks for it.

    Parameters
    ----------
    data : RuntimeData
        The runtime data of ``fragments`` (same order, ``p`` fragments, bonds ``data.edges (e, 2)``).
    anchors : Anchors or None
        From the ``anchors`` stage; with at least one anchored fragment the data gets ``anchored (p,)`` and the
        header's ``anchors`` object (feature ``"anchors"``). None or no fragment anchored: unchanged.
    fragments : Fragments
        The baked fragments, for the crack lines.
    options : RuntimeOptions
        With ``damage``: the ``damage`` object (``crack_level``, ``damage_rate``; feature ``"damage"``) and
        ``crack_ptr (e+1,)``, ``crack_segments (n, 2, 3)``.

    Returns
    -------
    RuntimeData
    """
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
    # on first use: scipy (0.5-1 s to import) is not loaded to resolve a recipe, which imports this module
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
