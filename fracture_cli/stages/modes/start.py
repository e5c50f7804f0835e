"""Start vectors of the modes' ICCM chains: the lowest eigenvectors of the tet mesh's graph Laplacian."""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh

from fracture_cli.errors import StageError
from fracture_cli.types import TetMesh

log = logging.getLogger(__name__)

STAGE = "modes"
# ARPACK iterations before the eigensolver tries again differently (shift-invert converges in a few when it can).
_ARPACK_MAXITER = 1000
# Largest vertex count for the dense eigensolver fallback (n^2 doubles of memory, n^3 time: ~4 s at 4000).
_DENSE_EIGEN_MAX = 4000


def scalar_start_vectors(tet_mesh: TetMesh, count: int, seed: int) -> np.ndarray:
    """The first ``count`` non-constant generalized eigenvectors of ``(K, M_V)``, averaged onto tets.

    Returns (count, t). Shift-invert just below 0 (``K`` is singular); ARPACK's
    start vector is drawn from ``seed`` so runs are reproducible.
    """
    K = tet_mesh.stiffness.tocsc()
    M = tet_mesh.vertex_mass.tocsc()
    n = K.shape[0]
    want = min(count + 1, n - 1)
    # Below the spectrum by a margin far smaller than the first non-zero eigenvalue.
    shift = -1e-6 * float(K.diagonal().sum() / M.diagonal().sum())
    # Uniform, not normal: numpy's normal draws call libm's exp/log, which round by the CPU (numeric_env.py).
    v0 = np.random.default_rng(seed).uniform(-1.0, 1.0, n)
    try:
        values, vectors = lowest_eigenpairs(K, M, want, shift, v0)
    except Exception as error:  # ARPACK and LAPACK raise several types; report one message
        raise StageError(f"the Laplacian eigensolver failed ({error}); is the tet mesh connected and valid?",
                         stage=STAGE) from error
    order = np.argsort(values, kind="stable")
    vectors = vectors[:, order[1:want]]  # the first is the constant
    return np.asarray((tet_mesh.tet_from_vertex @ vectors).T)


def lowest_eigenpairs(K: sp.csc_matrix, M: sp.csc_matrix, want: int, shift: float,
                       v0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``want`` (or a few more) lowest generalized eigenpairs of ``(K, M)``.

    ARPACK (shift-invert just below 0) first. When it does not converge (a
    near-flat tet puts the shift far below the spectrum; or ``want`` cuts
    through a cluster of repeated eigenvalues of a symmetric shape), it is
    asked for a few more pairs at shift -1 with a larger Krylov space, and as a
    last resort (small meshes only) LAPACK solves the dense problem.
    """
    from scipy.sparse.linalg import ArpackNoConvergence

    n = K.shape[0]
    try:
        return eigsh(K, k=want, M=M, sigma=shift, which="LM", v0=v0, maxiter=_ARPACK_MAXITER)
    except ArpackNoConvergence as first:
        log.info("%s: ARPACK did not converge for %d eigenpairs (%s); retrying with more", STAGE, want, first)
    # A near-flat tet inflates the stiffness trace, and with it the first shift, far below the spectrum,
    # where shift-invert separates nothing; the bounding-box diagonal is 1, so the smallest non-zero
    # eigenvalues are O(1) to O(100) and -1 sits just below them.
    more = min(want + 6, n - 1)
    try:
        return eigsh(K, k=more, M=M, sigma=-1.0, which="LM", v0=v0, ncv=min(n, 2 * more + 20),
                     maxiter=_ARPACK_MAXITER)
    except ArpackNoConvergence as second:
        if n > _DENSE_EIGEN_MAX:
            raise
        log.info("%s: ARPACK did not converge again (%s); solving the dense problem (%d vertices)", STAGE, second, n)
    import scipy.linalg

    return scipy.linalg.eigh(K.toarray(), M.toarray(), subset_by_index=[0, want - 1])
