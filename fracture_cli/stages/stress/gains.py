"""Bond tractions per unit impulse at every contact site: the ``G`` of the stress criterion.

Mechanics (docs/ALGORITHM.md, "Stress criterion"): the object floats freely, so
an impulse has no static equilibrium. We take the quasi-static response in the
body's accelerating frame (*inertia relief*): the load ``F`` spread over a patch
at the site is balanced by the inertial body force ``-m_i (a + alpha x r_i)`` of
the rigid acceleration it causes (``a = F / M``, ``alpha = I^{-1} tau``,
``tau`` the load's torque about the centre of mass; lumped vertex masses ``m_i``,
uniform density). The discrete load then has zero net force and torque, so the
rigid-body modes can be removed by pinning six DOFs (3-2-1) without changing
the stress (the pins carry no reaction, up to rounding).

Linear elasticity gives ``u = K^{-1} b``; each bond's mean normal traction over
its fault is a linear functional ``r_e . u``. With ``e`` bonds far fewer than
``3 s`` right-hand sides, the *adjoint* is solved instead: one factorization of
``K`` (pinned), ``e`` back-substitutions ``z_e = K^{-1} r_e``, then
``G[v, k, e] = A_e * z_e . b_{v, k}`` (``K`` symmetric), mathematically the same
numbers as ``3 s`` forward solves. Every product after the solve is a
scipy.sparse product or elementwise (no BLAS), in a fixed order.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from fracture_cli.errors import StageError
from fracture_cli.stages.stress.bonds import BondFaces, ContactPoints
from fracture_cli.stages.stress.fem import (
    STAGE,
    elasticity_matrix,
    lame,
    normal_traction_coefficients,
    traction_vector_coefficients,
)
from fracture_cli.types import TetMesh


def site_patches(tet_mesh: TetMesh, sites: np.ndarray, radius: float) -> sp.csr_matrix:
    """Load-spreading weights (n, s): column ``v`` spreads a unit load over the boundary around site ``v``.

    Boundary vertex ``j`` gets ``A_j * (1 - d_j / r)`` for ``d_j = |x_j - x_v| < r`` (``A_j`` a third of
    its boundary triangles' area), normalized to sum 1; the site itself always takes part.
    """
    from scipy.spatial import cKDTree

    V = tet_mesh.vertices
    faces = tet_mesh.boundary_faces
    a, b, c = V[faces[:, 0]], V[faces[:, 1]], V[faces[:, 2]]
    cross = np.cross(b - a, c - a)
    tri_area = 0.5 * np.sqrt((cross[:, 0] * cross[:, 0] + cross[:, 1] * cross[:, 1]) + cross[:, 2] * cross[:, 2])
    area = np.bincount(faces.reshape(-1), weights=np.repeat(tri_area / 3.0, 3), minlength=len(V))
    boundary = np.asarray(tet_mesh.boundary_vertices, dtype=np.int64)
    tree = cKDTree(V[boundary])
    rows, cols, vals = [], [], []
    for column, v in enumerate(np.asarray(sites, dtype=np.int64).tolist()):
        near = np.asarray(sorted(tree.query_ball_point(V[v], radius)), dtype=np.int64)
        js = boundary[near] if len(near) else np.zeros(0, dtype=np.int64)
        if v not in set(js.tolist()):
            js = np.append(js, v)
        delta = V[js] - V[v]
        d = np.sqrt((delta[:, 0] * delta[:, 0] + delta[:, 1] * delta[:, 1]) + delta[:, 2] * delta[:, 2])
        w = np.maximum(1.0 - d / radius, 0.0) * area[js]
        w[js == v] = np.maximum(w[js == v], area[v] if area[v] > 0.0 else 1.0)
        w = w / w.sum()
        rows.append(js)
        cols.append(np.full(len(js), column))
        vals.append(w)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(len(V), len(sites)))


def _pins(V: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Six DOFs (3-2-1) that remove the rigid motions: 3 at the vertex nearest the centre, 2 at the one
    farthest from it, 1 at the one farthest from their line."""
    def d2(x: np.ndarray) -> np.ndarray:
        return (x[:, 0] * x[:, 0] + x[:, 1] * x[:, 1]) + x[:, 2] * x[:, 2]

    A = int(d2(V - center).argmin())
    B = int(d2(V - V[A]).argmax())
    axis = V[B] - V[A]
    cross = np.cross(V - V[A], axis)
    C = int(d2(cross).argmax())
    along = int(np.abs(axis).argmax())
    normal = np.cross(V[C] - V[A], axis)
    pins = [3 * A, 3 * A + 1, 3 * A + 2] + [3 * B + c for c in range(3) if c != along]
    pins.append(3 * C + int(np.abs(normal).argmax()))
    return np.asarray(sorted(set(pins)), dtype=np.int64)


def _traction_functionals(tet_mesh: TetMesh, G: np.ndarray, faces: BondFaces, lam: float, mu: float,
                          contacts: ContactPoints | None = None, vector: bool = False) -> sp.csr_matrix:
    """``R`` (e, 3n): ``R u`` = the mean normal traction over every bond's fault (both tets averaged).

    Bonds without tet faces are measured at their ``contacts`` (one tet per sample) when given.
    ``vector``: ``R`` (3e, 3n) instead, row ``3 b + c`` the mean traction vector ``sigma n`` component ``c``
    with ``n`` oriented from the bond's fragment ``P`` to ``Q``.
    """
    ft = tet_mesh.interior_face_tets[faces.faces]  # (m, 2)
    normals = tet_mesh.interior_face_normals[faces.faces] * faces.sign[:, None]
    rows, cols, vals = [], [], []
    samples = [(ft[:, side], normals, faces.bond, 0.5 * faces.weight) for side in range(2)]
    if contacts is not None and len(contacts.bond):
        samples.append((contacts.tet, contacts.normal, contacts.bond, contacts.weight))
    for tets, normal, bond, weight in samples:
        dofs = 3 * tet_mesh.tets[tets][:, :, None] + np.arange(3)[None, None, :]  # (m, 4, 3)
        if vector:
            coef = traction_vector_coefficients(G[tets], normal, lam, mu)  # (m, 4, 3, 3)
            rows.append((3 * bond[:, None, None, None] + np.arange(3)[None, None, None, :]
                         + np.zeros((1, 4, 3, 1), dtype=np.int64)).reshape(-1))
            cols.append(np.repeat(dofs[:, :, :, None], 3, axis=3).reshape(-1))
            vals.append((coef * weight[:, None, None, None]).reshape(-1))
        else:
            coef = normal_traction_coefficients(G[tets], normal, lam, mu)  # (m, 4, 3)
            rows.append(np.repeat(bond, 12))
            cols.append(dofs.reshape(-1))
            vals.append((coef * weight[:, None, None]).reshape(-1))
    e = len(faces.face_area)
    R = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(3 * e if vector else e, 3 * tet_mesh.num_vertices)).tocsr()
    R.sum_duplicates()
    return R


def _inverse3(inertia: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive definite 3 x 3 matrix by cofactors (exact IEEE operations)."""
    c = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            r = [x for x in range(3) if x != i]
            s = [x for x in range(3) if x != j]
            c[i, j] = (1 - 2 * ((i + j) % 2)) * (inertia[r[0], s[0]] * inertia[r[1], s[1]]
                                                 - inertia[r[0], s[1]] * inertia[r[1], s[0]])
    det = (inertia[0, 0] * c[0, 0] + inertia[0, 1] * c[0, 1]) + inertia[0, 2] * c[0, 2]
    return c.T / det


def site_bond_tractions(tet_mesh: TetMesh, faces: BondFaces, sites: np.ndarray, radius: float,
                        youngs_modulus: float, poisson_ratio: float,
                        contacts: ContactPoints | None = None, reach: float = 0.0,
                        vector: bool = False) -> np.ndarray:
    """Mean normal traction on every bond's fault per unit load at every site, (s, 3, e) float64.

    Parameters
    ----------
    tet_mesh : TetMesh
        Normalized coordinates (unit bounding-box diagonal).
    faces : BondFaces
    sites : (s,) int
        Vertex index of every contact site.
    radius : float
        Load patch radius (normalized units).
    youngs_modulus, poisson_ratio : float
    contacts : ContactPoints, optional
        Where bonds without tet faces are measured (:func:`fracture_cli.stages.stress.bonds.contact_points`).
    reach : float, optional (default 0: quasi-static)
        ``l > 0``: the response after one implicit elastodynamic step (:func:`_impact_step`) instead of the
        quasi-static inertia relief; normalized units.
    vector : bool, optional (default False)
        Return the mean traction *vector* of every bond instead: ``(s, 3, 3e)``, entry ``3 b + c``.

    Returns
    -------
    (s, 3, e) float64
        ``out[v, k, e]``: traction (positive = tension) on bond ``e`` for a unit force along axis ``k``
        at site ``v`` with its inertia relief (module docstring); bonds without tet faces get 0.
    """
    lam, mu = lame(youngs_modulus, poisson_ratio)
    V = np.asarray(tet_mesh.vertices, dtype=np.float64)
    T = np.asarray(tet_mesh.tets, dtype=np.int64)
    n = len(V)
    K, G = elasticity_matrix(V, T, lam, mu)
    R = _traction_functionals(tet_mesh, G, faces, lam, mu, contacts, vector)
    mass = np.bincount(T.reshape(-1), weights=np.repeat(np.abs(tet_mesh.tet_volumes) / 4.0, 4), minlength=n)
    patchT = site_patches(tet_mesh, sites, radius).T.tocsr()
    if reach > 0.0:
        return _impact_step(K, R, mass, patchT, reach, youngs_modulus)
    total = float(mass.sum())
    if not total > 0.0:
        raise StageError("tet mesh has no volume", stage=STAGE)
    center = np.array([float((mass * V[:, c]).sum()) for c in range(3)]) / total
    r = V - center
    r2 = (r[:, 0] * r[:, 0] + r[:, 1] * r[:, 1]) + r[:, 2] * r[:, 2]
    inertia = np.array([[float((mass * ((r2 if a == b else 0.0) - r[:, a] * r[:, b])).sum()) for b in range(3)]
                        for a in range(3)])
    inertia_inv = _inverse3(inertia)

    pins = _pins(V, center)
    free = np.setdiff1d(np.arange(3 * n), pins)
    Kf = K[free][:, free].tocsc()
    try:
        lu = spla.splu(Kf, permc_spec="MMD_AT_PLUS_A")
    except RuntimeError as exc:
        raise StageError(f"cannot factor the elastic stiffness ({exc}); is the tet mesh valid?", stage=STAGE) from None
    e = R.shape[0]
    Z = np.zeros((3 * n, e))
    if e:
        Z[free] = lu.solve(np.asfortranarray(R[:, free].T.toarray()))
    Zc = [np.ascontiguousarray(Z[c::3]) for c in range(3)]  # (n, e) per component

    def weighted_sum(weights: np.ndarray, Zk: np.ndarray) -> np.ndarray:
        return np.asarray(sp.csr_matrix(weights[None, :]) @ Zk).reshape(-1)

    # z . q for the six inertial fields: translation along a (m_i e_a), rotation about a (m_i e_a x r_i).
    trans = [weighted_sum(mass, Zc[a]) for a in range(3)]
    rot = [weighted_sum(-mass * r[:, 2], Zc[1]) + weighted_sum(mass * r[:, 1], Zc[2]),
           weighted_sum(mass * r[:, 2], Zc[0]) + weighted_sum(-mass * r[:, 0], Zc[2]),
           weighted_sum(-mass * r[:, 1], Zc[0]) + weighted_sum(mass * r[:, 0], Zc[1])]
    centroid = np.stack([np.asarray(patchT @ V[:, c]) for c in range(3)], axis=1) - center  # (s, 3)
    out = np.empty((len(sites), 3, e))
    eye = np.eye(3)
    for k in range(3):
        torque = np.cross(centroid, eye[k])  # (s, 3) torque of a unit force along k
        alpha = [(torque[:, 0] * inertia_inv[a, 0] + torque[:, 1] * inertia_inv[a, 1])
                 + torque[:, 2] * inertia_inv[a, 2] for a in range(3)]
        value = np.asarray(patchT @ Zc[k]) - (trans[k] / total)[None, :]
        for a in range(3):
            value = value - alpha[a][:, None] * rot[a][None, :]
        out[:, k, :] = value
    return out


def _impact_step(K: sp.csr_matrix, R: sp.csr_matrix, mass: np.ndarray, patchT: sp.csr_matrix, reach: float,
                 youngs_modulus: float) -> np.ndarray:
    """Tractions (s, 3, e) after one implicit Euler step of elastodynamics over the contact time.

    With density 1, wave speed ``c = sqrt(E)`` and contact time ``h``, the first implicit step of
    ``M u'' + K u = f`` from rest under the impulse ``J = f h`` is ``(M + h^2 K) u = h^2 f``; with
    ``l = c h`` (the *reach*: how far a wave runs during the contact) and ``K = E K1``:
    ``(M / l^2 + K1) u = f / E``. The stress ``E sigma1(u)`` then does not depend on ``E``: ``G = R1 (M / l^2 +
    K1)^{-1} f``. For ``l`` -> infinity it tends to the quasi-static inertia relief (the rigid part of ``u``
    carries no stress); for small ``l`` the response stays within about ``l`` of the load. ``M / l^2 + K1``
    is symmetric positive definite: no pins, one factorization, ``e`` adjoint solves.
    """
    shift = sp.diags(np.repeat(mass, 3) * (youngs_modulus / (reach * reach)))
    system = (K + shift).tocsc()
    try:
        lu = spla.splu(system, permc_spec="MMD_AT_PLUS_A")
    except RuntimeError as exc:
        raise StageError(f"cannot factor M / l^2 + K ({exc}); is the tet mesh valid?", stage=STAGE) from None
    e = R.shape[0]
    out = np.zeros((patchT.shape[0], 3, e))
    if e:
        Z = lu.solve(np.asfortranarray(R.T.toarray()))
        for k in range(3):
            out[:, k, :] = np.asarray(patchT @ np.ascontiguousarray(Z[k::3]))
    return out
