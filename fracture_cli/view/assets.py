"""What ``fracture view`` shows: the baked assets of a folder and a version key per asset.

A baked asset ``<stem>`` is a ``<stem>.fracture.json`` runtime file with, next to
it, ``<stem>.fracture.bin``, the fragments ``<stem>.glb`` and optionally the
report ``<stem>.report.json`` and the aligned-fracture pair ``<stem>.aligned.json`` +
``.bin``. The folder is re-scanned on every request, so a
bake started in another terminal shows up (or updates) without restarting the
server.
"""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass

from fracture_cli.errors import InputError

RUNTIME_SUFFIX = ".fracture.json"
# Every file of a bake the page may fetch, by suffix; nothing else in the folder is served.
SERVED_SUFFIXES = (".glb", ".fracture.json", ".fracture.bin", ".report.json", ".aligned.json", ".aligned.bin")
# A bake writes its files within milliseconds; a change younger than this may be half done.
SETTLE_SECONDS = 0.75


@dataclass(frozen=True)
class ViewSource:
    """Where the assets come from: a bake folder, optionally narrowed to one stem.

    Attributes
    ----------
    folder : str
        Absolute path of the folder holding the bake outputs.
    stem : str or None
        Only this asset (the user named one runtime file), or None for all.
    """

    folder: str
    stem: str | None = None


def _strip_suffix(name: str) -> str | None:
    for suffix in SERVED_SUFFIXES:
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return None


def resolve_source(path: str) -> ViewSource:
    """The view source for a command-line argument: a bake folder or one of a bake's files.

    Raises
    ------
    InputError
        The path does not exist or is a file that is not part of a bake.
    """
    if os.path.isdir(path):
        return ViewSource(folder=os.path.abspath(path))
    if not os.path.exists(path):
        raise InputError("not found (expected a bake output folder or a <stem>.fracture.json)", path=path)
    stem = _strip_suffix(os.path.basename(path))
    if not stem:
        raise InputError("not a bake output (expected a folder, <stem>.fracture.json or <stem>.glb)", path=path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.exists(os.path.join(folder, stem + RUNTIME_SUFFIX)):
        raise InputError(f"no {stem}{RUNTIME_SUFFIX} next to it; bake the asset first", path=path)
    return ViewSource(folder=folder, stem=stem)


def _stat(path: str) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size


def asset_state(source: ViewSource, stem: str, now: float | None = None) -> dict:
    """Files, version key and readiness of one asset.

    Returns
    -------
    dict
        ``stem``; ``files``: suffix -> file name, for the files present;
        ``version``: a short hash of their names, sizes and modification times
        (changes whenever a bake rewrites any of them); ``settled``: no file
        changed in the last :data:`SETTLE_SECONDS` (a page reloads only then);
        ``missing``: required files that are absent.
    """
    now = time.time() if now is None else now
    files, stats, newest = {}, [], 0
    for suffix in SERVED_SUFFIXES:
        name = stem + suffix
        st = _stat(os.path.join(source.folder, name))
        if st is not None:
            files[suffix.lstrip(".")] = name
            stats.append(f"{name}:{st[0]}:{st[1]}")
            newest = max(newest, st[0])
    version = hashlib.sha1("|".join(stats).encode()).hexdigest()[:12]
    missing = [stem + s for s in (".glb", ".fracture.json", ".fracture.bin") if s.lstrip(".") not in files]
    return {"stem": stem, "files": files, "version": version, "missing": missing,
            "settled": now - newest / 1e9 >= SETTLE_SECONDS}


def list_assets(source: ViewSource) -> list[dict]:
    """:func:`asset_state` of every asset in the source, sorted by stem."""
    if source.stem is not None:
        stems = [source.stem]
    else:
        try:
            names = os.listdir(source.folder)
        except OSError as exc:
            raise InputError(f"cannot list the folder ({exc.strerror})", path=source.folder) from None
        stems = sorted(name[: -len(RUNTIME_SUFFIX)] for name in names
                       if name.endswith(RUNTIME_SUFFIX) and not name.startswith("."))
    now = time.time()
    return [asset_state(source, stem, now) for stem in stems]


def served_file(source: ViewSource, name: str) -> str | None:
    """Absolute path of a bake file the page may fetch, or None (unknown, hidden or outside the folder, also
    through a symbolic link)."""
    if not name or "/" in name or "\\" in name or name.startswith(".") or "\0" in name:
        return None
    stem = _strip_suffix(name)
    if not stem or (source.stem is not None and stem != source.stem):
        return None
    path = os.path.join(source.folder, name)
    # A symbolic link in the folder is followed only to a file that is in the folder too.
    real, root = os.path.realpath(path), os.path.realpath(source.folder)
    if os.path.commonpath([real, root]) != root:
        return None
    return path if os.path.isfile(path) else None
