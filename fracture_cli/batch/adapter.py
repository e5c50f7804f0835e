"""The one place the batch touches the bake API.

Everything else in :mod:`fracture_cli.batch` goes through :func:`bake_asset`
and :func:`output_names`, so when the bake moves to the pipeline table or
publishes through the output-set protocol, only this module changes.
"""

from __future__ import annotations

from dataclasses import dataclass

from fracture_cli.pipeline.recipe import Recipe


@dataclass(frozen=True)
class BakeOutcome:
    """What one bake published.

    Attributes
    ----------
    report : dict
        The bake report (as written to ``<stem>.report.json``).
    outputs : tuple of str
        Absolute paths of every file published, the report last.
    inputs : tuple of FileRead
        Every file the outputs depend on, hashed from the bytes the bake read
        (:class:`fracture_cli.io.inputs.FileRead`, the asset first).
    """

    report: dict
    outputs: tuple[str, ...]
    inputs: tuple = ()


def output_names(stem: str) -> tuple[str, ...]:
    """File names a bake of ``stem`` may publish (checked against the inputs before any work)."""
    # on first use: the batch driver starts light; workers load the stages
    from fracture_cli.io.outputs import all_names

    return all_names(stem)


def bake_asset(input_path: str, out_dir: str, recipe: Recipe, cache_dir: str | None) -> BakeOutcome:
    """Bake one asset and publish its outputs as a set into ``out_dir``.

    Raises
    ------
    FractureError
        Bad input or a stage that could not finish; nothing is published then.
    """
    # on first use: the batch driver starts light; workers load the stages
    from fracture_cli.pipeline.bake import bake

    # One process per asset: the batch's parallelism is across assets (one Dask worker per core),
    # a bake's own --jobs workers on top would oversubscribe the cores.
    result = bake(input_path, out_dir, recipe, cache_dir=cache_dir, jobs=1)
    return BakeOutcome(report=result.report, outputs=tuple(result.outputs), inputs=tuple(result.inputs))
