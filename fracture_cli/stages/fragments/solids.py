"""The input solid the fragments are cut from: one manifold3d solid per group of bodies that overlap.

The repair stage unites bodies that overlap and keeps apart those that only
touch (a wheel against the chassis, a lid on its pot; ``repair.touching``).
Where such bodies touch face to face, their vertices coincide, and welding the
repaired surface by position gives edges of four faces; the faces around them
are paired by the non-manifold split of the repair stage (material and empty
wedges), so each body is closed on its own. Each group is then cut by the
regions separately, and no fragment holds parts of two bodies.
"""

from __future__ import annotations

import manifold3d
import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.geometry.meshtopo import boundary_edges, nonmanifold_edges
from fracture_cli.geometry.solids import (
    SOLID_COLUMNS,
    SplitMesh,
    body_groups,
    surface_manifold,
    to_manifold,
    vertex_properties,
    weld_map,
)
from fracture_cli.stages.repair.carry import after_split
from fracture_cli.stages.repair.nonmanifold import split_nonmanifold
from fracture_cli.types import SurfaceMesh


def input_solids(surface: SurfaceMesh, *, stage: str) -> tuple[list[manifold3d.Manifold], dict[int, int]]:
    """The repaired surface as solids, one per group of overlapping bodies (see the module docstring).

    Parameters
    ----------
    surface : SurfaceMesh
        The closed surface of the repair stage (normalized coordinates).
    stage : str
        The calling stage, for error messages.

    Returns
    -------
    solids : list of manifold3d.Manifold
        ``[solid]`` for one body (as :func:`~fracture_cli.geometry.solids.surface_solid`
        gives it); otherwise one per group, in the order of their first body.
    id_to_material : dict of int -> int

    Raises
    ------
    StageError
        If the surface is not closed.
    """
    props = vertex_properties(surface, SOLID_COLUMNS)
    F = np.asarray(surface.faces, dtype=np.int64)
    mesh = SplitMesh(props, F, np.asarray(surface.material_ids), weld_map(props[:, :3], F))
    if not nonmanifold_edges(mesh.welded):
        solid, id_to_material = surface_manifold(surface, stage)
        return body_groups(solid)[0], id_to_material
    split = split_nonmanifold(props[:, :3], mesh.welded)
    if len(split.unresolved_edges) or not split.body_closed.all():
        solid, id_to_material = surface_manifold(surface, stage)
        return body_groups(solid)[0], id_to_material
    solid, id_to_material = to_manifold(after_split(mesh, split), len(surface.materials))
    if solid.status() != manifold3d.Error.NoError:
        boundary = len(boundary_edges(split.faces))
        raise StageError(f"the surface is not a closed solid ({solid.status().name}"
                         + (f", {boundary} open edges" if boundary else "") + "); run the 'repair' stage on it first",
                         stage=stage)
    return body_groups(solid)[0], id_to_material
