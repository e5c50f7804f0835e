"""Linear elasticity with P1 (linear tetrahedron) finite elements: stiffness, loads, tractions.

Unknowns are the vertex displacements ``u`` (3 per vertex, DOF ``3 i + a`` is
component ``a`` of vertex ``i``). In a tet the displacement is linear, so the
strain ``eps = sym(grad u)`` and the stress ``sigma = lambda tr(eps) I + 2 mu eps``
are constant; with ``g_i`` the gradient of the hat function of the tet's corner
``i``, ``grad u = sum_i u_i g_i^T`` and the element stiffness is

``K[(i, a), (j, b)] = V (lambda g_i[a] g_j[b] + mu (delta_ab g_i . g_j + g_i[b] g_j[a]))``.

Only ``+ - * /`` and the project's own FEM gradients
(:func:`fracture_cli.geometry.tetgeom.barycentric_gradients`) are used.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from fracture_cli.errors import StageError
from fracture_cli.geometry.tetgeom import barycentric_gradients, tet_volumes

STAGE = "runtime"


def lame(youngs_modulus: float, poisson_ratio: float) -> tuple[float, float]:
    """Lame parameters ``(lambda, mu)`` of an isotropic material.

    Parameters
    ----------
    youngs_modulus : float
        ``E > 0``.
    poisson_ratio : float
        ``-1 < nu < 0.5``.
    """
    E, nu = float(youngs_modulus), float(poisson_ratio)
    if not (E > 0.0 and -1.0 < nu < 0.5):
        raise StageError(f"need Young's modulus > 0 and -1 < Poisson ratio < 0.5, got E = {E}, nu = {nu}",
                         stage=STAGE)
    return E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), E / (2.0 * (1.0 + nu))


def elasticity_matrix(V: np.ndarray, T: np.ndarray, lam: float, mu: float) -> tuple[sp.csr_matrix, np.ndarray]:
    """The P1 elastic stiffness matrix ``K`` (3n, 3n) and the hat-function gradients.

    Parameters
    ----------
    V : (n, 3) float
        Vertex positions.
    T : (t, 4) int
        Positively oriented tets.
    lam, mu : float
        Lame parameters (:func:`lame`).

    Returns
    -------
    K : (3n, 3n) csr_matrix
        Symmetric positive semi-definite (six rigid-body modes in its kernel).
    gradients : (t, 4, 3) float64
        ``g_i`` of every tet (rows), from :func:`fracture_cli.geometry.tetgeom.barycentric_gradients`.
    """
    n = len(V)
    vol = np.abs(tet_volumes(V, T))
    G = barycentric_gradients(V, T)  # (t, 4, 3)
    dot = np.einsum("tid,tjd->tij", G, G)  # (t, 4, 4) g_i . g_j
    eye = np.eye(3)
    local = np.empty((len(T), 4, 3, 4, 3))  # local[t, i, a, j, b]
    for a in range(3):
        for b in range(3):
            local[:, :, a, :, b] = (lam * G[:, :, a][:, :, None] * G[:, :, b][:, None, :]
                                    + mu * (eye[a, b] * dot + G[:, :, b][:, :, None] * G[:, :, a][:, None, :]))
    local *= vol[:, None, None, None, None]
    dofs = (3 * T[:, :, None] + np.arange(3)[None, None, :]).reshape(len(T), 12)  # (t, 12), order (i, a)
    rows = np.repeat(dofs, 12, axis=1).reshape(-1)
    cols = np.tile(dofs, (1, 12)).reshape(-1)
    K = sp.coo_matrix((local.reshape(-1), (rows, cols)), shape=(3 * n, 3 * n)).tocsr()
    K.sum_duplicates()
    return ((K + K.T) * 0.5).tocsr(), G


def normal_traction_coefficients(G: np.ndarray, normals: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """Coefficients (f, 4, 3) of ``n . sigma n`` of one tet per face, on the tet's corner displacements.

    Parameters
    ----------
    G : (f, 4, 3) float
        Hat-function gradients of the tet on each face's side.
    normals : (f, 3) float
        Unit face normals (the sign does not matter: ``n . sigma n`` is even in ``n``).
    lam, mu : float

    Returns
    -------
    (f, 4, 3) float64
        ``c[i, a] = lambda g_i[a] + 2 mu (n . g_i) n[a]``: ``n . sigma n = sum_{i, a} c[i, a] u_i[a]``
        (positive = tension).
    """
    ng = np.einsum("fid,fd->fi", G, normals)  # (f, 4) n . g_i
    return lam * G + 2.0 * mu * ng[:, :, None] * normals[:, None, :]


def traction_vector_coefficients(G: np.ndarray, normals: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """Coefficients (f, 4, 3, 3) of the traction vector ``sigma n`` of one tet per face.

    ``(sigma n)[c] = sum_{i, a} coef[i, a, c] u_i[a]`` with
    ``coef[i, a, c] = lambda g_i[a] n[c] + mu (delta_ac (g_i . n) + g_i[c] n[a])``.
    """
    ng = np.einsum("fid,fd->fi", G, normals)  # (f, 4)
    coef = lam * G[:, :, :, None] * normals[:, None, None, :]
    coef = coef + mu * (np.eye(3)[None, None, :, :] * ng[:, :, None, None]
                        + normals[:, None, :, None] * G[:, :, None, :])
    return coef


def tet_stress(G: np.ndarray, T: np.ndarray, u: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """Stress tensors (t, 3, 3) of displacement ``u`` (n, 3); for tests and diagnostics."""
    grad = np.einsum("tia,tib->tab", u[T], G)  # grad u[a, b] = sum_i u_i[a] g_i[b]
    eps = 0.5 * (grad + grad.transpose(0, 2, 1))
    trace = eps[:, 0, 0] + eps[:, 1, 1] + eps[:, 2, 2]
    return lam * trace[:, None, None] * np.eye(3)[None] + 2.0 * mu * eps
