"""The atlas's JSON summary and its ``--require`` gate.

The summary is a plain dict with a fixed key order and floats rounded to 6
significant digits (Python's correctly rounded formatting: the same text on
every machine); non-finite or undefined figures are ``null``. A requirement is
``KEY<=VALUE``, ``KEY>=VALUE``, ``KEY<VALUE`` or ``KEY>VALUE`` with ``KEY`` one of
the figures (:data:`FIGURE_KEYS`, defined in :mod:`fracture_cli.atlas.sweep`);
an undefined figure fails every requirement on it.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, fields

from fracture_cli.atlas.sweep import AtlasFigures
from fracture_cli.errors import UsageError

SUMMARY_FORMAT = "fracture-atlas"
SUMMARY_VERSION = 1
SIGNIFICANT_DIGITS = 6
FIGURE_KEYS: tuple[str, ...] = tuple(f.name for f in fields(AtlasFigures))
_OPERATORS = {
    "<=": lambda a, b: a <= b,
    ">=": lambda a, b: a >= b,
    "<": lambda a, b: a < b,
    ">": lambda a, b: a > b,
}
_REQUIREMENT = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*(<=|>=|<|>)\s*(\S+)\s*$")


def rounded(value: float | int | None) -> float | int | None:
    """``value`` to :data:`SIGNIFICANT_DIGITS` significant digits; ints unchanged; None for None, inf, NaN."""
    if value is None or isinstance(value, (bool, int)):
        return value
    value = float(value)
    if not math.isfinite(value):
        return None
    return float(f"{value:.{SIGNIFICANT_DIGITS}g}")


def figures_dict(figures: AtlasFigures) -> dict[str, float | int | None]:
    """The figures as a dict in :data:`FIGURE_KEYS` order, rounded."""
    return {key: rounded(value) for key, value in asdict(figures).items()}


def summary_json(summary: dict) -> str:
    """The summary as JSON text: two-space indent, the dict's own key order, one trailing newline."""
    return json.dumps(summary, indent=2, ensure_ascii=True, allow_nan=False) + "\n"


@dataclass(frozen=True)
class Requirement:
    """One parsed ``KEY OP VALUE`` requirement.

    Attributes
    ----------
    key : str
        A figure name (:data:`FIGURE_KEYS`).
    operator : str
        ``"<="``, ``">="``, ``"<"`` or ``">"``.
    value : float
        The bound, finite.
    """

    key: str
    operator: str
    value: float

    def __str__(self) -> str:
        return f"{self.key}{self.operator}{self.value:g}"

    def holds(self, actual: float | int | None) -> bool:
        """Whether ``actual`` satisfies it (an undefined figure never does)."""
        return actual is not None and _OPERATORS[self.operator](actual, self.value)


def parse_requirement(text: str) -> Requirement:
    """Parse ``"KEY<=VALUE"`` (also ``>=``, ``<``, ``>``); :class:`UsageError` on anything else.

    Raises
    ------
    UsageError
        The text is malformed, the key unknown (the message lists the valid
        keys) or the value not a finite number.
    """
    match = _REQUIREMENT.match(text)
    if not match:
        raise UsageError(f"atlas requirement {text!r} is not KEY<=VALUE, KEY>=VALUE, KEY<VALUE or KEY>VALUE")
    key, operator, number = match.groups()
    if key not in FIGURE_KEYS:
        raise UsageError(f"atlas requirement {text!r}: unknown key {key!r}; pick one of {', '.join(FIGURE_KEYS)}")
    try:
        value = float(number)
    except ValueError:
        raise UsageError(f"atlas requirement {text!r}: {number!r} is not a number") from None
    if not math.isfinite(value):
        raise UsageError(f"atlas requirement {text!r}: the bound must be a finite number")
    return Requirement(key, operator, value)


def failed_requirements(figures: dict[str, float | int | None], requirements) -> tuple[str, ...]:
    """The requirements ``figures`` does not meet, one line each (empty: all hold).

    Parameters
    ----------
    figures : dict
        :func:`figures_dict` (the rounded figures: the gate judges what the summary shows).
    requirements : iterable of str or Requirement

    Returns
    -------
    tuple of str
        ``"hit_detached = 0.685, required >= 0.95"`` per failing requirement, in the given order.
    """
    failures = []
    for item in requirements:
        requirement = item if isinstance(item, Requirement) else parse_requirement(item)
        actual = figures.get(requirement.key)
        if not requirement.holds(actual):
            shown = "undefined" if actual is None else f"{actual:g}"
            failures.append(f"{requirement.key} = {shown}, required {requirement.operator} {requirement.value:g}")
    return tuple(failures)
