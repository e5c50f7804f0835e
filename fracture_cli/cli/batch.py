"""The ``fracture batch`` command: parses options and calls :func:`~fracture_cli.batch.runner.run_batch`.

Registers itself on the main group when imported (:mod:`fracture_cli.cli.commands`). The global flags (``-v``,
``-q``, ``--debug``, ``--recipes``, ``--set``) work before or after it.
"""

from __future__ import annotations

import json
from typing import Any

import click

from fracture_cli.cli.group import TerminalCommand, cli
from fracture_cli.errors import FractureError, UsageError


def _options(meta: dict[str, Any], out_dir: str, scheduler: str | None, workers: int | None, timeout: float,
             impacts: int, cache_dir: str | None, overrides: tuple[str, ...], force: bool, verbose: bool) -> Any:
    # on first use: keeps `fracture` start-up light
    from fracture_cli.batch.runner import BatchOptions

    if scheduler and workers is not None:
        raise UsageError("--workers sizes the local cluster; with --scheduler the cluster's own workers are used")
    extra = {"workers": workers} if workers is not None else {}
    return BatchOptions(out_dir=out_dir, scheduler=scheduler, timeout=timeout, impacts=impacts, cache_dir=cache_dir,
                        overrides=tuple(meta.get("fracture.overrides", ())) + tuple(overrides), force=force,
                        verbose=verbose, recipes_dir=meta.get("fracture.recipes_dir"), **extra)


def _run(manifest: str, options: Any, as_json: bool, quiet: bool, debug: bool) -> None:
    # on first use: keeps `fracture` start-up light
    from fracture_cli.batch.report import summary_text, to_json
    from fracture_cli.batch.runner import batch_files, run_batch

    report = run_batch(manifest, options)
    if as_json:
        click.echo(json.dumps(to_json(report), indent=2, sort_keys=True))
    if not quiet:
        click.echo(summary_text(report), err=True)
    for a in report.failed if debug else ():
        if a.detail:
            click.echo(f"{a.name}:\n{a.detail}", err=True)
    if report.failed:
        raise FractureError(f"{len(report.failed)} of {len(report.assets)} asset(s) failed; report: "
                            f"{batch_files(manifest, options.out_dir)[1]}")


def _command(command_cls: type[click.Command]) -> click.Command:
    @click.command("batch", cls=command_cls)
    @click.argument("manifest", type=click.Path(dir_okay=False, path_type=str))
    @click.option("-o", "--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=str),
                  help="Output folder; each asset's outputs mirror its folder below the manifest's.")
    @click.option("--scheduler", metavar="ADDRESS", default=None,
                  help="An existing Dask scheduler (tcp://host:8786) instead of a local cluster.")
    @click.option("--workers", type=int, default=None, metavar="N",
                  help="Worker processes of the local cluster.  [default: number of CPUs]")
    @click.option("--timeout", type=float, default=1800.0, show_default=True, metavar="S",
                  help="Seconds before one asset's bake is killed and marked failed (a manifest entry's "
                       "'timeout' wins).")
    @click.option("--impacts", type=int, default=0, show_default=True, metavar="N",
                  help="Also write N deterministic impacts per asset and their groups to <manifest>.impacts.parquet.")
    @click.option("--cache", "cache_dir", type=click.Path(file_okay=False, path_type=str), default=None,
                  help="Shared stage cache (cage, tets, modes), as for 'bake --cache'.")
    @click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
                  help="Override a recipe parameter for every asset, after the manifest's own (repeatable).")
    @click.option("--force", is_flag=True, help="Bake every asset, even those that are up to date.")
    @click.option("--json", "as_json", is_flag=True, help="Print the batch report as JSON on stdout.")
    @click.pass_context
    def batch_cmd(ctx: click.Context, manifest: str, out_dir: str, scheduler: str | None, workers: int | None,
                  timeout: float, impacts: int, cache_dir: str | None, overrides: tuple[str, ...], force: bool,
                  as_json: bool) -> Any:
        """Bake every asset of MANIFEST on Dask (a local cluster, or --scheduler).

        MANIFEST is a TOML file: [assets] "file or glob" = "recipe", and/or
        [[batch]] tables with glob (or file), recipe, set = [...] and timeout.
        Assets whose inputs, recipe and tool version are unchanged since their
        last successful bake are skipped. Recipe names are looked up in
        --recipes DIR, $FRACTURE_RECIPES, recipes/ beside the asset, recipes/
        beside the manifest, ./recipes, then the built-in recipes. Writes
        <manifest>.batch.json and .batch.md into OUT.
        """
        root = ctx.find_root()
        meta = root.meta
        verbose = (root.params.get("verbose") or 0) >= 1

        def process(chain: Any) -> None:
            options = _options(meta, out_dir, scheduler, workers, timeout, impacts, cache_dir, overrides, force,
                               verbose)
            _run(manifest, options, as_json, bool(meta.get("fracture.quiet")), bool(meta.get("fracture.debug")))

        return process

    return batch_cmd


cli.add_command(_command(TerminalCommand))
