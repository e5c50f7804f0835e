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
                raise UsageError(problem)
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


@click.group(cls=FractureGroup, chain=True, invoke_without_command=False, epilog=EXAMPLES,
             context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, "--version", prog_name="fracture")
@click.option("--debug", is_flag=True, help="Show tracebacks for errors.")
@click.option("-q", "--quiet", is_flag=True, help="Print only errors.")
@click.option("-v", "--verbose", count=True, help="More progress output (-vv for debug detail).")
@click.pass_context
def cli(ctx, debug, quiet, verbose):
    """Prefracture game assets with fracture modes (Sellan et al. 2023).

    Chain stages left to right (load, cage, tetra, modes, pieces, smooth,
    fragments, export), or run everything from a recipe with 'bake'.
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


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``fracture`` console script."""
    cli.main(args=argv, prog_name="fracture")


if __name__ == "__main__":
    main()
