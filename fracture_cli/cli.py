"""The ``fracture`` command line: a click chain of stages plus ``bake``.

Commands only parse options and call stages: each chained command returns a
processor ``state -> state`` (click's imagepipe pattern) and
:func:`run_chain` threads one :class:`PipelineState` through them. Option flags
are generated from the stages' option dataclasses, so library and CLI defaults
cannot drift.
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import traceback
from dataclasses import dataclass
from typing import Any, Callable

import click

from fracture_cli import __version__
from fracture_cli.errors import EXIT_FAILURE, FractureError, UsageError, exit_code_for
from fracture_cli.options import option_fields

log = logging.getLogger("fracture_cli")

EXAMPLES = """
\b
Examples:
  # bake an asset with a recipe (a reusable "destructible material")
  fracture bake chair.glb -o build/chair --recipe wood
\b
  # the same, step by step, saving intermediate results for inspection
  fracture load chair.glb cage --target-faces 2000 save-cage build/cage.obj \\
      tetra modes -k 12 pieces smooth --smoothing 0.002 fragments \\
      export build/chair
\b
  # try an impact on a baked asset
  fracture impact build/chair/chair.fracture.json --point 0 1 0 --impulse 0 -5 0
\b
  # round-trip a mesh (geometry, UVs, normals, materials)
  fracture load in.glb save out.glb
"""


@dataclass(frozen=True)
class PipelineState:
    """What the chain has produced so far; each stage fills one field."""

    source: str | None = None
    surface: Any = None
    cage: Any = None
    tet_mesh: Any = None
    modes: Any = None
    pieces: Any = None
    eta: Any = None
    regions: Any = None
    fragments: Any = None

    def need(self, name: str, command: str, producer: str):
        value = getattr(self, name)
        if value is None:
            raise UsageError(f"'{command}' needs a {name.replace('_', ' ')}: put '{producer}' before it in the chain")
        return value


Processor = Callable[[PipelineState], PipelineState]


# ----------------------------------------------------------------------------
# Options dataclass <-> click options

def _click_type(f: dataclasses.Field, default):
    choices = f.metadata.get("choices")
    if choices:
        return click.Choice([str(c) for c in choices])
    if isinstance(default, bool):
        return None
    if isinstance(default, int):
        return click.INT
    if isinstance(default, float):
        return click.FLOAT
    return click.STRING


def stage_options(options_cls, *, rename: dict[str, str] | None = None, short: dict[str, str] | None = None,
                  skip: tuple[str, ...] = ()):
    """Decorator adding one click option per field of a stage options dataclass."""
    rename = rename or {}
    short = short or {}

    def decorate(fn):
        for f in reversed(option_fields(options_cls)):
            if f.name in skip:
                continue
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            flag = "--" + rename.get(f.name, f.name).replace("_", "-")
            meta = f.metadata
            help_text = meta["help"]
            if meta.get("min") is not None or meta.get("max") is not None:
                help_text += f" [range {meta.get('min', '-inf')}..{meta.get('max') if meta.get('max') is not None else 'inf'}]"
            names = [flag] + ([short[f.name]] if f.name in short else [])
            if isinstance(default, bool):
                names = [f"{flag}/--no-{flag[2:]}"]
                fn = click.option(*names, f.name, default=None, help=help_text + f" [default: {default}]")(fn)
            elif isinstance(default, (list, tuple, dict)):
                continue  # structured options are recipe-only
            else:
                fn = click.option(*names, f.name, type=_click_type(f, default), default=None,
                                  help=help_text + f" [default: {default}]")(fn)
        return fn

    return decorate


def build_options(options_cls, kwargs: dict, base=None):
    """Make an options object from click kwargs (None = keep the default or ``base``)."""
    from fracture_cli.options import check_value

    base = base if base is not None else options_cls()
    changes = {}
    for f in option_fields(options_cls):
        if f.name in kwargs and kwargs[f.name] is not None:
            value = kwargs[f.name]
            default = getattr(base, f.name)
            if isinstance(default, float) and isinstance(value, int):
                value = float(value)
            if isinstance(default, int) and not isinstance(default, bool) and isinstance(value, str):
                value = int(value)
            problem = check_value(options_cls, f.name, value)
            if problem:
                flag = "--" + f.name.replace("_", "-")
                raise UsageError(problem.replace(f"{f.name} = ", f"{flag} ", 1))
            changes[f.name] = value
    return dataclasses.replace(base, **changes)


# ----------------------------------------------------------------------------
# Group, error handling, logging

class _StderrFormatter(logging.Formatter):
    def format(self, record):
        msg = record.getMessage()
        if record.levelno >= logging.WARNING:
            return f"{record.levelname.lower()}: {msg}"
        return msg


def configure_logging(verbose: int, quiet: bool) -> None:
    """Route the library's log records to stderr at a level the user chose."""
    logger = logging.getLogger("fracture_cli")
    for h in list(logger.handlers):
        if getattr(h, "_fracture", False):
            logger.removeHandler(h)
    if quiet:
        level = logging.ERROR
    elif verbose >= 2:
        level = logging.DEBUG
    elif verbose == 1 or sys.stderr.isatty():
        level = logging.INFO  # progress when someone is watching
    else:
        level = logging.WARNING
    handler = logging.StreamHandler(sys.stderr)
    handler._fracture = True
    handler.setFormatter(_StderrFormatter())
    logger.addHandler(handler)
    logger.setLevel(level)
    logger.propagate = False


class FractureGroup(click.Group):
    """A chain group that turns FractureError into one line and an exit code."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except KeyboardInterrupt:
            click.echo("fracture: interrupted; no output was written", err=True)
            ctx.exit(130)
        except FractureError as exc:
            if ctx.meta.get("fracture.debug"):
                traceback.print_exc()
            click.echo(f"error: {exc}", err=True)
            ctx.exit(exit_code_for(exc))
        except Exception as exc:  # a bug: still one line unless --debug
            if ctx.meta.get("fracture.debug"):
                traceback.print_exc()
            first = str(exc).splitlines()[0] if str(exc) else ""
            click.echo(f"error: internal error ({type(exc).__name__}: {first}); rerun with --debug for a traceback",
                       err=True)
            ctx.exit(EXIT_FAILURE)


class TerminalCommand(click.Command):
    """A command that ends the chain, so its options may follow its arguments.

    In a chain group click parses subcommands with interspersed options off
    (an argument would otherwise swallow the next command). Commands that take
    everything after them (bake, impact, preview, recipes) turn it back on, so
    ``fracture bake in.glb -o out`` works as users expect.
    """

    def make_context(self, info_name, args, parent=None, **extra):
        extra["allow_interspersed_args"] = True
        return super().make_context(info_name, args, parent=parent, **extra)


@click.group(cls=FractureGroup, chain=True, invoke_without_command=False, epilog=EXAMPLES,
             context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, "--version", prog_name="fracture")
@click.option("--debug", is_flag=True, help="Show tracebacks for errors.")
@click.option("-q", "--quiet", is_flag=True, help="Print only errors.")
@click.option("-v", "--verbose", count=True, help="More progress output (-vv for debug detail).")
@click.pass_context
def cli(ctx, debug, quiet, verbose):
    """Prefracture game assets with fracture modes (Sellan et al. 2023).

    Chain stages left to right (load, repair, cage, tetra, material, modes,
    pieces, smooth, fragments, export), or run everything from a recipe with
    'bake'. Stage options default to the library's defaults; 'bake' takes
    them from a recipe.
    """
    ctx.meta["fracture.debug"] = debug
    ctx.meta["fracture.quiet"] = quiet
    configure_logging(verbose, quiet)


@cli.result_callback()
def run_chain(processors, debug, quiet, verbose):
    """Thread one PipelineState through the chained commands' processors."""
    state = PipelineState()
    for process in processors:
        if process is None:
            continue
        state = process(state)
    return state


# ----------------------------------------------------------------------------
# Chained commands

from fracture_cli.io.read import LoadOptions  # noqa: E402


@cli.command("load")
@click.argument("path", type=click.Path(dir_okay=True, path_type=str))
@stage_options(LoadOptions)
def load_cmd(path, **kwargs):
    """Read a mesh (OBJ, PLY, STL, OFF, GLB, glTF)."""
    options = build_options(LoadOptions, kwargs)

    def process(state: PipelineState) -> PipelineState:
        from fracture_cli.io.read import load_surface

        return dataclasses.replace(state, source=path, surface=load_surface(path, options))

    return process


@cli.command("save")
@click.argument("path", type=click.Path(dir_okay=False, path_type=str))
def save_cmd(path):
    """Write the current surface (GLB, OBJ, PLY, STL, OFF) in the input's units."""

    def process(state: PipelineState) -> PipelineState:
        from fracture_cli.io.write import save_surface

        save_surface(path, state.need("surface", "save", "load PATH"))
        log.info("save: wrote %s", path)
        return state

    return process


def _stage_class(section: str):
    from fracture_cli.recipe import options_class

    return options_class(section)


def _stage_command(name: str, section: str, doc: str, run, short: dict[str, str] | None = None) -> None:
    """Register a chained command for one stage: flags from its options, ``run(state, options)`` does the work."""
    options_cls = _stage_class(section)

    @stage_options(options_cls, short=short)
    def command(**kwargs):
        options = build_options(options_cls, kwargs)
        return lambda state: run(state, options)

    cli.command(name, help=doc)(command)


def _file_command(name: str, doc: str, run) -> None:
    """Register a chained command taking one PATH argument; ``run(state, path)`` does the work."""

    @click.argument("path", type=click.Path(dir_okay=False, path_type=str))
    def command(path):
        return lambda state: run(state, path)

    cli.command(name, help=doc)(command)


def _run_repair(state: PipelineState, options) -> PipelineState:
    from fracture_cli.stages.repair import repair

    return dataclasses.replace(state, surface=repair(state.need("surface", "repair", "load PATH"), options))


def _run_cage(state: PipelineState, options) -> PipelineState:
    from fracture_cli.stages.cage import cage

    return dataclasses.replace(state, cage=cage(state.need("surface", "cage", "load PATH"), options))


def _run_tetra(state: PipelineState, options) -> PipelineState:
    from fracture_cli.stages.tetra import tetra

    return dataclasses.replace(state, tet_mesh=tetra(state.need("cage", "tetra", "cage"), options))


def _run_material(state: PipelineState, options) -> PipelineState:
    from fracture_cli.stages.material import material

    return dataclasses.replace(state, eta=material(state.need("tet_mesh", "material", "tetra"), state.surface, options))


def _run_modes(state: PipelineState, options) -> PipelineState:
    from fracture_cli.stages.modes import modes

    return dataclasses.replace(state, modes=modes(state.need("tet_mesh", "modes", "tetra"), options, eta=state.eta))


def _run_pieces(state: PipelineState, options) -> PipelineState:
    from fracture_cli.stages.pieces import pieces

    result = pieces(state.need("tet_mesh", "pieces", "tetra"), state.need("modes", "pieces", "modes"), options)
    return dataclasses.replace(state, pieces=result)


def _run_smooth(state: PipelineState, options) -> PipelineState:
    from fracture_cli.stages.smooth import smooth

    regions = smooth(state.need("tet_mesh", "smooth", "tetra"), state.need("pieces", "smooth", "pieces"), options,
                     surface=state.surface)
    return dataclasses.replace(state, regions=regions)


def _save_cage(state: PipelineState, path: str) -> PipelineState:
    from fracture_cli.io.cage_io import save_cage

    save_cage(path, state.need("cage", "save-cage", "cage"))
    return state


def _save_tets(state: PipelineState, path: str) -> PipelineState:
    from fracture_cli.io.cage_io import save_tetmesh

    save_tetmesh(path, state.need("tet_mesh", "save-tets", "tetra"))
    return state


def _load_tets(state: PipelineState, path: str) -> PipelineState:
    from fracture_cli.io.cage_io import load_tetmesh

    return dataclasses.replace(state, tet_mesh=load_tetmesh(path))


_stage_command("repair", "repair", "Make the surface a closed solid: weld, fix winding, close holes or thicken "
               "open sheets.", _run_repair)
_stage_command("cage", "cage", "Build the nested cage: a coarse closed surface around the input.", _run_cage)
_file_command("save-cage", "Write the cage surface (OBJ, PLY, STL, OFF) for inspection.", _save_cage)
_stage_command("tetra", "tetra", "Tetrahedralize the cage (TetGen), keeping its surface.", _run_tetra)
_file_command("save-tets", "Write the tet mesh as .npz (vertices, tets, normalization).", _save_tets)
_file_command("load-tets", "Read a tet mesh saved by save-tets (to resume a chain from it).", _load_tets)
_stage_command("material", "material", "Set material weights (grain, painted strength) on the tet faces.",
               _run_material)
_stage_command("modes", "modes", "Compute the fracture modes of the tet mesh.", _run_modes, short={"num_modes": "-k"})
_stage_command("pieces", "pieces", "Split the tet mesh into atomic pieces and build the piece graph.", _run_pieces)
_stage_command("smooth", "smooth", "Smooth the fault surfaces between pieces (Laplacian smoothing).", _run_smooth)


@cli.command("fragments")
@stage_options(_stage_class("fragments"))
def fragments_cmd(**kwargs):
    """Cut the input mesh into one closed fragment per piece."""
    options = build_options(_stage_class("fragments"), kwargs)

    def process(state: PipelineState) -> PipelineState:
        from fracture_cli.stages.fragments import fragments
        from fracture_cli.stages.smooth import SmoothOptions, smooth

        regions = state.regions
        if regions is None:  # no 'smooth' in the chain: tet-aligned faults
            regions = smooth(state.need("tet_mesh", "fragments", "tetra"),
                             state.need("pieces", "fragments", "pieces"),
                             dataclasses.replace(SmoothOptions(), smoothing=0.0))
        result = fragments(state.need("surface", "fragments", "load PATH"), regions, options)
        return dataclasses.replace(state, regions=regions, fragments=result)

    return process


@cli.command("export")
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=str))
@stage_options(_stage_class("runtime"))
def export_cmd(out_dir, **kwargs):
    """Write <stem>.glb and the runtime file <stem>.fracture.json/.bin into OUT_DIR."""
    options = build_options(_stage_class("runtime"), kwargs)

    def process(state: PipelineState) -> PipelineState:
        import os

        from fracture_cli.io.write import fragment_name, write_fragments_glb
        from fracture_cli.runtime.format import write_runtime
        from fracture_cli.stages.runtime import runtime

        frags = state.need("fragments", "export", "fragments")
        tet_mesh = state.need("tet_mesh", "export", "tetra")
        pieces = state.need("pieces", "export", "pieces")
        stem = os.path.splitext(os.path.basename(state.source or "asset"))[0]
        order = [int(f.piece) for f in frags.fragments]
        names = tuple(fragment_name(i) for i in range(len(order)))
        data = runtime(tet_mesh, state.need("modes", "export", "modes"), pieces, options,
                       fragment_pieces=order, fragment_names=names)
        os.makedirs(out_dir, exist_ok=True)
        write_fragments_glb(os.path.join(out_dir, f"{stem}.glb"), frags)
        write_runtime(data, os.path.join(out_dir, f"{stem}.fracture.json"))
        log.info("export: wrote %s/%s.glb and %s.fracture.json/.bin", out_dir, stem, stem)
        return state

    return process


@cli.command("bake", cls=TerminalCommand)
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=str))
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=str),
              help="Output folder (created if missing).")
@click.option("-r", "--recipe", "recipe_name", default="default", show_default=True,
              help="Recipe name (see 'fracture recipes') or path to a .toml file.")
@click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
              help="Override one recipe parameter, e.g. --set modes.num_modes=16 (repeatable).")
@click.option("--json", "as_json", is_flag=True, help="Print the bake report(s) as JSON on stdout.")
@click.option("--preview", is_flag=True, help="Also write <stem>.preview.png (input, fragments, modes, an impact).")
@click.option("--cache", "cache_dir", type=click.Path(file_okay=False, path_type=str), default=None,
              help="Reuse cage, tets and modes from this folder when nothing they depend on changed.")
@click.option("-k", "--keep-going", is_flag=True,
              help="With several inputs, bake the others when one fails (exit code 1 at the end).")
@click.option("-q", "--quiet", is_flag=True, help="Print only errors.")
@click.option("--debug", is_flag=True, help="Show tracebacks for errors.")
@click.pass_context
def bake_cmd(ctx, inputs, out_dir, recipe_name, overrides, as_json, preview, cache_dir, keep_going, quiet, debug):
    """Run the whole pipeline on INPUTS with a recipe, writing into OUT.

    For each input <stem>: <stem>.glb (fragments), <stem>.fracture.json/.bin
    (runtime file) and <stem>.report.json.
    """
    if debug:
        ctx.find_root().meta["fracture.debug"] = True
    if quiet:
        configure_logging(0, True)

    def process(state: PipelineState) -> PipelineState:
        import json as _json

        from fracture_cli.bake import bake
        from fracture_cli.recipe import load_recipe

        import os

        stems: dict[str, str] = {}
        for path in inputs:
            stem = os.path.splitext(os.path.basename(path))[0]
            if stem in stems:
                raise UsageError(f"{stems[stem]} and {path} would both write {stem}.* into {out_dir}; "
                                 "bake them into different folders")
            stems[stem] = path
        recipe = load_recipe(recipe_name, overrides)
        reports, failures = [], []
        for path in inputs:
            try:
                result = bake(path, out_dir, recipe, cache_dir=cache_dir)
            except FractureError as exc:
                if not keep_going or len(inputs) == 1:
                    raise
                click.echo(f"error: {exc}", err=True)
                failures.append(path)
                reports.append({"input": {"name": os.path.basename(path)}, "error": str(exc)})
                continue
            reports.append(result.report)
            if preview:
                from fracture_cli.preview import render_preview

                stem = os.path.splitext(os.path.basename(path))[0]
                render_preview(os.path.join(out_dir, f"{stem}.fracture.json"),
                               os.path.join(out_dir, f"{stem}.preview.png"))
            if not (quiet or as_json):
                r = result.report
                c = r["counts"]
                click.echo(
                    f"baked {path} with recipe '{recipe.name}': {c['fragments']} fragments, {c['modes']} modes, "
                    f"{c['tets']} tets, volume error {r['checks'].get('volume_error', float('nan')):.2e}, "
                    f"{sum(r['seconds'].values()):.1f} s -> {out_dir}",
                    err=True,
                )
        if as_json:
            click.echo(_json.dumps(reports[0] if len(reports) == 1 else reports, indent=2, sort_keys=True))
        if failures:
            raise FractureError(f"{len(failures)} of {len(inputs)} inputs failed: {', '.join(failures)}")
        return state

    return process


@cli.command("recipes", cls=TerminalCommand)
@click.argument("action", required=False, type=click.Choice(["list", "show"]), default="list")
@click.argument("name", required=False)
@click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE", help="Apply overrides before showing.")
def recipes_cmd(action, name, overrides):
    """List the destructible materials, or 'recipes show NAME' for one's resolved parameters."""

    def process(state: PipelineState) -> PipelineState:
        from fracture_cli.recipe import list_recipes, load_recipe

        if action == "list":
            for recipe_name in list_recipes():
                recipe = load_recipe(recipe_name)
                click.echo(f"{recipe_name:<12} {recipe.description}")
            return state
        if not name:
            raise UsageError("'recipes show' needs a recipe name, e.g. 'fracture recipes show glass'")
        recipe = load_recipe(name, overrides)
        click.echo(f"# {recipe.name}: {recipe.description}")
        if len(recipe.chain) > 1:
            click.echo(f"# extends: {' -> '.join(recipe.chain[1:])}")
        for section, values in recipe.to_dict().items():
            click.echo(f"\n[{section}]")
            for key, value in values.items():
                click.echo(f"{key} = {_toml_value(value)}")
        return state

    return process


def _toml_value(value) -> str:
    import json as _json

    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return _json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    return repr(value)


@cli.command("impact", cls=TerminalCommand)
@click.argument("runtime_file", type=click.Path(dir_okay=False, path_type=str))
@click.option("--point", nargs=3, type=float, required=True, metavar="X Y Z", help="Hit point, asset units.")
@click.option("--impulse", nargs=3, type=float, required=True, metavar="X Y Z", help="Impulse vector.")
@click.option("--threshold", type=float, default=None, help="Toughness (default: the file's).")
@click.option("-o", "--out", "out_glb", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Write the fragments regrouped into one mesh per group (GLB).")
@click.option("--png", "out_png", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="Render a preview picture of this impact.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def impact_cmd(runtime_file, point, impulse, threshold, out_glb, out_png, as_json):
    """Project an impact on a baked asset and print which fragments move together."""

    def process(state: PipelineState) -> PipelineState:
        import json as _json
        import os

        from fracture_cli.runtime.format import load_runtime
        from fracture_cli.runtime.impact import project_impact

        data = load_runtime(runtime_file)
        result = project_impact(data, point, impulse, threshold)
        groups: dict[int, list[str]] = {}
        for j, g in enumerate(result.groups):
            groups.setdefault(int(g), []).append(data.fragment_names[j])
        if as_json:
            click.echo(_json.dumps({"site": int(result.site), "broken_bonds": int(result.broken.sum()),
                                    "groups": list(groups.values())}, indent=2))
        else:
            click.echo(f"{len(groups)} group(s), {int(result.broken.sum())} of {len(result.broken)} bonds broken")
            for i, members in enumerate(groups.values()):
                click.echo(f"group {i}: {' '.join(members)}")
        if out_glb:
            from fracture_cli.io.regroup import write_groups_glb

            glb = runtime_file[: -len(".fracture.json")] + ".glb" if runtime_file.endswith(".fracture.json") else None
            if glb is None or not os.path.exists(glb):
                raise UsageError(f"cannot find the fragments file next to {runtime_file} (expected <stem>.glb)")
            write_groups_glb(glb, result.groups, out_glb)
        if out_png:
            from fracture_cli.preview import render_preview

            render_preview(runtime_file, out_png, impact=(point, impulse, threshold))
        return state

    return process


@cli.command("preview", cls=TerminalCommand)
@click.argument("runtime_file", type=click.Path(dir_okay=False, path_type=str))
@click.option("-o", "--out", "out_png", required=True, type=click.Path(dir_okay=False, path_type=str),
              help="Output PNG.")
@click.option("--size", nargs=2, type=int, default=(1600, 1000), show_default=True, metavar="W H",
              help="Image size in pixels.")
def preview_cmd(runtime_file, out_png, size):
    """Render a PNG of a bake: input, exploded fragments, modes, an example impact."""

    def process(state: PipelineState) -> PipelineState:
        from fracture_cli.preview import render_preview

        if size[0] < 200 or size[1] < 150 or size[0] > 8000 or size[1] > 8000:
            raise UsageError(f"--size {size[0]} {size[1]} is out of range (200..8000 x 150..8000)")
        render_preview(runtime_file, out_png, width=size[0], height=size[1])
        log.info("preview: wrote %s", out_png)
        return state

    return process


from fracture_cli.batch.command import register as _register_batch  # noqa: E402

_register_batch(cli, TerminalCommand)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``fracture`` console script."""
    cli.main(args=argv, prog_name="fracture")


if __name__ == "__main__":
    main()
