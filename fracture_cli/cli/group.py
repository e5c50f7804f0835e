"""The ``fracture`` command line: a click chain of the pipeline's stages, plus ``bake`` and tools.

Commands only parse options and call the library. The chained stage commands
are generated from :data:`fracture_cli.pipeline.STAGES` (click's imagepipe
pattern: each returns a processor, :func:`run_chain` threads one
:class:`~fracture_cli.pipeline.PipelineState` through them with one
:class:`~fracture_cli.pipeline.runner.Runner`), and their flags from the stages'
option dataclasses with the active recipe's values as defaults. The console
script's entry point, :func:`fracture_cli.cli.main`, imports this module after
installing its Ctrl-C handling (:mod:`fracture_cli.system.interrupts`).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import select
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NoReturn

import click

from fracture_cli import __version__
from fracture_cli.cli.options import build_options, configure_output, hoist_global_flags, stage_options, toml_text
from fracture_cli.errors import EXIT_FAILURE, FractureError, exit_code_for
from fracture_cli.pipeline import STAGE_NAMES, PipelineState, stage
from fracture_cli.pipeline.runner import Runner
from fracture_cli.system import progress
from fracture_cli.system.interrupts import EXIT_INTERRUPTED, caused_by_interrupt
from fracture_cli.system.parallel import available_cores

log = logging.getLogger("fracture_cli")

def full_chain(asset: str = "sample_assets/chair.glb", out_dir: str = "build/chair", recipe: str = "wood") -> list[str]:
    """The words after ``fracture`` of a chain of every stage, in :data:`~fracture_cli.pipeline.STAGES` order.

    It saves the cage after ``cage`` and the tets after ``tetra`` (beside
    ``out_dir``) and exports into ``out_dir``: the same bytes as
    ``fracture bake ASSET -o OUT_DIR -r RECIPE``. The ``--help`` example is
    made from it, so it cannot leave a stage out (tests check the README's too).
    """
    stem = os.path.basename(out_dir.rstrip("/")) or "out"
    words = ["-r", recipe]
    for name in STAGE_NAMES:
        words += [name, asset] if name == "load" else [name]
        if name == "cage":
            words += ["save-cage", f"{os.path.dirname(out_dir) or '.'}/{stem}.cage.obj"]
        if name == "tetra":
            words += ["save-tets", f"{os.path.dirname(out_dir) or '.'}/{stem}.tets.npz"]
    return words + ["export", out_dir]


def wrapped_command(words: list[str], width: int = 88, indent: str = "  ") -> str:
    """``fracture WORDS`` as shell lines of at most ``width`` columns, continued with a backslash."""
    lines, line = [], indent + "fracture"
    for word in words:
        if len(line) + 1 + len(word) > width - 2:
            lines.append(line + " \\")
            line = indent + "    " + word
        else:
            line += " " + word
    return "\n".join(lines + [line])


EXAMPLES = f"""
\b
Examples:
  # bake an asset with a recipe (a reusable "destructible material")
  fracture bake sample_assets/chair.glb -o build/chair --recipe wood
\b
  # the same, step by step (every stage: same bytes), saving the cage and tets for inspection
{wrapped_command(full_chain())}
\b
  # every stage's flags, with the values the recipe gives them
  fracture -r wood smooth --help
\b
  # try an impact on a baked asset
  fracture impact build/chair/chair.fracture.json --point 0 1 0 --impulse 0 -5 0
\b
  # round-trip a mesh (geometry, UVs, normals, materials)
  fracture load sample_assets/chair.glb save build/chair_copy.glb
\b
Global options (-v, -q, --debug, -j N, -r, --set, --recipes) may also follow any command.
"""


@dataclass
class Chain:
    """What the chained commands share: the runner and the state so far (and, through it, the recipe)."""

    runner: Runner
    state: PipelineState = dataclasses.field(default_factory=PipelineState)

    @property
    def recipe(self) -> Any:
        """The recipe of the command line, looked up beside the loaded asset too."""
        return active_recipe((self.state.source,) if self.state.source else ())


Processor = Callable[[Chain], None]


@dataclass(frozen=True)
class Step:
    """A chained command's processor with the files it reads and writes, known before the chain runs.

    :func:`run_chain` gives the whole chain's files to the output guard
    (:func:`fracture_cli.io.preflight.guard_outputs`) before the first step,
    so ``load s.obj repair cage save-cage s.obj`` is refused before any work.
    """

    run: Processor
    reads: tuple[str, ...] = ()
    writes: tuple[str, ...] = ()
    saves: str | None = None  # ``save PATH``: the surface file, and for an OBJ its material library
    loads: str | None = None  # ``load PATH``: the chain's source from here on
    exports: str | None = None  # ``export DIR``: the source's bake set is published into DIR

    def __call__(self, chain: Chain) -> None:
        self.run(chain)


def guard_chain(processors: list[Processor | None]) -> None:
    """Refuse a chain whose outputs would replace a file it reads or a published bake set's file."""
    # on first use: keeps `fracture` start-up light
    from fracture_cli.io.inputs import input_files
    from fracture_cli.io.names import surface_outputs
    from fracture_cli.io.preflight import guard_outputs
    from fracture_cli.pipeline.bake import stem_of

    steps = [p for p in processors if isinstance(p, Step)]
    if not any(s.writes or s.saves or s.exports for s in steps):
        return
    reads: list[str] = []
    writes: list[str] = []
    sets: list[tuple[str, str]] = []
    source = None
    for step in steps:
        if step.loads is not None:
            source = step.loads
            reads += input_files(source)
        reads += step.reads
        writes += list(step.writes) + (surface_outputs(step.saves) if step.saves is not None else [])
        if step.exports is not None and source is not None:
            sets.append((step.exports, stem_of(source)))
    guard_outputs(writes, reads, sets=sets)
    # on first use: keeps `fracture` start-up light
    from fracture_cli.io.preflight import preflight

    for folder, stem in sets:  # as a bake does: a dangling link, a file in the way, a read-only folder, up front
        preflight(folder, stem)


def _root_meta() -> dict[str, Any]:
    ctx = click.get_current_context(silent=True)
    return ctx.find_root().meta if ctx is not None else {}


def active_recipe(assets: tuple[str, ...] = ()) -> Any:
    """The recipe the command line chose (``-r``, ``--set``, ``--recipes``), loaded once."""
    # on first use: keeps `fracture` start-up light
    from fracture_cli.pipeline.recipe import load_recipe, search_path

    meta = _root_meta()
    loaded = meta.setdefault("fracture.recipes", {})  # by asset folders searched
    if assets not in loaded:
        search = search_path(meta.get("fracture.recipes_dir"), assets)
        loaded[assets] = load_recipe(meta.get("fracture.recipe_name", "default"), meta.get("fracture.overrides", ()),
                                     search=search)
    return loaded[assets]


def _recipe_value(section: str, field_name: str) -> tuple[str, Any]:
    recipe = active_recipe()
    return f"recipe '{recipe.name}'", getattr(recipe[section], field_name)


class FractureGroup(click.Group):
    """The chain group: global flags anywhere, stage commands built on demand, errors as one line."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        return super().parse_args(ctx, hoist_global_flags(args))

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(STAGE_NAMES) + [n for n in super().list_commands(ctx) if n not in STAGE_NAMES]

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in STAGE_NAMES and cmd_name not in self.commands:
            self.add_command(_stage_command(cmd_name))
        return super().get_command(ctx, cmd_name)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        # Stage lines come from the table, so `fracture --help` does not import every stage.
        rows = [(s, stage(s).help) for s in STAGE_NAMES]
        rows += [(n, self.commands[n].get_short_help_str(60)) for n in super().list_commands(ctx)
                 if n not in STAGE_NAMES]
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    def make_context(self, info_name: str | None, args: list[str], parent: click.Context | None = None,
                     **extra: Any) -> click.Context:
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except KeyboardInterrupt:  # while parsing (click would say "Aborted!" and exit 1)
            _interrupted()

    def invoke(self, ctx: click.Context) -> Any:
        # on first use: keeps `fracture` start-up light
        from fracture_cli.io.outputs import forget_published

        forget_published()  # the Ctrl-C message lists only this run's outputs
        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except KeyboardInterrupt:
            _interrupted()
        except Exception as exc:  # FractureError: one line; anything else is a bug: one line unless --debug
            # on first use: keeps `fracture` start-up light
            from fracture_cli.pipeline.bake import describe_error

            if caused_by_interrupt(exc):  # an interrupt that surfaced as another error (a native import that failed)
                _interrupted()
            if isinstance(exc, BrokenPipeError) and stdout_closed():  # the reader left: a normal end, quietly
                ctx.exit(quiet_broken_pipe())
            if ctx.meta.get("fracture.debug"):
                traceback.print_exc()
            click.echo(f"error: {describe_error(exc)}", err=True)
            ctx.exit(exit_code_for(exc) if isinstance(exc, FractureError) else EXIT_FAILURE)
        finally:
            # the stream this command wrote progress to may close after it (a test runner's capture):
            # library calls after the command are silent again, as the library default
            progress.configure(None)


def _interrupted() -> NoReturn:
    """End the command as interrupted: one truthful line (what was published), exit code 130."""
    # on first use: keeps `fracture` start-up light
    from fracture_cli.io.outputs import interrupt_message

    click.echo(f"fracture: {interrupt_message()}", err=True)
    raise click.exceptions.Exit(EXIT_INTERRUPTED)


#: Exit code when whoever reads stdout stopped reading (``fracture recipes | head -1``): 128 + SIGPIPE, what a
#: shell reports for git, ls or any C tool stopped by the closed pipe, so ``set -o pipefail`` treats it alike.
EXIT_BROKEN_PIPE = 141


def stdout_closed() -> bool:
    """Whether stdout is a pipe whose reader has gone (poll reports POLLERR on its write end)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # not a file (tests capture it)
        return False
    poll = select.poll()
    poll.register(fd, select.POLLOUT)
    return any(events & select.POLLERR for _, events in poll.poll(0))


def quiet_broken_pipe() -> int:
    """Point stdout at /dev/null (so the exit's flush cannot fail again); returns :data:`EXIT_BROKEN_PIPE`."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return EXIT_BROKEN_PIPE


class TerminalCommand(click.Command):
    """A command that ends the chain, so its options may follow its arguments.

    In a chain group click parses subcommands with interspersed options off (an
    argument would otherwise swallow the next command). Commands that take
    everything after them (bake, impact, preview, recipes) turn it back on.
    """

    def make_context(self, info_name: str | None, args: list[str], parent: click.Context | None = None,
                     **extra: Any) -> click.Context:
        extra["allow_interspersed_args"] = True
        return super().make_context(info_name, args, parent=parent, **extra)


@click.group(cls=FractureGroup, chain=True, invoke_without_command=False, epilog=EXAMPLES,
             context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, "--version", prog_name="fracture")
@click.option("--debug", is_flag=True, help="Show tracebacks for errors.")
@click.option("-q", "--quiet", is_flag=True, help="Print only errors (no progress).")
@click.option("-v", "--verbose", count=True, help="Log every step (-vv for debug detail).")
@click.option("-r", "--recipe", "recipe_name", default="default", show_default=True,
              help="Recipe the chained stages take their options from (see 'fracture recipes').")
@click.option("--set", "overrides", multiple=True, metavar="SECTION.KEY=VALUE",
              help="Override one recipe parameter, e.g. --set modes.num_modes=16 (repeatable).")
@click.option("--recipes", "recipes_dir", type=click.Path(file_okay=False, path_type=str), default=None,
              help="Folder of your own recipes, searched first (then $FRACTURE_RECIPES, recipes/ beside the "
                   "asset, ./recipes, the built-ins).")
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=None, metavar="N",
              help="Processes a bake may use for independent work (default: every core, here "
                   f"{available_cores()}); the outputs are the same bytes for any N.")
@click.pass_context
def cli(ctx: click.Context, debug: bool, quiet: bool, verbose: int, recipe_name: str, overrides: tuple[str, ...],
        recipes_dir: str | None, jobs: int | None) -> None:
    """Prefracture game assets with fracture modes (Sellan et al. 2023).

    Run everything from a recipe with 'bake', or chain the stages left to
    right; a chain of every stage writes the same files as 'bake'. Stage
    flags default to the recipe's values (-r, default 'default').
    """
    ctx.meta.update({"fracture.debug": debug, "fracture.quiet": quiet, "fracture.recipe_name": recipe_name,
                     "fracture.overrides": overrides, "fracture.recipes_dir": recipes_dir,
                     "fracture.jobs": jobs})
    configure_output(verbose, quiet)


@cli.result_callback()
def run_chain(processors: list[Processor | None], **_: Any) -> None:
    """Thread one pipeline state through the chained commands' processors."""
    if not any(processors):
        return
    guard_chain(processors)
    chain = Chain(runner=Runner("fracture", jobs=_root_meta().get("fracture.jobs")))
    for process in processors:
        if process is not None:
            process(chain)


# ----------------------------------------------------------------------------
# Chained commands: one per stage of the pipeline table, plus saving and loading intermediate results

def _stage_command(name: str) -> click.Command:
    """The chained command of stage ``name``: its flags from the options class, defaults from the recipe."""
    row = stage(name)

    @stage_options(row.options_class, name, _recipe_value, short=row.short)
    def command(**kwargs: Any) -> Processor:
        path = kwargs.pop("path", None)

        def process(chain: Chain) -> None:
            if path is not None:
                chain.state = PipelineState(source=path)
                chain.runner.label = os.path.splitext(os.path.basename(path))[0]
            options = build_options(row.options_class, kwargs, chain.recipe[name])
            chain.state = chain.runner.run(name, chain.state, options)

        return Step(process, loads=path) if path is not None else process

    if name == "load":
        command = click.argument("path", type=click.Path(dir_okay=True, path_type=str))(command)
    return click.command(name, help=row.help + _consumes(row.consumes))(command)


def _consumes(fields: tuple[str, ...]) -> str:
    needs = [f for f in fields if f != "source"]
    return f"\n\nNeeds: {', '.join(needs)} (from earlier commands in the chain)." if needs else ""


def _file_command(name: str, doc: str, run: Callable[[Chain, str], None], access: str) -> None:
    """Register a chained command taking one PATH argument; ``run(chain, path)`` works.

    ``access`` says what PATH is to the output guard: ``"reads"`` (a file read), ``"writes"`` (a file
    written), ``"saves"`` (a surface written, with its companion files) or ``"exports"`` (the folder a
    bake set is published into).
    """
    folder = access == "exports"

    @click.argument("path", type=click.Path(dir_okay=folder, file_okay=not folder, path_type=str))
    def command(path: str) -> Processor:
        def process(chain: Chain) -> None:
            run(chain, path)

        if access == "exports":
            return Step(process, exports=path)
        if access == "saves":
            return Step(process, saves=path)
        return Step(process, reads=(path,)) if access == "reads" else Step(process, writes=(path,))

    cli.command(name, help=doc)(command)


def _save(chain: Chain, path: str) -> None:
    # on first use: keeps `fracture` start-up light
    from fracture_cli.io.write import save_surface

    save_surface(path, chain.state.need("surface", "save"))
    log.info("save: wrote %s", path)


def _save_cage(chain: Chain, path: str) -> None:
    # on first use: keeps `fracture` start-up light
    from fracture_cli.io.cage_io import save_cage

    save_cage(path, chain.state.need("cage", "save-cage"))


def _save_tets(chain: Chain, path: str) -> None:
    # on first use: keeps `fracture` start-up light
    from fracture_cli.io.cage_io import save_tetmesh

    save_tetmesh(path, chain.state.need("tet_mesh", "save-tets"))


def _load_tets(chain: Chain, path: str) -> None:
    # on first use: keeps `fracture` start-up light
    from fracture_cli.io.cage_io import load_tetmesh

    chain.state = dataclasses.replace(chain.state, tet_mesh=load_tetmesh(path))


def _export(chain: Chain, out_dir: str) -> None:
    # on first use: keeps `fracture` start-up light
    from fracture_cli.pipeline.bake import build_report, stem_of, write_outputs

    state = chain.state
    report = build_report(state, chain.recipe, chain.runner)
    stem = stem_of(state.need("source", "export"))
    write_outputs(out_dir, stem, state, report, chain.runner)
    log.info("export: wrote %s/%s.glb, %s.fracture.json/.bin and %s.report.json", out_dir, stem, stem, stem)


_file_command("save", "Write the current surface (GLB, OBJ with its <stem>.mtl, PLY, STL, OFF) in the input's "
              "units.", _save, "saves")
_file_command("save-cage", "Write the cage surface (OBJ, PLY, STL, OFF) for inspection.", _save_cage, "writes")
_file_command("save-tets", "Write the tet mesh as .npz (vertices, tets, normalization).", _save_tets, "writes")
_file_command("load-tets", "Read a tet mesh saved by save-tets (to resume a chain from it).", _load_tets, "reads")
_file_command("export", "Write <stem>.glb, the runtime file <stem>.fracture.json/.bin and <stem>.report.json "
              "into the folder PATH, as bake does (needs runtime).", _export, "exports")



__all__ = ["Chain", "EXAMPLES", "Step", "TerminalCommand", "active_recipe", "cli", "guard_chain",
           "toml_text"]
