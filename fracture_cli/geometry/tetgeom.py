"""Vectorized geometry of tetrahedral meshes: volumes, faces, FEM matrices.

All functions take plain arrays so they can be tested on tiny meshes built in
code; :class:`fracture_cli.types.TetMesh` caches their results.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.rows import unique_rows
from fracture_cli.system import detmath

if TYPE_CHECKING:  # only for annotations: the functions that build matrices import scipy when they run
    import scipy.sparse as sp

# Faces of a positively oriented tet (a, b, c, d), each oriented outward (its
# normal points away from the opposite vertex).
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)


def tet_volumes(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Signed volumes of tetrahedra.

    Parameters
    ----------
    V : (n, 3) float
        Vertex positions.
    T : (t, 4) int
        Tetrahedra.

    Returns
    -------
    vol : (t,) float64
        ``det(b - a, c - a, d - a) / 6``; positive for positively oriented tets.
    """
    a, b, c, d = (V[T[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def triangle_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Areas (m,) of triangles ``F`` (m, 3) over vertices ``V`` (n, 3)."""
    if len(F) == 0:
        return np.zeros(0)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def tet_faces(T: np.ndarray):
    """Interior and boundary faces of a tet mesh.

    Parameters
    ----------
    T : (t, 4) int
        Positively oriented tetrahedra.

    Returns
    -------
    interior : (f, 3) int64
        Vertex ids of faces shared by two tets, oriented outward from the first.
    interior_tets : (f, 2) int64
        The two tets of each interior face, smaller id first.
    boundary : (b, 3) int64
        Vertex ids of faces with one tet, oriented outward.
    boundary_tets : (b,) int64
        The tet of each boundary face.

    Raises
    ------
    ValueError
        If a face is shared by more than two tets (not a valid tet mesh).
    """
    T = np.asarray(T, dtype=np.int64)
    t = len(T)
    all_faces = T[:, TET_FACES].reshape(-1, 3)  # (4t, 3), outward per tet
    owner = np.repeat(np.arange(t, dtype=np.int64), 4)
    key = np.sort(all_faces, axis=1)
    _, inverse, counts = unique_rows(key, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    if np.any(counts > 2):
        raise ValueError(f"{int(np.sum(counts > 2))} faces are shared by more than two tets")
    # Stable sort so that, within a face group, the lower tet id comes first.
    order = np.lexsort((owner, inverse))
    grouped = inverse[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = grouped[1:] != grouped[:-1]
    starts = np.flatnonzero(first)
    group_counts = counts[grouped[starts]]
    interior_starts = starts[group_counts == 2]
    boundary_starts = starts[group_counts == 1]
    interior = all_faces[order[interior_starts]]
    interior_tets = np.stack([owner[order[interior_starts]], owner[order[interior_starts + 1]]], axis=1)
    boundary = all_faces[order[boundary_starts]]
    boundary_tets = owner[order[boundary_starts]]
    return interior, interior_tets, boundary, boundary_tets


def interior_face_normals(V: np.ndarray, T: np.ndarray, faces: np.ndarray, face_tets: np.ndarray) -> np.ndarray:
    """Unit normals (f, 3) of interior ``faces`` (f, 3), pointing from ``face_tets[:, 0]`` to ``face_tets[:, 1]``.

    ``faces`` are those returned by :func:`tet_faces` (already outward from the
    first tet), so only a normalization is needed.
    """
    if len(faces) == 0:
        return np.zeros((0, 3))
    a, b, c = V[faces[:, 0]], V[faces[:, 1]], V[faces[:, 2]]
    n = np.cross(b - a, c - a)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)


def barycentric_gradients(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Gradients (t, 4, 3) of the four barycentric (hat) functions in each tet.

    A tet flat to rounding (``|det| <= 1e-14 * longest_edge^3``, e.g. a child
    of a near-flat tet after refinement) has no usable gradients: they are
    returned as zeros, so it adds nothing to a stiffness matrix (its volume is
    zero too).
    """
    x0 = V[T[:, 0]]
    E = np.stack([V[T[:, 1]] - x0, V[T[:, 2]] - x0, V[T[:, 3]] - x0], axis=1)  # (t, 3, 3) rows = edges
    scale = detmath.cube(np.abs(E).max(axis=(1, 2)))
    flat = np.abs(np.linalg.det(E)) <= 1e-14 * scale
    if flat.any():
        E = E.copy()
        E[flat] = np.eye(3)
    Einv = np.linalg.inv(E)  # columns = gradients of lambda_1..3
    Einv[flat] = 0.0
    G123 = np.transpose(Einv, (0, 2, 1))  # (t, 3, 3) rows = gradients
    G0 = -G123.sum(axis=1, keepdims=True)
    return np.concatenate([G0, G123], axis=1)


def stiffness_matrix(V: np.ndarray, T: np.ndarray) -> sp.csr_matrix:
    """Cotangent (P1 FEM) stiffness matrix ``K`` (n, n), positive semi-definite.

    ``K = sum_t vol_t G_t G_t^T`` with ``G_t`` the hat-function gradients; this
    equals the cotangent formula (libigl's ``cotmatrix`` is ``-K``).
    """
    # on first use: scipy.sparse (0.3-1 s to import) stays out of modules that only need this file's array geometry
    import scipy.sparse as sp

    n = len(V)
    vol = np.abs(tet_volumes(V, T))
    G = barycentric_gradients(V, T)
    local = np.einsum("tid,tjd->tij", G, G) * vol[:, None, None]  # (t, 4, 4)
    rows = np.repeat(T, 4, axis=1).reshape(-1)
    cols = np.tile(T, (1, 4)).reshape(-1)
    K = sp.coo_matrix((local.reshape(-1), (rows, cols)), shape=(n, n)).tocsr()
    K.sum_duplicates()
    # Exact symmetry, so SPD factorizations of M + tau K see a symmetric matrix.
    return ((K + K.T) * 0.5).tocsr()


def lumped_mass(V: np.ndarray, T: np.ndarray) -> sp.dia_matrix:
    """Lumped vertex mass matrix (n, n): each vertex gets a quarter of its tets' volume."""
    # on first use: scipy.sparse (0.3-1 s to import) stays out of modules that only need this file's array geometry
    import scipy.sparse as sp

    n = len(V)
    vol = np.abs(tet_volumes(V, T))
    m = np.bincount(T.reshape(-1), weights=np.repeat(vol / 4.0, 4), minlength=n)
    return sp.diags(m)


def tet_from_vertex(T: np.ndarray, n: int) -> sp.csr_matrix:
    """Averaging operator ``C`` (t, n): each tet takes the mean of its four vertices."""
    # on first use: scipy.sparse (0.3-1 s to import) stays out of modules that only need this file's array geometry
    import scipy.sparse as sp

    t = len(T)
    rows = np.repeat(np.arange(t), 4)
    return sp.csr_matrix((np.full(4 * t, 0.25), (rows, T.reshape(-1))), shape=(t, n))


def orient_positive(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Return ``T`` (t, 4) with negatively oriented tets flipped (swap of two vertices)."""
    T = np.array(T, dtype=np.int64, copy=True)
    neg = tet_volumes(V, T) < 0
    T[neg, 2], T[neg, 3] = T[neg, 3].copy(), T[neg, 2].copy()
    return T


# The six edges of a tet as pairs of its corner slots.
TET_EDGES = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])


def tet_edge_lengths(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Lengths (t, 6) of every tet's edges, in :data:`TET_EDGES` order."""
    return np.linalg.norm(V[T[:, TET_EDGES[:, 0]]] - V[T[:, TET_EDGES[:, 1]]], axis=2)


def refine_red(V: np.ndarray, T: np.ndarray):
    """One level of regular (1:8) refinement: every tet split at its edge midpoints.

    Parameters
    ----------
    V : (n, 3) float64
        Vertex positions.
    T : (t, 4) int64
        Positively oriented tets.

    Returns
    -------
    V2 : (n + e, 3) float64
        The old vertices followed by one midpoint per unique edge (sorted by edge).
    T2 : (8 t, 4) int64
        Positively oriented child tets; children of tet ``i`` are rows ``8 i .. 8 i + 7``.
    parent : (8 t,) int64
        The tet each child came from.

    Notes
    -----
    Four children are the corner tets; the inner octahedron is split along its
    shortest diagonal, which keeps the children's shapes from degrading level
    after level (Bey's rule picks a fixed diagonal; the shortest one is the usual
    quality choice). The refinement is conforming whatever diagonal each tet
    picks: faces shared by two tets are split the same way from both sides.
    """
    V = np.asarray(V, dtype=np.float64)
    T = np.asarray(T, dtype=np.int64)
    n, t = len(V), len(T)
    E = np.sort(T[:, TET_EDGES].reshape(-1, 2), axis=1)
    edges, inverse = unique_rows(E, return_inverse=True)
    mid = n + inverse.reshape(t, 6)
    V2 = np.vstack([V, 0.5 * (V[edges[:, 0]] + V[edges[:, 1]])])
    a, b, c, d = T.T
    ab, ac, ad, bc, bd, cd = mid.T
    corners = [np.stack(x, axis=1) for x in ((a, ab, ac, ad), (ab, b, bc, bd), (ac, bc, c, cd), (ad, bd, cd, d))]
    # The octahedron's three diagonals join opposite midpoints: (ab, cd), (ac, bd), (ad, bc).
    diagonals = np.stack([np.stack([ab, cd], 1), np.stack([ac, bd], 1), np.stack([ad, bc], 1)], axis=1)
    lengths = np.linalg.norm(V2[diagonals[:, :, 0]] - V2[diagonals[:, :, 1]], axis=2)
    k = np.argmin(lengths, axis=1)
    rows = np.arange(t)
    m1, m2 = diagonals[rows, k, 0], diagonals[rows, k, 1]
    # The equator around diagonal k is the other two opposite pairs (p1, q1), (p2, q2): cycle p1 p2 q1 q2.
    other = np.array([[1, 2], [0, 2], [0, 1]])[k]
    p1, q1 = diagonals[rows, other[:, 0], 0], diagonals[rows, other[:, 0], 1]
    p2, q2 = diagonals[rows, other[:, 1], 0], diagonals[rows, other[:, 1], 1]
    inner = [np.stack(x, axis=1) for x in ((m1, m2, p1, p2), (m1, m2, p2, q1), (m1, m2, q1, q2), (m1, m2, q2, p1))]
    T2 = np.stack(corners + inner, axis=1).reshape(-1, 4)
    return V2, orient_positive(V2, T2), np.repeat(np.arange(t), 8)
