"""The one table of pipeline stages and the runner that executes them.

:data:`STAGES` says, for every stage, its name (the recipe section, the CLI
command and the report's key), its options class, what it consumes from the
:class:`PipelineState` and what it produces. ``bake``, the recipe sections,
the CLI chain, its ``--help`` and the report's stage list are all generated
from it, so they cannot disagree. :class:`Runner` runs one stage at a time:
it logs, times, caches (``--cache``) and reports progress for each.
"""

from __future__ import annotations

import dataclasses
import importlib
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, overload

from fracture_cli.errors import UsageError

if TYPE_CHECKING:  # numpy and the types only for annotations: `fracture --help` imports neither
    import numpy as np

    from fracture_cli.checks import CheckValue
    from fracture_cli.runtime.aligned_data import AlignedData
    from fracture_cli.runtime.format import RuntimeData
    from fracture_cli.stages.aligned.options import AlignedOptions
    from fracture_cli.stages.anchors import AnchorOptions
    from fracture_cli.stages.cage import CageOptions
    from fracture_cli.stages.collision import CollisionOptions
    from fracture_cli.stages.faults import FaultOptions
    from fracture_cli.stages.fragments import FragmentOptions
    from fracture_cli.stages.levels import Levels
    from fracture_cli.stages.levels.options import LevelsOptions
    from fracture_cli.stages.load import LoadOptions
    from fracture_cli.stages.material import MaterialOptions
    from fracture_cli.stages.modes import ModesOptions
    from fracture_cli.stages.pattern import PatternOptions
    from fracture_cli.stages.pieces import PiecesOptions
    from fracture_cli.stages.repair import RepairOptions
    from fracture_cli.stages.repair.records import RepairRecord
    from fracture_cli.stages.runtime import RuntimeOptions
    from fracture_cli.stages.simplify import SimplifyOptions
    from fracture_cli.stages.smooth import SmoothOptions
    from fracture_cli.stages.tetra import TetraOptions
    from fracture_cli.types import Anchors, Cage, Fragments, Modes, Pieces, Regions, SurfaceMesh, TetMesh

log = logging.getLogger(__name__)



@dataclass(frozen=True)
class PipelineState:
    """What the pipeline has produced so far; each stage fills its fields (see :data:`STAGES`)."""

    source: str | None = None  # the input file
    source_sha256: str | None = None  # digest of the bytes the load read (the asset and its companions)
    source_files: tuple = ()  # (io.inputs.FileRead, ...): each file as the load read it, the asset first
    loaded: SurfaceMesh | None = None  # as read, before repair
    surface: SurfaceMesh | None = None  # the solid every later stage uses
    repairs: tuple[RepairRecord, ...] = ()  # what the repair stage did (report.json ``repairs``)
    cage: Cage | None = None
    tet_mesh: TetMesh | None = None
    eta: np.ndarray | None = None  # (f,) or (f, d) material weights of the interior faces
    cells: np.ndarray | None = None  # (t,) an authored pattern's cell of every tet (None: the modes decide)
    modes: Modes | None = None
    pieces: Pieces | None = None
    regions: Regions | None = None
    fragments: Fragments | None = None
    collision: tuple | None = None  # convex parts of every fragment, model space (stages.collision.Parts)
    physics: tuple | None = None  # (io.physics.FragmentPhysics, ...): mass, pivot and parts of every fragment
    checks: dict[str, CheckValue] | None = None  # what the report says of the fragments
    anchors: Anchors | None = None  # the fragments held by the world (none unless the recipe's [anchors] asks)
    runtime: RuntimeData | None = None
    aligned: AlignedData | None = None  # the aligned-fracture companion file (None: the recipe did not ask)
    levels: Levels | None = None  # fragments broken again (None or no refinement: one level)
    stage_options: dict[str, Any] = field(default_factory=dict)  # the options each stage ran with (the runner's)

    # One overload per field kind: a stage gets its input with its type (no Any on the spine).
    @overload
    def need(self, name: Literal["source", "source_sha256"], stage: str) -> str: ...
    @overload
    def need(self, name: Literal["loaded", "surface"], stage: str) -> SurfaceMesh: ...
    @overload
    def need(self, name: Literal["cage"], stage: str) -> Cage: ...
    @overload
    def need(self, name: Literal["tet_mesh"], stage: str) -> TetMesh: ...
    @overload
    def need(self, name: Literal["eta"], stage: str) -> np.ndarray: ...
    @overload
    def need(self, name: Literal["modes"], stage: str) -> Modes: ...
    @overload
    def need(self, name: Literal["pieces"], stage: str) -> Pieces: ...
    @overload
    def need(self, name: Literal["regions"], stage: str) -> Regions: ...
    @overload
    def need(self, name: Literal["fragments"], stage: str) -> Fragments: ...
    @overload
    def need(self, name: Literal["runtime"], stage: str) -> RuntimeData: ...

    def need(self, name: str, stage: str) -> object:
        """The field ``name``, or a usage error naming the stage that produces it."""
        value = getattr(self, name)
        if value is None:
            producer = next(s.name for s in STAGES if name in s.produces)
            what = "load PATH" if producer == "load" else producer
            raise UsageError(f"'{stage}' needs {_NOUNS.get(name, name)}: put '{what}' before it in the chain")
        return value


_NOUNS = {"surface": "a surface", "cage": "a cage", "tet_mesh": "a tet mesh", "modes": "modes",
          "pieces": "pieces", "regions": "piece regions", "fragments": "fragments", "anchors": "anchors",
          "runtime": "runtime data"}

StageFunction = Callable[[PipelineState, Any], PipelineState]


@dataclass(frozen=True)
class Stage:
    """One row of the pipeline table.

    Attributes
    ----------
    name : str
        Recipe section, CLI command and report key.
    help : str
        One line for ``--help``.
    options : str
        ``module:Class`` of the options dataclass (imported on demand, so the CLI starts fast).
    run : callable
        ``run(state, options) -> state``: calls the stage function with what it consumes.
    consumes, uses, produces : tuple of str
        :class:`PipelineState` fields it needs, reads when present, and fills.
    cached : bool
        Whether ``--cache`` stores its result (the expensive geometry: cage, tets, modes).
    short : dict of str -> str
        Short CLI flags for option fields.
    """

    name: str
    help: str
    options: str
    run: StageFunction
    consumes: tuple[str, ...]
    produces: tuple[str, ...]
    uses: tuple[str, ...] = ()
    cached: bool = False
    short: dict[str, str] = field(default_factory=dict)

    @property
    def options_class(self) -> type:
        module, name = self.options.split(":")
        return getattr(importlib.import_module(module), name)


# ---------------------------------------------------------------------------
# What each stage calls. Imports are local so `fracture --help` does not load the geometry stack.

def _load(state: PipelineState, options: LoadOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.io.inputs import digest_of, input_files, recording_reads
    from fracture_cli.stages.load import load_surface

    path = state.need("source", "load")
    # The key of the input is the hash of the bytes the readers used (an edit during the bake, undone
    # later, must not leave these outputs vouched for by the other bytes' hash).
    with recording_reads() as reads:
        surface = load_surface(path, options)
    files = reads.as_read(input_files(path))
    return dataclasses.replace(state, loaded=surface, surface=surface, source_sha256=digest_of(files),
                               source_files=files)


def _repair(state: PipelineState, options: RepairOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.repair import repair_surface

    # Cage and fragments both use the repaired solid, so they agree on what is inside.
    result = repair_surface(state.need("surface", "repair"), options)
    return dataclasses.replace(state, surface=result.surface, repairs=result.records)


def _cage(state: PipelineState, options: CageOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.cage import cage

    return dataclasses.replace(state, cage=cage(state.need("surface", "cage"), options))


def _tetra(state: PipelineState, options: TetraOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.tetra import tetra

    return dataclasses.replace(state, tet_mesh=tetra(state.need("cage", "tetra"), options))


def _material(state: PipelineState, options: MaterialOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.material import material

    return dataclasses.replace(state, eta=material(state.need("tet_mesh", "material"), state.surface, options))


def _pattern(state: PipelineState, options: PatternOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.pattern import pattern

    return dataclasses.replace(state, cells=pattern(state.need("tet_mesh", "pattern"), state.surface, options))


def _modes(state: PipelineState, options: ModesOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.modes import modes

    result = modes(state.need("tet_mesh", "modes"), options, eta=state.eta, cells=state.cells)
    return dataclasses.replace(state, modes=result)


def _pieces(state: PipelineState, options: PiecesOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.pieces import pieces

    # Piece sizes are measured in asset volume: the repaired surface says what is material.
    result = pieces(state.need("tet_mesh", "pieces"), state.need("modes", "pieces"), options, surface=state.surface,
                    cells=state.cells)
    return dataclasses.replace(state, pieces=result)


def _smooth(state: PipelineState, options: SmoothOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.smooth import smooth

    regions = smooth(state.need("tet_mesh", "smooth"), state.need("pieces", "smooth"), options, surface=state.surface)
    return dataclasses.replace(state, regions=regions)


def _faults(state: PipelineState, options: FaultOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.faults import faults

    return dataclasses.replace(state, regions=faults(state.need("regions", "faults"), options))


def _fragments(state: PipelineState, options: FragmentOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.checks import checked_fragments
    from fracture_cli.stages.fragments import fragments_with_split

    surface = state.need("surface", "fragments")
    frags, split = fragments_with_split(surface, state.need("regions", "fragments"), options)
    frags, checks = checked_fragments(surface, dataclasses.replace(frags, pivot=options.pivot))
    # Cuts that fell apart: bodies that became fragments of their own, and tiny ones glued to a neighbour.
    checks["split_bodies"] = sum(split.bodies) - len(split.bodies) - split.merged + split.pinched
    checks["merged_bodies"] = split.merged
    # Fragments added by splitting fragments that pinched as written (fragments/resolve.py).
    checks["pinch_split_bodies"] = split.pinched
    return dataclasses.replace(state, fragments=frags, checks=checks)


def _simplify(state: PipelineState, options: SimplifyOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.checks import checked_fragments
    from fracture_cli.stages.fragments.resolve import PINCH_GAPS, separate_pinched_vertices
    from fracture_cli.stages.simplify import simplify, skipped, triangle_budget

    surface, frags = state.need("surface", "simplify"), state.need("fragments", "simplify")
    before = sum(len(f.faces) for f in frags.fragments)
    if not skipped(surface, options):
        frags = simplify(frags, surface, options)[0]
    # Last of the fragments' geometry: a fragment touching itself at a single vertex gets the copies apart.
    separated, moved = separate_pinched_vertices(frags)
    if moved:
        log.warning("simplify: %d place(s) where a fragment touched itself at a single vertex were moved %.0e to "
                    "%.0e of the diagonal apart", moved, PINCH_GAPS[0], PINCH_GAPS[-1])
    if not skipped(surface, options) or moved:
        frags, checks = checked_fragments(surface, separated)
        if skipped(surface, options):
            checks = {**(state.checks or {}), **checks}
    else:
        checks = dict(state.checks or {})
    # Triangle counts as written, against the budget of issue 20 (input = the solid that was cut).
    checks["separated_vertices"] = moved  # self-touching vertices moved apart (fragments/resolve.py)
    checks["triangles_cut"] = before
    checks["triangles"] = sum(len(f.faces) for f in frags.fragments)
    checks["triangle_budget"] = triangle_budget(len(surface.faces), len(frags.fragments))
    return dataclasses.replace(state, fragments=frags, checks=checks)


def _collision(state: PipelineState, options: CollisionOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.io.physics import fragment_physics
    from fracture_cli.stages.collision import collision

    frags = state.need("fragments", "collision")
    parts, checks = collision(frags, options)
    # Mass properties and pivots once, with the parts: the runtime file and the GLB both carry them.
    physics = tuple(fragment_physics(frags, parts, frags.pivot))
    return dataclasses.replace(state, collision=parts, physics=physics, checks={**(state.checks or {}), **checks})


def _anchors(state: PipelineState, options: AnchorOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.anchors import anchors

    return dataclasses.replace(state, anchors=anchors(state.need("fragments", "anchors"), state.surface, options))


def _runtime(state: PipelineState, options: RuntimeOptions) -> PipelineState:
    # on first use: `fracture --help` loads no stage
    from fracture_cli.geometry import trigeom
    from fracture_cli.io.names import fragment_name
    from fracture_cli.io.physics import fragment_physics, runtime_arrays
    from fracture_cli.stages.fragments.interfaces import fragments_graph
    from fracture_cli.stages.runtime import runtime, with_structure

    frags = state.need("fragments", "runtime")
    order = [int(f.piece) for f in frags.fragments]
    stem = os.path.splitext(os.path.basename(state.need("source", "runtime")))[0]
    names = tuple(fragment_name(i, stem) for i in range(len(order)))  # as the GLB's nodes
    # Bonds where fragments share fault faces: every group the game splits off is connected in space. Where the
    # repaired solid is several bodies (kept apart where they only touch), also where they touch face to face.
    contacts = state.surface is not None and trigeom.face_components(state.surface.faces) > 1
    graph = fragments_graph(frags, contacts=contacts)
    data = runtime(state.need("tet_mesh", "runtime"), state.need("modes", "runtime"), state.need("pieces", "runtime"),
                   options, fragment_pieces=order, fragment_names=names, fragment_graph=graph)
    if options.criterion == "stress":
        # the elasticity solve loads only for the stress criterion
        from fracture_cli.stages.stress.stage import with_stress

        data = with_stress(data, state.need("tet_mesh", "runtime"), state.need("pieces", "runtime"), frags,
                           state.eta, graph, options, parts=state.collision)
    # Mass properties and collision parts for engines that read the runtime file only (FORMAT.md section 8).
    physics = state.physics if state.physics is not None else fragment_physics(frags, state.collision, frags.pivot)
    data = dataclasses.replace(data, gameready=runtime_arrays(physics))
    # Format version 2's structures (docs/FORMAT.md section 12): only what the recipe asks for, so that every
    # other bake keeps its bytes.
    data = with_structure(data, state.anchors, frags, options)
    return dataclasses.replace(state, runtime=data)


def _levels(state: PipelineState, options: LevelsOptions) -> PipelineState:
    if options.count < 2:  # the default: one level, nothing to load, the same bytes
        return dataclasses.replace(state, levels=None)
    # on first use: `fracture --help` loads no stage
    from fracture_cli.pipeline.levels import LEVEL_ONE, run_levels

    # The children are made with the options the level-1 stages ran with (their defaults where a chain skipped one).
    return run_levels(state, options, {name: state.stage_options.get(name) or stage(name).options_class()
                                       for name in LEVEL_ONE})


def _aligned(state: PipelineState, options: AlignedOptions) -> PipelineState:
    if not options.enabled:  # the default: nothing to load
        return dataclasses.replace(state, aligned=None)
    # on first use: `fracture --help` loads no stage
    from fracture_cli.stages.aligned import aligned
    from fracture_cli.stages.simplify.rebuild import uv_scale

    frags = state.need("fragments", "aligned")
    stem = os.path.splitext(os.path.basename(state.need("source", "aligned")))[0]
    # The new faces' UVs continue the bake's box projection of its fault faces (fragments.uv_scale).
    data = aligned(frags, state.collision, options, uv_scale=uv_scale(frags, frags.interior_slot), stem=stem)
    return dataclasses.replace(state, aligned=data)


STAGES: tuple[Stage, ...] = (
    Stage("load", "Read a mesh (OBJ, PLY, STL, OFF, GLB, glTF).", "fracture_cli.stages.load:LoadOptions",
          _load, consumes=("source",), produces=("loaded", "surface", "source_sha256", "source_files")),
    Stage("repair", "Make the surface a closed solid: weld, fix winding, close holes or thicken open sheets.",
          "fracture_cli.stages.repair:RepairOptions", _repair, consumes=("surface",), produces=("surface", "repairs")),
    Stage("cage", "Build the nested cage: a coarse closed surface around the input.",
          "fracture_cli.stages.cage:CageOptions", _cage, consumes=("surface",), produces=("cage",), cached=True),
    Stage("tetra", "Tetrahedralize the cage (TetGen), keeping its surface.", "fracture_cli.stages.tetra:TetraOptions",
          _tetra, consumes=("cage",), produces=("tet_mesh",), cached=True),
    Stage("material", "Set material weights (grain, painted strength, boxes) on the tet faces.",
          "fracture_cli.stages.material:MaterialOptions", _material, consumes=("tet_mesh",), uses=("surface",),
          produces=("eta",)),
    Stage("pattern", "Choose what decides the pieces: the fracture modes, or an authored pattern's cells.",
          "fracture_cli.stages.pattern:PatternOptions", _pattern, consumes=("tet_mesh",), uses=("surface",),
          produces=("cells",)),
    Stage("modes", "Compute the fracture modes of the tet mesh (on the pattern's cells, if any).",
          "fracture_cli.stages.modes:ModesOptions", _modes, consumes=("tet_mesh",), uses=("eta", "cells"),
          produces=("modes",), cached=True, short={"num_modes": "-k"}),
    Stage("pieces", "Split the tet mesh into atomic pieces and build the piece graph.",
          "fracture_cli.stages.pieces:PiecesOptions", _pieces, consumes=("tet_mesh", "modes"),
          uses=("surface", "cells"),
          produces=("pieces",)),
    Stage("smooth", "Smooth the fault surfaces between pieces into closed piece regions.",
          "fracture_cli.stages.smooth:SmoothOptions", _smooth, consumes=("tet_mesh", "pieces"), uses=("surface",),
          produces=("regions",)),
    Stage("faults", "Add value noise to the shared faults (off unless faults.noise > 0); both sides move alike.",
          "fracture_cli.stages.faults:FaultOptions", _faults, consumes=("regions",), produces=("regions",)),
    Stage("fragments", "Cut the input into one closed fragment per piece region, and check them.",
          "fracture_cli.stages.fragments:FragmentOptions", _fragments, consumes=("surface", "regions"),
          produces=("fragments", "checks")),
    Stage("simplify", "Simplify the fragments' faults to a tolerance (outer surface kept), and check them again.",
          "fracture_cli.stages.simplify:SimplifyOptions", _simplify, consumes=("surface", "fragments"),
          produces=("fragments", "checks")),
    Stage("collision", "Convex collision parts per fragment that do not overlap (GLB and runtime file).",
          "fracture_cli.stages.collision:CollisionOptions", _collision, consumes=("fragments",),
          produces=("collision", "physics")),
    Stage("anchors", "Choose the fragments held by the world: on the ground, in boxes, painted (none by default).",
          "fracture_cli.stages.anchors:AnchorOptions", _anchors, consumes=("fragments",), uses=("surface",),
          produces=("anchors",)),
    Stage("runtime", "Precompute the impact-projection data for the game (the runtime file).",
          "fracture_cli.stages.runtime:RuntimeOptions", _runtime,
          consumes=("tet_mesh", "modes", "pieces", "fragments"),
          uses=("collision", "physics", "anchors", "surface"),
          produces=("runtime",)),
    Stage("levels", "Break the largest fragments again into children with their own impact data (off unless "
          "levels.count = 2).", "fracture_cli.stages.levels.options:LevelsOptions", _levels,
          consumes=("tet_mesh", "pieces", "fragments", "runtime"),
          uses=("eta", "anchors", "stage_options"), produces=("levels", "runtime")),
    Stage("aligned", "Convex pieces and fracture patterns for cutting at the hit at runtime (off unless enabled).",
          "fracture_cli.stages.aligned.options:AlignedOptions", _aligned, consumes=("fragments",),
          uses=("collision",), produces=("aligned",)),
)
STAGE_NAMES: tuple[str, ...] = tuple(s.name for s in STAGES)
# The steps a bake reports seconds for: every stage, then writing the outputs.
STEPS: tuple[str, ...] = STAGE_NAMES + ("export",)


def stage(name: str) -> Stage:
    """The row of :data:`STAGES` called ``name``."""
    for s in STAGES:
        if s.name == name:
            return s
    raise KeyError(name)
