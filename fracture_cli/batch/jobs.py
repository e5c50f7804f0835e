"""What travels between the planner, the Dask workers and the bake process.

Both are plain frozen dataclasses, pickled by Dask to the worker and by the
worker to its bake subprocess, so every field is plain data (the resolved
recipe included: a worker never re-reads a recipe file that may have changed
since the batch was planned).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fracture_cli.batch.impacts import ImpactRows
from fracture_cli.batch.inputs import InputFile
from fracture_cli.pipeline.recipe import Recipe

BAKED = "baked"
UP_TO_DATE = "up to date"
FAILED = "failed"
STATUSES = (BAKED, UP_TO_DATE, FAILED)


@dataclass(frozen=True)
class BakeJob:
    """One asset's task.

    Attributes
    ----------
    index : int
        Position in the batch (manifest order, sorted by name).
    name : str
        Asset name relative to the manifest's folder.
    input_path, out_dir, stem : str
        Absolute input path, absolute output folder and output stem.
    recipe : Recipe
        Resolved recipe.
    key : str
        Incremental key (inputs' bytes, recipe, tool version); stored after a
        successful publish.
    inputs : tuple of InputFile
        The asset and its dependencies, hashed (stored with the key).
    hashed_at_ns : int
        When the planner hashed the inputs (``time.time_ns()``).
    bake : bool
        False when the outputs are up to date and only impacts are wanted.
    impacts : int
        Number of dataset impacts to compute (0: none).
    seed : int
        Impact seed, from the asset's content hash.
    cache_dir : str or None
        Shared stage cache.
    timeout : float
        Seconds before the bake process is killed.
    """

    index: int
    name: str
    input_path: str
    out_dir: str
    stem: str
    recipe: Recipe
    key: str
    inputs: tuple[InputFile, ...]
    hashed_at_ns: int = 0
    bake: bool = True
    impacts: int = 0
    seed: int = 0
    cache_dir: str | None = None
    timeout: float = 1800.0


@dataclass(frozen=True)
class TaskResult:
    """How one asset ended.

    Attributes
    ----------
    index : int
        The job's index.
    status : str
        One of :data:`STATUSES`.
    seconds : float
        Wall-clock seconds of the bake process (0 when nothing ran).
    error : str or None
        One line, for a failed asset.
    detail : str
        Traceback of an unexpected error (a bug), else empty.
    report : dict or None
        The bake report (fresh, or the one on disk for an up-to-date asset).
    impacts : ImpactRows or None
        The asset's dataset rows, when impacts were asked for.
    warnings : tuple of str
        Warnings the bake logged.
    worker : str
        Dask worker address (empty when nothing ran).
    inputs : tuple of InputFile
        The asset's files as the bake read them (the planner's for an up-to-date asset).
    """

    index: int
    status: str
    seconds: float = 0.0
    error: str | None = None
    detail: str = ""
    report: dict | None = None
    impacts: ImpactRows | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)
    worker: str = ""
    inputs: tuple[InputFile, ...] = ()
