"""Repair: closing open surfaces, by filling holes that close into a solid or thickening sheets inward."""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.edges import edge_table, face_bodies
from fracture_cli.geometry.solids import POS, SplitMesh
from fracture_cli.stages.repair.carry import after_fill, after_thicken
from fracture_cli.stages.repair.holes import FillOptions, FillPlan, fill_holes, plan_fill
from fracture_cli.stages.repair.orient import sheet_faces_away
from fracture_cli.stages.repair.records import RepairRecord
from fracture_cli.stages.repair.thicken import thicken_inward
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Material

_INTERIOR_COLOR = (0.55, 0.5, 0.45, 1.0)


def interior_slot(materials: tuple[Material, ...]) -> tuple[int, tuple[Material, ...]]:
    """Index of the interior material (the input's own, or a new last slot) and the material tuple."""
    for i, m in enumerate(materials):
        if m.name == INTERIOR_MATERIAL_NAME:
            return i, materials
    return len(materials), materials + (Material(INTERIOR_MATERIAL_NAME, base_color=_INTERIOR_COLOR),)


def open_bodies(mesh: SplitMesh) -> list[np.ndarray]:
    """Face indices of every body (faces joined across two-face edges) that has an edge with one face."""
    table = edge_table(mesh.welded)
    if not (table.count == 1).any():
        return []  # closed: no bodies to find
    body = face_bodies(table)
    is_open = np.zeros(int(body.max()) + 1 if len(body) else 0, dtype=bool)
    is_open[body[table.face[table.count[table.edge] == 1]]] = True
    return [np.flatnonzero(body == b) for b in np.flatnonzero(is_open).tolist()]


def fill_where_planned(mesh: SplitMesh, options: FillOptions,
                       interior_material: int) -> tuple[SplitMesh, FillPlan, list[RepairRecord]]:
    """Decide per open body whether its holes close into a solid (:func:`~fracture_cli.stages.repair.holes.plan_fill`)
    and fill those; the bodies decided ``thicken`` are left open."""
    V = mesh.props[:, POS]
    plan = plan_fill(V, mesh.welded, options)
    if not any(b.action == "fill" for b in plan.bodies):
        return mesh, plan, list(plan.records)
    filled = fill_holes(V, mesh.welded, plan)
    mesh = after_fill(mesh, filled, plan.loops_to_fill(), interior_material)
    return mesh, plan, list(plan.records) + list(filled.records)


def thicken_sheets(mesh: SplitMesh, thickness: float, box: np.ndarray, shading: bool,
                   interior_material: int) -> tuple[SplitMesh, list[RepairRecord]]:
    """Thicken every open body inward (behind its visible side), inside ``box`` (2, 3).

    Along an axis where ``box`` is thinner than ``thickness`` (a flat or nearly
    flat sheet), the box is widened by ``thickness`` on both sides: such a sheet
    can only grow behind itself.
    """
    box = np.array(box, dtype=np.float64)
    thin = box[1] - box[0] < thickness
    box[0, thin] -= thickness
    box[1, thin] += thickness
    records: list[RepairRecord] = []
    for body in open_bodies(mesh)[::-1]:  # last first: thickening appends faces, earlier ids stay valid
        if sheet_faces_away(mesh.props, mesh.welded[body], shading):
            faces = mesh.faces.copy()
            faces[body] = faces[body][:, ::-1]
            mesh = SplitMesh(mesh.props, faces, mesh.material_ids, mesh.weld)
        sheet = thicken_inward(mesh.props[:, POS], mesh.welded[body], thickness, box=box)
        mesh = after_thicken(mesh, body, sheet, interior_material)
        records += sheet.records
    return mesh, records
