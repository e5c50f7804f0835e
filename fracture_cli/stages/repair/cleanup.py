"""Repair: splitting edges shared by more than two faces, boundary loops, and small measures."""

from __future__ import annotations

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.meshtopo import manifold_patches
from fracture_cli.stages._solids import SplitMesh, split_bodies

STAGE = "repair"


# Smallest / largest singular value of the centred positions below which they are coplanar.
_FLAT = 1e-9


def split_nonmanifold(mesh: SplitMesh) -> tuple[SplitMesh, int, str]:
    """Split edge fans of more than two faces into closed bodies that are united later.

    Faces are grouped into patches joined across two-face edges. A patch in
    which every edge has two of its faces is a closed body (two boxes touching
    along an edge). Open patches whose boundary runs only along edges of more
    than two faces, and which share that boundary exactly, close each other
    in consecutive pairs (cells sharing an internal wall: left + wall, wall +
    right). Returns the split mesh, the
    number of many-face edges left touching unclosed patches, and a log note.
    """
    patch, edge_id, face, counts = manifold_patches(mesh.welded)
    num_patches = int(patch.max()) + 1
    many = counts > 2
    # Faces of each (patch, edge): 2 everywhere means the patch is closed.
    key = patch[face] * len(counts) + edge_id
    uniq, per = np.unique(key, return_counts=True)
    key_patch, key_edge = uniq // len(counts), uniq % len(counts)
    boundary_of: list[list[int]] = [[] for _ in range(num_patches)]
    for p, e in zip(key_patch[per == 1].tolist(), key_edge[per == 1].tolist()):
        boundary_of[p].append(e)
    odd = np.zeros(num_patches, dtype=bool)
    odd[key_patch[(per != 2)]] = True
    bodies: list[np.ndarray] = []
    groups: dict[tuple[int, ...], list[int]] = {}
    leftover_patches: list[int] = []
    for p in range(num_patches):
        faces_p = np.flatnonzero(patch == p)
        if not odd[p]:
            bodies.append(faces_p)
        elif boundary_of[p] and all(many[e] for e in boundary_of[p]) and np.all(np.isin(
                key_edge[(key_patch == p) & (per != 2)], boundary_of[p])):
            groups.setdefault(tuple(sorted(boundary_of[p])), []).append(p)
        else:
            leftover_patches.append(p)
    paired = 0
    for members in groups.values():
        if len(members) < 2:
            leftover_patches += members
            continue
        for a, b in zip(members[:-1], members[1:]):
            bodies.append(np.concatenate([np.flatnonzero(patch == a), np.flatnonzero(patch == b)]))
            paired += 1
    touched: set[int] = set()
    for p in leftover_patches:
        bodies.append(np.flatnonzero(patch == p))
        touched.update(e for e in key_edge[key_patch == p].tolist() if many[e])
    mesh = split_bodies(mesh, bodies)
    note = (f"split {int(many.sum())} edges shared by more than two faces into {len(bodies)} bodies"
            + (f" ({paired} closed by pairing open patches along internal walls)" if paired else ""))
    return mesh, len(touched), note


def boundary_loops(boundary: np.ndarray) -> list[np.ndarray]:
    """Chain directed boundary edges (b, 2) into closed loops of vertex ids, in edge direction."""
    nxt: dict[int, list[int]] = {}
    for a, b in boundary.tolist():
        nxt.setdefault(a, []).append(b)
    loops = []
    visited = set()
    for a0, b0 in boundary.tolist():
        if (a0, b0) in visited:
            continue
        loop = [a0]
        a, b = a0, b0
        while True:
            visited.add((a, b))
            if b == a0:
                break
            loop.append(b)
            following = [c for c in nxt.get(b, []) if (b, c) not in visited]
            if not following:
                raise StageError("the mesh's holes are not simple loops (a boundary vertex is pinched or the "
                                 "winding is not orientable); close the mesh in your modelling tool", stage=STAGE)
            a, b = b, following[0]
        loops.append(np.array(loop, dtype=np.int64))
    return loops


def fan_area(P: np.ndarray) -> float:
    """Area of the fan closing a loop (k, 3) around its centroid."""
    c = P.mean(axis=0)
    return float(0.5 * np.linalg.norm(np.cross(P - c, np.roll(P, -1, axis=0) - c), axis=1).sum())


def is_flat(P: np.ndarray) -> bool:
    """Whether points (k, 3) lie in one plane (or are fewer than 4)."""
    if len(P) < 4:
        return True
    s = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    return bool(s[0] == 0 or s[2] <= _FLAT * s[0])

