"""Bond tractions per unit impulse when the fragments are rigid blocks and the faults are the compliant part.

``stress_model = "blocks"`` (docs/ALGORITHM.md, "Stress criterion"): the fracture modes put the faults
where the object is weak, so the model lets the fragments move as rigid bodies (six degrees of freedom
each: a translation ``t_A`` of the centre of mass ``c_A`` and a small rotation ``theta_A``) held together by
their faults, each fault patch an elastic layer of unit thickness: the opening ``delta = u_Q(x) - u_P(x)`` at
the patch's centroid ``x`` (``u_A(x) = t_A + theta_A x (x - c_A)``) gives the traction
``t = k_n (n . delta) n + k_s (delta - (n . delta) n)`` with ``k_n = 1`` and ``k_s = (1 - 2 nu) / (2 (1 - nu))``
(``mu / (lambda + 2 mu)`` of a thin layer), ``n`` from ``P`` to ``Q``. Mass and inertia come from the
fragment's tets (density 1; a tet counts as a point mass at its centroid).

The hit is one implicit Euler step from rest, as for the tet mesh
(:func:`fracture_cli.stages.stress.gains.site_bond_tractions` with a reach): ``(M / l^2 + K) q = f`` with
``l`` the recipe's ``stress_reach``, ``K`` the faults' stiffness and ``f`` the unit load with its torque
about the centre of the fragment it acts on. The load acts on one fragment, the one the site lands on
(the fragment whose collision parts are nearest it, as a game's collider reports the hit), at the
centroid of the load spread around the site. For a short contact the fragment hit moves and its
neighbours barely do, so every bond of the fragment hit is loaded, wherever on it the bond lies: the
struck piece is pushed out of its seat.
``6 p`` unknowns: one dense solve, with the kernels pinned like every other solve of the bake.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from fracture_cli.errors import StageError
from fracture_cli.stages.stress.bonds import BondFaces, ContactPoints
from fracture_cli.stages.stress.fem import STAGE
from fracture_cli.types import TetMesh


def _cross_matrix(r: np.ndarray) -> np.ndarray:
    """``[r]_x`` (m, 3, 3): ``[r]_x v = r x v``."""
    out = np.zeros((len(r), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -r[:, 2], r[:, 1]
    out[:, 1, 0], out[:, 1, 2] = r[:, 2], -r[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -r[:, 1], r[:, 0]
    return out


def _mass_properties(tet_mesh: TetMesh, owner: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass (p,), centre (p, 3) and inertia about the centre (p, 3, 3) of every fragment's tets."""
    volume = np.abs(np.asarray(tet_mesh.tet_volumes, dtype=np.float64))
    centroid = np.asarray(tet_mesh.tet_centroids, dtype=np.float64)
    mine = owner >= 0
    mass = np.bincount(owner[mine], weights=volume[mine], minlength=p)
    if not np.all(mass > 0.0):
        raise StageError("a fragment holds no tet of the tet mesh: the blocks stress model needs its mass",
                         stage=STAGE)
    center = np.stack([np.bincount(owner[mine], weights=volume[mine] * centroid[mine, c], minlength=p)
                       for c in range(3)], axis=1) / mass[:, None]
    r = centroid[mine] - center[owner[mine]]
    r2 = (r[:, 0] * r[:, 0] + r[:, 1] * r[:, 1]) + r[:, 2] * r[:, 2]
    inertia = np.zeros((p, 3, 3))
    for a in range(3):
        for b in range(3):
            term = volume[mine] * ((r2 if a == b else 0.0) - r[:, a] * r[:, b])
            inertia[:, a, b] = np.bincount(owner[mine], weights=term, minlength=p)
    return mass, center, inertia


def _patch_points(tet_mesh: TetMesh, patches: BondFaces, contacts: ContactPoints | None, count: int) -> np.ndarray:
    """Centroid (P, 3) of every patch: its tet faces' centroids by area, or its contact samples' tets."""
    faces = np.asarray(tet_mesh.interior_faces, dtype=np.int64)[patches.faces]
    V = np.asarray(tet_mesh.vertices, dtype=np.float64)
    middle = (V[faces[:, 0]] + V[faces[:, 1]] + V[faces[:, 2]]) / 3.0
    total = np.stack([np.bincount(patches.bond, weights=patches.weight * middle[:, c], minlength=count)
                      for c in range(3)], axis=1)
    weight = np.bincount(patches.bond, weights=patches.weight, minlength=count)
    if contacts is not None and len(contacts.bond):
        at = np.asarray(tet_mesh.tet_centroids, dtype=np.float64)[contacts.tet]
        total += np.stack([np.bincount(contacts.bond, weights=contacts.weight * at[:, c], minlength=count)
                           for c in range(3)], axis=1)
        weight += np.bincount(contacts.bond, weights=contacts.weight, minlength=count)
    return total / np.where(weight > 0.0, weight, 1.0)[:, None]


def _opening_operators(points: np.ndarray, ends: np.ndarray, center: np.ndarray, p: int) -> sp.csr_matrix:
    """``D`` (3P, 6p) sparse: the opening ``u_Q(x) - u_P(x)`` at every patch centroid (rows ``3 k + c``) from the
    blocks' motions (columns ``6 A + j``: translation ``j < 3``, rotation ``j >= 3``); 12 entries per row."""
    count = len(points)
    local = np.zeros((count, 3, 12))  # the patch's 3 x 12 block: P's six unknowns, then Q's
    for side, sign in ((0, -1.0), (1, 1.0)):
        arm = _cross_matrix(points - center[ends[:, side]])  # theta x r = -[r]_x theta
        local[:, :, 6 * side: 6 * side + 3] = sign * np.eye(3)[None, :, :]
        local[:, :, 6 * side + 3: 6 * side + 6] = -sign * arm
    rows = np.repeat(np.arange(3 * count), 12)
    blocks = np.stack([ends[:, 0], ends[:, 1]], axis=1)  # (P, 2)
    per_patch = (6 * blocks[:, :, None] + np.arange(6)[None, None, :]).reshape(count, 12)  # (P, 12)
    cols = np.repeat(per_patch[:, None, :], 3, axis=1).reshape(-1)
    return sp.csr_matrix((local.reshape(-1), (rows, cols)), shape=(3 * count, 6 * p))


def most_loaded_block(tet_mesh: TetMesh, owner: np.ndarray, patchT: sp.csr_matrix, p: int) -> np.ndarray:
    """Per site (s,) int64: the fragment whose tets hold the most of the site's load spread (ties: the smallest).

    Parameters
    ----------
    tet_mesh : TetMesh
    owner : (t,) int
        Fragment of every tet (-1: none).
    patchT : (s, n) sparse
        Each site's load spread over the tet mesh's vertices.
    p : int
        Number of fragments.
    """
    T = np.asarray(tet_mesh.tets, dtype=np.int64)
    volume = np.abs(np.asarray(tet_mesh.tet_volumes, dtype=np.float64))
    mine = owner >= 0
    share = sp.coo_matrix((np.repeat(volume[mine], 4), (T[mine].reshape(-1), np.repeat(owner[mine], 4))),
                          shape=(tet_mesh.num_vertices, p)).tocsr()  # (n, p): tet volume at vertex j of block A
    return np.asarray((patchT @ share).toarray().argmax(axis=1)).reshape(-1).astype(np.int64)


def _loads(tet_mesh: TetMesh, owner: np.ndarray, center: np.ndarray, patchT: sp.csr_matrix, p: int,
           site_owner: np.ndarray | None) -> np.ndarray:
    """``F`` (6p, 3s): the generalized force of a unit force along axis ``k`` at site ``v`` (column ``3 v + k``).

    The force acts on one block, the fragment the site lands on (``site_owner``; by default the fragment
    whose tets hold the most of the load spread ``patchT`` (s, n) gives it), at the spread's centroid, with its
    torque about the block's centre: a hit touches one fragment, as a game's collider reports it.
    """
    V = np.asarray(tet_mesh.vertices, dtype=np.float64)
    s = patchT.shape[0]
    if site_owner is None:
        site_owner = most_loaded_block(tet_mesh, owner, patchT, p)
    site_owner = np.asarray(site_owner, dtype=np.int64).reshape(-1)
    point = np.stack([np.asarray(patchT @ V[:, c]).reshape(-1) for c in range(3)], axis=1)  # (s, 3)
    arm = point - center[site_owner]
    F = np.zeros((6 * p, 3 * s))
    eye = np.eye(3)
    columns = np.arange(s)
    for k in range(3):
        torque = np.cross(arm, eye[k])  # (s, 3)
        for c in range(3):
            F[6 * site_owner + c, 3 * columns + k] = eye[k][c]
            F[6 * site_owner + 3 + c, 3 * columns + k] = torque[:, c]
    return F


def block_tractions(tet_mesh: TetMesh, owner: np.ndarray, patches: BondFaces, patch_ends: np.ndarray,
                    normals: np.ndarray, patchT: sp.csr_matrix, reach: float, poisson_ratio: float,
                    contacts: ContactPoints | None = None, vector: bool = False,
                    site_owner: np.ndarray | None = None) -> np.ndarray:
    """Mean traction on every fault patch per unit load at every site, rigid blocks (module docstring).

    Parameters
    ----------
    tet_mesh : TetMesh
    owner : (t,) int
        Fragment of every tet (-1: none).
    patches : BondFaces
        The fault patches (``bond`` = patch index).
    patch_ends : (P, 2) int
        The fragments ``(P, Q)`` of every patch's bond.
    normals : (P, 3) float
        Unit patch normals, from ``P`` to ``Q``.
    patchT : (s, n) sparse
        Load spread of every site (:func:`fracture_cli.stages.stress.gains.site_patches`, transposed).
    reach : float
        ``l > 0``, normalized units.
    poisson_ratio : float
    contacts : ContactPoints, optional
    vector : bool, optional (default False)
        Traction vectors ``(s, 3, 3P)`` (entry ``3 p + c``) instead of normal tractions ``(s, 3, P)``.
    site_owner : (s,) int, optional
        The fragment every site lands on (:func:`_loads`).

    Returns
    -------
    (s, 3, P) or (s, 3, 3P) float64
    """
    if not reach > 0.0:
        raise StageError("the blocks stress model needs stress_reach > 0", stage=STAGE)
    count = len(patch_ends)
    p = int(max(int(owner.max()) + 1, int(patch_ends.max()) + 1 if count else 0, 1))
    mass, center, inertia = _mass_properties(tet_mesh, owner, p)
    points = _patch_points(tet_mesh, patches, contacts, count)
    area = np.bincount(patches.bond, weights=tet_mesh.interior_face_areas[patches.faces], minlength=count)
    area = np.where(area > 0.0, area, float(area.max()) if count and area.max() > 0.0 else 1.0)
    shear = (1.0 - 2.0 * poisson_ratio) / (2.0 * (1.0 - poisson_ratio))
    nn = normals[:, :, None] * normals[:, None, :]
    stiff = shear * np.eye(3)[None, :, :] + (1.0 - shear) * nn  # (P, 3, 3): traction per unit opening
    D = _opening_operators(points, patch_ends, center, p)  # (3P, 6p)
    stiff_blocks = sp.block_diag(list(stiff), format="csr") if count else sp.csr_matrix((0, 0))
    traction_op = (stiff_blocks @ D).tocsr()  # (3P, 6p): traction per unit motion
    K = (D.T @ sp.diags(np.repeat(area, 3)) @ traction_op).toarray()  # sum_p a_p D_p^T S_p D_p
    M = np.zeros((6 * p, 6 * p))
    for a in range(p):
        M[6 * a: 6 * a + 3, 6 * a: 6 * a + 3] = mass[a] * np.eye(3)
        M[6 * a + 3: 6 * a + 6, 6 * a + 3: 6 * a + 6] = inertia[a]
    F = _loads(tet_mesh, owner, center, patchT, p, site_owner)  # (6p, 3s)
    try:
        Q = sla.solve(M / (reach * reach) + K, F, assume_a="pos")  # (6p, 3s)
    except (sla.LinAlgError, ValueError) as exc:
        raise StageError(f"cannot solve the blocks' impact step ({exc})", stage=STAGE) from None
    s = patchT.shape[0]
    t = np.asarray(traction_op @ Q).reshape(count, 3, s, 3).transpose(2, 3, 0, 1)  # (s, k, P, c)
    if vector:
        return t.reshape(s, 3, 3 * count)
    return (t[..., 0] * normals[None, None, :, 0] + t[..., 1] * normals[None, None, :, 1]) \
        + t[..., 2] * normals[None, None, :, 2]
