"""The commands that end a ``fracture`` chain: ``bake``, ``recipes``, ``impact``, ``preview`` and ``view``.

Each only parses its options and calls the library (:func:`fracture_cli.pipeline.bake.bake_many`,
:mod:`fracture_cli.pipeline.recipe`, the runtime reader, the preview renderer).
"""

from __future__ import annotations

import json
import logging
import os
from typing import Any

import click

from fracture_cli.cli.group import Chain, Processor, TerminalCommand, active_recipe, cli
from fracture_cli.cli.options import toml_text
from fracture_cli.errors import FractureError, UsageError
from fracture_cli.system import clock

log = logging.getLogger("fracture_cli")


@cli.command("bake", cls=TerminalCommand)
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=str))
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=str),
              help="Output folder (created if missing).")
@click.option("-r", "--recipe", "recipe_name", default=None,
              help="Recipe name (see 'fracture recipes') or path to a .toml file.  [default: default]")
@click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
              help="Override one recipe parameter, e.g. --set modes.num_modes=16 (repeatable).")
@click.option("--json", "as_json", is_flag=True, help="Print the bake report(s) as JSON on stdout.")
@click.option("--preview", is_flag=True, help="Also write <stem>.preview.png (input, fragments, modes, an impact); "
              "without it a stale <stem>.preview.png from an earlier bake is removed.")
@click.option("--preview-size", nargs=2, type=int, default=None, metavar="W H",
              help="Preview size in pixels (implies --preview).  [default: 1600 1000]")
@click.option("--cache", "cache_dir", type=click.Path(file_okay=False, path_type=str), default=None,
              help="Reuse cage, tets and modes from this folder when nothing they depend on changed.")
@click.option("-k", "--keep-going", is_flag=True,
              help="With several inputs, bake the others when one fails (exit code 1 at the end).")
@click.pass_context
def bake_cmd(ctx: click.Context, inputs: tuple[str, ...], out_dir: str, recipe_name: str | None,
             overrides: tuple[str, ...], as_json: bool, preview: bool, preview_size: tuple[int, int] | None,
             cache_dir: str | None, keep_going: bool) -> Processor:
    """Run the whole pipeline on INPUTS with a recipe, writing into OUT.

    For each input <stem>: <stem>.glb (fragments), <stem>.fracture.json/.bin
    (runtime file) and <stem>.report.json. Recipe names are looked up in
    --recipes DIR, $FRACTURE_RECIPES, recipes/ beside the input, ./recipes,
    then the built-in recipes.
    """
    meta = ctx.find_root().meta
    quiet = bool(meta.get("fracture.quiet"))
    if recipe_name is not None:
        meta["fracture.recipe_name"] = recipe_name
    meta["fracture.overrides"] = tuple(meta.get("fracture.overrides", ())) + overrides
    if preview_size is not None:
        check_preview_size(preview_size, "--preview-size")
        preview = True

    def process(chain: Chain) -> None:
        # on first use: keeps `fracture` start-up light
        from fracture_cli.pipeline.bake import bake_many

        recipe = active_recipe(inputs)
        reports: list[dict[str, Any]] = []
        failures = []
        for item in bake_many(inputs, out_dir, recipe, cache_dir=cache_dir, keep_going=keep_going,
                              preview=preview, preview_size=preview_size or (1600, 1000),
                              jobs=meta.get("fracture.jobs"), started=clock.process_origin()):
            if item.result is None:
                click.echo(f"error: {item.error}", err=True)
                failures.append(item.input_path)
                reports.append({"input": {"name": os.path.basename(item.input_path)}, "error": item.error})
                continue
            reports.append(item.result.report)
            if not (quiet or as_json):
                r = item.result.report
                c = r["counts"]
                click.echo(
                    f"baked {item.input_path} with recipe '{recipe.name}': {c['fragments']} fragments, "
                    f"{c['modes']} modes, {c['tets']} tets, volume error "
                    f"{r['checks'].get('volume_error', float('nan')):.2e}, {r['seconds']['total']:.1f} s "
                    f"-> {out_dir}", err=True)
        if as_json:
            click.echo(json.dumps(reports[0] if len(reports) == 1 else reports, indent=2, sort_keys=True))
        if failures:
            raise FractureError(f"{len(failures)} of {len(inputs)} inputs failed: {', '.join(failures)}")

    return process


@cli.command("recipes", cls=TerminalCommand)
@click.argument("action", required=False, type=click.Choice(["list", "show"]), default="list")
@click.argument("name", required=False)
@click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE", help="Apply overrides before showing.")
def recipes_cmd(action: str, name: str | None, overrides: tuple[str, ...]) -> Processor:
    """List the destructible materials, or 'recipes show NAME' for one's resolved parameters."""

    def process(chain: Chain) -> None:
        # on first use: keeps `fracture` start-up light
        from fracture_cli.pipeline.recipe import list_recipes, load_recipe, search_path

        meta = click.get_current_context().find_root().meta
        search = search_path(meta.get("fracture.recipes_dir"))
        if action == "list":
            names = list_recipes(search)
            width = max([12, *map(len, names)])  # one column of descriptions, however long a name
            for recipe_name in names:
                recipe = load_recipe(recipe_name, search=search)
                click.echo(f"{recipe_name:<{width}} {recipe.description}")
            return
        if not name:
            raise UsageError("'recipes show' needs a recipe name, e.g. 'fracture recipes show glass'")
        recipe = load_recipe(name, tuple(meta.get("fracture.overrides", ())) + overrides, search=search)
        click.echo(f"# {recipe.name}: {recipe.description}")
        if len(recipe.chain) > 1:
            click.echo(f"# extends: {' -> '.join(recipe.chain[1:])}")
        for section, values in recipe.to_dict().items():
            click.echo(f"\n[{section}]")
            for key, value in values.items():
                click.echo(f"{key} = {toml_text(value)}")

    return process


@cli.command("impact", cls=TerminalCommand)
@click.argument("runtime_file", type=click.Path(dir_okay=False, path_type=str))
@click.option("--point", nargs=3, type=float, default=None, metavar="X Y Z", help="Hit point, asset units.")
@click.option("--impulse", nargs=3, type=float, default=None, metavar="X Y Z", help="Impulse vector.")
@click.option("--hit", "more_hits", nargs=6, type=float, multiple=True, metavar="X Y Z IX IY IZ",
              help="Another hit (point, then impulse) after --point/--impulse, on the same damage state "
                   "(repeatable, in order).")
@click.option("--repeat", type=click.IntRange(min=1, max=100000), default=1, show_default=True, metavar="N",
              help="Apply the hits N times over to one damage state: on a file with damage, light hits crack "
                   "bonds and wear them down until they break.")
@click.option("--threshold", type=float, default=None, help="Toughness (default: the file's).")
@click.option("-o", "--out", "out_glb", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Write a GLB with one node per group, named group_### like the printed groups (after the last "
                   "hit), holding its fragments (as child nodes, or one merged mesh when they share a transform).")
@click.option("--warn-distance", type=click.FloatRange(min=0), default=0.1, show_default=True,
              help="Warn when the point is farther than this fraction of the bounding-box diagonal from the "
                   "nearest contact site (probably not on the asset, or in other units).")
@click.option("--png", "out_png", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Render a preview picture of this impact (one hit).")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def impact_cmd(runtime_file: str, point: tuple[float, float, float] | None,
               impulse: tuple[float, float, float] | None, more_hits: tuple[tuple[float, ...], ...], repeat: int,
               threshold: float | None, out_glb: str | None, out_png: str | None, as_json: bool,
               warn_distance: float) -> Processor:
    """Project an impact on a baked asset and print which fragments move together.

    Each group is named group_### after its smallest fragment index, as in the
    GLB that -o writes; a group held by the world (a structure's anchored base)
    ends with "(anchored)", and a bond that holds but is cracked gets a
    "cracked:" line with its health. Several hits (--hit, --repeat) act on one
    damage state, as in a game: a line per hit, then the groups after the last.
    """
    if (point is None) != (impulse is None):
        raise UsageError("--point and --impulse come together (one hit); more hits: --hit X Y Z IX IY IZ")
    hits = ([(point, impulse)] if point is not None and impulse is not None else []) + [
        ((h[0], h[1], h[2]), (h[3], h[4], h[5])) for h in more_hits]
    if not hits:
        raise UsageError("give a hit: --point X Y Z --impulse X Y Z (or --hit X Y Z IX IY IZ)")
    hits = hits * repeat
    if out_png and len(hits) > 1:
        raise UsageError("--png pictures one hit; give a single hit (no --hit or --repeat) with it")

    def process(chain: Chain) -> None:
        # on first use: keeps `fracture` start-up light
        import numpy as np

        from fracture_cli.cli.hits import apply_hits, json_body, text_lines
        from fracture_cli.runtime.format import load_runtime

        guard_beside(runtime_file, [p for p in (out_glb, out_png) if p], glb=bool(out_glb or out_png),
                     report=bool(out_png))
        data = load_runtime(runtime_file)
        outcomes = apply_hits(data, hits, threshold)
        sites = np.asarray(data.sites, dtype=np.float64)
        diagonal = float(np.linalg.norm(sites.max(axis=0) - sites.min(axis=0))) or 1.0
        distances, warned = [], set()
        for (where, _), outcome in zip(hits, outcomes):
            distance = float(np.linalg.norm(sites[outcome.result.site] - np.asarray(where, dtype=np.float64)))
            distances.append(distance)
            if distance > warn_distance * diagonal and where not in warned:  # once per point of a sequence
                warned.add(where)
                log.warning("the point is %.4g units from the nearest contact site, %.2g times the asset's %.4g-unit "
                            "diagonal: is it on the asset, in model space and the asset's units?", distance,
                            distance / diagonal, diagonal)
        if as_json:
            click.echo(json.dumps(json_body(data, outcomes, distances), indent=2))
        else:
            for line in text_lines(data, outcomes):
                click.echo(line)
        if out_glb:
            # on first use: keeps `fracture` start-up light
            from fracture_cli.io.regroup import write_groups_glb

            glb = runtime_file[: -len(".fracture.json")] + ".glb" if runtime_file.endswith(".fracture.json") else None
            if glb is None or not os.path.exists(glb):
                raise UsageError(f"cannot find the fragments file next to {runtime_file} (expected <stem>.glb)")
            write_groups_glb(glb, outcomes[-1].result.groups, out_glb, fragment_names=data.fragment_names)
        if out_png:
            # on first use: keeps `fracture` start-up light
            from fracture_cli.view.preview import render_preview

            render_preview(runtime_file, out_png, impact=(hits[0][0], hits[0][1], threshold))

    return process


@cli.command("preview", cls=TerminalCommand)
@click.argument("runtime_file", type=click.Path(dir_okay=False, path_type=str))
@click.option("-o", "--out", "out_png", required=True, type=click.Path(dir_okay=False, path_type=str),
              help="Output PNG.")
@click.option("--size", nargs=2, type=int, default=(1600, 1000), show_default=True, metavar="W H",
              help="Image size in pixels.")
@click.option("--panels", type=click.Choice(["all", "fragments"]), default="all", show_default=True,
              help="'all': input, exploded fragments, an impact and the first modes; 'fragments': the exploded "
                   "fragments and the impact only, in one row (the README's picture of each pattern kind).")
def preview_cmd(runtime_file: str, out_png: str, size: tuple[int, int], panels: str) -> Processor:
    """Render a PNG of a bake: input, exploded fragments, modes, an example impact."""

    def process(chain: Chain) -> None:
        # on first use: keeps `fracture` start-up light
        from fracture_cli.view.preview import render_preview

        check_preview_size(size, "--size")
        guard_beside(runtime_file, [out_png], glb=True, report=True)
        render_preview(runtime_file, out_png, width=size[0], height=size[1], panels=panels)
        log.info("preview: wrote %s", out_png)

    return process


def guard_beside(runtime_file: str, outputs: list[str], *, glb: bool, report: bool) -> None:
    """The output guard of a command reading a bake: the runtime file and its .bin, and the GLB and report beside.

    Raises
    ------
    OutputError
        An output would replace one of them, or a file of a published bake set.
    """
    # on first use: keeps `fracture` start-up light
    from fracture_cli.io.preflight import guard_outputs
    from fracture_cli.runtime.format import runtime_files

    reads = runtime_files(runtime_file)
    if runtime_file.endswith(".fracture.json"):
        stem_path = runtime_file[: -len(".fracture.json")]
        reads += [stem_path + ".glb"] * glb + [stem_path + ".report.json"] * report
    guard_outputs(outputs, reads)


def check_preview_size(size: tuple[int, int], flag: str) -> None:
    """Refuse a preview size outside 200..8000 x 150..8000 pixels (a usage error naming the flag)."""
    if size[0] < 200 or size[1] < 150 or size[0] > 8000 or size[1] > 8000:
        raise UsageError(f"{flag} {size[0]} {size[1]} is out of range (200..8000 x 150..8000)")


@cli.command("view", cls=TerminalCommand)
@click.argument("path", type=click.Path(path_type=str))
@click.option("--port", type=click.IntRange(0, 65535), default=8765, show_default=True,
              help="TCP port (0 picks a free one).")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Interface to listen on; anything but loopback exposes the folder to the network.")
@click.option("--no-browser", is_flag=True, help="Only print the address; do not open a browser.")
def view_cmd(path: str, port: int, host: str, no_browser: bool) -> Processor:
    """Open a bake in the browser: click to hit it, watch it break, tune magnitude and threshold.

    PATH is a bake output folder (a picker lists every asset in it) or one
    <stem>.fracture.json. The page reloads when a bake rewrites the files.
    Runs until Ctrl-C.
    """

    def process(chain: Chain) -> None:
        # on first use: keeps `fracture` start-up light
        import sys

        from fracture_cli.view.assets import list_assets, resolve_source
        from fracture_cli.view.server import ViewOptions, ViewServer, is_loopback

        source = resolve_source(path)
        if not list_assets(source):
            log.warning("no baked assets (<stem>.fracture.json) in %s yet; the page shows them once a bake "
                        "writes them", source.folder)
        if not is_loopback(host):
            log.warning("listening on %s: anyone who can reach this machine can read the bake files", host)
        server = ViewServer(source, ViewOptions(host=host, port=port)).start()
        click.echo(f"fracture view: {server.url}  (Ctrl-C to stop)")
        sys.stdout.flush()
        if not no_browser:
            import webbrowser

            webbrowser.open(server.url)
        try:
            server.wait()
        except KeyboardInterrupt:
            # on first use: keeps `fracture` start-up light
            from fracture_cli.system import interrupts

            interrupts.forget()  # Ctrl-C is how the server is stopped: a normal end (exit 0), not an interrupt
        finally:
            server.stop()

    return process
