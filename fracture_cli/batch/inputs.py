"""Every file a bake reads, and their content hashes (for incremental batches).

A ``.gltf`` reads its external buffers and images, an OBJ its ``mtllib``
material files and the textures they name; all of them change the output, so
all of them are part of an asset's key. Hashes are reused from the previous
state when a file's size and modification time are unchanged (as git does), so
a re-run reads only what changed (the state module offers only hashes taken
well after the file's modification time, so an edit within one timestamp tick
is never missed).
"""

from __future__ import annotations

import json
import logging
import os
import stat
import urllib.parse
from dataclasses import dataclass

from fracture_cli.bake import file_sha256

log = logging.getLogger(__name__)

# OBJ material statements that name a texture file (the file name is the last token).
_MTL_MAPS = ("map_", "bump", "disp", "decal", "refl", "norm")


@dataclass(frozen=True)
class InputFile:
    """One file an asset depends on.

    Attributes
    ----------
    name : str
        Path relative to the asset's folder (``/`` separators), so keys survive
        moving the whole tree (a CI checkout in another folder).
    size, mtime_ns : int
        From ``os.stat``; -1 when the file is missing.
    sha256 : str
        Hex digest of the bytes, or ``missing`` / ``not-a-file`` (a FIFO or a
        device is never read, so it cannot block the planner).
    """

    name: str
    size: int
    mtime_ns: int
    sha256: str


def _uri_files(doc: dict, folder: str) -> list[str]:
    out = []
    for kind in ("buffers", "images"):
        for item in doc.get(kind) or []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and uri and not uri.startswith("data:") and "://" not in uri:
                out.append(os.path.join(folder, urllib.parse.unquote(uri)))
    return out


def _gltf_files(path: str) -> list[str]:
    from fracture_cli.io.gltf import read_glb_chunks

    try:
        if path.lower().endswith(".glb"):
            doc, _ = read_glb_chunks(path)
        else:
            with open(path, encoding="utf-8") as fh:
                doc = json.load(fh)
    except Exception as exc:  # the bake reports an unreadable file; its key is then the file alone
        log.debug("batch: %s: cannot list external files (%s)", path, exc)
        return []
    return _uri_files(doc, os.path.dirname(path)) if isinstance(doc, dict) else []


def _statement_files(path: str, prefixes: tuple[str, ...], last_token: bool) -> list[str]:
    """Files named by lines starting with one of ``prefixes`` (OBJ ``mtllib``, MTL ``map_Kd`` ...)."""
    if not _is_regular(path):
        return []
    out = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            words = line.split()
            if words and words[0].startswith(prefixes):
                names = words[-1:] if last_token else words[1:]
                out += [os.path.join(os.path.dirname(path), n) for n in names]
    return out


def _obj_files(path: str) -> list[str]:
    materials = _statement_files(path, ("mtllib",), last_token=False)
    textures = [t for m in materials for t in _statement_files(m, _MTL_MAPS, last_token=True)]
    return materials + textures


def _is_regular(path: str) -> bool:
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return False


def dependency_files(path: str) -> list[str]:
    """Absolute paths of the files an asset reads besides itself (sorted, no duplicates)."""
    ext = os.path.splitext(path)[1].lower()
    if ext in (".gltf", ".glb"):
        found = _gltf_files(path)
    elif ext == ".obj":
        found = _obj_files(path)
    else:
        found = []
    return sorted({os.path.abspath(p) for p in found} - {os.path.abspath(path)})


def hash_input(path: str, name: str, previous: dict[str, InputFile] | None = None) -> InputFile:
    """Stat and hash one input, reusing ``previous[name]`` when its size and mtime are unchanged."""
    try:
        st = os.stat(path)
    except OSError:
        return InputFile(name=name, size=-1, mtime_ns=-1, sha256="missing")
    if not stat.S_ISREG(st.st_mode):
        return InputFile(name=name, size=-1, mtime_ns=-1, sha256="not-a-file")
    old = (previous or {}).get(name)
    if old is not None and (old.size, old.mtime_ns) == (st.st_size, st.st_mtime_ns):
        return old
    return InputFile(name=name, size=st.st_size, mtime_ns=st.st_mtime_ns, sha256=file_sha256(path))


def hash_inputs(path: str, previous: dict[str, InputFile] | None = None) -> tuple[InputFile, ...]:
    """The asset itself (first) and every file it depends on, hashed."""
    folder = os.path.dirname(os.path.abspath(path))
    files = [os.path.abspath(path)] + dependency_files(path)
    return tuple(hash_input(p, os.path.relpath(p, folder).replace(os.sep, "/"), previous) for p in files)
