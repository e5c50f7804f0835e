"""Repair: closing open surfaces, by filling holes with fans or thickening sheets into thin solids."""

from __future__ import annotations

import numpy as np

from fracture_cli import trigeom
from fracture_cli.errors import StageError
from fracture_cli.stages._solids import COLOR, NORMAL, NUM_COLUMNS, POS, UV, SplitMesh
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Material

STAGE = "repair"

_INTERIOR_COLOR = (0.55, 0.5, 0.45, 1.0)


# Shell thickness: at most this fraction of the free distance along the inward normal
# (to the opposite wall or the next fold), and the floor below which shelling fails.
_RAY_FRACTION = 0.45


_MIN_THICKNESS_FRACTION = 1e-3


def interior_slot(materials: tuple[Material, ...]) -> tuple[int, tuple[Material, ...]]:
    """Index of the interior material (the input's own, or a new last slot) and the material tuple."""
    for i, m in enumerate(materials):
        if m.name == INTERIOR_MATERIAL_NAME:
            return i, materials
    return len(materials), materials + (Material(INTERIOR_MATERIAL_NAME, base_color=_INTERIOR_COLOR),)


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


def fill(mesh: SplitMesh, loops: list[np.ndarray], interior_material: int) -> SplitMesh:
    """Close each loop with a fan around its centroid; cap vertices are copies welded to the loop's."""
    props = mesh.props
    new_props, new_faces, new_weld = [], [], []
    n = len(props)
    for loop in loops:
        P = props[loop, POS]
        centre = P.mean(axis=0)
        following = np.roll(loop, -1)
        # Boundary edges run loop[j] -> loop[j+1] in the surface; the cap runs them the other way.
        area_vector = np.cross(props[following, POS] - centre, P - centre).sum(axis=0)
        normal = area_vector / max(np.linalg.norm(area_vector), 1e-300)
        k = len(loop)
        block = np.zeros((k + 1, NUM_COLUMNS))
        block[:k, POS] = P
        block[k, POS] = centre
        block[:, NORMAL] = normal
        block[:, UV] = _plane_uvs(block[:, POS], normal)
        block[:k, COLOR] = props[loop, COLOR]
        block[k, COLOR] = props[loop, COLOR].mean(axis=0)
        ids = n + np.arange(k + 1)
        local = np.arange(k)
        new_faces.append(np.stack([ids[np.roll(local, -1)], ids[local], np.full(k, ids[k])], axis=1))
        new_weld.append(np.append(loop, ids[k]))
        new_props.append(block)
        n += k + 1
    cap_faces = np.concatenate(new_faces)
    return _added(mesh, np.vstack([props] + new_props), cap_faces, new_weld, interior_material)


def _added(mesh: SplitMesh, props: np.ndarray, faces: np.ndarray, welds: list[np.ndarray],
           interior_material: int) -> SplitMesh:
    """``mesh`` with new vertices (all rows of ``props`` past the old ones, welded by ``welds``) and new
    ``faces`` (k, 3) of the interior material."""
    return SplitMesh(props=props, faces=np.vstack([mesh.faces, faces]),
                     material_ids=np.concatenate([mesh.material_ids, np.full(len(faces), interior_material, np.int32)]),
                     weld=np.concatenate([mesh.weld] + welds))


def _free_distance(V: np.ndarray, F: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance (k,) along each ray to the first face hit (inf if none)."""
    from fracture_cli._open3d import open3d as _import_open3d

    o3d = _import_open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    rays = np.hstack([origins, directions]).astype(np.float32)
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)


def shell(mesh: SplitMesh, sheet: np.ndarray, boundary: np.ndarray, thickness: float,
          interior_material: int) -> tuple[SplitMesh, int]:
    """Thicken the sheet faces (mask ``sheet`` (m,)) into a closed slab on their inner side.

    ``boundary`` (b, 2) are the sheet's directed boundary edges (welded ids). Returns the closed mesh and the
    number of vertices where the slab is thinner than ``thickness`` (to keep it from folding).
    """
    props, weld = mesh.props, mesh.weld
    n = len(props)
    V = props[:, POS]
    sheet_welded = mesh.welded[sheet]
    normal = trigeom.vertex_normals(V, sheet_welded, n)
    t, thinned = _thickness(V, mesh.welded, sheet_welded, normal, thickness)

    # Offset copy of every split vertex of the sheet: same attributes, normal reversed, interior material.
    sheet_faces = mesh.faces[sheet]
    split_used = np.unique(sheet_faces)
    offset_index = np.full(n, -1, dtype=np.int64)
    offset_index[split_used] = n + np.arange(len(split_used))
    offset_props = props[split_used].copy()
    rep = weld[split_used]
    offset_props[:, POS] = V[rep] - t[rep, None] * normal[rep]
    offset_props[:, NORMAL] *= -1.0
    # Copies weld to the first copy made at their position.
    _, first = np.unique(rep, return_index=True)
    group_offset = np.full(n, -1, dtype=np.int64)
    group_offset[rep[first]] = offset_index[split_used[first]]
    offset_weld = group_offset[rep]
    offset_faces = offset_index[sheet_faces][:, ::-1]

    # Strip along the boundary: its own vertex copies (normals across the strip), welded to sheet and offset.
    m0 = n + len(split_used)
    a, b = boundary[:, 0], boundary[:, 1]
    ends = np.unique(boundary)
    strip_index = np.full(n, -1, dtype=np.int64)
    strip_index[ends] = m0 + np.arange(len(ends))
    strip_offset_index = np.full(n, -1, dtype=np.int64)
    strip_offset_index[ends] = m0 + len(ends) + np.arange(len(ends))
    strip_props = np.zeros((2 * len(ends), NUM_COLUMNS))
    strip_props[: len(ends), POS] = V[ends]
    strip_props[len(ends):, POS] = V[ends] - t[ends, None] * normal[ends]
    strip_props[:, COLOR] = np.tile(props[ends, COLOR], (2, 1))
    sa, sb = strip_index[a], strip_index[b]
    oa, ob = strip_offset_index[a], strip_offset_index[b]
    strip_faces = np.concatenate([np.stack([sb, sa, oa], axis=1), np.stack([sb, oa, ob], axis=1)])
    strip_weld = np.concatenate([ends, group_offset[ends]])

    props = np.vstack([props, offset_props, strip_props])
    strip_rows = slice(m0, len(props))
    props[strip_rows, NORMAL] = trigeom.vertex_normals(props[:, POS], strip_faces)[strip_rows]
    props[strip_rows, UV] = _axis_uvs(props[strip_rows, POS], props[strip_rows, NORMAL])
    added = np.vstack([offset_faces, strip_faces])
    return _added(mesh, props, added, [offset_weld, strip_weld], interior_material), thinned


def _thickness(V: np.ndarray, W: np.ndarray, sheet_welded: np.ndarray, normal: np.ndarray,
               thickness: float) -> tuple[np.ndarray, int]:
    """Slab thickness (n,) at each welded sheet vertex, and how many are thinner than ``thickness``.

    At most ``_RAY_FRACTION`` of the free distance behind the vertex (to the opposite wall of ``W`` or where
    the sheet folds back), halved where an offset face would flip.
    """
    used = np.unique(sheet_welded)
    eps = 1e-6
    free = _free_distance(V, W, V[used] - eps * normal[used], -normal[used]) + eps
    t = np.zeros(len(V))
    t[used] = np.minimum(thickness, _RAY_FRACTION * free)
    original_fn = np.cross(V[sheet_welded[:, 1]] - V[sheet_welded[:, 0]], V[sheet_welded[:, 2]] - V[sheet_welded[:, 0]])
    for _ in range(12):
        offset = V - t[:, None] * normal
        fn = np.cross(offset[sheet_welded[:, 1]] - offset[sheet_welded[:, 0]],
                      offset[sheet_welded[:, 2]] - offset[sheet_welded[:, 0]])
        bad = np.einsum("ij,ij->i", fn, original_fn) <= 0
        if not bad.any():
            break
        t[np.unique(sheet_welded[bad])] *= 0.5
    else:
        raise StageError(f"cannot thicken the open sheet by {thickness:g}: it folds too tightly (offset faces "
                         "keep flipping); use --set repair.open_surface=fill, or a smaller repair.shell_thickness",
                         stage=STAGE)
    if t[used].min() < _MIN_THICKNESS_FRACTION * thickness:
        raise StageError(f"cannot thicken the open sheet by {thickness:g}: at some vertices it has only "
                         f"{t[used].min():.2g} of free space behind it (touching or folded parts); separate them, "
                         "or use --set repair.open_surface=fill", stage=STAGE)
    return t, int((t[used] < thickness * (1 - 1e-9)).sum())
