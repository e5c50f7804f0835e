"""Command-line plumbing: click options generated from stage options, global flags, logging to stderr.

Every field of a stage's options dataclass becomes one flag of that stage's
command. A flag left out keeps the recipe's value (``fracture -r NAME ...``,
``default`` unless given), and ``--help`` shows that value, so the chain and
``bake`` never disagree on a default. Lists and tables (colours, material
boxes) take a TOML value: ``--interior-color "[0.9, 0.8, 0.7, 1]"``.
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import tomllib
from collections.abc import Callable, Sequence
from typing import Any

import click

from fracture_cli.errors import UsageError
from fracture_cli.options import check_value, option_fields
from fracture_cli.system import progress

# Flags of the top-level group that may also follow a command (``fracture bake x.glb -o out -v``).
GLOBAL_FLAGS = frozenset({"-v", "-vv", "-vvv", "--verbose", "-q", "--quiet", "--debug"})
# ... and global options that take a value (``--jobs 2``, ``--jobs=2``, ``-j2``, ``--recipes DIR``).
GLOBAL_VALUED = ("-j", "--jobs", "-r", "--recipe", "--set", "--recipes")


def hoist_global_flags(args: Sequence[str]) -> list[str]:
    """``args`` with the global flags moved to the front, so they work before and after any command.

    Every option of the top-level group moves (:data:`GLOBAL_FLAGS`, and
    :data:`GLOBAL_VALUED` with its value, as ``--opt VALUE`` or ``--opt=VALUE``),
    in order. ``bake``, ``batch`` and ``recipes`` also have ``-r``/``--set`` of
    their own; given after them, the global ones do the same. Nothing after a
    ``--`` moves, nor ``--help`` or ``--version``.
    """
    args = list(args)
    end = args.index("--") if "--" in args else len(args)
    flags, rest = [], []
    i = 0
    while i < end:
        a = args[i]
        if a in GLOBAL_FLAGS:
            flags.append(a)
        elif a in GLOBAL_VALUED and i + 1 < end:
            flags += [a, args[i + 1]]
            i += 1
        elif a.startswith("--") and a.split("=", 1)[0] in GLOBAL_VALUED:
            flags.append(a)
        elif a.startswith("-j") and a[2:].isdigit():
            flags.append(a)
        else:
            rest.append(a)
        i += 1
    return flags + rest + args[end:]


class TomlValue(click.ParamType):
    """A value in TOML syntax (``[0.5, 0.5, 0.5, 1]``, ``[{name = "leg", ...}]``); bare words are strings."""

    name = "toml"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if not isinstance(value, str):
            return value
        return parse_toml_value(value)


def parse_toml_value(raw: str) -> Any:
    """The value of TOML text ``raw``; text that is not TOML is taken as a string."""
    try:
        return tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        return raw.strip()


def _field_default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    factory: Any = f.default_factory
    return factory()


def _toml_text(value: Any) -> str:
    """A value as TOML (what ``recipes show`` prints and structured flags accept)."""
    import json

    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_text(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_text(v)}" for k, v in value.items()) + " }"
    return repr(value)


toml_text = _toml_text


class RecipeOption(click.Option):
    """A stage flag whose ``--help`` shows the value the active recipe gives it."""

    def __init__(self, *args: Any, section: str, field_name: str, recipe_value: Callable[[str, str], Any],
                 **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.section = section
        self.field_name = field_name
        self.recipe_value = recipe_value

    def get_help_record(self, ctx: click.Context) -> tuple[str, str] | None:
        record = super().get_help_record(ctx)
        if record is None:
            return None
        name, value = self.recipe_value(self.section, self.field_name)
        return record[0], f"{record[1]} [{name}: {_toml_text(value)}]"


def stage_options(options_cls: type, section: str, recipe_value: Callable[[str, str], Any],
                  short: dict[str, str] | None = None) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Decorator adding one click option per field of a stage's options dataclass (default: the recipe's)."""
    short = short or {}

    def decorate(fn: Callable[..., Any]) -> Callable[..., Any]:
        for f in reversed(option_fields(options_cls)):
            default = _field_default(f)
            flag = "--" + f.name.replace("_", "-")
            meta = f.metadata
            help_text = meta["help"]
            if meta.get("min") is not None or meta.get("max") is not None:
                hi = meta.get("max") if meta.get("max") is not None else "inf"
                help_text += f" [range {meta.get('min', '-inf')}..{hi}]"
            names = [flag] + ([short[f.name]] if f.name in short else [])
            extra: dict[str, Any] = {}
            if isinstance(default, bool):
                names = [f"{flag}/--no-{flag[2:]}"]
            elif isinstance(default, (list, tuple, dict)):
                extra = {"type": TomlValue(), "metavar": "TOML"}
            else:
                extra = {"type": _click_type(f, default)}
            fn = click.option(*names, f.name, cls=RecipeOption, section=section, field_name=f.name,
                              recipe_value=recipe_value, default=None, help=help_text, **extra)(fn)
        return fn

    return decorate


def _click_type(f: dataclasses.Field, default: Any) -> click.ParamType:
    choices = f.metadata.get("choices")
    if choices:
        return click.Choice([str(c) for c in choices])
    if isinstance(default, int):
        return click.INT
    if isinstance(default, float):
        return click.FLOAT
    return click.STRING


def build_options(options_cls: type, kwargs: dict[str, Any], base: Any) -> Any:
    """``base`` (the recipe's options) with the flags given in ``kwargs`` (None = not given) applied."""
    changes = {}
    for f in option_fields(options_cls):
        value = kwargs.get(f.name)
        if value is None:
            continue
        default = getattr(base, f.name)
        if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        problem = check_value(options_cls, f.name, value)
        if problem:
            flag = "--" + f.name.replace("_", "-")
            raise UsageError(problem.replace(f"{f.name} = ", f"{flag} ", 1))
        changes[f.name] = value
    return dataclasses.replace(base, **changes)


class _StderrFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        msg = record.getMessage()
        if record.levelno >= logging.WARNING:
            return f"{record.levelname.lower()}: {msg}"
        return msg


class _ProgressHandler(logging.Handler):
    """Writes log lines through :func:`fracture_cli.system.progress.write`, above any progress bars."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            progress.write(self.format(record))
        except Exception:  # a logging failure must not hide the error being logged
            self.handleError(record)


def configure_output(verbose: int, quiet: bool) -> None:
    """Route the library's log records and progress to stderr at the level the user chose.

    ``-q``: errors only, no progress. Default: warnings, and progress (a bar on
    a terminal, a line every 10 s otherwise). ``-v``: every step's start and
    time; ``-vv``: debug detail.
    """
    logger = logging.getLogger("fracture_cli")
    for h in list(logger.handlers):
        if isinstance(h, _ProgressHandler):
            logger.removeHandler(h)
    if quiet:
        level = logging.ERROR
    elif verbose >= 2:
        level = logging.DEBUG
    elif verbose == 1:
        level = logging.INFO
    else:
        level = logging.WARNING
    handler = _ProgressHandler()
    handler.setFormatter(_StderrFormatter())
    logger.addHandler(handler)
    logger.setLevel(level)
    logger.propagate = False
    progress.configure(None if quiet else sys.stderr)
