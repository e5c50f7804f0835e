"""Duplicated faces and consistent winding of welded triangle meshes."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fracture_cli.geometry.edges import EdgeTable, components, edge_table
from fracture_cli.geometry.rows import unique_rows
from fracture_cli.stages.repair.records import RepairRecord


@dataclass(frozen=True)
class UniqueFaces:
    """Result of :func:`unique_faces`: the faces to keep (m,) bool, and what was removed."""

    keep: np.ndarray
    duplicates: int
    enclosing_nothing: int
    records: list[RepairRecord] = field(default_factory=list)


def unique_faces(W: np.ndarray) -> UniqueFaces:
    """Decide which copies of repeated faces (same three welded corners) to keep.

    Parameters
    ----------
    W : (m, 3) int
        Faces over welded vertices, degenerate faces removed.

    Returns
    -------
    UniqueFaces

    Notes
    -----
    Repeated faces are judged together with the repeated faces next to them
    (a patch: groups of copies joined across shared edges). A patch whose
    every edge leading out of it meets exactly one other face, a surface face
    listed once, is a piece of surface listed several times (a triangle soup
    repeats faces with either winding; a closed object listed twice has no
    such edge at all): one copy of each face is kept and winding propagation
    orients it. A patch whose rim edges each lead to exactly two faces is a
    wall between two solids touching face to face (or overlapping there, when
    both copies have one winding): both copies stay, one per solid (the
    non-manifold split separates the solids and the union joins them).
    Otherwise (a free double-sided card), copies of opposite winding in equal
    numbers enclose nothing and all go; an unbalanced group keeps one copy of
    its majority winding.
    """
    W = np.asarray(W, dtype=np.int64).reshape(-1, 3)
    m = len(W)
    if m == 0:
        return UniqueFaces(np.ones(0, dtype=bool), 0, 0)
    key = np.sort(W, axis=1)
    uniq, group, counts = unique_rows(key, return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    if counts.max() == 1:
        return UniqueFaces(np.ones(m, dtype=bool), 0, 0)
    # Winding parity of each face relative to its sorted corners: +1 when it is a rotation of (lo, mid, hi).
    first = np.argmin(W, axis=1)
    rotated = np.stack([W[np.arange(m), (first + k) % 3] for k in range(3)], axis=1)
    parity = np.where(rotated[:, 1] < rotated[:, 2], 1, -1)
    net = np.bincount(group, weights=parity, minlength=len(uniq))
    surface_face, wall = _repeated_patches(uniq, counts > 1)
    # A wall between two solids keeps both copies: each belongs to one solid (touching, or overlapping where both
    # have the same winding), and the union joins them.
    wall &= counts == 2
    keep_group = surface_face | (net != 0)
    # One copy per kept group: the first face with the group's majority winding (any face for a surface face).
    wanted = np.where(net[group] == 0, True, np.sign(net[group]) == parity) | surface_face[group]
    chosen = np.full(len(uniq), m, dtype=np.int64)
    np.minimum.at(chosen, group[wanted], np.flatnonzero(wanted))
    keep = np.zeros(m, dtype=bool)
    keep[chosen[keep_group & (chosen < m)]] = True
    keep |= wall[group]
    keep_group |= wall
    repeated = counts > 1
    dropped = int((repeated & ~keep_group).sum())
    duplicates = int((counts[keep_group & ~wall] - 1).sum())
    records = []
    if duplicates:
        records.append(RepairRecord("removed_duplicate_faces", f"removed {duplicates} repeated copies of faces",
                                    count=duplicates))
    if dropped:
        records.append(RepairRecord("removed_double_sided_faces", f"removed {dropped} faces listed with both windings "
                                    "that enclose nothing (walls between touching solids, double-sided cards)",
                                    count=int(counts[repeated & ~keep_group].sum())))
    return UniqueFaces(keep, duplicates, dropped, records)


def _repeated_patches(groups: np.ndarray, repeated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per group of copies (g, 3): whether its patch of repeated groups is a piece of surface listed again, and
    whether it is a wall between two solids.

    A surface listed again: every edge of the patch is either inside it (two
    repeated groups, no other face) or leads out of it to exactly one face
    listed once. A wall: its edges inside it, or leading out of it to exactly
    two faces listed once (one per solid).
    """
    table = edge_table(groups)
    side_repeated = repeated[table.face]
    num_repeated = np.bincount(table.edge, weights=side_repeated, minlength=len(table.count)).astype(np.int64)
    num_single = table.count - num_repeated
    inside = (num_repeated == 2) & (num_single == 0)
    edge_ok = ((num_repeated == 1) & (num_single == 1)) | inside
    edge_wall = ((num_repeated == 1) & (num_single == 2)) | inside
    # Patches: repeated groups joined across edges that only repeated groups share.
    order, start = table.sides_of_edges()
    inner = np.flatnonzero((num_repeated == 2) & (num_single == 0))
    pairs = np.column_stack([table.face[order[start[inner]]], table.face[order[start[inner] + 1]]])
    patch = components(len(groups), pairs)
    bad_patch = np.zeros(int(patch.max()) + 1, dtype=bool)
    bad_patch[patch[table.face[side_repeated & ~edge_ok[table.edge]]]] = True
    not_wall = np.zeros(len(bad_patch), dtype=bool)
    not_wall[patch[table.face[side_repeated & ~edge_wall[table.edge]]]] = True
    return repeated & ~bad_patch[patch], repeated & ~not_wall[patch]


def orient_consistently(W: np.ndarray, table: EdgeTable | None = None) -> tuple[np.ndarray, list[RepairRecord]]:
    """Flip mask (m,) making the winding agree across every edge with exactly two faces.

    A breadth-first search over each patch (faces joined across two-face
    edges) gives every face its flip relative to the patch's first face; the
    patch then keeps the winding most of its faces already had. ``table`` is
    ``edge_table(W)`` if the caller has it.
    """
    # on first use: scipy.sparse (0.3-1 s to import) is not loaded to resolve a recipe, which imports this module
    import scipy.sparse as sp
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    W = np.asarray(W, dtype=np.int64).reshape(-1, 3)
    m = len(W)
    if table is None:
        table = edge_table(W)
    pairs = table.manifold_pairs()
    fa, fb = table.face[pairs[:, 0]], table.face[pairs[:, 1]]
    # Two faces agree when they run their shared edge in opposite directions.
    same = table.forward[pairs[:, 0]] == table.forward[pairs[:, 1]]
    graph = sp.coo_matrix((np.ones(2 * len(fa)), (np.concatenate([fa, fb]), np.concatenate([fb, fa]))),
                          shape=(m + 1, m + 1)).tocsr()
    num, patch = connected_components(graph[:m, :m], directed=False)
    # A virtual root (node m) joined to the first face of every patch makes one search cover all patches.
    firsts = np.unique(patch, return_index=True)[1]
    root = sp.coo_matrix((np.ones(len(firsts)), (np.full(len(firsts), m), firsts)), shape=(m + 1, m + 1))
    order, parent = breadth_first_order((graph + root).tocsr(), m, directed=True, return_predecessors=True)
    code = np.minimum(fa, fb) * m + np.maximum(fa, fb)
    sorter = np.argsort(code, kind="stable")
    step = order[1:]
    up = parent[step]
    at = np.searchsorted(code[sorter], np.minimum(step, up) * m + np.maximum(step, up))
    step_same = np.zeros(len(step), dtype=bool)
    inner = up != m
    step_same[inner] = same[sorter[np.minimum(at[inner], len(code) - 1)]]
    flip_list = [False] * (m + 1)
    for f, p, s in zip(step.tolist(), up.tolist(), step_same.tolist()):  # parents come first in BFS order
        flip_list[f] = flip_list[p] ^ s
    flip = np.array(flip_list[:m], dtype=bool)
    flipped = np.bincount(patch, weights=flip, minlength=num)
    sizes = np.bincount(patch, minlength=num)
    flip ^= (2 * flipped > sizes)[patch]
    records = []
    if flip.any():
        records.append(RepairRecord("flipped_winding", f"re-wound {int(flip.sum())} faces to agree with their "
                                    "neighbours", count=int(flip.sum())))
    return flip, records
