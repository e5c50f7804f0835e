"""Crack lines: where each bond's fault meets the outer surface (docs/FORMAT.md section 12.2).

A bond ``(P, Q)`` holds through its fault: the faces of ``P`` (interior material)
that lie on ``Q``. Where that patch ends on the input's surface, a crack shows
first when the bond is loaded but holds; those are the edges of ``P`` shared by a
fault face on ``Q`` and an outer face (any other material). Edges between the
patch and a fault towards a third fragment lie inside the asset and are not drawn.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.rows import unique_rows
from fracture_cli.stages.fragments.interfaces import coincident_faces
from fracture_cli.types import Fragments


def crack_segments(fragments: Fragments, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The crack segments of every bond, as the runtime file stores them.

    Parameters
    ----------
    fragments : Fragments
        The baked fragments (normalized coordinates).
    edges : (e, 2) int
        Bonds ``(P, Q)``, ``P < Q``, in the runtime file's order.

    Returns
    -------
    crack_ptr : (e + 1,) int32
        Bond ``b``'s segments are ``crack_ptr[b] .. crack_ptr[b + 1] - 1``.
    crack_segments : (n, 2, 3) float32
        Segments in the input's model space and units, taken from ``P``'s side of the fault, each directed as
        the fault face's edge (so a closed crack loop runs one way round), in ``P``'s face order.
    """
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    interior = fragments.interior_slot
    meshes = [(f.vertices, f.faces) for f in fragments.fragments]
    faults = [np.asarray(f.material_ids) == interior for f in fragments.fragments]
    match = coincident_faces(meshes, faults)
    # Fault faces of each fragment, grouped by the fragment they lie on.
    on: dict[tuple[int, int], np.ndarray] = {}
    for owner, other in {(int(a), int(b)) for a, b in zip(match.owner.tolist(), match.other.tolist())}:
        on[(owner, other)] = np.sort(match.face[(match.owner == owner) & (match.other == other)])
    per_bond: list[np.ndarray] = []
    boundary = {}  # fragment -> its (directed edge -> outer?) tables, built once
    for P, Q in edges.tolist():
        faces = on.get((P, Q), np.zeros(0, dtype=np.int64))
        if P not in boundary:
            boundary[P] = _surface_edges(fragments, P)
        per_bond.append(_patch_rim(fragments, P, faces, *boundary[P]))
    counts = np.array([len(s) for s in per_bond], dtype=np.int64)
    ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    segments = np.concatenate(per_bond) if per_bond else np.zeros((0, 2, 3))
    world = fragments.normalization.to_world(segments.reshape(-1, 3)).reshape(-1, 2, 3)
    return ptr, world.astype(np.float32)


def _surface_edges(fragments: Fragments, index: int) -> tuple[np.ndarray, np.ndarray]:
    """Fragment ``index``'s welded corners (m, 3) int64 and, per face edge, whether an outer face shares it (m, 3).

    Corners are welded by position (the mesh is split at UV seams). Edge ``k`` of face ``f`` runs from corner
    ``k`` to corner ``k + 1``.
    """
    frag = fragments.fragments[index]
    _, weld = unique_rows(np.asarray(frag.vertices, dtype=np.float64), return_inverse=True)
    corners = weld.reshape(-1)[np.asarray(frag.faces, dtype=np.int64)]  # (m, 3)
    outer_face = np.asarray(frag.material_ids) != fragments.interior_slot
    a, b = corners, np.roll(corners, -1, axis=1)
    key = np.minimum(a, b) * (int(corners.max(initial=0)) + 1) + np.maximum(a, b)  # (m, 3) undirected edge ids
    outer_keys = np.unique(key[outer_face])
    return corners, np.isin(key, outer_keys)


def _patch_rim(fragments: Fragments, index: int, faces: np.ndarray, corners: np.ndarray,
               shared_with_outer: np.ndarray) -> np.ndarray:
    """Segments (n, 2, 3) of the fault faces ``faces`` of fragment ``index`` along edges shared with an outer face."""
    if len(faces) == 0:
        return np.zeros((0, 2, 3))
    V = np.asarray(fragments.fragments[index].vertices, dtype=np.float64)
    F = np.asarray(fragments.fragments[index].faces, dtype=np.int64)
    _, first = np.unique(corners.reshape(-1), return_index=True)
    position = np.zeros((int(corners.max()) + 1, 3))
    position[corners.reshape(-1)[first]] = V[F.reshape(-1)[first]]  # one position per welded corner
    face, slot = np.nonzero(shared_with_outer[faces])
    start = corners[faces[face], slot]
    end = corners[faces[face], (slot + 1) % 3]
    return np.stack([position[start], position[end]], axis=1)
