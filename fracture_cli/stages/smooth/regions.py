"""The work of the ``smooth`` stage: the chosen method, then closed regions by marching tets or convex cells."""

from __future__ import annotations

import logging

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.stages.smooth.cells import union_regions
from fracture_cli.stages.smooth.field import forced_field, refined, winning_field
from fracture_cli.stages.smooth.geometric import smoothed_vertices
from fracture_cli.stages.smooth.marching import region_defects, repaired_regions
from fracture_cli.stages.smooth.options import STAGE, SmoothOptions
from fracture_cli.stages.smooth.topology import Topology
from fracture_cli.types import Pieces, Regions, SurfaceMesh, TetMesh

log = logging.getLogger(__name__)


def smoothed_regions(tet_mesh: TetMesh, pieces: Pieces, options: SmoothOptions,
                     surface: SurfaceMesh | None = None) -> Regions:
    """The body of :func:`fracture_cli.stages.smooth.smooth` (parameters, results and notes there)."""
    t = tet_mesh.num_tets
    tet_piece = np.asarray(pieces.tet_piece, dtype=np.int64)
    if tet_piece.shape != (t,):
        raise StageError(f"pieces cover {tet_piece.shape[0]} tets but the tet mesh has {t}", stage=STAGE)
    p = pieces.num_pieces
    lam = float(options.smoothing)
    if lam > 0.0 and options.method == "field":
        tet_mesh, tet_piece = refined(tet_mesh, tet_piece, options.refine, options.max_refined_tets)
        t = tet_mesh.num_tets
    V, T = tet_mesh.vertices, tet_mesh.tets
    topo = Topology(T, tet_mesh.num_vertices)

    vanished: list[int] = []
    Z: np.ndarray | None = None
    if lam == 0.0 or options.method == "geometric":
        if lam > 0.0:
            V, moves = smoothed_vertices(tet_mesh, topo, tet_piece, p, lam, surface)
            log.info("%s: geometric smoothing moved %d fault vertices (%d on junction curves, %d slid along the cage, "
                     "%d sent back to keep the cage around the input), %d held back in %d round(s) to keep tets from "
                     "flattening, displacement scale %g", STAGE, moves["moved"], moves["curve"], moves["slid"],
                     moves["reverted"], moves["frozen"], moves["rounds"], moves["alpha"])
        meshes, pinches, repaired = repaired_regions(V, T, topo, None, np.ones(t, dtype=bool), tet_piece, p)
    else:
        Z, vanished, built = winning_field(tet_mesh, topo, tet_piece, pieces, lam, options.vanish_fraction)
        forced, Zv = forced_field(Z, tet_piece, vanished)
        meshes, pinches, repaired = repaired_regions(V, T, topo, Zv, forced, tet_piece, p, first=built)

    broken = [P for P in range(p) if region_defects(*meshes[P])]
    if broken:
        log.warning("%s: %d region(s) were not closed and edge-manifold when built directly (e.g. piece %d); "
                    "rebuilding them as unions of cells", STAGE, len(broken), broken[0])
        rebuilt = union_regions(V, T, Z, tet_piece, p, vanished, broken)
        for P, mesh in zip(broken, rebuilt):
            meshes[P] = mesh
    log.info("%s: %d regions, lambda=%g, %d triangles, %d vanished, %d tet(s) made tet-aligned, %d pinched edge(s) "
             "given a spindle", STAGE, p, lam, sum(len(f) for _, f in meshes), len(vanished), repaired, pinches)
    return Regions(meshes=tuple(meshes), smoothing=lam, vanished=tuple(sorted(vanished)))
