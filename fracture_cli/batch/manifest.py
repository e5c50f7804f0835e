"""Batch manifests: which assets to bake, with which recipe and overrides.

A manifest is a TOML file; paths are relative to the manifest's folder::

    [assets]                                   # "file or glob" = "recipe"
    "pillar.glb" = "stone"
    "props/*.glb" = "stone"
    "chair.glb" = { recipe = "wood", set = ["modes.num_modes=16"] }

    [[batch]]                                  # the same as a table
    glob = "rocks/**/*.obj"                    # or: file = "rocks/big.obj"
    recipe = "recipes/granite.toml"            # a path (relative to the manifest) or a name
    set = ["cage.target_faces=1000"]
    timeout = 7200                             # seconds; instead of --timeout for these assets

An explicit file wins over a glob that also matches it; two globs that match one
file with different settings are an error. Globs skip files that are not meshes
(a glTF's ``.bin``, an OBJ's ``.mtl``) and earlier outputs (a ``.glb`` beside a
``.fracture.json`` of the same stem), so a glob never picks up what a batch baked.
Recipe names are looked up as ``fracture bake`` does (``--recipes``,
``$FRACTURE_RECIPES``, ``recipes/`` beside the asset), then in ``recipes/``
beside the manifest, ``./recipes`` and the built-ins. Outputs mirror the asset's
folder below the manifest's: ``props/rock.glb`` is baked into ``OUTDIR/props/``.
"""

from __future__ import annotations

import glob
import math
import os
import tomllib
from dataclasses import dataclass
from typing import Any

from fracture_cli.errors import FractureError, InputError
from fracture_cli.pipeline.recipe import Recipe, load_recipe, search_path

TOP_LEVEL_KEYS = ("assets", "batch")
ENTRY_KEYS = ("file", "glob", "recipe", "set", "timeout")
GLOB_CHARS = "*?["


@dataclass(frozen=True)
class Entry:
    """One manifest entry as written.

    Attributes
    ----------
    where : str
        How error messages name the entry, e.g. ``[assets] "props/*.glb"``.
    pattern : str
        File or glob, relative to the manifest's folder (``/`` separators).
    is_glob : bool
    recipe : str
        Recipe name or path (a path is relative to the manifest's folder).
    overrides : tuple of str
        ``section.key=value`` strings applied after the recipe.
    timeout : float or None
        Seconds before a bake of these assets is killed (None: ``--timeout``).
    """

    where: str
    pattern: str
    is_glob: bool
    recipe: str
    overrides: tuple[str, ...] = ()
    timeout: float | None = None


@dataclass(frozen=True)
class Asset:
    """One asset to bake, resolved from the manifest.

    Attributes
    ----------
    name : str
        Path relative to the manifest's folder (``/`` separators); names the
        asset in reports and in the impacts dataset.
    path : str
        Absolute input path.
    out_dir : str
        Absolute output folder (OUTDIR plus the asset's folder below the manifest's).
    stem : str
        Output file stem.
    recipe : Recipe
        The resolved recipe, manifest and command-line overrides applied.
    entry : str
        The manifest entry that selected the asset (for error messages).
    timeout : float or None
        The entry's own timeout (None: the batch's).
    """

    name: str
    path: str
    out_dir: str
    stem: str
    recipe: Recipe
    entry: str
    timeout: float | None = None


@dataclass(frozen=True)
class Manifest:
    """A parsed manifest: its path, folder and entries in file order."""

    path: str
    folder: str
    entries: tuple[Entry, ...]


def _error(manifest: str, message: str) -> InputError:
    return InputError(message, path=manifest)


def _string_list(value: Any, manifest: str, where: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise _error(manifest, f"{where}: 'set' must be a list of \"section.key=value\" strings")
    return tuple(value)


def _entry(pattern: Any, table: dict, manifest: str, where: str) -> Entry:
    unknown = sorted(set(table) - set(ENTRY_KEYS))
    if unknown:
        raise _error(manifest, f"{where}: unknown key(s) {', '.join(unknown)}; valid: recipe, set, timeout, and file "
                               "or glob")
    if not isinstance(pattern, str) or not pattern.strip():
        raise _error(manifest, f"{where}: the file or glob must be a non-empty string")
    recipe = table.get("recipe", "default")
    if not isinstance(recipe, str) or not recipe:
        raise _error(manifest, f"{where}: 'recipe' must be a recipe name or a path to a .toml file")
    timeout = table.get("timeout")
    if timeout is not None and (isinstance(timeout, bool) or not isinstance(timeout, (int, float))
                                or not math.isfinite(timeout) or timeout <= 0):
        raise _error(manifest, f"{where}: 'timeout' must be a positive number of seconds, got {timeout!r}")
    pattern = pattern.replace("\\", "/")
    return Entry(where=where, pattern=pattern, is_glob=any(c in pattern for c in GLOB_CHARS), recipe=recipe,
                 overrides=_string_list(table.get("set", []), manifest, where),
                 timeout=float(timeout) if timeout is not None else None)


def _assets_entries(table: Any, manifest: str) -> list[Entry]:
    if not isinstance(table, dict):
        raise _error(manifest, "[assets] must be a table of \"file or glob\" = \"recipe\"")
    entries = []
    for pattern, value in table.items():
        where = f'[assets] "{pattern}"'
        if isinstance(value, str):
            value = {"recipe": value}
        if not isinstance(value, dict) or "file" in value or "glob" in value:
            raise _error(manifest, f"{where}: the value must be a recipe name or {{ recipe = \"...\", set = [...] }}")
        entries.append(_entry(pattern, value, manifest, where))
    return entries


def _batch_entries(tables: Any, manifest: str) -> list[Entry]:
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise _error(manifest, "'batch' must be an array of tables: [[batch]] with glob or file, recipe, set")
    entries = []
    for number, table in enumerate(tables, start=1):
        where = f"[[batch]] #{number}"
        if ("file" in table) == ("glob" in table):
            raise _error(manifest, f"{where}: give exactly one of 'file' or 'glob'")
        pattern = table.get("file", table.get("glob"))
        entries.append(_entry(pattern, table, manifest, f'{where} "{pattern}"'))
    return entries


def read_manifest(path: str) -> Manifest:
    """Parse and check a manifest's structure (files and recipes are resolved later).

    Raises
    ------
    InputError
        Missing or invalid file, unknown key, wrong type, no entries; the
        message names the manifest and the entry.
    """
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise _error(path, f"is not valid TOML: {exc}") from None
    except IsADirectoryError:
        raise _error(path, "is a folder; give the manifest's .toml file") from None
    except OSError as exc:
        raise _error(path, f"cannot be read: {exc.strerror}") from None
    unknown = sorted(set(data) - set(TOP_LEVEL_KEYS))
    if unknown:
        raise _error(path, f"unknown key(s) {', '.join(unknown)}; a manifest has [assets] and/or [[batch]]")
    entries = _assets_entries(data.get("assets", {}), path) + _batch_entries(data.get("batch", []), path)
    if not entries:
        raise _error(path, "names no assets; add an [assets] table or [[batch]] entries")
    return Manifest(path=path, folder=os.path.dirname(os.path.abspath(path)), entries=tuple(entries))


def _inside(path: str, folder: str) -> bool:
    return os.path.commonpath([path, folder]) == folder


def _baked_output(path: str) -> bool:
    """A ``<stem>.glb`` beside a ``<stem>.fracture.json`` is a bake's output, never an asset to bake."""
    stem, ext = os.path.splitext(path)
    return ext.lower() == ".glb" and os.path.exists(stem + ".fracture.json")


def _matches(manifest: Manifest, entry: Entry, extensions: frozenset[str]) -> list[str]:
    """Absolute paths an entry selects, sorted."""
    pattern = os.path.join(manifest.folder, entry.pattern)
    if not entry.is_glob:
        path = os.path.abspath(pattern)
        if not os.path.isfile(path):
            raise _error(manifest.path, f"{entry.where}: no such file {pattern}")
        if os.path.splitext(path)[1].lower() not in extensions:
            raise _error(manifest.path, f"{entry.where}: not a mesh file; pick one of {', '.join(sorted(extensions))}")
        return [path]
    found = sorted({os.path.abspath(p) for p in glob.glob(pattern, recursive=True)
                    if os.path.isfile(p) and os.path.splitext(p)[1].lower() in extensions and not _baked_output(p)})
    if not found:
        raise _error(manifest.path, f"{entry.where}: the glob matches no mesh file")
    return found


def _selected(manifest: Manifest, extensions: frozenset[str]) -> dict[str, Entry]:
    """Each selected file's entry: explicit files win over globs; conflicting globs are an error."""
    explicit: dict[str, Entry] = {}
    globbed: dict[str, Entry] = {}
    for entry in manifest.entries:
        for path in _matches(manifest, entry, extensions):
            chosen = explicit if not entry.is_glob else globbed
            other = chosen.get(path)
            if other is not None and (other.recipe, other.overrides, other.timeout) != \
                    (entry.recipe, entry.overrides, entry.timeout):
                kind = "globs" if entry.is_glob else "entries"
                raise _error(manifest.path, f"{other.where} and {entry.where}: both {kind} select "
                                            f"{os.path.relpath(path, manifest.folder)} with different settings; "
                                            "name it explicitly once")
            chosen.setdefault(path, entry)
    return {**globbed, **explicit}


def _recipe(manifest: Manifest, entry: Entry, asset: str, extra: tuple[str, ...], recipes_dir: str | None,
            memo: dict) -> Recipe:
    """The entry's recipe: a path relative to the manifest, or a name on bake's search path (the asset's
    ``recipes/`` folder first, then the manifest's)."""
    name = entry.recipe
    if name.endswith(".toml") or "/" in name or os.sep in name:
        name = os.path.join(manifest.folder, name)
    search = tuple(search_path(recipes_dir, (asset, manifest.path)))
    key = (name, entry.overrides + extra, search)
    if key not in memo:
        try:
            memo[key] = load_recipe(name, list(key[1]), search=search)
        except FractureError as exc:
            raise _error(manifest.path, f"{entry.where}: {exc}") from None
    return memo[key]


def resolve_assets(manifest: Manifest, out_root: str, overrides: tuple[str, ...] = (),
                   recipes_dir: str | None = None) -> list[Asset]:
    """Expand globs, resolve recipes and place the outputs.

    Parameters
    ----------
    manifest : Manifest
    out_root : str
        OUTDIR; outputs mirror the asset's folder below the manifest's.
    overrides : tuple of str, optional
        Command-line ``--set`` overrides, applied after each entry's own.
    recipes_dir : str, optional
        The ``--recipes`` folder, searched first for recipe names.

    Returns
    -------
    list of Asset
        Sorted by name.

    Raises
    ------
    InputError
        A file that does not exist or is not a mesh, a glob that matches no
        mesh, an unknown recipe or bad override, an asset outside the
        manifest's folder, or two assets that would write the same outputs.
    """
    # on first use: the batch driver starts light; workers load the stages
    from fracture_cli.stages.load import READERS

    out_root = os.path.abspath(out_root)
    selected = _selected(manifest, frozenset(READERS))
    memo: dict = {}
    assets: list[Asset] = []
    stems: dict[tuple[str, str], str] = {}
    for path, entry in selected.items():
        if not _inside(path, manifest.folder):
            raise _error(manifest.path, f"{entry.where}: {path} is outside the manifest's folder; outputs mirror "
                                        "the folders below it (move the manifest up)")
        name = os.path.relpath(path, manifest.folder).replace(os.sep, "/")
        folder, base = os.path.split(name)
        stem = os.path.splitext(base)[0]
        out_dir = os.path.normpath(os.path.join(out_root, folder))
        clash = stems.get((out_dir, stem))
        if clash is not None:
            raise _error(manifest.path, f"{entry.where}: {clash} and {name} would both write {stem}.* into "
                                        f"{out_dir}; rename one")
        stems[(out_dir, stem)] = name
        assets.append(Asset(name=name, path=path, out_dir=out_dir, stem=stem,
                            recipe=_recipe(manifest, entry, path, tuple(overrides), recipes_dir, memo),
                            entry=entry.where,
                            timeout=entry.timeout))
    return sorted(assets, key=lambda a: a.name)
