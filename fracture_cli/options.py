"""One way to declare stage options, shared by the library, the CLI and recipes.

Every stage has a frozen dataclass of options whose fields are declared with
:func:`option`. The metadata (help text, allowed range or choices) is read by
the CLI to build its flags and by :mod:`fracture_cli.pipeline.recipe` to validate
recipes and ``--set`` overrides, so the three can never disagree on a default
or a range.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import field
from typing import Any, ClassVar, Protocol

# What a recipe key or a flag can hold (TOML scalars and lists of them).
OptionValue = bool | int | float | str | list | tuple | None


class StageOptions(Protocol):
    """Every stage's options: a frozen dataclass of :func:`option` fields (one class per stage)."""

    __dataclass_fields__: ClassVar[dict[str, Any]]


def option(default: Any, help: str, *, min: float | None = None, max: float | None = None,
           choices: tuple | None = None, min_exclusive: bool = False):
    """Declare one option field.

    Parameters
    ----------
    default : object
        Default value; its type is the option's type.
    help : str
        One line for ``--help`` and ``fracture recipes show``.
    min, max : float, optional
        Inclusive bounds for numbers (``min`` exclusive when ``min_exclusive``).
    choices : tuple, optional
        The allowed values.
    """
    meta = {"help": help, "min": min, "max": max, "choices": choices, "min_exclusive": min_exclusive}
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda: type(default)(default), metadata=meta)
    return field(default=default, metadata=meta)


def option_fields(options_cls) -> list[dataclasses.Field]:
    """The declared option fields of an options dataclass, in declaration order."""
    return [f for f in dataclasses.fields(options_cls) if "help" in f.metadata]


def check_value(options_cls, name: str, value: Any) -> str | None:
    """Return why ``value`` is not allowed for option ``name``, or None if it is."""
    fields = {f.name: f for f in option_fields(options_cls)}
    if name not in fields:
        return f"{name}: unknown option; valid: {', '.join(sorted(fields))}"
    f = fields[name]
    meta = f.metadata
    default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[operator]
    if meta["choices"] is not None and value not in meta["choices"]:
        return f"{name} = {value!r} is not one of {', '.join(map(repr, meta['choices']))}"
    if isinstance(default, list):
        if not isinstance(value, list):
            return f"{name} = {value!r} must be a list"
        if not _all_finite(value):
            return f"{name} = {_show(value)} must contain finite numbers only (no nan or inf)"
        if default and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in default):
            # A fixed-size vector of numbers (e.g. a colour): same length, each in range.
            if len(value) != len(default) or not all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
                return f"{name} = {value!r} must be a list of {len(default)} numbers"
            lo, hi = meta["min"], meta["max"]
            if any((lo is not None and x < lo) or (hi is not None and x > hi) for x in value):
                return f"{name} = {value!r} has values out of range [{lo}, {hi}]"
        return None
    if isinstance(default, bool):
        if not isinstance(value, bool):
            return f"{name} = {value!r} must be true or false"
        return None
    if isinstance(default, (int, float)) and not isinstance(default, bool):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"{name} = {value!r} must be a number"
        if isinstance(default, int) and not isinstance(value, int):
            return f"{name} = {_show(value)} must be a whole number"
        if not math.isfinite(value):
            # NaN passes every comparison and inf is never a usable size or weight: both would end up as
            # invalid JSON in the report or GLB, or as a failure after the whole bake.
            return f"{name} = {_show(value)} must be a finite number (not nan or inf)"
        lo, hi = meta["min"], meta["max"]
        bad_lo = lo is not None and (value <= lo if meta["min_exclusive"] else value < lo)
        bad_hi = hi is not None and value > hi
        if bad_lo or bad_hi:
            left = "(" if meta["min_exclusive"] else "["
            low, high = lo if lo is not None else "-inf", hi if hi is not None else "inf"
            return f"{name} = {value!r} is out of range {left}{low}, {high}]"
    if isinstance(default, str) and not isinstance(value, str):
        return f"{name} = {value!r} must be a string"
    return None


def _show(value: Any) -> str:
    """``value`` as the user would type it in TOML (``nan``, ``inf``), for messages."""
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, list):
        return "[" + ", ".join(_show(x) for x in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_show(v)}" for k, v in value.items()) + " }"
    return repr(value)


def _all_finite(value: Any) -> bool:
    """False if a float anywhere inside ``value`` (lists, dicts: e.g. material boxes) is nan or inf."""
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, (list, tuple)):
        return all(_all_finite(x) for x in value)
    if isinstance(value, dict):
        return all(_all_finite(x) for x in value.values())
    return True
