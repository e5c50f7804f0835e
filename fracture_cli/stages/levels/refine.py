"""One level-1 fragment broken again: its children and its body's impact data (docs/ALGORITHM.md section 13).

Two steps per fragment, each a function of that fragment alone (so the stage runs them on
``--jobs`` workers and the bytes do not depend on the count):

1. :func:`plan_refinement`: the fracture modes of its piece's tets (their own solve, the
   level-1 material weights) and the atomic pieces they make, sized against the fragment's
   own volume: how many children it would get.
2. :func:`refine`: the regions of those pieces, grown over every tet near the fragment and
   smoothed, cut from the fragment's mesh (so the children's outer surface and the faults to
   the fragment's neighbours are the fragment's own faces, split where a new fault meets
   them), checked, simplified, given collision parts and mass properties; and the body's
   runtime arrays (contact sites on the piece's tets, ``B``, ``W``, bonds among the children).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from fracture_cli.errors import FractureError
from fracture_cli.geometry import trigeom
from fracture_cli.geometry.scenes import surface_scene
from fracture_cli.geometry.surface_query import distances
from fracture_cli.geometry.tetgeom import triangle_areas
from fracture_cli.io.physics import fragment_physics
from fracture_cli.runtime.data import RuntimeData
from fracture_cli.stages.collision import collision
from fracture_cli.stages.fragments import fragments_with_split
from fracture_cli.stages.fragments.cracks import crack_segments
from fracture_cli.stages.fragments.interfaces import fragments_graph
from fracture_cli.stages.fragments.resolve import separate_pinched_vertices
from fracture_cli.stages.levels.options import STAGE, LevelsOptions
from fracture_cli.stages.levels.submesh import (
    covering_tets,
    manifold_cover,
    propagate_labels,
    submesh,
    submesh_eta,
)
from fracture_cli.stages.modes import modes
from fracture_cli.stages.pieces import PiecesOptions, pieces
from fracture_cli.stages.runtime.build import site_coefficients
from fracture_cli.stages.simplify import simplify, skipped
from fracture_cli.stages.smooth import smooth
from fracture_cli.system import detmath
from fracture_cli.types import Fragments, Pieces, Regions, SurfaceMesh, TetMesh

log = logging.getLogger(__name__)

# A piece with fewer tets than this is not broken again (too coarse for modes and smooth faults).
MIN_TETS = 12
# A child face counts as on its parent's surface within this distance (normalized units, diagonal 1): the simplify
# stage moves outer corners within coplanar patches of the parent's triangles, which are flat to ~1e-9.
ON_PARENT = 1e-7

CheckFunction = Callable[[SurfaceMesh, Fragments], tuple[Fragments, dict]]


@dataclass(frozen=True, eq=False)
class Context:
    """What every fragment's refinement reads (shared with the forked workers, never pickled).

    Attributes
    ----------
    tet_mesh : TetMesh
        The bake's tet mesh (``t`` tets).
    tet_piece : (t,) int
        Level-1 piece of every tet.
    eta : (f,) or (f, d) float or None
        Material weights of its interior faces.
    fragments : Fragments
        The level-1 fragments as written.
    options : LevelsOptions
    stages : dict of str -> options
        The options the level-1 stages ran with (``modes``, ``pieces``, ``smooth``, ``fragments``,
        ``simplify``, ``collision``, ``runtime``): the children are made the same way.
    radius, threshold : float
        The level-1 runtime file's impact radius and default threshold.
    check : callable or None
        ``check(surface, fragments) -> (fragments, checks)``: the report's checks of fragments cut from
        ``surface`` (the pipeline's :func:`fracture_cli.checks.checked_fragments`); None: not checked.
    """

    tet_mesh: TetMesh
    tet_piece: np.ndarray
    eta: np.ndarray | None
    fragments: Fragments
    options: LevelsOptions
    stages: dict
    radius: float
    threshold: float
    check: CheckFunction | None = None


@dataclass(frozen=True, eq=False)
class Plan:
    """The modes and pieces of one fragment's tets (step 1).

    Attributes
    ----------
    fragment : int
        The level-1 fragment.
    tets : (q,) int64
        Its piece's tets, ascending.
    U : (k, q, d) float64
        The modes on them.
    pieces : Pieces
        The atomic pieces of those modes (merged below ``min_fragment_fraction`` of the fragment).
    """

    fragment: int
    tets: np.ndarray
    U: np.ndarray
    pieces: Pieces

    @property
    def children(self) -> int:
        """How many children the fragment is expected to break into (its pieces)."""
        return self.pieces.num_pieces


@dataclass(frozen=True, eq=False)
class Refinement:
    """A fragment broken into its children (step 2).

    Attributes
    ----------
    fragment : int
        The parent (a level-1 fragment).
    children : Fragments
        Closed one-body children (normalized coordinates), in stable order; ``input_volume`` is the parent's.
    parts : tuple of tuple of (k, 3) float64
        Convex collision parts of every child, model space.
    physics : tuple of FragmentPhysics
        Mass properties, pivot and parts of every child (:func:`fracture_cli.io.physics.fragment_physics`).
    body : dict of str -> array
        The body's runtime arrays: ``sites (s, 3)``, ``B (s, k, d)``, ``W (k, c, d)``, ``edges (e, 2)`` (local
        child indices), ``edge_areas (e,)``; with the stress criterion ``site_bonds_ptr``, ``site_bonds``,
        ``site_bond_gain``, ``bond_strength``; with damage ``crack_ptr``, ``crack_segments``.
    checks : dict
        The children's checks (the pipeline's, and the nesting: ``volume_error`` against the parent,
        ``parent_area_error``, ``parent_distance``).
    """

    fragment: int
    children: Fragments
    parts: tuple
    physics: tuple
    body: dict
    checks: dict


def parent_surface(fragments: Fragments, index: int) -> SurfaceMesh:
    """Level-1 fragment ``index`` as the closed surface its children are cut from (its materials, UVs, normals)."""
    frag = fragments.fragments[index]
    return SurfaceMesh(vertices=frag.vertices, faces=frag.faces, uvs=frag.uvs, normals=frag.normals, colors=None,
                       material_ids=frag.material_ids, materials=fragments.materials,
                       normalization=fragments.normalization, name=f"fragment {index}")


def plan_refinement(ctx: Context, index: int) -> Plan | str:
    """Step 1 for level-1 fragment ``index``: the modes and pieces of its piece's tets, or why it stays whole."""
    piece = ctx.fragments.fragments[index].piece
    tets = np.flatnonzero(np.asarray(ctx.tet_piece) == piece)
    if len(tets) < MIN_TETS:
        return f"its piece has {len(tets)} tets (fewer than {MIN_TETS})"
    sub = submesh(ctx.tet_mesh, tets)
    base = ctx.stages["modes"]
    d = int(base.dim)
    k = min(int(ctx.options.num_modes), d * (len(tets) - 1), d * (sub.num_vertices - 3))
    try:
        result = modes(sub, dataclasses.replace(base, num_modes=k), eta=submesh_eta(ctx.tet_mesh, tets, sub, ctx.eta))
        split = pieces(sub, result, PiecesOptions(min_fragment_fraction=ctx.options.min_fragment_fraction,
                                                  deviation_warning=ctx.stages["pieces"].deviation_warning),
                       surface=parent_surface(ctx.fragments, index))
    except FractureError as exc:
        return f"its modes could not be computed ({exc})"
    if split.num_pieces < 2:
        return "its modes make one piece"
    return Plan(fragment=index, tets=tets, U=np.asarray(result.U, dtype=np.float64), pieces=split)


def refine_fragment(ctx: Context, plan: Plan) -> Refinement | str:
    """Step 2: the children of ``plan.fragment`` and its body's data, or why it stays whole (a message)."""
    try:
        return _refine(ctx, plan)
    except FractureError as exc:
        return f"its children could not be made ({exc})"


def _refine(ctx: Context, plan: Plan) -> Refinement | str:
    surface = parent_surface(ctx.fragments, plan.fragment)
    regions = _child_regions(ctx, plan, surface)
    children, _ = fragments_with_split(surface, regions, ctx.stages["fragments"])
    if len(children.fragments) < 2:
        return "its cut gives one child"
    children, checks = _simplified(ctx, surface, children)
    if len(children.fragments) < 2:
        return "its children merge into one"
    base = ctx.stages["collision"]
    parts, collision_checks = collision(children, dataclasses.replace(
        base, max_parts=min(int(base.max_parts), int(ctx.options.max_parts))))
    physics = tuple(fragment_physics(children, parts, children.pivot))
    checks = {**checks, **collision_checks, **nesting(surface, children)}
    return Refinement(fragment=plan.fragment, children=children, parts=parts, physics=physics,
                      body=body_arrays(ctx, plan, children, parts), checks=checks)


def _child_regions(ctx: Context, plan: Plan, surface: SurfaceMesh) -> Regions:
    """Closed regions, one per child piece, that partition every tet near the parent (its faults smoothed)."""
    cover = manifold_cover(ctx.tet_mesh, covering_tets(ctx.tet_mesh, surface.vertices.min(axis=0),
                                                       surface.vertices.max(axis=0)))
    labels = np.full(len(cover), -1, dtype=np.int64)
    where = np.searchsorted(cover, plan.tets)
    inside = (where < len(cover)) & (cover[np.minimum(where, len(cover) - 1)] == plan.tets)
    labels[where[inside]] = np.asarray(plan.pieces.tet_piece, dtype=np.int64)[inside]
    labels = propagate_labels(ctx.tet_mesh, cover, labels)
    mesh = submesh(ctx.tet_mesh, cover)
    p = plan.pieces.num_pieces
    volumes = np.bincount(labels, weights=np.abs(mesh.tet_volumes), minlength=p)
    grown = dataclasses.replace(plan.pieces, tet_piece=labels.astype(np.int32), volumes=volumes)
    options = ctx.stages["smooth"]
    options = dataclasses.replace(options, smoothing=float(options.smoothing) * ctx.options.smoothing_factor)
    return smooth(mesh, grown, options, surface=None)


def _simplified(ctx: Context, surface: SurfaceMesh, children: Fragments) -> tuple[Fragments, dict]:
    """The children checked, simplified (as the level-1 ``simplify`` stage does), and checked again."""
    checks: dict = {}
    options = ctx.stages["simplify"]
    if not skipped(surface, options):
        children = simplify(children, surface, options)[0]
    children, moved = separate_pinched_vertices(children)
    if ctx.check is not None:  # once, as written (level 1 checks before simplifying too: a fraction of the time)
        children, checks = ctx.check(surface, children)
    checks["separated_vertices"] = moved
    checks["triangles"] = sum(len(f.faces) for f in children.fragments)
    return children, checks


def nesting(parent: SurfaceMesh, children: Fragments) -> dict[str, float]:
    """How exactly ``children`` nest in ``parent`` (normalized units).

    Returns
    -------
    dict
        ``volume_error``: |sum of the children's volumes - the parent's| / the parent's;
        ``parent_area_error``: |area of the children's faces on the parent's surface (centroid within
        :data:`ON_PARENT`) - the parent's area| / the parent's area (0: the children's outer faces tile the
        parent's surface, its faults to its neighbours included); ``parent_distance``: the largest distance
        from a corner of such a face to the parent's surface.
    """
    query = surface_scene(parent.vertices, parent.faces)
    volume = trigeom.signed_volume(parent.vertices, parent.faces)
    total = sum(trigeom.signed_volume(f.vertices, f.faces) for f in children.fragments)
    area = float(triangle_areas(parent.vertices, parent.faces).sum())
    on_area, worst = 0.0, 0.0
    for frag in children.fragments:
        centroids = frag.vertices[frag.faces].mean(axis=1)
        on = distances(query, centroids) <= ON_PARENT
        on_area += float(triangle_areas(frag.vertices, frag.faces[on]).sum())
        corners = np.unique(frag.faces[on])
        if len(corners):
            worst = max(worst, float(distances(query, frag.vertices[corners]).max()))
    return {"volume_error": float(abs(total - volume) / volume), "parent_area_error": float(abs(on_area - area) / area),
            "parent_distance": worst}


def body_arrays(ctx: Context, plan: Plan, children: Fragments, parts: tuple | None = None) -> dict[str, np.ndarray]:
    """The body's runtime arrays (see :class:`Refinement`), in the asset's units, float32/int32 as written.

    ``parts``: the children's collision parts (model space), where the stress criterion's blocks model places
    every site's hit.
    """
    sub = submesh(ctx.tet_mesh, plan.tets)
    volume = float(np.abs(sub.tet_volumes).sum())
    scale = np.sqrt(volume)  # unit-RMS modes over the body, a unit-mass impulse (ALGORITHM.md section 8)
    radius = ctx.radius * ctx.options.radius_factor
    sites = sub.boundary_vertices
    B = site_coefficients(sub, plan.U, detmath.square(radius))[sites] * scale
    order = np.array([f.piece for f in children.fragments], dtype=np.int64)
    W = np.asarray(plan.pieces.W, dtype=np.float64)[:, order] * scale
    edges, areas = fragments_graph(children)
    sort = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, areas = edges[sort], areas[sort]
    norm = ctx.tet_mesh.normalization
    body: dict[str, Any] = {
        "sites": norm.to_world(sub.vertices[sites]).astype(np.float32),
        "B": B.astype(np.float32),
        "W": W.astype(np.float32),
        "edges": edges.astype(np.int32).reshape(-1, 2),
        "edge_areas": (areas * detmath.square(norm.scale)).astype(np.float32),
    }
    runtime = ctx.stages["runtime"]
    if runtime.criterion == "stress":
        body.update(_stress(ctx, plan, sub, children, (edges, areas), body, parts))
    if runtime.damage:
        body["crack_ptr"], body["crack_segments"] = crack_segments(children, edges)
    return body


def _stress(ctx: Context, plan: Plan, sub: TetMesh, children: Fragments, graph: tuple[np.ndarray, np.ndarray],
            body: dict, parts: tuple | None = None) -> dict[str, np.ndarray]:
    """The stress criterion's arrays of the body (:func:`fracture_cli.stages.stress.stage.with_stress` on its tets)."""
    # on first use: the elasticity solve loads only for the stress criterion
    from fracture_cli.stages.stress.stage import with_stress

    data = RuntimeData(sites=body["sites"], B=body["B"], W=body["W"], edges=body["edges"],
                       edge_areas=body["edge_areas"], fragment_names=tuple(str(j) for j in range(len(body["W"][0]))))
    options = dataclasses.replace(ctx.stages["runtime"], radius=ctx.radius * ctx.options.radius_factor)
    stressed = with_stress(data, sub, plan.pieces, children, submesh_eta(ctx.tet_mesh, plan.tets, sub, ctx.eta), graph,
                           options, parts=parts)
    return {name: np.asarray(value) for name, value in stressed.stress.items()}


__all__ = ["STAGE", "Context", "LevelsOptions", "Plan", "Refinement", "nesting", "parent_surface",
           "plan_refinement", "refine_fragment"]
