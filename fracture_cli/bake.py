"""``bake``: the whole pipeline from an asset and a recipe to game-ready files.

For input ``<stem>`` a bake writes, into the output folder:

* ``<stem>.glb``            one node and mesh per fragment (``fragment_000`` ...);
* ``<stem>.fracture.json``  + ``<stem>.fracture.bin``: the runtime file (docs/FORMAT.md);
* ``<stem>.report.json``    what was done: versions, recipe, counts, checks, seconds.

The four files are replaced as one set (:mod:`fracture_cli.io.outputs`): the
output folder is checked before any work, the files are written into a staging
folder and published under a per-stem lock, report last, with the other files'
hashes in it; a failed or interrupted bake leaves the previous set. The meshes and the runtime file are
byte-identical for the same input, recipe and tool version; the report is too,
except for its ``seconds`` block.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from dataclasses import dataclass

import numpy as np

from fracture_cli import __version__
from fracture_cli.errors import FractureError, StageError
from fracture_cli.io.outputs import file_sha256, output_names, output_set, preflight  # noqa: F401 (file_sha256: API)
from fracture_cli.recipe import Recipe
from fracture_cli.types import Fragments

log = logging.getLogger(__name__)

STAGES = ("load", "repair", "cage", "tetra", "material", "modes", "pieces", "smooth", "fragments", "runtime",
          "export")


@dataclass(frozen=True)
class BakeResult:
    """What a bake produced: the report and the paths of the files written."""

    report: dict
    outputs: tuple[str, ...]


def _signed_volume(V: np.ndarray, F: np.ndarray) -> float:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def fragment_summary(fragments: Fragments) -> list[dict]:
    """Per-fragment summary for reports and golden files (input units, rounded)."""
    out = []
    scale = fragments.normalization.scale
    for i, frag in enumerate(fragments.fragments):
        world = fragments.normalization.to_world(frag.vertices)
        out.append({
            "name": f"fragment_{i:03d}",
            "piece": int(frag.piece),
            "triangles": int(len(frag.faces)),
            "volume": float(_signed_volume(frag.vertices, frag.faces) * scale**3),
            "bbox_min": [float(x) for x in world.min(axis=0)],
            "bbox_max": [float(x) for x in world.max(axis=0)],
        })
    return out


def bake(input_path: str, out_dir: str, recipe: Recipe, cache_dir: str | None = None) -> BakeResult:
    """Run the whole pipeline on one asset and write its outputs.

    Parameters
    ----------
    input_path : str
        The asset (any format :func:`~fracture_cli.io.read.load_surface` reads).
    out_dir : str
        Output folder; created if missing.
    recipe : Recipe
        The destructible material: options of every stage.
    cache_dir : str, optional (default None)
        Folder of a :class:`~fracture_cli.cache.StageCache`: the cage, tets and
        modes are reused when nothing they depend on changed.

    Returns
    -------
    BakeResult

    Raises
    ------
    FractureError
        On bad input or a stage that cannot finish; no output is then written.
        Every error names the input file (stage errors get its path), so a
        batch log says which asset failed.
    """
    try:
        return _bake(input_path, out_dir, recipe, cache_dir)
    except FractureError as exc:
        if exc.path is None:
            exc.path = input_path
        raise


def _bake(input_path: str, out_dir: str, recipe: Recipe, cache_dir: str | None) -> BakeResult:
    """The body of :func:`bake`; errors are labelled with the input file by the caller."""
    from fracture_cli.io.read import load_surface
    from fracture_cli.io.write import fragment_name, write_fragments_glb
    from fracture_cli.runtime.format import write_runtime
    from fracture_cli.stages.cage import cage
    from fracture_cli.stages.checks import fragment_fault_shape, fragment_invariants
    from fracture_cli.stages.fragments import fragments as cut_fragments
    from fracture_cli.stages.material import material
    from fracture_cli.stages.modes import modes as solve_modes
    from fracture_cli.stages.pieces import pieces as atomic_pieces
    from fracture_cli.stages.repair import repair
    from fracture_cli.stages.runtime import runtime as precompute_runtime
    from fracture_cli.stages.smooth import smooth
    from fracture_cli.stages.tetra import tetra

    from fracture_cli.cache import input_digest
    from fracture_cli.io.inputs import estimate_output_bytes, input_files

    stem = os.path.splitext(os.path.basename(input_path))[0]
    depends = input_files(input_path)
    preflight(out_dir, stem, inputs=depends, estimate_bytes=estimate_output_bytes(depends))
    seconds: dict[str, float] = {}
    step = [0]

    @contextlib.contextmanager
    def timed(name):
        step[0] += 1
        log.info("bake %s: [%d/%d] %s ...", stem, step[0], len(STAGES), name)
        t0 = time.perf_counter()
        yield
        seconds[name] = round(time.perf_counter() - t0, 3)
        log.info("bake %s: [%d/%d] %s done in %.2f s", stem, step[0], len(STAGES), name, seconds[name])

    with timed("load"):
        loaded = load_surface(input_path, recipe["load"])
    with timed("repair"):
        # Cage and fragments both use the repaired solid, so they agree on what is inside.
        surface = repair(loaded, recipe["repair"])
    input_hash = input_digest(depends)
    stage_cache = None
    if cache_dir is not None:
        from fracture_cli.cache import StageCache, cache_key

        stage_cache = StageCache(cache_dir)
        cage_key = cache_key("cage", input_hash, recipe["load"], recipe["repair"], recipe["cage"], recipe["tetra"])
        modes_key = cache_key("modes", cage_key, recipe["material"], recipe["modes"])
    cached = stage_cache.get_cage(cage_key, surface.normalization) if stage_cache else None
    with timed("cage"):
        cage_result = cached[0] if cached else cage(surface, recipe["cage"])
    with timed("tetra"):
        tet_mesh = cached[1] if cached else tetra(cage_result, recipe["tetra"])
    if stage_cache and not cached:
        stage_cache.put_cage(cage_key, cage_result, tet_mesh)
    with timed("material"):
        eta = material(tet_mesh, surface, recipe["material"])
    with timed("modes"):
        modes = stage_cache.get_modes(modes_key) if stage_cache else None
        if modes is None:
            modes = solve_modes(tet_mesh, recipe["modes"], eta=eta)
            if stage_cache:
                stage_cache.put_modes(modes_key, modes)
    with timed("pieces"):
        pieces = atomic_pieces(tet_mesh, modes, recipe["pieces"])
    with timed("smooth"):
        regions = smooth(tet_mesh, pieces, recipe["smooth"], surface=surface)
    with timed("fragments"):
        frags = cut_fragments(surface, regions, recipe["fragments"])
        checks = fragment_invariants(surface, frags)
        checks["input_volume"] = float(frags.input_volume * surface.normalization.scale**3)
        # How jagged the faults look (what smoothing is for), so a recipe change shows up in review.
        shape = fragment_fault_shape(frags)
        checks["fault_mean_dihedral_degrees"] = round(shape["mean_dihedral_degrees"], 6)
        checks["fault_crease_density"] = round(shape["crease_density"], 6)
    if not frags.fragments:
        raise StageError("no fragment intersects the input; is the asset empty?", stage="fragments", path=input_path)
    with timed("runtime"):
        fragment_pieces = [int(f.piece) for f in frags.fragments]
        names = tuple(fragment_name(i) for i in range(len(frags.fragments)))
        runtime_data = precompute_runtime(tet_mesh, modes, pieces, recipe["runtime"],
                                          fragment_pieces=fragment_pieces, fragment_names=names)

    report = {
        "tool": "fracture",
        "version": __version__,
        "input": {"name": os.path.basename(input_path), "sha256": input_hash,
                  "triangles": loaded.num_faces, "vertices": loaded.num_vertices,
                  "scale": surface.normalization.scale},
        "recipe": {"name": recipe.name, "chain": list(recipe.chain), "description": recipe.description,
                   "parameters": recipe.to_dict()},
        "counts": {
            "cage_faces": int(len(cage_result.faces)),
            "cage_offset": float(cage_result.offset),
            "tets": tet_mesh.num_tets,
            "modes": modes.num_modes,
            "mode_pieces": [int(c) for c in modes.piece_counts],
            "pieces": pieces.num_pieces,
            "fragments": len(frags.fragments),
            "bonds": int(runtime_data.num_edges),
            "contact_sites": int(runtime_data.num_sites),
        },
        "checks": checks,
        "fragments": fragment_summary(frags),
        "outputs": [f"{stem}.glb", f"{stem}.fracture.json", f"{stem}.fracture.bin", f"{stem}.report.json"],
    }

    with timed("export"), output_set(out_dir, stem) as staging:
        write_fragments_glb(staging.file(f"{stem}.glb"), frags)
        write_runtime(runtime_data, staging.file(f"{stem}.fracture.json"))
        report["seconds"] = dict(seconds)
        if stage_cache:
            report["cache"] = dict(stage_cache.events)
        staging.write_report(report)  # the manifest: hashes of the other files, written and published last
    outputs = [os.path.join(out_dir, name) for name in output_names(stem)]
    report["seconds"] = dict(seconds)
    return BakeResult(report=report, outputs=tuple(outputs))
