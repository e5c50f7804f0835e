"""Repair: carry split-vertex attributes (UVs, normals, colours) through meshfix's welded operations.

The meshfix modules work on welded meshes: one vertex per position. The
repair stage keeps vertices split where their attributes differ (UV seams),
as a :class:`~fracture_cli.geometry.solids.SplitMesh` whose welded ids are the
representative split vertices. Each function here takes a meshfix result
computed on ``(mesh.props[:, POS], mesh.welded)`` and returns the split mesh it
describes: faces the input had keep their split vertices; copies of welded
vertices (a non-manifold split) copy the split vertices' attributes; faces
that meshfix adds (hole patches, the back and rim of a thickened sheet) get
split vertices of their own with the interior material's attributes.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.rows import unique_rows
from fracture_cli.geometry.solids import COLOR, NORMAL, POS, UV, SplitMesh
from fracture_cli.stages.repair.holes import FilledMesh, HoleLoop
from fracture_cli.stages.repair.nonmanifold import NonManifoldSplit
from fracture_cli.stages.repair.thicken import ThickenedSheet


def _first_of_each(labels: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """For every entry, the first of ``ids`` (k,) that shares its label (k,): one representative per label."""
    _, first, group = np.unique(labels, return_index=True, return_inverse=True)
    return ids[first][group.reshape(-1)]


def after_split(mesh: SplitMesh, split: NonManifoldSplit) -> SplitMesh:
    """The split mesh of :func:`~fracture_cli.stages.repair.nonmanifold.split_nonmanifold` run on ``mesh.welded``.

    A corner whose welded vertex was copied (one copy per fan) gets a copy of
    its split vertex; copies of one welded vertex weld to the first of them.
    Reversed copies of internal-wall faces keep their material.
    """
    n = len(mesh.props)
    source = mesh.faces.reshape(-1)[split.source_corner.reshape(-1)]
    welded = split.faces.reshape(-1)
    copied = welded >= n  # split_nonmanifold keeps a vertex's first fan under its own id
    faces = source.copy()
    props, weld = mesh.props, mesh.weld
    if copied.any():
        pairs, inverse = unique_rows(np.column_stack([source[copied], welded[copied]]), return_inverse=True)
        new_ids = n + np.arange(len(pairs))
        faces[copied] = new_ids[inverse.reshape(-1)]
        props = np.vstack([props, props[pairs[:, 0]]])
        weld = np.concatenate([weld, _first_of_each(pairs[:, 1], new_ids)])
    return SplitMesh(props, faces.reshape(-1, 3), mesh.material_ids[split.source_face], weld)


def _plane_uvs(P: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Planar UVs (k, 2) of points on a plane with unit ``normal``."""
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    return np.column_stack([P @ u, P @ v])


def _axis_uvs(P: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """UVs (k, 2) projecting each point along its normal's dominant axis."""
    axis = np.argmax(np.abs(normals), axis=1)
    u_axis = np.array([1, 0, 0])[axis]
    v_axis = np.array([2, 2, 1])[axis]
    rows = np.arange(len(P))
    return np.column_stack([P[rows, u_axis], P[rows, v_axis]])


def _appended(mesh: SplitMesh, faces: np.ndarray, flipped: np.ndarray, new_props: np.ndarray,
              new_weld: np.ndarray, new_faces: np.ndarray, interior_material: int) -> SplitMesh:
    """``mesh`` with ``faces`` (its faces, rows ``flipped`` reversed), new vertex rows and interior faces."""
    faces = faces.copy()
    faces[flipped] = faces[flipped][:, ::-1]
    return SplitMesh(props=np.vstack([mesh.props, new_props]), faces=np.vstack([faces, new_faces]),
                     material_ids=np.concatenate([mesh.material_ids,
                                                  np.full(len(new_faces), interior_material, np.int32)]),
                     weld=np.concatenate([mesh.weld, new_weld]))


def after_fill(mesh: SplitMesh, filled: FilledMesh, loops: list[HoleLoop], interior_material: int) -> SplitMesh:
    """The split mesh of :func:`~fracture_cli.stages.repair.holes.fill_holes` run on ``mesh.welded``.

    ``loops`` are the plan's loops to fill, in order (their patches follow the
    mesh's faces in ``filled.faces``). Every patch gets its own vertices: the
    cap's flat normal, planar UVs, the loop vertices' colours (their mean at a
    fan's centre), welded to the loop's vertices.
    """
    n, m = len(mesh.props), len(mesh.faces)
    flipped = np.any(filled.faces[:m] != mesh.welded, axis=1)
    patch = filled.faces[m:]
    loop_of = np.repeat(np.arange(len(loops)), [len(loop.patch) for loop in loops])
    V = filled.vertices
    area_vector = np.cross(V[patch[:, 1]] - V[patch[:, 0]], V[patch[:, 2]] - V[patch[:, 0]])
    summed = np.stack([np.bincount(loop_of, weights=area_vector[:, k], minlength=len(loops)) for k in range(3)], 1)
    normal = summed / np.maximum(np.linalg.norm(summed, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    keys, inverse = unique_rows(np.column_stack([np.repeat(loop_of, 3), patch.reshape(-1)]), return_inverse=True)
    loop_id, welded = keys[:, 0], keys[:, 1]
    block = np.zeros((len(keys), mesh.props.shape[1]))
    block[:, POS] = V[welded]
    block[:, NORMAL] = normal[loop_id]
    for i in np.unique(loop_id).tolist():
        rows = loop_id == i
        block[rows, UV] = _plane_uvs(block[rows, POS], normal[i])
    if mesh.props.shape[1] > COLOR.start:
        on_loop = welded < n
        block[on_loop, COLOR] = mesh.props[welded[on_loop], COLOR]
        for row in np.flatnonzero(~on_loop).tolist():  # a fan's centre: the loop's mean colour
            block[row, COLOR] = mesh.props[loops[loop_id[row]].vertices, COLOR].mean(axis=0)
    new_ids = n + np.arange(len(keys))
    # Loop vertices weld to the surface's own vertex there; a fan centre to its first copy.
    new_weld = np.where(welded < n, mesh.weld[np.minimum(welded, n - 1)], _first_of_each(welded, new_ids))
    new_faces = new_ids[inverse.reshape(-1)].reshape(-1, 3)
    return _appended(mesh, mesh.faces, flipped, block, new_weld, new_faces, interior_material)


def after_thicken(mesh: SplitMesh, body: np.ndarray, sheet: ThickenedSheet, interior_material: int) -> SplitMesh:
    """The split mesh of :func:`~fracture_cli.stages.repair.thicken.thicken_inward` run on ``mesh.welded[body]``.

    The sheet's faces are unchanged. The back side copies every split vertex
    of the sheet (same UVs and colour, reversed normal); the rim has one
    vertex per corner position with normals across the strip and box-projected
    UVs. Back and rim are of the interior material.
    """
    n = len(mesh.props)
    V = sheet.vertices
    used = np.unique(mesh.welded[body])
    back_start, rim_start = n, n + len(used)
    num_ends = (len(V) - rim_start) // 2
    ends = sheet.source_vertex[rim_start:rim_start + num_ends]
    # Canonical welded id of every vertex of the sheet's result (the rim's copies are the same points).
    canonical = np.arange(len(V))
    canonical[rim_start:rim_start + num_ends] = ends
    canonical[rim_start + num_ends:] = back_start + np.searchsorted(used, ends)
    k = len(body)
    back_faces, rim_faces = sheet.faces[k:2 * k], sheet.faces[2 * k:]
    # Back: a copy per split vertex of the sheet, in the reversed corner order of the back faces.
    source = mesh.faces[body][:, ::-1].reshape(-1)
    split_source, back_inverse = np.unique(source, return_inverse=True)
    back_welded = np.zeros(len(split_source), dtype=np.int64)
    back_welded[back_inverse.reshape(-1)] = back_faces.reshape(-1)
    back = mesh.props[split_source].copy()
    back[:, POS] = V[back_welded]
    back[:, NORMAL] *= -1.0
    back_ids = n + np.arange(len(split_source))
    back_rep = _first_of_each(back_welded, back_ids)
    rep_of_welded = dict(zip(back_welded.tolist(), back_rep.tolist()))
    # Rim: one vertex per rim point.
    rim_points, rim_inverse = np.unique(rim_faces.reshape(-1), return_inverse=True)
    rim = np.zeros((len(rim_points), mesh.props.shape[1]))
    rim[:, POS] = V[rim_points]
    if mesh.props.shape[1] > COLOR.start:
        rim[:, COLOR] = mesh.props[mesh.weld[sheet.source_vertex[rim_points]], COLOR]
    rim_ids = n + len(back_ids) + np.arange(len(rim_points))
    rim_local = rim_inverse.reshape(-1, 3)
    normals = trigeom.vertex_normals(rim[:, POS], rim_local, len(rim_points))
    rim[:, NORMAL] = normals
    rim[:, UV] = _axis_uvs(rim[:, POS], normals)
    rim_canonical = canonical[rim_points]
    rim_weld = np.array([mesh.weld[c] if c < n else rep_of_welded[c] for c in rim_canonical.tolist()],
                        dtype=np.int64)
    new_faces = np.vstack([back_ids[back_inverse.reshape(-1)].reshape(-1, 3), rim_ids[rim_local]])
    return _appended(mesh, mesh.faces, np.zeros(len(mesh.faces), dtype=bool), np.vstack([back, rim]),
                     np.concatenate([back_rep, rim_weld]), new_faces, interior_material)
