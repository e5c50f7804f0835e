"""Repair: fins and sheets hinged on a solid, and bodies that enclose nothing.

Game meshes often carry a few zero-thickness faces attached to a solid along
one of its edges: a fin, a flag, a card for a decal. At such a hinge edge the
faces do not bound alternating solid and empty wedges, so the non-manifold
split (:mod:`.nonmanifold`) cannot pair them and the mesh has no inside
there. Rather than refuse the asset, the open patches that touch an edge of
more than two faces are cut off the solid along their hinge (their vertices
copied) and become open sheets of their own, which the next step thickens
behind their visible side (``repair.fins = "thicken"``) or leaves out
(``"drop"``). Closed bodies that enclose no volume (a fin doubled into a wall
of nothing) carry no material and are left out too; both are recorded.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.edges import edge_table, face_bodies
from fracture_cli.geometry.solids import SplitMesh
from fracture_cli.stages.repair.nonmanifold import NonManifoldSplit
from fracture_cli.stages.repair.records import RepairRecord


def hinged_sheets(welded: np.ndarray) -> np.ndarray:
    """Mask (m,) of the faces of open patches that touch an edge of more than two faces.

    A patch is a set of faces joined across two-face edges; it is open when
    one of its edges has one face. Closed patches meeting at an edge (bodies
    touching along it) are left to the non-manifold split.
    """
    table = edge_table(welded)
    patch = face_bodies(table)
    num = int(patch.max()) + 1 if len(patch) else 0
    per_side = table.count[table.edge]
    is_open = np.zeros(num, dtype=bool)
    is_open[patch[table.face[per_side == 1]]] = True
    hinged = np.zeros(num, dtype=bool)
    hinged[patch[table.face[per_side > 2]]] = True
    return (is_open & hinged)[patch]


def detach(mesh: SplitMesh, faces: np.ndarray) -> SplitMesh:
    """``mesh`` with the faces of mask ``faces`` (m,) given their own copies of their vertices.

    The copies keep the attributes and positions; they weld among themselves
    (one representative per position among the copies) but not to the rest,
    so the detached faces no longer share an edge or vertex with it.
    """
    n = len(mesh.props)
    used = np.unique(mesh.faces[faces])
    new_id = np.full(n, -1, dtype=np.int64)
    new_id[used] = n + np.arange(len(used))
    rep = mesh.weld[used]
    # The first copy of each welded vertex represents the copies at its position.
    _, first, group = np.unique(rep, return_index=True, return_inverse=True)
    new_weld = (n + first)[group.reshape(-1)]
    out_faces = mesh.faces.copy()
    out_faces[faces] = new_id[mesh.faces[faces]]
    return SplitMesh(np.vstack([mesh.props, mesh.props[used]]), out_faces, mesh.material_ids,
                     np.concatenate([mesh.weld, new_weld]))


def without(mesh: SplitMesh, faces: np.ndarray) -> SplitMesh:
    """``mesh`` without the faces of mask ``faces`` (m,) (vertices kept: unused ones are harmless)."""
    return SplitMesh(mesh.props, mesh.faces[~faces], mesh.material_ids[~faces], mesh.weld)


def empty_bodies(split: NonManifoldSplit, min_volume: float) -> np.ndarray:
    """Mask (m,) of the *input* faces of the split's closed bodies with no volume (at most ``min_volume``).

    Their faces come back as a mask over the faces given to the split (a
    doubled wall face counts for its original).
    """
    flat = split.body_closed & (np.abs(split.body_volume) <= min_volume)
    out_faces = np.isin(split.body, np.flatnonzero(flat))
    num_input = int(split.source_face.max()) + 1 if len(split.source_face) else 0
    mask = np.zeros(num_input, dtype=bool)
    mask[split.source_face[out_faces]] = True
    return mask


def fin_record(count: int, dropped: bool, where: tuple[float, ...]) -> RepairRecord:
    """The record of fins cut off a solid (thickened later as sheets, or dropped)."""
    if dropped:
        detail = (f"dropped {count} faces of fins or sheets hinged on a solid (zero thickness, no inside; to keep "
                  "them as thickened sheets: --set repair.fins=thicken)")
    else:
        detail = (f"cut {count} faces of fins or sheets hinged on a solid off along their hinge edges, to be "
                  "thickened as sheets of their own (to leave them out: --set repair.fins=drop; to refuse: "
                  "--set repair.fins=error)")
    return RepairRecord("dropped_fins" if dropped else "detached_fins", detail, count=count, where=where)


def empty_record(count: int, where: tuple[float, ...]) -> RepairRecord:
    """The record of closed bodies with no volume that were left out."""
    return RepairRecord("dropped_empty_bodies", f"dropped {count} faces of closed bodies that enclose no volume "
                        "(a sheet folded onto itself: no material; to refuse instead: --set repair.fins=error)",
                        count=count, where=where)
