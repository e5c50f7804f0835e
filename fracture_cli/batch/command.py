"""The ``fracture batch`` command: parses options and calls :func:`~fracture_cli.batch.runner.run_batch`.

Registered on the main group by :func:`register` (so this module does not
import :mod:`fracture_cli.cli`, which imports it).
"""

from __future__ import annotations

import json
import sys

import click

from fracture_cli.errors import FractureError, UsageError


def _options(manifest, out_dir, scheduler, workers, timeout, impacts, cache_dir, overrides, force, verbose):
    from fracture_cli.batch.runner import BatchOptions

    if scheduler and workers is not None:
        raise UsageError("--workers sizes the local cluster; with --scheduler the cluster's own workers are used")
    extra = {"workers": workers} if workers is not None else {}
    return BatchOptions(out_dir=out_dir, scheduler=scheduler, timeout=timeout, impacts=impacts, cache_dir=cache_dir,
                        overrides=tuple(overrides), force=force, verbose=verbose, **extra)


def _run(manifest: str, options, as_json: bool, quiet: bool, debug: bool) -> None:
    from fracture_cli.batch.progress import Progress
    from fracture_cli.batch.report import summary_text, to_json
    from fracture_cli.batch.runner import batch_files, run_batch

    progress: list[Progress] = []
    stream = sys.stderr

    def on_plan(jobs) -> None:
        if not quiet:
            progress.append(Progress(len(jobs), stream, stream.isatty(), {j.index: j.name for j in jobs}))

    def on_result(result) -> None:
        for p in progress:
            p.update(result)

    try:
        report = run_batch(manifest, options, on_result=on_result, on_plan=on_plan)
    finally:
        for p in progress:
            p.close()
    if as_json:
        click.echo(json.dumps(to_json(report), indent=2, sort_keys=True))
    if not quiet:
        click.echo(summary_text(report), err=True)
    elif report.failed:
        for a in report.failed:
            click.echo(f"failed: {a.name}: {a.error}", err=True)
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
                  help="Worker processes of the local cluster [default: number of CPUs].")
    @click.option("--timeout", type=float, default=1800.0, show_default=True, metavar="S",
                  help="Seconds before one asset's bake is killed and marked failed.")
    @click.option("--impacts", type=int, default=0, show_default=True, metavar="N",
                  help="Also write N deterministic impacts per asset and their groups to <manifest>.impacts.parquet.")
    @click.option("--cache", "cache_dir", type=click.Path(file_okay=False, path_type=str), default=None,
                  help="Shared stage cache (cage, tets, modes), as for 'bake --cache'.")
    @click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
                  help="Override a recipe parameter for every asset, after the manifest's own (repeatable).")
    @click.option("--force", is_flag=True, help="Bake every asset, even those that are up to date.")
    @click.option("--json", "as_json", is_flag=True, help="Print the batch report as JSON on stdout.")
    @click.option("-q", "--quiet", is_flag=True, help="Print only errors.")
    @click.option("--debug", is_flag=True, help="Show tracebacks for errors.")
    @click.pass_context
    def batch_cmd(ctx, manifest, out_dir, scheduler, workers, timeout, impacts, cache_dir, overrides, force,
                  as_json, quiet, debug):
        """Bake every asset of MANIFEST on Dask (a local cluster, or --scheduler).

        MANIFEST is a TOML file: [assets] "file or glob" = "recipe", and/or
        [[batch]] tables with glob (or file), recipe and set = [...]. Assets
        whose inputs, recipe and tool version are unchanged since their last
        successful bake are skipped. Writes <manifest>.batch.json/.md into OUT.
        """
        if debug:
            ctx.find_root().meta["fracture.debug"] = True
        root = ctx.find_root().params
        verbose = (root.get("verbose") or 0) >= 1
        quiet = quiet or bool(root.get("quiet"))

        def process(state):
            from fracture_cli.cli import configure_logging

            if quiet:
                configure_logging(0, True)
            _run(manifest, _options(manifest, out_dir, scheduler, workers, timeout, impacts, cache_dir, overrides,
                                    force, verbose), as_json, quiet, debug)
            return state

        return process

    return batch_cmd


def register(group: click.Group, command_cls: type[click.Command]) -> None:
    """Add ``batch`` to the main command group (``command_cls``: the group's terminal command class)."""
    group.add_command(_command(command_cls))
