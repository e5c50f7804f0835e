"""Which tet faces carry each bond, and how strong each bond is.

A *bond* is an edge ``(P, Q)`` of the runtime file's fragment graph. Its *fault*
on the tet mesh is the set of interior tet faces whose two tets belong to
fragments ``P`` and ``Q``. A tet belongs to the fragment of its atomic piece
(``pieces.tet_piece``); when a piece was cut into several fragments (separate
bodies), each of its tets goes to the fragment with the nearest mesh vertex to
its centroid (ties: the smallest fragment index). Tets of pieces without a
fragment belong to none.

Strength ``S_e = A_e * sigma_t * eta_e``: ``A_e`` the bond's fault area as measured
on the fragment meshes (normalized units, unit bounding-box diagonal),
``sigma_t`` the recipe's tensile strength, and ``eta_e`` the area-weighted mean
material weight (grain, painted strength, boxes: :mod:`fracture_cli.stages.material`)
over the bond's tet faces, 1 when it has none.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.types import Fragments, Pieces, TetMesh


@dataclass(frozen=True, eq=False)
class BondFaces:
    """The tet faces of every bond.

    Attributes
    ----------
    faces : (m,) int64
        Interior face indices (into ``tet_mesh.interior_faces``) on some bond's fault, ascending.
    bond : (m,) int64
        The bond of each of them.
    weight : (m,) float64
        ``area_f / sum of the areas of its bond's faces``: averaging weights (sum 1 per bond).
    face_area : (e,) float64
        Total tet-face area of each bond (0 for a bond with no tet face).
    sign : (m,) float64
        +1 where ``interior_face_normals`` points from the bond's fragment ``P`` to ``Q``, else -1.
    """

    faces: np.ndarray
    bond: np.ndarray
    weight: np.ndarray
    face_area: np.ndarray
    sign: np.ndarray


def tet_fragments(tet_mesh: TetMesh, pieces: Pieces, fragment_pieces: Sequence[int] | np.ndarray,
                  fragment_vertices: list[np.ndarray] | None = None) -> np.ndarray:
    """The fragment (t,) int64 of every tet (-1: its piece has no fragment); see the module docstring.

    Parameters
    ----------
    tet_mesh : TetMesh
    pieces : Pieces
    fragment_pieces : (p,) int
        Piece of every fragment.
    fragment_vertices : list of (n_j, 3) float, optional
        Mesh vertices of every fragment (normalized coordinates); needed only when a piece has several fragments.
    """
    fragment_pieces = np.asarray(fragment_pieces, dtype=np.int64).reshape(-1)
    tet_piece = np.asarray(pieces.tet_piece, dtype=np.int64)
    first = np.full(max(int(pieces.num_pieces), int(tet_piece.max()) + 1), -1, dtype=np.int64)
    counts = np.bincount(fragment_pieces, minlength=len(first))
    for j in range(len(fragment_pieces) - 1, -1, -1):  # descending: the smallest index wins
        first[fragment_pieces[j]] = j
    out = first[tet_piece]
    shared = np.flatnonzero(counts > 1)
    if len(shared) and fragment_vertices is not None:
        from scipy.spatial import cKDTree

        centroids = tet_mesh.tet_centroids
        for piece in shared.tolist():
            owners = np.flatnonzero(fragment_pieces == piece)
            points = np.concatenate([np.asarray(fragment_vertices[j], dtype=np.float64) for j in owners])
            owner_of_point = np.concatenate([np.full(len(fragment_vertices[j]), j) for j in owners])
            tets = np.flatnonzero(tet_piece == piece)
            _, nearest = cKDTree(points).query(centroids[tets])
            out[tets] = owner_of_point[nearest]
    return out


def bond_faces(tet_mesh: TetMesh, tet_fragment: np.ndarray, edges: np.ndarray) -> BondFaces:
    """The interior tet faces on every bond's fault (module docstring).

    Parameters
    ----------
    tet_mesh : TetMesh
    tet_fragment : (t,) int
        :func:`tet_fragments`.
    edges : (e, 2) int
        Bonds ``(P, Q)``, ``P < Q``.
    """
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    e = len(edges)
    pair = tet_fragment[tet_mesh.interior_face_tets]  # (f, 2)
    lo, hi = np.minimum(pair[:, 0], pair[:, 1]), np.maximum(pair[:, 0], pair[:, 1])
    candidate = np.flatnonzero((lo >= 0) & (lo != hi))
    p = int(max(edges.max() + 1 if e else 0, tet_fragment.max() + 1, 1))
    keys = edges[:, 0] * p + edges[:, 1]
    order = np.argsort(keys, kind="stable")
    face_keys = lo[candidate] * p + hi[candidate]
    where = np.searchsorted(keys[order], face_keys)
    where = np.minimum(where, max(e - 1, 0))
    found = (keys[order][where] == face_keys) if e else np.zeros(len(candidate), dtype=bool)
    faces = candidate[found]
    bond = order[where[found]]
    area = tet_mesh.interior_face_areas[faces]
    face_area = np.bincount(bond, weights=area, minlength=e)
    weight = area / np.where(face_area[bond] > 0.0, face_area[bond], 1.0)
    first = tet_fragment[tet_mesh.interior_face_tets[faces, 0]]
    sign = np.where(first == edges[bond, 0], 1.0, -1.0)
    return BondFaces(faces=faces, bond=bond, weight=weight, face_area=face_area, sign=sign)


def bond_strengths(faces: BondFaces, eta: np.ndarray | None, edge_areas: np.ndarray,
                   tensile_strength: float) -> np.ndarray:
    """``S_e = A_e * sigma_t * eta_e`` (e,) float64 (module docstring).

    Parameters
    ----------
    faces : BondFaces
    eta : (f,) or (f, d) float or None
        Material weights of the interior faces (None: all 1); for ``(f, d)`` the mean over components.
    edge_areas : (e,) float
        Fault area of every bond on the fragment meshes, normalized units squared.
    tensile_strength : float
        ``sigma_t``, per unit (normalized) area.
    """
    e = len(edge_areas)
    if eta is None:
        per_bond = np.ones(e)
    else:
        eta = np.asarray(eta, dtype=np.float64)
        if eta.ndim == 2:
            eta = eta.sum(axis=1) / eta.shape[1]
        mean = np.bincount(faces.bond, weights=faces.weight * eta[faces.faces], minlength=e)
        per_bond = np.where(faces.face_area > 0.0, mean, 1.0)
    return np.asarray(edge_areas, dtype=np.float64) * float(tensile_strength) * per_bond


@dataclass(frozen=True, eq=False)
class ContactPoints:
    """Where a bond without tet faces is measured instead: tets at its fault on the fragment meshes.

    Attributes
    ----------
    bond : (m,) int64
        Bond of every sample.
    tet : (m,) int64
        Tet containing (nearest to) the sample.
    weight : (m,) float64
        Averaging weight (sum 1 per bond).
    normal : (m, 3) float64
        Unit fault normal at the sample.
    """

    bond: np.ndarray
    tet: np.ndarray
    weight: np.ndarray
    normal: np.ndarray


def contact_points(tet_mesh: TetMesh, fragments: Fragments, edges: np.ndarray, bonds: np.ndarray) -> ContactPoints:
    """Samples for the ``bonds`` (indices into ``edges``) that have no tet face.

    The fragments' fault (interior-material) faces of ``P`` whose three corners are corners of ``Q``'s fault
    faces too (within 1e-9 of the diagonal) are the shared fault; each gives one sample at its centroid, in
    the tet whose centroid is nearest, with its own normal and its area as weight. A bond with no such face
    gets no sample (its traction is then 0: it never breaks under the stress criterion).
    """
    from scipy.spatial import cKDTree

    tets_tree = cKDTree(tet_mesh.tet_centroids)
    interior = fragments.interior_slot
    out_b, out_t, out_w, out_n = [], [], [], []
    for index in np.asarray(bonds, dtype=np.int64).tolist():
        P, Q = (int(x) for x in edges[index])
        fp, fq = fragments.fragments[P], fragments.fragments[Q]
        faces_p = fp.faces[fp.material_ids == interior]
        faces_q = fq.faces[fq.material_ids == interior]
        if not len(faces_p) or not len(faces_q):
            continue
        corners_q = cKDTree(fq.vertices[np.unique(faces_q)])
        dist, _ = corners_q.query(fp.vertices)
        shared = np.all(dist[faces_p] <= tol.SAME_POINT, axis=1)
        tri = fp.vertices[faces_p[shared]]
        if not len(tri):
            continue
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.sqrt((cross[:, 0] * cross[:, 0] + cross[:, 1] * cross[:, 1]) + cross[:, 2] * cross[:, 2])
        good = length > 0.0
        if not good.any():
            continue
        _, tet = tets_tree.query((tri[good, 0] + tri[good, 1] + tri[good, 2]) / 3.0)
        out_b.append(np.full(int(good.sum()), index))
        out_t.append(np.asarray(tet, dtype=np.int64))
        out_w.append(length[good] / length[good].sum())
        out_n.append(cross[good] / length[good][:, None])
    if not out_b:
        return ContactPoints(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)))
    return ContactPoints(np.concatenate(out_b), np.concatenate(out_t), np.concatenate(out_w),
                         np.concatenate(out_n))


def split_into_patches(tet_mesh: TetMesh, faces: BondFaces, parts: int = 2) -> tuple[BondFaces, np.ndarray]:
    """Each bond's fault cut into up to ``parts * parts`` patches: quadrants about its area centroid.

    The mean normal traction over a whole fault is the net force across it: a bond bent by a hit beside
    it (tension on one side, compression on the other) would average to nothing. The Rankine criterion
    asks for the most stressed part instead; patches keep that linear in the load: every patch has its own
    mean traction, and the criterion uses the bond's most loaded patch (:mod:`fracture_cli.stages.stress.stage`).

    The quadrants are the signs of ``(c_f - c) . t1`` and ``(c_f - c) . t2`` for face centroids ``c_f``,
    the bond's area centroid ``c`` and two tangents of its mean normal ``n``: ``t1 = n x a / |n x a|`` with
    ``a`` the coordinate axis least aligned with ``n`` (ties: the first), ``t2 = n x t1``. ``parts = 1``:
    one patch per bond.

    Returns
    -------
    patch_faces : BondFaces
        Its ``bond`` is the patch index and ``face_area`` is per patch.
    patch_bond : (P,) int64
        The bond of every patch (ascending).
    """
    e = len(faces.face_area)
    if parts <= 1 or not len(faces.faces):
        return faces, np.arange(e, dtype=np.int64)
    V = tet_mesh.vertices
    tri = tet_mesh.interior_faces[faces.faces]
    centroid = (V[tri[:, 0]] + V[tri[:, 1]] + V[tri[:, 2]]) / 3.0
    normals = tet_mesh.interior_face_normals[faces.faces]
    # Orient normals alike within a bond (towards the mean of the first face), then average.
    first = np.full(e, -1, dtype=np.int64)
    first[faces.bond[::-1]] = np.arange(len(faces.bond))[::-1]
    ref = normals[first[faces.bond]]
    sign = np.where(((normals[:, 0] * ref[:, 0] + normals[:, 1] * ref[:, 1]) + normals[:, 2] * ref[:, 2]) < 0.0,
                    -1.0, 1.0)
    w = faces.weight
    mean_n = np.stack([np.bincount(faces.bond, weights=w * sign * normals[:, c], minlength=e) for c in range(3)], 1)
    center = np.stack([np.bincount(faces.bond, weights=w * centroid[:, c], minlength=e) for c in range(3)], 1)
    axis = np.zeros((e, 3))
    axis[np.arange(e), np.abs(mean_n).argmin(axis=1)] = 1.0
    t1 = np.cross(mean_n, axis)
    length = np.sqrt((t1[:, 0] * t1[:, 0] + t1[:, 1] * t1[:, 1]) + t1[:, 2] * t1[:, 2])
    t1 = t1 / np.where(length > 0.0, length, 1.0)[:, None]
    t2 = np.cross(mean_n, t1)
    rel = centroid - center[faces.bond]
    q1 = ((rel * t1[faces.bond]).sum(axis=1) >= 0.0).astype(np.int64)
    q2 = ((rel * t2[faces.bond]).sum(axis=1) >= 0.0).astype(np.int64)
    key = faces.bond * 4 + q1 * 2 + q2
    unique, patch = np.unique(key, return_inverse=True)
    area = tet_mesh.interior_face_areas[faces.faces]
    patch_area = np.bincount(patch, weights=area, minlength=len(unique))
    weight = area / patch_area[patch]
    patch_bond = unique // 4
    # Bonds without faces keep one (empty) patch so every bond has at least one.
    empty = np.setdiff1d(np.arange(e), patch_bond)
    if len(empty):
        patch_bond = np.concatenate([patch_bond, empty])
        patch_area = np.concatenate([patch_area, np.zeros(len(empty))])
    return BondFaces(faces=faces.faces, bond=patch, weight=weight, face_area=patch_area, sign=faces.sign), patch_bond
