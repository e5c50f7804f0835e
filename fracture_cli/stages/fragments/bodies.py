"""One connected body per fragment: split fragments into bodies, merge tiny ones, rebuild the fragment graph.

A fragment is the input cut by one piece region, and the cut can fall apart:
the region of a chair's piece may hold the tips of two legs. A game spawns one
rigid body per fragment, so every closed body becomes a fragment of its own
(same piece, so the runtime's piece modes still apply), except bodies too small
to matter, which are glued to the neighbour they share the most fault area with.

Connectivity is through edges shared by exactly two faces of the welded mesh:
two bodies that touch only at a vertex or along an edge (a pinch) are separate
bodies, and each gets its own copy of the shared vertices.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import manifold3d
import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.mass import mass_properties
from fracture_cli.geometry.meshtopo import manifold_patches
from fracture_cli.geometry.rows import unique_rows
from fracture_cli.geometry.solids import SplitMesh, from_manifold, shell_mask, to_manifold
from fracture_cli.geometry.trigeom import face_signed_volumes
from fracture_cli.stages.fragments.interfaces import interface_areas
from fracture_cli.stages.fragments.resolve import needs_split, written_check
from fracture_cli.types import Fragment, Fragments

log = logging.getLogger(__name__)

STAGE = "components"



@dataclass(frozen=True)
class SplitReport:
    """What :func:`split_fragments` did.

    Attributes
    ----------
    bodies : tuple of int
        Number of closed bodies found in each input fragment.
    source : tuple of int
        For each output fragment, the input fragment its largest body came from.
    merged : int
        Tiny bodies glued to a neighbour.
    isolated : int
        Tiny bodies with no neighbour to merge into, or whose union with it
        would pinch (kept as fragments of their own).
    pinched : int, optional (default 0)
        Fragments added by splitting fragments that pinch as written (parts
        touching along an edge or at a point; :mod:`.resolve`).
    """

    bodies: tuple[int, ...]
    source: tuple[int, ...]
    merged: int
    isolated: int
    pinched: int = 0


def body_faces(vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """The faces of each connected closed body of a mesh.

    Parameters
    ----------
    vertices : (n, 3) float
        Positions; vertices at the same position (split for UV seams or flat
        normals) are one point.
    faces : (m, 3) int
        Closed, outward-oriented triangles (possibly several bodies, cavities).

    Returns
    -------
    list of (k_i,) int64
        Face indices of each body, largest volume first (ties: smallest first
        face). Faces are joined across edges with exactly two faces, so bodies
        touching at a vertex or along an edge come out separate. A cavity (a
        shell of negative volume) goes with the smallest body whose bounding
        box contains it. Shells of no volume are dropped.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(F) == 0:
        return []
    _, weld = unique_rows(V, return_inverse=True)
    W = weld.reshape(-1)[F]
    patch = manifold_patches(W)[0]
    _, patch = np.unique(patch, return_inverse=True)
    patch = patch.reshape(-1)
    num = int(patch.max()) + 1
    volume = np.bincount(patch, weights=face_signed_volumes(V - V.mean(axis=0), F), minlength=num)
    lo = np.full((num, 3), np.inf)
    hi = np.full((num, 3), -np.inf)
    for k in range(3):
        np.minimum.at(lo, patch, V[F[:, k]])
        np.maximum.at(hi, patch, V[F[:, k]])
    scale = max(float(np.linalg.norm(V.max(axis=0) - V.min(axis=0))), tol.SMALLEST_DIVISOR)
    empty = np.abs(volume) <= tol.SLIVER_VOLUME * scale * scale * scale
    positive = np.flatnonzero((volume > 0) & ~empty)
    members = {int(p): [int(p)] for p in positive}
    for cavity in np.flatnonzero((volume < 0) & ~empty).tolist():
        holds = positive[np.all((lo[positive] <= lo[cavity]) & (hi[positive] >= hi[cavity]), axis=1)]
        if len(holds):
            members[int(holds[np.argmin(volume[holds])])].append(cavity)
    first_face = np.full(num, len(F))
    np.minimum.at(first_face, patch, np.arange(len(F)))
    order = sorted(members, key=lambda p: (-sum(volume[q] for q in members[p]), first_face[p]))
    return [np.flatnonzero(np.isin(patch, members[p])) for p in order]


def split_fragments(fragments: Fragments, min_volume_fraction: float = 1e-4) -> tuple[Fragments, SplitReport]:
    """Make every fragment one connected body.

    Parameters
    ----------
    fragments : Fragments
        Closed fragments (normalized coordinates), possibly of several bodies.
    min_volume_fraction : float, optional (default 1e-4)
        Bodies below this fraction of ``fragments.input_volume`` are merged
        (a boolean union) into the body they share the largest fault area
        with; if that body is tiny too, the merged body keeps looking.

    Returns
    -------
    fragments : Fragments
        One body per fragment, in the pipeline's stable order (by centroid).
        A body split off a fragment keeps that fragment's ``piece``; a merged
        group keeps the piece of its largest body. Materials, normalization and
        input volume are unchanged.
    report : SplitReport

    Notes
    -----
    Tiny bodies are taken smallest first; a tiny body that touches no other
    body through faults stays a fragment of its own (logged). Several output
    fragments may share one piece: the runtime then repeats that piece's column
    of ``W`` and takes its edges from :func:`fragment_graph`, not from the
    piece graph.
    """
    interior = fragments.interior_slot
    bodies: list[tuple[int, np.ndarray]] = []  # (fragment index, face indices)
    counts = []
    for i, frag in enumerate(fragments.fragments):
        found = body_faces(frag.vertices, frag.faces)
        counts.append(len(found))
        bodies.extend((i, faces) for faces in found)
    meshes = [(fragments.fragments[i].vertices, fragments.fragments[i].faces[faces]) for i, faces in bodies]
    volumes = np.array([mass_properties(V, F).volume for V, F in meshes])
    min_volume = min_volume_fraction * fragments.input_volume
    if len(bodies) == len(fragments.fragments) and not np.any(volumes < min_volume):
        # Nothing to split or merge: the fragments as given (same order, same bytes).
        return fragments, SplitReport(bodies=tuple(counts), source=tuple(range(len(counts))), merged=0, isolated=0)
    fault = [fragments.fragments[i].material_ids[faces] == interior for i, faces in bodies]
    pairs, areas = interface_areas(meshes, fault)
    groups, merged, isolated = _merge_tiny(volumes, pairs, areas, min_volume)
    kept_apart = 0
    results, source = [], []
    for members in groups:
        host = max(members, key=lambda b: (volumes[b], -b))
        frag_index = bodies[host][0]
        group = _group_fragment(fragments, [bodies[b] for b in members], fragments.fragments[frag_index].piece)
        if len(members) > 1 and needs_split(written_check(group, fragments)):
            # The union pinches as written (the tiny body also touches its host along an edge or at a point, or
            # rounding joins them there): the bodies stay fragments of their own rather than one broken one.
            for b in members:
                results.append(_group_fragment(fragments, [bodies[b]], fragments.fragments[bodies[b][0]].piece))
                source.append(bodies[b][0])
            merged -= len(members) - 1
            kept_apart += len(members) - 1
            continue
        results.append(group)
        source.append(frag_index)
    order = stable_order(results)
    if isolated:
        log.warning("%s: %d tiny bod(ies) touch no other fragment through a fault and stay fragments of their own",
                    STAGE, isolated)
    if kept_apart:
        log.warning("%s: %d tiny bod(ies) stay fragments of their own: united with their neighbour they would "
                    "pinch (touch it along an edge or at a point as well)", STAGE, kept_apart)
    log.info("%s: %d fragments -> %d bodies -> %d fragments (%d tiny bodies merged)", STAGE,
             len(fragments.fragments), len(bodies), len(results), merged)
    report = SplitReport(bodies=tuple(counts), source=tuple(source[k] for k in order), merged=merged,
                         isolated=isolated + kept_apart)
    new = dataclasses.replace(fragments, fragments=tuple(results[k] for k in order))
    return new, report


def _merge_tiny(volumes: np.ndarray, pairs: np.ndarray, areas: np.ndarray,
                min_volume: float) -> tuple[list[list[int]], int, int]:
    """Groups of body indices after gluing every tiny body to its largest-interface neighbour.

    Returns the groups (lists, each sorted, ordered by first member), the number
    of bodies merged and the number of tiny bodies left alone.
    """
    n = len(volumes)
    root = list(range(n))
    volume = [float(v) for v in volumes]
    adjacency: list[dict[int, float]] = [{} for _ in range(n)]
    for (i, j), area in zip(pairs.tolist(), areas.tolist()):
        adjacency[i][j] = adjacency[i].get(j, 0.0) + area
        adjacency[j][i] = adjacency[j].get(i, 0.0) + area
    merged = isolated = 0
    for body in sorted(range(n), key=lambda b: (volumes[b], b)):
        if root[body] != body or volume[body] >= min_volume:
            continue  # already absorbed, or grew by absorbing others
        neighbours = adjacency[body]
        if not neighbours:
            isolated += 1
            continue
        host = max(neighbours, key=lambda k: (neighbours[k], -k))
        for k, area in neighbours.items():
            if k == host:
                continue
            adjacency[host][k] = adjacency[host].get(k, 0.0) + area
            adjacency[k][host] = adjacency[k].get(host, 0.0) + area
            del adjacency[k][body]
        del adjacency[host][body]
        adjacency[body] = {}
        volume[host] += volume[body]
        root[body] = host
        merged += 1

    def find(b: int) -> int:
        while root[b] != b:
            b = root[b]
        return b

    groups: dict[int, list[int]] = {}
    for b in range(n):
        groups.setdefault(find(b), []).append(b)
    return sorted(groups.values()), merged, isolated


def _group_fragment(fragments: Fragments, members: list, piece: int) -> Fragment:
    """One fragment from bodies ``(fragment index, face indices)``: a face subset, or a union if several."""
    if len(members) == 1:
        i, faces = members[0]
        frag = fragments.fragments[i]
        used, local = np.unique(frag.faces[faces], return_inverse=True)
        return Fragment(vertices=frag.vertices[used], faces=local.reshape(-1, 3), normals=frag.normals[used],
                        uvs=None if frag.uvs is None else frag.uvs[used], material_ids=frag.material_ids[faces],
                        piece=piece)
    solids, id_to_material = [], {}
    has_uvs = any(fragments.fragments[i].uvs is not None for i, _ in members)
    for i, faces in members:
        frag = fragments.fragments[i]
        used, local = np.unique(frag.faces[faces], return_inverse=True)
        uvs = frag.uvs[used] if frag.uvs is not None else np.zeros((len(used), 2))
        props = np.column_stack([frag.vertices[used], uvs, frag.normals[used]])
        _, first, weld = unique_rows(props[:, :3], return_index=True, return_inverse=True)
        body = SplitMesh(props, local.reshape(-1, 3), frag.material_ids[faces], first[weld.reshape(-1)])
        solid, ids = to_manifold(body, len(fragments.materials))
        solids.append(solid)
        id_to_material.update(ids)
    union = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    props, F, material_ids = from_manifold(union, id_to_material)
    keep = shell_mask(union.to_mesh64(), tol.SLIVER_VOLUME * fragments.input_volume)
    F, material_ids = F[keep], material_ids[keep]
    used, local = np.unique(F, return_inverse=True)
    props = props[used]
    return Fragment(vertices=props[:, :3], faces=local.reshape(-1, 3), normals=props[:, 5:8],
                    uvs=props[:, 3:5] if has_uvs else None, material_ids=material_ids.astype(np.int32), piece=piece)

# Rounding of fragment centroids for the export order (normalized units).
_ORDER_DECIMALS = 6


def _mesh_centroid(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    vol = face_signed_volumes(V, F)
    total = vol.sum()
    if abs(total) < tol.SMALLEST_DIVISOR:
        return V.mean(axis=0)
    return ((a + b + c) / 4.0 * vol[:, None]).sum(axis=0) / total


def stable_order(results: list[Fragment]) -> np.ndarray:
    """The order (p,) of fragments by rounded centroid, then piece: the same on every run and machine."""
    keys = np.array([_mesh_centroid(f.vertices, f.faces) for f in results])
    keys = np.round(keys, _ORDER_DECIMALS)
    pieces = np.array([f.piece for f in results])
    return np.lexsort((pieces, keys[:, 2], keys[:, 1], keys[:, 0]))

