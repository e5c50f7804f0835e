"""Recipes: reusable "destructible materials" (seed 004).

A recipe is a TOML file with a one-line ``description``, an optional
``extends = "<recipe>"``, and one table per stage whose keys are that stage's
option fields::

    description = "Wood: long splinters along the grain."
    extends = "default"

    [modes]
    num_modes = 16

    [material]
    grain_axis = "z"
    grain_strength = 8.0

Every key is validated against the stage's options dataclass (type and range),
and so is every ``--set section.key=value`` override; errors name the key, the
value and the allowed range.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import tomllib
from dataclasses import dataclass, field
from typing import Any

from fracture_cli.errors import RecipeError
from fracture_cli.options import check_value, option_fields

# Section -> (module, options class). Order is the pipeline order.
SECTIONS: dict[str, tuple[str, str]] = {
    "load": ("fracture_cli.io.read", "LoadOptions"),
    "repair": ("fracture_cli.stages.repair", "RepairOptions"),
    "cage": ("fracture_cli.stages.cage", "CageOptions"),
    "tetra": ("fracture_cli.stages.tetra", "TetraOptions"),
    "material": ("fracture_cli.stages.material", "MaterialOptions"),
    "modes": ("fracture_cli.stages.modes", "ModesOptions"),
    "pieces": ("fracture_cli.stages.pieces", "PiecesOptions"),
    "smooth": ("fracture_cli.stages.smooth", "SmoothOptions"),
    "fragments": ("fracture_cli.stages.fragments", "FragmentOptions"),
    "runtime": ("fracture_cli.stages.precompute", "RuntimeOptions"),
}
TOP_LEVEL_KEYS = {"description", "extends"}


def recipes_dir() -> str:
    """Folder of the built-in recipes (``recipes/`` at the repo root, or $FRACTURE_RECIPES)."""
    env = os.environ.get("FRACTURE_RECIPES")
    if env:
        return env
    return os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "recipes")


def options_class(section: str):
    """The options dataclass of a recipe section."""
    module, name = SECTIONS[section]
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class Recipe:
    """A resolved recipe: every stage's options, defaults filled in.

    Attributes
    ----------
    name : str
        Recipe name (file stem).
    description : str
        One line for ``fracture recipes``.
    options : dict of str -> options dataclass
        One entry per section of :data:`SECTIONS`.
    chain : tuple of str
        The recipe and the recipes it extends, most derived first.
    """

    name: str
    description: str
    options: dict = field(default_factory=dict)
    chain: tuple[str, ...] = ()

    def __getitem__(self, section: str):
        return self.options[section]

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Resolved parameters as plain data (for reports and ``recipes show``)."""
        out = {}
        for section, opts in self.options.items():
            out[section] = {f.name: getattr(opts, f.name) for f in option_fields(type(opts))}
        return out


def find_recipe(name_or_path: str) -> str:
    """Path of a recipe given by name (``recipes/<name>.toml``) or by path."""
    if name_or_path.endswith(".toml") or os.sep in name_or_path or "/" in name_or_path:
        if not os.path.isfile(name_or_path):
            raise RecipeError("no such recipe file", path=name_or_path)
        return name_or_path
    path = os.path.join(recipes_dir(), f"{name_or_path}.toml")
    if not os.path.isfile(path):
        raise RecipeError(f"unknown recipe '{name_or_path}'; pick one of {', '.join(list_recipes()) or '(none)'}"
                          " or give a path to a .toml file")
    return path


def list_recipes() -> list[str]:
    """Names of the built-in recipes, sorted."""
    folder = recipes_dir()
    if not os.path.isdir(folder):
        return []
    return sorted(f[:-5] for f in os.listdir(folder) if f.endswith(".toml"))


def _read_toml(path: str) -> dict:
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise RecipeError(f"is not valid TOML: {exc}", path=path) from None
    except OSError as exc:
        raise RecipeError(f"cannot be read: {exc.strerror}", path=path) from None


def _raw_chain(name_or_path: str, seen: tuple[str, ...] = ()) -> list[tuple[str, str, dict]]:
    path = find_recipe(name_or_path)
    key = os.path.realpath(path)
    if key in seen:
        raise RecipeError(f"'extends' forms a cycle through {os.path.basename(path)}", path=path)
    data = _read_toml(path)
    unknown = set(data) - TOP_LEVEL_KEYS - set(SECTIONS)
    if unknown:
        raise RecipeError(f"unknown key(s) {', '.join(sorted(unknown))}; valid: "
                          f"{', '.join(sorted(TOP_LEVEL_KEYS | set(SECTIONS)))}", path=path)
    entry = (os.path.splitext(os.path.basename(path))[0], path, data)
    parent = data.get("extends")
    if parent is None:
        return [entry]
    if not isinstance(parent, str):
        raise RecipeError(f"extends = {parent!r} must be a recipe name or path", path=path)
    return [entry] + _raw_chain(parent, seen + (key,))


def _coerce(section: str, key: str, value: Any, where: str | None) -> Any:
    cls = options_class(section)
    fields = {f.name: f for f in option_fields(cls)}
    if key in fields:
        default = getattr(cls(), key)
        if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
    problem = check_value(cls, key, value)
    if problem:
        raise RecipeError(f"{section}.{problem}", path=where)
    return value


def parse_override(text: str) -> tuple[str, str, Any]:
    """Parse ``section.key=value`` (value in TOML syntax; bare words are strings)."""
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise RecipeError(f"--set '{text}' must look like section.key=value (e.g. modes.num_modes=16)")
    lhs, raw = text.split("=", 1)
    section, key = lhs.strip().split(".", 1)
    raw = raw.strip()
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return section, key, value


def load_recipe(name_or_path: str = "default", overrides: list[str] | tuple[str, ...] = ()) -> Recipe:
    """Resolve a recipe, its ``extends`` chain and ``--set`` overrides.

    Parameters
    ----------
    name_or_path : str, optional (default "default")
        A built-in recipe name or a path to a .toml file.
    overrides : sequence of str, optional
        ``section.key=value`` strings applied last.

    Returns
    -------
    Recipe

    Raises
    ------
    RecipeError
        Unknown recipe, section or key; wrong type; value out of range; cycle.
    """
    chain = _raw_chain(name_or_path)
    values: dict[str, dict[str, Any]] = {s: {} for s in SECTIONS}
    for _, path, data in reversed(chain):  # base first, derived last
        for section in SECTIONS:
            table = data.get(section, {})
            if not isinstance(table, dict):
                raise RecipeError(f"[{section}] must be a table", path=path)
            for key, value in table.items():
                values[section][key] = _coerce(section, key, value, path)
    for text in overrides:
        section, key, value = parse_override(text)
        if section not in SECTIONS:
            raise RecipeError(f"--set {text}: unknown section '{section}'; valid: {', '.join(SECTIONS)}")
        values[section][key] = _coerce(section, key, value, None)
    options = {s: dataclasses.replace(options_class(s)(), **values[s]) for s in SECTIONS}
    name, _, data = chain[0]
    description = data.get("description") or next((d.get("description") for _, _, d in chain if d.get("description")), "")
    return Recipe(name=name, description=str(description), options=options, chain=tuple(c[0] for c in chain))
