"""``bake``: the whole pipeline from an asset and a recipe to game-ready files.

For input ``<stem>`` a bake writes, into the output folder:

* ``<stem>.glb``            one node and mesh per fragment (``fragment_000`` ...);
* ``<stem>.fracture.json``  + ``<stem>.fracture.bin``: the runtime file (docs/FORMAT.md);
* ``<stem>.report.json``    what was done: versions, recipe, counts, checks, seconds.

The stages come from :data:`fracture_cli.pipeline.STAGES`. The four files are
replaced as one set (:mod:`fracture_cli.io.outputs`, docs/OUTPUTS.md): the
output folder is checked before any work, the files are written into a staging
folder and published under a per-stem lock, the report last with the other
files' hashes; a failed or interrupted bake leaves the previous set. Meshes and runtime file are
byte-identical for the same input, recipe and tool version; so is the report,
except for its ``seconds`` block. :func:`bake_many` bakes a batch.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fracture_cli import __version__
from fracture_cli.errors import FractureError, UsageError
from fracture_cli.geometry import trigeom
from fracture_cli.io.inputs import estimate_output_bytes, input_files
from fracture_cli.io.names import fragment_name
from fracture_cli.io.outputs import output_set
from fracture_cli.io.preflight import check_inputs_untouched, guard_outputs, preflight
from fracture_cli.pipeline import STAGE_NAMES, STEPS, PipelineState
from fracture_cli.pipeline.cache import file_sha256
from fracture_cli.pipeline.recipe import Recipe
from fracture_cli.pipeline.runner import Runner
from fracture_cli.system import numeric_env
from fracture_cli.system.interrupts import caused_by_interrupt
from fracture_cli.types import Fragments

__all__ = ["STAGES", "BakeResult", "BatchItem", "bake", "bake_many", "describe_error", "file_sha256",
           "fragment_summary", "run_pipeline", "step_seconds", "structure_summary", "write_outputs"]

log = logging.getLogger(__name__)

# The steps of a bake, in order (the report's ``seconds`` keys).
STAGES = STEPS


@dataclass(frozen=True)
class BakeResult:
    """What a bake produced: the report, the paths of the files written and the input files as read.

    ``inputs`` holds one :class:`~fracture_cli.io.inputs.FileRead` per file the
    outputs depend on (the asset first), hashed from the bytes the load read,
    so a caller that records "these inputs give these outputs" (an incremental
    batch) records what was baked, not what was on disk before or after.
    """

    report: dict[str, Any]
    outputs: tuple[str, ...]
    inputs: tuple = ()


@dataclass(frozen=True)
class BatchItem:
    """The outcome of one input of :func:`bake_many`: a result, or an error line naming the input."""

    input_path: str
    result: BakeResult | None = None
    error: str | None = None
    exception: BaseException | None = None


def fragment_summary(fragments: Fragments, stem: str | None = None) -> list[dict[str, Any]]:
    """Per-fragment summary for reports and golden files (input units); names as the GLB's nodes."""
    out = []
    scale = fragments.normalization.scale
    for i, frag in enumerate(fragments.fragments):
        world = fragments.normalization.to_world(frag.vertices)
        out.append({
            "name": fragment_name(i, stem),
            "piece": int(frag.piece),
            "triangles": int(len(frag.faces)),
            "volume": float(trigeom.signed_volume(frag.vertices, frag.faces) * scale * scale * scale),
            "bbox_min": [float(x) for x in world.min(axis=0)],
            "bbox_max": [float(x) for x in world.max(axis=0)],
        })
    return out


def structure_summary(state: PipelineState, stem: str | None = None) -> dict[str, Any]:
    """What the report says of a structure (docs/FORMAT.md section 12): anchored fragments, damage, cracks.

    ``anchored`` names the fragments bonded to the world (as the GLB's nodes), ``anchor_rules`` which rule
    picked which, ``anchors`` is the runtime header's object, ``damage`` its ``crack_level`` and
    ``damage_rate`` (None: hits are judged alone), ``crack_segments`` and ``bonds_with_cracks`` count the
    crack lines written.
    """
    data = state.need("runtime", "export")
    names = [fragment_name(i, stem) for i in range(data.p)]
    anchored = [] if data.anchored is None else [names[j] for j in np.flatnonzero(data.anchored == 1).tolist()]
    rules = {} if state.anchors is None else {
        rule: [names[j] for j in np.flatnonzero(which).tolist()] for rule, which in state.anchors.rules.items()}
    ptr = data.cracks.get("crack_ptr")
    return {
        "anchored": anchored,
        "anchor_rules": rules,
        "anchors": dict(data.anchors_info),
        "damage": dict(data.damage) if data.damage else None,
        "crack_segments": 0 if ptr is None else int(ptr[-1]),
        "bonds_with_cracks": 0 if ptr is None else int(np.count_nonzero(np.diff(ptr))),
    }


def stem_of(path: str) -> str:
    """The output name of an input file: its base name without the extension."""
    return os.path.splitext(os.path.basename(path))[0]


def bake(input_path: str, out_dir: str, recipe: Recipe, cache_dir: str | None = None,
         jobs: int | None = None, preview_size: tuple[int, int] | None = None,
         started: float | None = None) -> BakeResult:
    """Run the whole pipeline on one asset and write its outputs.

    Parameters
    ----------
    input_path : str
        The asset (any format :func:`~fracture_cli.stages.load.load_surface` reads).
    out_dir : str
        Output folder; created if missing.
    recipe : Recipe
        The destructible material: options of every stage.
    cache_dir : str, optional (default None)
        Folder of a :class:`~fracture_cli.pipeline.cache.StageCache`: the cage, tets and
        modes are reused when nothing they depend on changed.
    jobs : int, optional (default None: every core)
        Processes the stages may use for independent work (see :mod:`fracture_cli.system.parallel`); the
        outputs are the same bytes for any value.
    preview_size : (int, int), optional (default None: no preview)
        Also render ``<stem>.preview.png`` of this size (width, height) into the
        output set. Without it an older preview is removed when the new set is
        published (it would show other fragments than the files beside it).
    started : float, optional (default None: this call)
        When the bake began on the :func:`time.monotonic` clock; the CLI passes the process's start
        (:func:`fracture_cli.system.clock.process_origin`) so that the report's ``startup`` (to the first
        stage) and ``total`` (to the published outputs) count the interpreter and every import too.

    Returns
    -------
    BakeResult

    Raises
    ------
    FractureError
        On bad input or a stage that cannot finish; no output is then written.
        Every error names the input file, so a batch log says which asset
        failed. Any other exception is a bug; it carries the input file and
        stage as attributes for :func:`describe_error`.
    """
    origin = time.monotonic() if started is None else started
    try:
        stem = stem_of(input_path)
        depends = input_files(input_path)
        preflight(out_dir, stem, inputs=depends, estimate_bytes=estimate_output_bytes(depends))
        cache = None
        if cache_dir is not None:
            # on first use: keeps `fracture` start-up light
            from fracture_cli.pipeline.cache import StageCache

            cache = StageCache(cache_dir)
        runner = Runner(f"bake {stem}", total=len(STEPS), cache=cache, jobs=jobs, origin=origin)
        if not numeric_env.pinned():
            log.warning("%s: numeric kernels not pinned (%s): the outputs may differ from another machine's", stem,
                        numeric_env.unpinned_because())
        state = run_pipeline(input_path, recipe, runner)
        report = build_report(state, recipe, runner)
        outputs = write_outputs(out_dir, stem, state, report, runner, preview_size)
        return BakeResult(report=report, outputs=outputs, inputs=state.source_files)
    except FractureError as exc:
        if exc.path is None:
            exc.path = input_path
        raise
    except Exception as exc:
        exc.fracture_input = input_path  # type: ignore[attr-defined]
        raise


def run_pipeline(input_path: str, recipe: Recipe, runner: Runner) -> PipelineState:
    """Every stage of :data:`~fracture_cli.pipeline.STAGES` on one input, with the recipe's options."""
    state = PipelineState(source=input_path)
    for name in STAGE_NAMES:
        state = runner.run(name, state, recipe[name])
    return state


def build_report(state: PipelineState, recipe: Recipe, runner: Runner) -> dict[str, Any]:
    """The bake report (without ``seconds``) of a finished pipeline ``state``.

    ``recipe`` names the recipe; the parameters are those the stages ran with
    (``runner.options``), so a chain with changed flags reports what it did.
    """
    # on first use: keeps `fracture` start-up light
    from fracture_cli.stages.repair.report import records_for_report

    loaded, surface = state.need("loaded", "export"), state.need("surface", "export")
    frags, data = state.need("fragments", "export"), state.need("runtime", "export")
    used = dataclasses.replace(recipe, options={**recipe.options, **runner.options})
    cage, tet_mesh, modes, pieces = state.cage, state.tet_mesh, state.modes, state.pieces
    stem = stem_of(state.need("source", "export"))
    report: dict[str, Any] = {
        "tool": "fracture",
        "version": __version__,
        # The numeric kernels and the versions of what computes the outputs (same values: same bytes).
        "numerics": numeric_env.environment(),
        "input": {"name": os.path.basename(state.need("source", "export")), "sha256": state.source_sha256,
                  "triangles": loaded.num_faces, "vertices": loaded.num_vertices,
                  "scale": surface.normalization.scale},
        "recipe": {"name": recipe.name, "chain": list(recipe.chain), "description": recipe.description,
                   "parameters": used.to_dict()},
        "counts": {
            "cage_faces": int(len(cage.faces)) if cage is not None else None,
            "cage_offset": float(cage.offset) if cage is not None else None,
            "tets": tet_mesh.num_tets if tet_mesh is not None else None,
            "modes": modes.num_modes if modes is not None else None,
            "mode_pieces": [int(c) for c in modes.piece_counts] if modes is not None else None,
            "pieces": pieces.num_pieces if pieces is not None else None,
            "fragments": len(frags.fragments),
            "bonds": int(data.num_edges),
            "contact_sites": int(data.num_sites),
        },
        "checks": dict(state.checks or {}),
        "repairs": records_for_report(state.repairs, surface.normalization),
        "fragments": fragment_summary(frags, stem),
        "structure": structure_summary(state, stem),
        "outputs": [f"{stem}.glb", f"{stem}.fracture.json", f"{stem}.fracture.bin", f"{stem}.report.json"],
    }
    if state.levels is not None:  # fragments broken again (docs/FORMAT.md section 14); absent with one level
        # on first use: keeps `fracture` start-up light
        from fracture_cli.pipeline.levels import levels_summary

        report["levels"] = levels_summary(state.levels, [fragment_name(i, stem) for i in range(len(frags.fragments))])
    return report


def write_outputs(out_dir: str, stem: str, state: PipelineState, report: dict[str, Any],
                  runner: Runner, preview_size: tuple[int, int] | None = None) -> tuple[str, ...]:
    """Write the fragments, the runtime file and the report as the ``export`` step; returns the paths.

    The files are written into a staging folder and published as one set
    (:func:`fracture_cli.io.outputs.output_set`), the report last with the
    other files' hashes. ``report`` gets its ``seconds`` (and ``cache``) block.
    With ``preview_size`` (width, height) the preview PNG is rendered from the
    staged files and published with them.
    """
    # on first use: keeps `fracture` start-up light
    from fracture_cli.io.write import write_fragments_glb
    from fracture_cli.runtime.format import write_runtime

    check_inputs_untouched(out_dir, [stem], input_files(state.need("source", "export")))  # also for a chain
    with runner.step("export"), output_set(out_dir, stem) as staging:
        collision_options = runner.options.get("collision")
        frags = state.need("fragments", "export")
        children = [] if state.levels is None else [(r.fragment, r.children, r.physics)
                                                     for r in state.levels.refinements]
        write_fragments_glb(staging.file(f"{stem}.glb"), frags, pivot=frags.pivot, parts=state.collision,
                            collision=getattr(collision_options, "glb", "none") if state.collision else "none",
                            stem=stem, physics=state.physics, children=children)
        write_runtime(state.need("runtime", "export"), staging.file(f"{stem}.fracture.json"))
        if state.aligned is not None:  # the companion pair, only when the recipe asks (docs/FORMAT.md section 13)
            # on first use: keeps `fracture` start-up light
            from fracture_cli.runtime.aligned_data import write_aligned

            write_aligned(state.aligned, staging.file(f"{stem}.aligned.json"))
            report["outputs"] = [*report["outputs"][:-1], f"{stem}.aligned.bin", f"{stem}.aligned.json",
                                 report["outputs"][-1]]
        if preview_size is not None:
            # on first use: keeps `fracture` start-up light
            from fracture_cli.view.preview import render_preview

            # The report is not in the staging folder yet (it is written last, with the others' hashes).
            render_preview(staging.file(f"{stem}.fracture.json"), staging.file(f"{stem}.preview.png"),
                           width=preview_size[0], height=preview_size[1], report=report)
            report["outputs"] = [*report["outputs"][:-1], f"{stem}.preview.png", report["outputs"][-1]]
        if runner.origin is not None:  # up to the report: publishing the set is a few renames after it
            runner.stop_clock("export")  # the export's seconds end where the total is taken
            runner.seconds["total"] = round(time.monotonic() - runner.origin, 3)
        report["seconds"] = dict(runner.seconds)
        if runner.cache is not None:
            report["cache"] = dict(runner.cache.events)
        staging.write_report(report)
        names = staging.names()
    report["seconds"] = dict(runner.seconds)
    return tuple(os.path.join(out_dir, name) for name in names)


def check_batch(inputs: Sequence[str], out_dir: str) -> None:
    """Refuse a batch in which two inputs would write the same outputs, or an output would replace an input.

    Also an output over a file of another published bake set in ``out_dir``
    (:func:`~fracture_cli.io.preflight.guard_outputs`); each input's own set is republished.
    """
    stems: dict[str, str] = {}
    for path in inputs:
        stem = stem_of(path)
        if stem in stems:
            raise UsageError(f"{stems[stem]} and {path} would both write {stem}.* into {out_dir}; "
                             "bake them into different folders")
        stems[stem] = path
    if out_dir:  # preflight() says what is wrong with an empty one
        guard_outputs(inputs=[f for p in inputs for f in input_files(p)], sets=[(out_dir, s) for s in stems])


def bake_many(inputs: Sequence[str], out_dir: str, recipe: Recipe, *, cache_dir: str | None = None,
              keep_going: bool = False, preview: bool = False,
              preview_size: tuple[int, int] = (1600, 1000), jobs: int | None = None,
              started: float | None = None) -> Iterator[BatchItem]:
    """Bake several inputs into one folder, yielding each one's outcome as it finishes.

    Parameters
    ----------
    inputs : sequence of str
        Asset paths; no two may share a stem (checked before any work).
    out_dir, recipe, cache_dir, jobs
        As for :func:`bake`.
    keep_going : bool, optional (default False)
        With several inputs, an input that fails (any error, bugs included) is
        yielded with its error line and the others are still baked; without
        it (or with one input) the first error is raised.
    preview : bool, optional (default False)
        Also render ``<stem>.preview.png`` for each bake, as part of its output
        set; without it a ``<stem>.preview.png`` left by an earlier bake is
        removed with the publish (it would show other fragments than the files
        beside it).
    preview_size : (int, int), optional (default (1600, 1000))
        Width and height of the preview in pixels.
    started : float, optional
        As for :func:`bake`, for the first input (the others start when their bake is called).

    Yields
    ------
    BatchItem
        One per input, in order.
    """
    check_batch(inputs, out_dir)
    for index, path in enumerate(inputs):
        try:
            result = bake(path, out_dir, recipe, cache_dir=cache_dir, jobs=jobs,
                          preview_size=preview_size if preview else None, started=started if index == 0 else None)
        except Exception as exc:
            if not keep_going or len(inputs) == 1 or caused_by_interrupt(exc):  # Ctrl-C stops the whole batch
                raise
            yield BatchItem(path, error=describe_error(exc, path), exception=exc)
            continue
        yield BatchItem(path, result=result)


def step_seconds(report: dict[str, Any]) -> dict[str, float]:
    """The ``seconds`` of every step (stages and ``export``) of a report, without ``startup`` and ``total``."""
    return {name: value for name, value in report.get("seconds", {}).items() if name not in ("startup", "total")}


def describe_error(exc: BaseException, path: str | None = None) -> str:
    """One line for an error: a FractureError's own message, or an internal error naming file and stage."""
    if isinstance(exc, FractureError):
        return str(exc)
    path = getattr(exc, "fracture_input", None) or path
    stage = getattr(exc, "fracture_stage", None)
    first = str(exc).splitlines()[0] if str(exc) else ""
    where = "".join(x for x in (f"{stage}: " if stage else "", f"{path}: " if path else ""))
    return f"{where}internal error ({type(exc).__name__}: {first}); rerun with --debug for a traceback"
