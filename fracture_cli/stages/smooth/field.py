"""The field method: smooth the one-hot piece field on a refined tet mesh (ALGORITHM.md section 5)."""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from fracture_cli.errors import StageError
from fracture_cli.geometry import tetgeom, trigeom
from fracture_cli.geometry import tolerances as tol
from fracture_cli.stages.smooth.marching import direct_regions
from fracture_cli.stages.smooth.options import STAGE
from fracture_cli.stages.smooth.topology import Topology
from fracture_cli.types import Pieces, TetMesh

log = logging.getLogger(__name__)



# Field method: the most a vanishing piece's field (values in [0, 1]) may be raised to keep its volume.
_MAX_BIAS = 0.5


def refined(tet_mesh: TetMesh, tet_piece: np.ndarray, levels: int, max_tets: int) -> tuple[TetMesh, np.ndarray]:
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


def winning_field(tet_mesh: TetMesh, topo: Topology, tet_piece: np.ndarray, pieces: Pieces, lam: float,
                   vanish_fraction: float) -> tuple[np.ndarray, list[int], tuple[
                       list[tuple[np.ndarray, np.ndarray]], int, list[np.ndarray]]]:
    """Field method: the smoothed field ``Z`` (n, p), raised for pieces that would vanish, the pieces that
    vanish anyway (they keep their own tets), and the direct regions of that field (``direct_regions``' result,
    so the caller need not build them again)."""
    V, T, p = tet_mesh.vertices, tet_mesh.tets, pieces.num_pieces
    Z = smoothed_field(tet_mesh, tet_piece, p, lam)
    vanished: list[int] = []
    raised: list[int] = []
    while True:
        forced, Zv = forced_field(Z, tet_piece, vanished)
        built = direct_regions(V, T, topo, Zv, forced, tet_piece, p)
        meshes = built[0]
        won = np.array([trigeom.signed_volume(*m) for m in meshes])
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
    return Z, vanished, built


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


def forced_field(Z: np.ndarray, tet_piece: np.ndarray, vanished: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Tets (t,) bool that vanished pieces keep, and the field with those pieces never winning."""
    forced = np.isin(tet_piece, vanished)
    Zv = Z.copy()
    if vanished:
        Zv[:, vanished] = -1.0
    return forced, Zv


def smoothed_field(tet_mesh: TetMesh, tet_piece: np.ndarray, p: int, lam: float) -> np.ndarray:
    """Smoothed piece membership ``Z`` (n, p) at the vertices."""
    n = tet_mesh.num_vertices
    vol = np.abs(tet_mesh.tet_volumes)
    # Tets flat to rounding (a flat cage tet refined) still weigh a little (ROUNDOFF of the mean tet volume), so
    # that a vertex only they touch has a mass and the value of their piece instead of making the system singular.
    vol = np.maximum(vol, tol.ROUNDOFF * vol.mean()) if len(vol) else vol
    # M_V Z0 with Z0 the lumped-mass average of the one-hot tet field: each tet
    # gives a quarter of its volume to each of its vertices, in its piece's column.
    quarter = np.repeat(vol / 4.0, 4)
    mass_onehot = sp.coo_matrix(
        (quarter, (tet_mesh.tets.reshape(-1), np.repeat(tet_piece, 4))), shape=(n, p)
    ).toarray()
    mass = sp.diags(np.bincount(tet_mesh.tets.reshape(-1), weights=quarter, minlength=n))
    system = (mass + lam * tet_mesh.stiffness).tocsc()
    if not p:
        return np.zeros((n, 0))
    try:
        factor = _spd_factor(system)
    except RuntimeError as exc:  # singular: degenerate tets
        raise StageError(f"the smoothing system is singular ({exc}); check the tet mesh for flat tets",
                         stage=STAGE) from exc
    # All right-hand sides in one call: the triangular solves then run as dense block operations.
    return factor.solve(mass_onehot)


def _spd_factor(system: sp.csc_matrix) -> spla.SuperLU:
    """A sparse factorization of the symmetric positive definite ``system`` (n, n).

    SuperLU told the matrix is symmetric: a symmetric fill-reducing ordering
    (minimum degree on A + A^T) and no row pivoting (none is needed: the
    lumped mass makes the system positive definite). On the 54k-unknown field
    system of the chair this factorizes in about half the CPU time of the
    default (COLAMD, partial pivoting), with L holding 40% fewer entries;
    bench/RESULTS.md ("Field smoothing solvers") compares it with a sparse
    Cholesky (CHOLMOD) and preconditioned conjugate gradients.
    """
    return spla.splu(system, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                     options={"SymmetricMode": True})
