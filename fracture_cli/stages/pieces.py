"""Atomic pieces, their modes and the piece graph (ALGORITHM.md section 3)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.edges import components, renumber_by_first
from fracture_cli.geometry.rows import unique_rows
from fracture_cli.options import option
from fracture_cli.types import Modes, Pieces, SurfaceMesh, TetMesh

log = logging.getLogger(__name__)

STAGE = "pieces"


@dataclass(frozen=True)
class PiecesOptions:
    """Options of :func:`pieces`."""

    min_fragment_fraction: float = option(
        0.0,
        "merge pieces holding less than this fraction of the asset's volume into their largest-interface "
        "neighbour, so fragments have a size relative to the asset, not to its tessellation (0 = only pieces "
        "holding none of the asset are merged)",
        min=0.0,
        max=0.5,
    )
    deviation_warning: float = option(
        1e-2,
        "warn when a mode deviates from its piece mean by more than this fraction of the mode's largest value",
        min=0.0,
    )

    # Keys of older recipes (see fracture_cli.pipeline.recipe): old name -> (new name, what changed).
    RENAMED = {"min_volume_fraction": ("min_fragment_fraction", "a fraction of the asset's volume now, not of the "
                                       "cage's")}


# Barycentric lattice order of the points sampled in each tet to estimate how much of it is asset material.
_SAMPLE_ORDER = 3


def tet_material_fraction(tet_mesh: TetMesh, surface: SurfaceMesh) -> np.ndarray:
    """Share (t,) of each tet inside the closed ``surface``, from a lattice of interior sample points.

    The points are the barycentric lattice of order 3 (20 per tet), moved
    inside (``(i, j, k, l) + 1/4) / 4``); each is inside when a ray from it
    crosses the surface an odd number of times
    (:func:`fracture_cli.geometry.surface_query.hit_counts` along the first of its
    :data:`~fracture_cli.geometry.surface_query.VOTE_DIRECTIONS`). Tets of the cage
    around a thin shell or an empty inside get 0.
    """
    from fracture_cli.geometry.scenes import surface_scene
    from fracture_cli.geometry.surface_query import VOTE_DIRECTIONS, hit_counts  # compiled: imported when first needed

    n = _SAMPLE_ORDER
    lattice = np.array([(i, j, k, n - i - j - k) for i in range(n + 1) for j in range(n + 1 - i)
                        for k in range(n + 1 - i - j)], dtype=np.float64)
    weights = (lattice + 0.25) / (n + 1)  # (s, 4), rows sum to 1
    corners = tet_mesh.vertices[tet_mesh.tets]  # (t, 4, 3)
    points = np.einsum("sc,tcd->tsd", weights, corners).reshape(-1, 3)
    query = surface_scene(surface.vertices, surface.faces)  # the cage stage's, when it ran on this surface
    inside = hit_counts(query, points, VOTE_DIRECTIONS[0]) % 2 == 1
    return inside.reshape(len(corners), len(weights)).mean(axis=1)


def pieces(tet_mesh: TetMesh, modes: Modes, options: PiecesOptions = PiecesOptions(), *,
           surface: SurfaceMesh | None = None, cells: np.ndarray | None = None) -> Pieces:
    """Atomic pieces of a tet mesh under a set of fracture modes.

    Two tets sharing an interior face are glued when that face is cut in no
    mode; the connected components of the glued tets are the atomic pieces.

    Parameters
    ----------
    tet_mesh : TetMesh
        The tet mesh the modes live on (``t`` tets, ``f`` interior faces).
    modes : Modes
        Fracture modes; ``modes.U`` is (k, t, d) and ``modes.cut`` is (k, f) bool
        over ``tet_mesh.interior_faces``.
    options : PiecesOptions, optional
        ``min_fragment_fraction`` (default 0.0: only pieces holding none of the
        asset merge; the recipes set it) and
        ``deviation_warning`` (default 1e-2).
    surface : SurfaceMesh, optional
        The repaired input the fragments will be cut from: piece sizes are
        then the asset volume they hold (:func:`tet_material_fraction`), so
        cage volume around thin or open parts does not count. Without it, the
        tets' own volume.
    cells : (t,) int, optional
        An authored pattern's cell of every tet (the ``pattern`` stage): the
        cells are then the atomic pieces (the modes were solved on them).

    Returns
    -------
    Pieces
        ``tet_piece`` (t,) numbered by lowest tet id (piece 0 holds tet 0), piece
        modes ``W`` (k, p, d), volumes, centroids, and the piece graph: edges
        (e, 2) with ``P < Q`` sorted, shared interface areas, area-weighted
        interface centroids and unit normals pointing from ``P`` to ``Q``.

    Raises
    ------
    StageError
        If ``modes`` does not match ``tet_mesh``.

    Notes
    -----
    ALGORITHM.md section 3; section 8 says what merging small pieces trades.
    ``max_deviation`` is the worst deviation of any tet's mode value from its
    atomic piece's volume-weighted mean (relative to the mode's largest
    magnitude), measured before merging.
    """
    t = tet_mesh.num_tets
    face_tets = tet_mesh.interior_face_tets
    U, cut = _checked_modes(tet_mesh, modes)

    if cells is None:
        glued = ~cut.any(axis=0)
        tet_piece = components(t, face_tets[glued])
    else:
        tet_piece = renumber_by_first(np.asarray(cells, dtype=np.int64))
    volumes_t = np.abs(tet_mesh.tet_volumes)
    k = U.shape[0]

    atomic = int(tet_piece.max()) + 1 if t else 0
    max_deviation = _atomic_deviation(U, tet_piece, volumes_t, atomic, options.deviation_warning)

    held = volumes_t if surface is None else volumes_t * tet_material_fraction(tet_mesh, surface)
    tet_piece = _merge_small(tet_piece, face_tets, tet_mesh.interior_face_areas, held,
                             max(options.min_fragment_fraction, tol.SLIVER_VOLUME))
    p = int(tet_piece.max()) + 1 if t else 0

    volumes = np.bincount(tet_piece, weights=volumes_t, minlength=p)
    centroids = np.stack(
        [np.bincount(tet_piece, weights=volumes_t * tet_mesh.tet_centroids[:, a], minlength=p) for a in range(3)],
        axis=1,
    ) / volumes[:, None]

    # Merged pieces take the volume-weighted mean of their atomic pieces' modes.
    W, merged_deviation = _piece_means(U, tet_piece, volumes_t, p)
    if p < atomic:
        log.info("%s: merged %d small atomic pieces; the modes deviate from the merged pieces' means by up to "
                 "%.3g of their largest value (expected: merged pieces move as one)", STAGE, atomic - p,
                 merged_deviation)

    edges, edge_areas, edge_centroids, edge_normals = _piece_graph(tet_mesh, tet_piece, centroids)
    log.info("%s: %d pieces (%d atomic) from %d modes, %d graph edges, volumes %.3g..%.3g, max deviation %.2g",
             STAGE, p, atomic, k, len(edges), volumes.min() if p else 0.0, volumes.max() if p else 0.0,
             max_deviation)
    return Pieces(
        tet_piece=tet_piece.astype(np.int32),
        W=W,
        volumes=volumes,
        centroids=centroids,
        edges=edges,
        edge_areas=edge_areas,
        edge_centroids=edge_centroids,
        edge_normals=edge_normals,
        max_deviation=max_deviation,
    )


def _atomic_deviation(U: np.ndarray, tet_piece: np.ndarray, volumes_t: np.ndarray, atomic: int,
                      warn_above: float) -> float:
    """How far the modes are from constant on the atomic pieces (logged when above ``warn_above``).

    Checked before merging, which makes them non-constant on merged pieces by design.
    """
    _, max_deviation = _piece_means(U, tet_piece, volumes_t, atomic)
    if max_deviation > warn_above:
        log.warning(
            "%s: a mode deviates from its atomic piece's mean by %.3g of its largest value (> %.3g): the modes are "
            "not piecewise constant on the atomic pieces; the modes' solver tolerance or cut threshold may be too "
            "loose", STAGE, max_deviation, warn_above,
        )
    return max_deviation


def _piece_means(U: np.ndarray, tet_piece: np.ndarray, volumes_t: np.ndarray, p: int) -> tuple[np.ndarray, float]:
    """Volume-weighted mean of every mode per piece, ``W`` (k, p, d), and the worst relative deviation from it.

    ``W[i, P] = sum_{t in P} vol_t U[i, t] / vol_P``; the deviation is the
    largest ``||U[i, t] - W[i, P(t)]||`` relative to mode ``i``'s largest
    magnitude.
    """
    # on first use: a recipe reads PiecesOptions from this module without loading scipy
    import scipy.sparse as sp

    k, t, d = U.shape
    volumes = np.bincount(tet_piece, weights=volumes_t, minlength=p)
    average = sp.csr_matrix((volumes_t / volumes[tet_piece], (tet_piece, np.arange(t))), shape=(p, t))
    W = (average @ U.transpose(1, 0, 2).reshape(t, k * d)).reshape(p, k, d).transpose(1, 0, 2)
    W = np.ascontiguousarray(W)
    deviation = 0.0
    for i in range(k):
        scale = float(np.abs(U[i]).max()) if U[i].size else 0.0
        if scale > 0:
            deviation = max(deviation, float(np.linalg.norm(U[i] - W[i][tet_piece], axis=1).max()) / scale)
    return W, deviation


def _checked_modes(tet_mesh: TetMesh, modes: Modes) -> tuple[np.ndarray, np.ndarray]:
    """``modes.U`` (k, t, d) float64 and ``modes.cut`` (k, f) bool, checked against the tet mesh."""
    t, f = tet_mesh.num_tets, len(tet_mesh.interior_face_tets)
    U = np.asarray(modes.U, dtype=np.float64)
    cut = np.asarray(modes.cut, dtype=bool)
    if U.ndim != 3 or U.shape[1] != t:
        raise StageError(f"modes have shape {U.shape}, expected (k, {t}, d) for this tet mesh", stage=STAGE)
    if cut.ndim != 2 or cut.shape[1] != f or cut.shape[0] != U.shape[0]:
        raise StageError(f"modes.cut has shape {cut.shape}, expected ({U.shape[0]}, {f}): the modes were computed "
                         "on another tet mesh", stage=STAGE)
    return U, cut


def _merge_small(tet_piece: np.ndarray, face_tets: np.ndarray, face_areas: np.ndarray, volumes_t: np.ndarray,
                 fraction: float) -> np.ndarray:
    """Merge pieces below ``fraction`` of the total of ``volumes_t`` (t,) into their largest-interface neighbour.

    ``volumes_t`` is what counts of each tet (its volume, or the asset volume
    it holds). Smallest piece first (ties by id); repeats until none is left
    below the threshold or a small piece has no neighbour.
    """
    total = volumes_t.sum()
    labels = tet_piece.copy()
    stuck = set()
    while True:
        p = int(labels.max()) + 1
        vol = np.bincount(labels, weights=volumes_t, minlength=p)
        small = [P for P in np.lexsort((np.arange(p), vol)) if vol[P] < fraction * total and P not in stuck]
        if not small or p == 1:
            break
        P = int(small[0])
        a, b = labels[face_tets[:, 0]], labels[face_tets[:, 1]]
        touching = (a != b) & ((a == P) | (b == P))
        if not touching.any():
            stuck.add(P)
            continue
        other = np.where(a[touching] == P, b[touching], a[touching])
        shared = np.bincount(other, weights=face_areas[touching], minlength=p)
        Q = int(np.argmax(shared))  # argmax takes the lowest id on ties
        log.debug("%s: merging piece of volume %.3g into its neighbour (interface %.3g)", STAGE, vol[P], shared[Q])
        labels[labels == P] = Q
        labels = renumber_by_first(labels)
        stuck = set()
    return labels


def _piece_graph(tet_mesh: TetMesh, tet_piece: np.ndarray,
                 centroids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Edges (P < Q), shared areas, area-weighted centroids and P-to-Q normals."""
    face_tets = tet_mesh.interior_face_tets
    a, b = tet_piece[face_tets[:, 0]], tet_piece[face_tets[:, 1]]
    between = np.flatnonzero(a != b)
    if len(between) == 0:
        return (np.zeros((0, 2), np.int32), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))
    a, b = a[between], b[between]
    P, Q = np.minimum(a, b), np.maximum(a, b)
    # interior_face_normals point from face_tets[:, 0] to face_tets[:, 1]; flip where that tet is in Q.
    sign = np.where(a == P, 1.0, -1.0)
    areas = tet_mesh.interior_face_areas[between]
    normals = tet_mesh.interior_face_normals[between] * sign[:, None]
    centres = tet_mesh.vertices[tet_mesh.interior_faces[between]].mean(axis=1)
    pairs, inverse = unique_rows(np.stack([P, Q], axis=1), return_inverse=True)
    inverse = inverse.reshape(-1)
    e = len(pairs)
    edge_areas = np.bincount(inverse, weights=areas, minlength=e)
    edge_centroids = np.stack(
        [np.bincount(inverse, weights=areas * centres[:, c], minlength=e) for c in range(3)], axis=1
    ) / edge_areas[:, None]
    summed = np.stack([np.bincount(inverse, weights=areas * normals[:, c], minlength=e) for c in range(3)], axis=1)
    norm = np.linalg.norm(summed, axis=1, keepdims=True)
    # A curved interface can have a near-zero mean normal; fall back to the centroid direction.
    fallback = centroids[pairs[:, 1]] - centroids[pairs[:, 0]]
    fallback /= np.maximum(np.linalg.norm(fallback, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    edge_normals = np.where(norm > tol.ROUNDOFF * edge_areas[:, None], summed / np.maximum(norm, tol.SMALLEST_DIVISOR),
                            fallback)
    return pairs.astype(np.int32), edge_areas, edge_centroids, edge_normals
