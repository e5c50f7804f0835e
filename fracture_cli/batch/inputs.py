"""Every file a bake reads, and their content hashes (for incremental batches).

A ``.gltf`` reads its external buffers and images, an OBJ its ``mtllib``
material files and the textures they name, a PLY its texture; all of them
change the output, so all of them are part of an asset's key (the list is
:func:`fracture_cli.io.inputs.input_files`, the one the bake's cache uses). Hashes are reused from the previous
state when a file's size and modification time are unchanged (as git does), so
a re-run reads only what changed (the state module offers only hashes taken
well after the file's modification time, so an edit within one timestamp tick
is never missed).

The planner's hashes decide what to bake; the state records the hashes the
bake took of the bytes it read (:func:`as_read`), so an input edited between
planning and baking (and the edit undone later) is never reported up to date
with outputs baked from other bytes.
"""

from __future__ import annotations

import logging
import os
import stat
from dataclasses import dataclass

from fracture_cli.io.inputs import file_sha256

log = logging.getLogger(__name__)

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


def dependency_files(path: str) -> list[str]:
    """Absolute paths of the files an asset reads besides itself (sorted, no duplicates).

    The list is the bake's own (:func:`fracture_cli.io.inputs.input_files`, which
    the cache key and the output preflight use too), so a batch never decides
    "up to date" from a different set of files than the bake reads.
    """
    # on first use: the batch driver starts light; workers load the stages
    from fracture_cli.io.inputs import input_files

    return sorted({os.path.abspath(p) for p in input_files(path)[1:]} - {os.path.abspath(path)})


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


def _name(path: str, folder: str) -> str:
    return os.path.relpath(path, folder).replace(os.sep, "/")


def hash_inputs(path: str, previous: dict[str, InputFile] | None = None,
                also: tuple[str, ...] = ()) -> tuple[InputFile, ...]:
    """The asset itself (first) and every file it depends on (sorted by path), hashed.

    ``also`` adds names (relative to the asset's folder) a previous bake read
    besides the listed companions (a texture trimesh found by another path),
    so the key is taken over the same files the last bake's key was.
    """
    # on first use: the batch driver starts light; workers load the stages
    from fracture_cli.io.inputs import companion_or_none

    folder = os.path.dirname(os.path.abspath(path))
    extra = {os.path.normpath(p) for p in (companion_or_none(folder, n) for n in also) if p is not None}
    deps = sorted((set(dependency_files(path)) | extra) - {os.path.abspath(path)})
    files = [os.path.abspath(path)] + deps
    return tuple(hash_input(p, _name(p, folder), previous) for p in files)


def as_read(path: str, reads: tuple) -> tuple[InputFile, ...]:
    """The files a bake read (:class:`fracture_cli.io.inputs.FileRead`, from its result) as :class:`InputFile`.

    The same order and names as :func:`hash_inputs` (the asset first, then by
    path), so the key of the bytes the bake read is comparable with the key
    the next run's planner takes from disk.
    """
    folder = os.path.dirname(os.path.abspath(path))
    asset = os.path.normpath(os.path.abspath(path))
    by_path = {r.path: r for r in reads}
    order = [asset] + sorted(set(by_path) - {asset})
    if asset not in by_path:  # every bake reads its asset; without it the result is not from a bake
        raise ValueError(f"the bake's result does not list its input {path}")
    return tuple(InputFile(name=_name(p, folder), size=by_path[p].size, mtime_ns=by_path[p].mtime_ns,
                           sha256=by_path[p].sha256) for p in order)
