"""Solids shared by the repair, smooth and fragments stages: split-vertex meshes <-> manifold3d.

The repair stage makes the input a closed solid and the fragments stage cuts
that same solid, so both convert it the same way: vertex properties (position,
uv, normal[, colour]) kept per split vertex, vertices at one position welded
topologically, one manifold3d run per material.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import manifold3d
import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.meshtopo import boundary_edges, manifold_patches, nonmanifold_edges
from fracture_cli.geometry.rows import unique_rows, used_vertices

if TYPE_CHECKING:  # the surface type only for annotations: geometry sits below the pipeline's types
    from fracture_cli.types import SurfaceMesh

log = logging.getLogger(__name__)

# Vertex property columns carried through manifold3d: position, uv, normal, colour.
POS, UV, NORMAL, COLOR = slice(0, 3), slice(3, 5), slice(5, 8), slice(8, 12)
# Column count with colours (the repair stage) and without (:func:`surface_solid`: fragments do not carry them).
NUM_COLUMNS = 12
SOLID_COLUMNS = 8


@dataclass(frozen=True)
class SplitMesh:
    """A triangle mesh with vertices split where attributes differ (UV seams), and its weld map.

    Attributes
    ----------
    props : (n, c) float64
        Per split vertex: position, uv, normal (and RGBA colour when c = 12).
    faces : (m, 3) int64
        Triangles over split vertex ids.
    material_ids : (m,) int32
        Material slot of each triangle.
    weld : (n,) int64
        Representative split vertex of each (vertices at one position share one).
    """

    props: np.ndarray
    faces: np.ndarray
    material_ids: np.ndarray
    weld: np.ndarray

    @property
    def welded(self) -> np.ndarray:
        """Triangles (m, 3) over welded vertex ids."""
        return self.weld[self.faces]


def vertex_properties(surface: SurfaceMesh, columns: int = SOLID_COLUMNS) -> np.ndarray:
    """Per-vertex properties (n, columns): position, uv, normal (and RGBA colour if ``columns`` is 12).

    Missing UVs are zero, missing colours white, missing normals area-weighted
    normals averaged over vertices sharing a position.
    """
    V = np.asarray(surface.vertices, dtype=np.float64)
    n = len(V)
    props = np.zeros((n, columns))
    props[:, POS] = V
    if surface.uvs is not None:
        props[:, UV] = surface.uvs
    if surface.normals is not None:
        props[:, NORMAL] = surface.normals
    else:
        # Area-weighted normals averaged over vertices sharing a position.
        unique_positions, pos = unique_rows(V, return_inverse=True)
        pos = pos.reshape(-1)
        props[:, NORMAL] = trigeom.vertex_normals(unique_positions, pos[np.asarray(surface.faces, dtype=np.int64)])[pos]
    if columns > SOLID_COLUMNS:
        props[:, COLOR] = surface.colors if surface.colors is not None else 1.0
    return props


def weld_map(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Representative vertex (n,) of each vertex: exact position weld, then manifold3d's open-edge merge."""
    n = len(V)
    _, first, inverse = unique_rows(V, return_index=True, return_inverse=True)
    target = first[inverse.reshape(-1)]
    src = np.flatnonzero(target != np.arange(n))
    mesh = manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(V, dtype=np.float64),
        tri_verts=np.ascontiguousarray(F, dtype=np.uint64).reshape(-1, 3),
        merge_from_vert=np.ascontiguousarray(src, dtype=np.uint64),
        merge_to_vert=np.ascontiguousarray(target[src], dtype=np.uint64),
    )
    mesh.merge()
    target = np.arange(n)
    src = np.asarray(mesh.merge_from_vert, dtype=np.int64)
    target[src] = np.asarray(mesh.merge_to_vert, dtype=np.int64)
    for _ in range(64):  # chains a -> b -> c collapse to their end
        nxt = target[target]
        if np.array_equal(nxt, target):
            break
        target = nxt
    # The smallest referenced index of each group represents it (stable under input order).
    key = np.arange(n) + n
    key[used_vertices(F, n)] -= n
    smallest = np.full(n, 2 * n, dtype=np.int64)
    np.minimum.at(smallest, target, key)
    return smallest[target] % n


def surface_solid(surface: SurfaceMesh, *, stage: str) -> tuple[manifold3d.Manifold, dict[int, int]]:
    """A closed surface as a manifold3d solid with uv/normal properties and one run id per material.

    Parameters
    ----------
    surface : SurfaceMesh
        A closed surface, normally the result of the repair stage; vertices are
        welded by position, attributes kept per split vertex.
    stage : str
        The calling stage, for error messages.

    Returns
    -------
    solid : manifold3d.Manifold
        Vertex properties (:data:`SOLID_COLUMNS`): position, uv, normal.
        Several overlapping positive bodies are united.
    id_to_material : dict of int -> int
        manifold3d run id -> index into ``surface.materials``.

    Raises
    ------
    StageError
        If the surface is not closed and manifold.
    """
    solid, id_to_material = surface_manifold(surface, stage)
    solid, bodies, _ = union_bodies(solid)
    if bodies > 1:
        log.info("%s: the surface has %d overlapping bodies; using their union", stage, bodies)
    return solid, id_to_material


def surface_manifold(surface: SurfaceMesh, stage: str) -> tuple[manifold3d.Manifold, dict[int, int]]:
    """The surface as one manifold3d mesh of closed bodies (not united), and its run id -> material map.

    Bodies touching along an edge are separated by manifold patches (faces joined across two-face edges); see
    :func:`fracture_cli.stages.fragments.solids.input_solids` for bodies touching face to face.
    """
    props = vertex_properties(surface, SOLID_COLUMNS)
    F = np.asarray(surface.faces, dtype=np.int64)
    weld = weld_map(props[:, :3], F)
    material_ids = np.asarray(surface.material_ids)
    mesh = SplitMesh(props, F, material_ids, weld)
    if nonmanifold_edges(mesh.welded):
        # Bodies touching along an edge (a union result): weld each only within itself.
        patch = manifold_patches(mesh.welded)[0]
        mesh = split_bodies(mesh, [np.flatnonzero(patch == p) for p in range(int(patch.max()) + 1)])
    solid, id_to_material = to_manifold(mesh, len(surface.materials))
    if solid.status() != manifold3d.Error.NoError:
        boundary = len(boundary_edges(mesh.welded))
        raise StageError(
            f"the surface is not a closed solid ({solid.status().name}"
            + (f", {boundary} open edges" if boundary else "") + "); run the 'repair' stage on it first "
            "(e.g. 'fracture load IN repair cage ...'); 'bake' does this itself", stage=stage)
    return solid, id_to_material


def union_bodies(solid: manifold3d.Manifold) -> tuple[manifold3d.Manifold, int, int]:
    """Union the positive bodies of ``solid`` and subtract its cavities (negative-volume shells).

    Overlapping closed bodies stored as one mesh are resolved this way;
    manifold3d does not resolve them inside a single Manifold.

    Returns
    -------
    solid : manifold3d.Manifold
        Unchanged when it has at most one positive body.
    bodies : int
        How many positive bodies it had.
    cavities : int
        How many cavities were subtracted (0 when there was nothing to union).
    """
    parts = solid.decompose()
    positive = [p for p in parts if p.volume() > 0]
    if len(positive) <= 1:
        return solid, len(positive), 0
    cavities = [reversed_solid(p) for p in parts if p.volume() < 0]
    solid = manifold3d.Manifold.batch_boolean(positive, manifold3d.OpType.Add)
    if cavities:
        solid = solid - manifold3d.Manifold.batch_boolean(cavities, manifold3d.OpType.Add)
    return solid, len(positive), len(cavities)


def body_groups(solid: manifold3d.Manifold) -> tuple[list[manifold3d.Manifold], int, int]:
    """The bodies of ``solid`` united where they overlap, each minus the cavities inside it; bodies that only
    touch stay apart.

    Parameters
    ----------
    solid : manifold3d.Manifold
        Closed bodies stored as one mesh (they may overlap or touch; cavities
        are shells of negative volume).

    Returns
    -------
    groups : list of manifold3d.Manifold
        One solid per group of bodies connected by overlaps (with positive
        volume in common), in the order of their first body; ``[solid]``
        when it has at most one positive body.
    bodies : int
        Positive bodies found.
    cavities : int
        Cavities subtracted.

    Notes
    -----
    A truck's wheels pressed against its chassis, a lid resting on a pot, the
    fragments of a baked asset: bodies an artist modelled apart that only
    touch. United, they would be cut across as one solid; kept apart, each
    breaks on its own and the fragments stage cuts each group separately.
    """
    parts = solid.decompose()
    positive = [p for p in parts if p.volume() > 0]
    holes = [reversed_solid(p) for p in parts if p.volume() < 0]
    if len(positive) <= 1:
        return [solid], len(positive), 0  # a cavity in a single body is already its inside
    boxes = np.array([p.bounding_box() for p in positive], dtype=np.float64).reshape(-1, 6)
    root = list(range(len(positive)))

    def find(i: int) -> int:
        while root[i] != i:
            i = root[i]
        return i

    for i in range(len(positive)):
        for j in range(i + 1, len(positive)):
            if np.any(boxes[i, :3] > boxes[j, 3:]) or np.any(boxes[j, :3] > boxes[i, 3:]):
                continue
            # Overlapping, not touching: exact booleans give 0 for bodies that only touch (along a face, an edge
            # or at a point).
            common = (positive[i] ^ positive[j]).volume()
            if common > tol.SLIVER_VOLUME * min(positive[i].volume(), positive[j].volume()):
                root[max(find(i), find(j))] = min(find(i), find(j))
    members: dict[int, list[int]] = {}
    for i in range(len(positive)):
        members.setdefault(find(i), []).append(i)
    groups = [positive[m[0]] if len(m) == 1 else manifold3d.Manifold.batch_boolean([positive[i] for i in m],
                                                                                    manifold3d.OpType.Add)
              for m in members.values()]
    for hole in holes:
        groups = [g - hole if (g ^ hole).volume() > 0 else g for g in groups]
    return groups, len(positive), len(holes)


def split_bodies(mesh: SplitMesh, bodies: list[np.ndarray]) -> SplitMesh:
    """Copy each body (an array of face indices) with its own vertices, welded only within the body.

    A face may belong to several bodies (it is copied); vertices of different
    bodies are never welded, so bodies that touch along an edge stay separate.
    """
    new_props, new_faces, new_ids, new_weld = [], [], [], []
    n = 0
    for faces in bodies:
        corners = mesh.faces[faces]
        used, local = np.unique(corners, return_inverse=True)
        _, first, group = np.unique(mesh.weld[used], return_index=True, return_inverse=True)
        new_props.append(mesh.props[used])
        new_faces.append(n + local.reshape(-1, 3))
        new_weld.append(n + first[group.reshape(-1)])
        new_ids.append(mesh.material_ids[faces])
        n += len(used)
    return SplitMesh(np.vstack(new_props), np.vstack(new_faces), np.concatenate(new_ids).astype(np.int32),
                     np.concatenate(new_weld))


def to_manifold(mesh: SplitMesh, num_materials: int) -> tuple[manifold3d.Manifold, dict[int, int]]:
    """A manifold3d solid from split vertices, their weld map, and one run (original id) per material.

    Returns the solid and the map manifold3d run id -> material index.
    """
    props, weld = mesh.props, mesh.weld
    order = np.argsort(mesh.material_ids, kind="stable")
    F = mesh.faces[order]
    material_ids = np.asarray(mesh.material_ids)[order]
    first_id = manifold3d.Manifold.reserve_ids(num_materials)
    id_to_material = {first_id + i: i for i in range(num_materials)}
    used = np.unique(material_ids)
    run_index = np.append(np.searchsorted(material_ids, used), len(F)) * 3
    src = np.flatnonzero(weld != np.arange(len(weld)))
    mesh = manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(props, dtype=np.float64),
        tri_verts=np.ascontiguousarray(F, dtype=np.uint64),
        merge_from_vert=np.ascontiguousarray(src, dtype=np.uint64),
        merge_to_vert=np.ascontiguousarray(weld[src], dtype=np.uint64),
        run_index=np.ascontiguousarray(run_index, dtype=np.uint64),
        run_original_id=np.ascontiguousarray(first_id + used, dtype=np.uint32),
    )
    return manifold3d.Manifold(mesh), id_to_material


def reversed_solid(part: manifold3d.Manifold) -> manifold3d.Manifold:
    """The same manifold3d body with every triangle reversed (a cavity as a positive solid)."""
    mesh = part.to_mesh64()
    tris = np.array(mesh.tri_verts, dtype=np.uint64).reshape(-1, 3)[:, ::-1]
    # Copies: manifold3d's buffers come back as read-only views, and Mesh64 refuses read-only arrays.
    flipped = manifold3d.Mesh64(
        vert_properties=np.array(mesh.vert_properties, dtype=np.float64),
        tri_verts=np.ascontiguousarray(tris),
        merge_from_vert=np.array(mesh.merge_from_vert, dtype=np.uint64),
        merge_to_vert=np.array(mesh.merge_to_vert, dtype=np.uint64),
        run_index=np.array(mesh.run_index, dtype=np.uint64),
        run_original_id=np.array(mesh.run_original_id, dtype=np.uint32),
    )
    return manifold3d.Manifold(flipped)


def from_manifold(solid: manifold3d.Manifold, id_to_material: dict[int, int]):
    """Split-vertex properties (n, 12), faces (m, 3) and material ids (m,) of a manifold3d result."""
    mesh = solid.to_mesh64()
    props = np.array(mesh.vert_properties, dtype=np.float64)
    F = np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)
    run_index = np.asarray(mesh.run_index, dtype=np.int64) // 3
    run_ids = np.asarray(mesh.run_original_id, dtype=np.int64)
    material_ids = np.empty(len(F), dtype=np.int32)
    for r, original in enumerate(run_ids.tolist()):
        material_ids[run_index[r]:run_index[r + 1]] = id_to_material[original]
    # Merge vectors mark vertices that are one point: give them one position exactly.
    src = np.asarray(mesh.merge_from_vert, dtype=np.int64)
    props[src, POS] = props[np.asarray(mesh.merge_to_vert, dtype=np.int64), POS]
    return props, F, material_ids


def shell_mask(mesh: manifold3d.Mesh64, min_volume: float) -> np.ndarray:
    """Triangles (m,) bool of a manifold3d ``Mesh64`` that are not on a zero-volume shell.

    Booleans of solids with coincident faces can leave closed shells of
    (near) zero volume. ``Manifold.decompose`` finds them, but
    ``Manifold.compose`` of the remaining parts loses cavities (shells of
    negative volume), so the shells are removed on the mesh instead: triangles
    are grouped by connectivity (through shared, welded vertices) and every
    group whose signed volume is at most ``min_volume`` in magnitude is dropped.
    """
    tris = np.asarray(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)
    positions = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    n = len(positions)
    weld = np.arange(n)
    src = np.asarray(mesh.merge_from_vert, dtype=np.int64)
    if len(src):
        weld[src] = np.asarray(mesh.merge_to_vert, dtype=np.int64)
    corners = weld[tris]
    m = len(tris)
    if m == 0:
        return np.zeros(0, dtype=bool)
    # on first use: scipy.sparse costs 0.2-0.3 s to import, and resolving a recipe imports this module
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    # Triangles sharing a vertex are connected: the vertices joined by two edges of every triangle form the same
    # groups as the triangle-vertex incidence graph, on a graph a third its size.
    graph = sp.coo_matrix((np.ones(2 * m), (corners[:, :2].reshape(-1), corners[:, 1:].reshape(-1))), shape=(n, n))
    _, vertex_labels = connected_components(graph, directed=False)
    labels = vertex_labels[corners[:, 0]]
    volume = trigeom.face_signed_volumes(positions, tris)
    _, group = np.unique(labels, return_inverse=True)
    shell_volume = np.bincount(group.reshape(-1), weights=volume)
    return np.abs(shell_volume[group.reshape(-1)]) > min_volume
