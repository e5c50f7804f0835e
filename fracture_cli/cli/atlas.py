"""The ``fracture atlas`` command: parse options, call :func:`fracture_cli.atlas.run_atlas`, print, gate."""

from __future__ import annotations

import logging

import click

from fracture_cli.cli.group import Chain, Processor, TerminalCommand, cli
from fracture_cli.errors import FractureError

log = logging.getLogger("fracture_cli")


@cli.command("atlas", cls=TerminalCommand)
@click.argument("runtime_file", type=click.Path(dir_okay=False, path_type=str))
@click.option("--criterion", type=click.Choice(["file", "modes", "stress"]), default="file", show_default=True,
              help="Break criterion: the file's own ('file'), or 'modes' / 'stress' (stress needs a file baked "
                   "with runtime.criterion = 'stress').")
@click.option("--sites", type=click.IntRange(min=1), default=200, show_default=True,
              help="How many contact sites to hit (farthest-point sampling).")
@click.option("--require", "require", multiple=True, metavar="KEY<=VALUE",
              help="Fail (exit code 1) unless the figure holds, e.g. --require hit_detached>=0.95 (repeatable; "
                   "also >=, <, >).")
@click.option("--png", "out_png", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Write the atlas picture: the asset coloured by the first-detachment impulse, and a few hits.")
@click.option("--json", "as_json", is_flag=True, help="Print the JSON summary (default: a short table).")
def atlas_cmd(runtime_file: str, criterion: str, sites: int, require: tuple[str, ...], out_png: str | None,
              as_json: bool) -> Processor:
    """Sweep hits over a baked asset and measure where and how much it breaks (the break atlas).

    RUNTIME_FILE is <stem>.fracture.json; <stem>.glb beside it gives fragment
    positions and the picture. Figures: docs/ALGORITHM.md section 10 and
    fracture_cli/atlas/sweep.py.
    """

    def process(chain: Chain) -> None:
        # on first use: keeps `fracture` start-up light
        from fracture_cli.atlas import run_atlas
        from fracture_cli.cli.tools import guard_beside
        from fracture_cli.runtime.format import load_runtime

        if out_png:
            guard_beside(runtime_file, [out_png], glb=True, report=True)
        name = load_runtime(runtime_file).criterion if criterion == "file" else criterion
        result = run_atlas(runtime_file, sites=sites, require=require, png_path=out_png, criterion=name)
        if as_json:
            click.echo(result.json(), nl=False)
        else:
            click.echo(f"break atlas of {runtime_file}, criterion {name}, {result.summary['hits']['used']} hits")
            for key, value in result.summary["figures"].items():
                click.echo(f"  {key:<22} {'undefined' if value is None else value}")
        if out_png:
            log.info("atlas: wrote %s", out_png)
        if result.failures:
            raise FractureError("atlas requirement(s) failed: " + "; ".join(result.failures))

    return process
