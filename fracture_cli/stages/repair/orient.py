"""Repair: orientation of closed components (cavities), of open sheets and of shading normals."""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry import trigeom
from fracture_cli.geometry.edges import edge_table, face_bodies
from fracture_cli.geometry.meshtopo import components, undirected_edges
from fracture_cli.geometry.solids import NORMAL, POS

# Closed components compared for nesting (cavities) only when their bounding boxes nest;
# at most this many sample vertices per component.
_NESTING_SAMPLES = 32


def internal_open_faces(V: np.ndarray, W: np.ndarray, weld: np.ndarray) -> np.ndarray:
    """Mask (m,) of faces of open components lying entirely inside a closed component (internal faces)."""
    m = len(W)
    component = components(W, len(weld))
    num = int(component.max()) + 1
    directed, edge_id, face = undirected_edges(W)
    open_face = np.bincount(edge_id)[edge_id] == 1
    is_open = np.zeros(num, dtype=bool)
    is_open[component[face[open_face]]] = True
    closed = np.flatnonzero(~is_open)
    inside = np.zeros(m, dtype=bool)
    if not len(closed):
        return inside
    for c in np.flatnonzero(is_open).tolist():
        verts = np.unique(W[component == c])
        samples = V[verts[np.linspace(0, len(verts) - 1, min(_NESTING_SAMPLES, len(verts))).astype(int)]]
        for k in closed.tolist():
            if np.all(np.abs(trigeom.winding_numbers(samples, V, W[component == k])) > 0.5):
                inside[component == c] = True
                break
    return inside


def component_orientation(V: np.ndarray, F: np.ndarray, component: np.ndarray) -> np.ndarray:
    """Flip flag (c,) per closed component: positive volume, or negative when nested in another (a cavity)."""
    num = int(component.max()) + 1
    volume = np.bincount(component, weights=trigeom.face_signed_volumes(V, F), minlength=num)
    depth = np.zeros(num, dtype=np.int64)
    container = np.full(num, -1, dtype=np.int64)  # the smallest component containing each
    if num > 1:
        lo = np.full((num, 3), np.inf)
        hi = np.full((num, 3), -np.inf)
        for k in range(3):
            np.minimum.at(lo, component, V[F[:, k]])
            np.maximum.at(hi, component, V[F[:, k]])
        for i in range(num):
            inside_box = np.all((lo <= lo[i]) & (hi >= hi[i]), axis=1)
            inside_box[i] = False
            candidates = np.flatnonzero(inside_box)
            if not len(candidates):
                continue
            verts = np.unique(F[component == i])
            samples = V[verts[np.linspace(0, len(verts) - 1, min(_NESTING_SAMPLES, len(verts))).astype(int)]]
            for j in candidates.tolist():
                w = trigeom.winding_numbers(samples, V, F[component == j])
                if np.all(np.abs(w) > 0.5):
                    depth[i] += 1
                    if container[i] < 0 or abs(volume[j]) < abs(volume[container[i]]):
                        container[i] = j
    # A nested component wound against its container (as given) is a cavity; wound like it, it is
    # internal geometry of the same solid (the union absorbs it). Outermost components are positive.
    order = np.argsort(depth, kind="stable")
    positive = np.ones(num, dtype=bool)
    for i in order.tolist():
        if container[i] >= 0:
            j = container[i]
            same = (volume[i] > 0) == (volume[j] > 0)
            positive[i] = positive[j] if same else not positive[j]
    return (volume > 0) != positive


def fix_shading_normals(props: np.ndarray, F: np.ndarray) -> int:
    """Flip vertex normals (in place) that point against their own faces; returns how many."""
    acc = trigeom.vertex_normals(props[:, POS], F, unit=False)
    against = np.einsum("ij,ij->i", acc, props[:, NORMAL]) < 0
    props[against, NORMAL] *= -1.0
    return int(against.sum())


def sheet_faces_away(props: np.ndarray, F: np.ndarray, shading: bool) -> bool:
    """Whether an open sheet's faces ``F`` (m, 3) must be reversed so its winding shows its visible side.

    With the input's shading normals (``shading``), the visible side is the one
    they point to (area-weighted vote); without them (STL, or normals made from
    the file's own winding), it is the side facing away from the sheet's centre.
    """
    V = props[:, POS]
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    if shading:
        towards = props[F[:, 0], NORMAL] + props[F[:, 1], NORMAL] + props[F[:, 2], NORMAL]
    else:
        centres = V[F].mean(axis=1)
        towards = centres - V[np.unique(F)].mean(axis=0)
    return bool(np.einsum("ij,ij->i", fn, towards).sum() < 0)


def closed_patches_outward(V: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Flip mask (m,) turning inside-out closed patches that touch an edge of more than two faces outward.

    The non-manifold split pairs the faces around such an edge by which side
    of each the material is on, so the bodies meeting there must face out.
    Patches not touching such an edge keep their winding (cavities stay).
    """
    table = edge_table(W)
    patch = face_bodies(table)
    num = int(patch.max()) + 1 if len(patch) else 0
    at_many = np.zeros(num, dtype=bool)
    at_many[patch[table.face[table.count[table.edge] > 2]]] = True
    # A patch is closed when each of its (patch, edge) pairs has two of its faces.
    key = patch[table.face] * len(table.count) + table.edge
    _, per = np.unique(key, return_inverse=True)
    uses = np.bincount(per)
    closed = np.ones(num, dtype=bool)
    closed[patch[table.face[uses[per] != 2]]] = False
    volume = np.bincount(patch, weights=trigeom.face_signed_volumes(V, W), minlength=num)
    return (at_many & closed & (volume < 0))[patch]
