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
value and the allowed range. Keys of older versions still load: a renamed key
(``RENAMED`` of the options class) is read under its new name and a retired
one (``RETIRED``) is ignored, each with a warning saying what replaced it.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import tomllib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from fracture_cli.errors import RecipeError
from fracture_cli.options import OptionValue, StageOptions, check_value, option_fields
from fracture_cli.pipeline import STAGE_NAMES, stage

log = logging.getLogger(__name__)
T = TypeVar("T")

# The recipe sections, in pipeline order: one per stage of the pipeline table.
SECTIONS: tuple[str, ...] = STAGE_NAMES
TOP_LEVEL_KEYS = {"description", "extends"}
# Environment variable naming a folder of the user's own recipes.
RECIPES_ENV = "FRACTURE_RECIPES"


def builtin_recipes_dir() -> Path:
    """Folder of the built-in recipes: package data in a wheel, the top-level ``recipes/`` in a checkout."""
    packaged = resources.files("fracture_cli") / "recipes"
    if packaged.is_dir():
        return Path(str(packaged))
    return Path(__file__).resolve().parents[2] / "recipes"  # fracture_cli/pipeline/recipe.py -> the checkout


def search_path(recipes_dir: str | None = None, assets: Iterable[str] = ()) -> list[Path]:
    """Folders searched for a recipe given by name, first match wins.

    In order: ``recipes_dir`` (the ``--recipes`` flag), ``$FRACTURE_RECIPES``,
    a ``recipes/`` folder beside each asset (in the order given), ``./recipes``
    in the working directory, then the built-in recipes.
    """
    folders: list[Path] = []
    if recipes_dir:
        folders.append(Path(recipes_dir))
    if os.environ.get(RECIPES_ENV):
        folders.append(Path(os.environ[RECIPES_ENV]))
    folders += [Path(os.path.dirname(os.path.abspath(a))) / "recipes" for a in assets]
    folders += [Path.cwd() / "recipes", builtin_recipes_dir()]
    unique: list[Path] = []
    for folder in folders:
        if folder.resolve() not in [f.resolve() for f in unique]:
            unique.append(folder)
    return unique


def options_class(section: str) -> type:
    """The options dataclass of a recipe section."""
    return stage(section).options_class


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
    options: dict[str, StageOptions] = field(default_factory=dict)
    chain: tuple[str, ...] = ()

    def __getitem__(self, section: str) -> StageOptions:
        return self.options[section]

    def section(self, section: str, kind: type[T]) -> T:
        """The options of ``section``, typed as the stage's options class ``kind``."""
        options = self.options[section]
        if not isinstance(options, kind):
            raise TypeError(f"recipe section {section!r} holds {type(options).__name__}, not {kind.__name__}")
        return options

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Resolved parameters as plain data (for reports and ``recipes show``)."""
        out: dict[str, dict[str, Any]] = {}
        for section, opts in self.options.items():
            out[section] = {f.name: getattr(opts, f.name) for f in option_fields(type(opts))}
        return out


def find_recipe(name_or_path: str, search: Sequence[Path] | None = None, *, base: str | None = None,
                asked_by: str | None = None) -> str:
    """Path of a recipe given by name (first ``<folder>/<name>.toml`` on the search path) or by path.

    Parameters
    ----------
    name_or_path : str
        A name, or a path to a .toml file (relative paths resolve against ``base``).
    search : sequence of Path, optional (default :func:`search_path`)
    base : str, optional (default the working directory)
        Folder that relative paths are relative to (an ``extends`` resolves against its recipe's folder).
    asked_by : str, optional
        The recipe file that names this one (for errors).
    """
    folders = search_path() if search is None else list(search)
    if name_or_path.endswith(".toml") or os.sep in name_or_path or "/" in name_or_path:
        path = os.path.join(base, name_or_path) if base and not os.path.isabs(name_or_path) else name_or_path
        if not os.path.isfile(path):
            raise RecipeError(f"extends = {name_or_path!r}: no such recipe file {path}" if asked_by
                              else "no such recipe file", path=asked_by or path)
        return path
    for folder in folders:
        candidate = folder / f"{name_or_path}.toml"
        if candidate.is_file():
            return str(candidate)
    names = ", ".join(list_recipes(folders)) or "(none)"
    where = f"extends = {name_or_path!r}: " if asked_by else ""
    raise RecipeError(f"{where}unknown recipe '{name_or_path}'; pick one of {names} or give a path to a .toml file",
                      path=asked_by)


def list_recipes(search: Sequence[Path] | None = None) -> list[str]:
    """Names of the recipes on the search path (user folders and built-ins), sorted."""
    folders = search_path() if search is None else search
    names = {p.stem for folder in folders if folder.is_dir() for p in folder.glob("*.toml")}
    return sorted(names)


def _read_toml(path: str) -> dict[str, Any]:
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise RecipeError(f"is not valid TOML: {exc}", path=path) from None
    except OSError as exc:
        raise RecipeError(f"cannot be read: {exc.strerror}", path=path) from None


def _raw_chain(name_or_path: str, search: Sequence[Path], seen: tuple[str, ...] = (), base: str | None = None,
               asked_by: str | None = None) -> list[tuple[str, str, dict[str, Any]]]:
    path = find_recipe(name_or_path, search, base=base, asked_by=asked_by)
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
    return [entry] + _raw_chain(parent, search, seen + (key,), base=os.path.dirname(os.path.abspath(path)),
                                asked_by=path)


def _coerce(section: str, key: str, value: OptionValue, where: str | None) -> OptionValue:
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


def _current_key(section: str, key: str, where: str | None) -> str | None:
    """The key to use for ``section.key`` of an older recipe: renamed keys map to their new name, retired ones
    to None (ignored), each with a warning; ``--set`` (``where`` None) of a retired key is an error."""
    cls = options_class(section)
    renamed = getattr(cls, "RENAMED", {})
    if key in renamed:
        new, note = renamed[key]
        log.warning("%s: %s.%s is now %s.%s (%s)", where or "--set", section, key, section, new, note)
        return new
    note = getattr(cls, "RETIRED", {}).get(key)
    if note is None:
        return key
    if where is None:
        raise RecipeError(f"--set {section}.{key}: this option is no longer used: {note}")
    log.warning("%s: %s.%s is no longer used and is ignored: %s", where, section, key, note)
    return None


def parse_override(text: str) -> tuple[str, str, OptionValue]:
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


def load_recipe(name_or_path: str = "default", overrides: Sequence[str] = (), *,
                search: Sequence[Path] | None = None) -> Recipe:
    """Resolve a recipe, its ``extends`` chain and ``--set`` overrides.

    Parameters
    ----------
    name_or_path : str, optional (default "default")
        A built-in recipe name or a path to a .toml file.
    overrides : sequence of str, optional
        ``section.key=value`` strings applied last.
    search : sequence of Path, optional (default :func:`search_path`)
        Folders searched for recipe names (also for names in ``extends``).

    Returns
    -------
    Recipe

    Raises
    ------
    RecipeError
        Unknown recipe, section or key; wrong type; value out of range; cycle.
    """
    chain = _raw_chain(name_or_path, search_path() if search is None else search)
    values: dict[str, dict[str, Any]] = {s: {} for s in SECTIONS}
    for _, path, data in reversed(chain):  # base first, derived last
        for section in SECTIONS:
            table = data.get(section, {})
            if not isinstance(table, dict):
                raise RecipeError(f"[{section}] must be a table", path=path)
            for old_key, value in table.items():
                key = _current_key(section, old_key, path)
                if key is not None:
                    values[section][key] = _coerce(section, key, value, path)
    for text in overrides:
        section, key, value = parse_override(text)
        if section not in SECTIONS:
            raise RecipeError(f"--set {text}: unknown section '{section}'; valid: {', '.join(SECTIONS)}")
        current = _current_key(section, key, None)
        if current is not None:
            values[section][current] = _coerce(section, current, value, None)
    options = {s: dataclasses.replace(options_class(s)(), **values[s]) for s in SECTIONS}
    name, _, data = chain[0]
    description = data.get("description") or next(
        (d.get("description") for _, _, d in chain if d.get("description")), "")
    return Recipe(name=name, description=str(description), options=options, chain=tuple(c[0] for c in chain))
