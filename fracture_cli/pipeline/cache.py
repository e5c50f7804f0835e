"""A content-addressed cache of expensive stage results (cage, tets, modes).

``fracture bake --cache DIR`` stores the result of every stage the pipeline
table marks ``cached``, keyed by a hash of everything it depends on: the tool
version, every byte of the input (the asset and its companion files: glTF
buffers and images, OBJ material libraries and textures; :func:`input_digest`)
and the options of every stage up to and
including that one (:class:`~fracture_cli.pipeline.runner.Runner` chains the keys). A
bake that only changes later options (smoothing, fragments, runtime) then skips
the cage search and the modes solve. Entries are written atomically; an
unreadable entry is reported and recomputed, never trusted. The cache only
saves time: a folder that cannot be made, or that takes no new file (read-only,
full), is reported by one warning line and the bake carries on without it
(reading what it can, storing nothing).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import logging
import os
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from fracture_cli import __version__
from fracture_cli.errors import printable
from fracture_cli.io.atomic import atomic_path
from fracture_cli.io.inputs import file_sha256  # noqa: F401 (part of this module's API: the input hash)
from fracture_cli.system import numeric_env
from fracture_cli.types import Cage, Modes, Normalization, TetMesh

if TYPE_CHECKING:
    from fracture_cli.pipeline import PipelineState

log = logging.getLogger(__name__)


def input_key(path: str) -> str:
    """What the cache keys of an input depend on: its bytes and its companion files' (:func:`input_digest`)."""
    # on first use: keeps `fracture` start-up light
    from fracture_cli.io.inputs import input_files

    return input_digest(input_files(path))


def input_digest(files: list[str]) -> str:
    """Hex SHA-256 of an input's bytes: its file alone, or its file and its companion files.

    Parameters
    ----------
    files : list of str
        The asset first, then its companions
        (:func:`fracture_cli.io.inputs.input_files`).

    Returns
    -------
    str
        For a single file, the SHA-256 of its bytes (what ``sha256sum``
        prints). Otherwise the SHA-256 of one line per file,
        ``<sha256 or "missing">  <name relative to the asset's folder>``, so
        editing, adding, removing or renaming a companion changes it.
    """
    if len(files) == 1:
        return file_sha256(files[0])
    folder = os.path.dirname(files[0])
    lines = []
    for path in files:
        if not os.path.exists(path):
            digest = "missing"
        elif not os.path.isfile(path):  # a FIFO or a device named as a texture: never read (it could block)
            digest = "not-a-file"
        else:
            digest = file_sha256(path)
        lines.append(f"{digest}  {os.path.relpath(path, folder or '.')}\n")
    return hashlib.sha256("".join(lines).encode("utf-8", "surrogateescape")).hexdigest()


def cache_key(*parts: Any) -> str:
    """Hex SHA-256 of the JSON encoding of ``parts`` (dataclasses as their fields)."""

    def encode(value: object) -> object:
        if dataclasses.is_dataclass(value):
            return {f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, (list, tuple)):
            return [encode(v) for v in value]
        if isinstance(value, dict):
            return {str(k): encode(v) for k, v in sorted(value.items())}
        return value

    # Other numeric kernels or dependency versions may give other bits: never reuse across them.
    text = json.dumps([__version__, numeric_env.environment()] + [encode(p) for p in parts], sort_keys=True,
                      default=str)
    return hashlib.sha256(text.encode()).hexdigest()


class StageCache:
    """Cache folder for stage results; see the module docstring."""

    def __init__(self, directory: str):
        self.directory = directory
        self.events: dict[str, str] = {}
        self.readable = self.writable = True
        try:
            os.makedirs(directory, exist_ok=True)
        except OSError as exc:
            self.readable = self.writable = False
            log.warning("%s: cannot use the cache folder (%s); baking without the cache", printable(directory),
                        exc.strerror or exc)

    def _path(self, kind: str, key: str) -> str:
        return os.path.join(self.directory, f"{kind}-{key[:32]}.npz")

    def _load(self, kind: str, key: str) -> dict[str, np.ndarray] | None:
        path = self._path(kind, key)
        if not self.readable or not os.path.exists(path):
            self.events[kind] = "miss"
            return None
        if not os.path.isfile(path):  # a FIFO or a folder at an entry's name: never opened (it could block)
            log.warning("cache: ignoring %s (not a regular file)", os.path.basename(path))
            self.events[kind] = "miss"
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {name: data[name] for name in data.files}
            if str(arrays.pop("key")) != key:
                raise ValueError("key mismatch")
        except Exception as exc:  # a damaged entry is recomputed, and said so
            log.warning("cache: ignoring unreadable entry %s (%s)", os.path.basename(path), exc)
            self.events[kind] = "miss"
            return None
        self.events[kind] = "hit"
        return arrays

    def _store(self, kind: str, key: str, arrays: dict[str, np.ndarray]) -> None:
        if not self.writable:
            return
        buf = io.BytesIO()
        np.savez(buf, **{"key": np.array(key), **arrays})  # type: ignore[arg-type]  # numpy's stub: any name
        try:
            with atomic_path(self._path(kind, key)) as tmp:
                with open(tmp, "wb") as fh:
                    fh.write(buf.getvalue())
        except OSError as exc:  # read-only, full, or not ours: the bake goes on, nothing more is stored
            self.writable = False
            log.warning("%s: cannot store in the cache folder (%s); this bake's results are not cached",
                        printable(self.directory), exc.strerror or exc)

    def get(self, stage: str, key: str, state: PipelineState) -> PipelineState | None:
        """``state`` with the cached result of ``stage`` filled in, or None on a miss."""
        arrays = self._load(stage, key)
        if arrays is None:
            return None
        field, decode, _ = _CODECS[stage]
        normalization = state.need("surface", stage).normalization
        try:
            value = decode(arrays, normalization)
        except (KeyError, ValueError, TypeError) as exc:  # an entry of the right key without the right arrays
            log.warning("cache: ignoring unreadable entry %s (%s)", os.path.basename(self._path(stage, key)), exc)
            self.events[stage] = "miss"
            return None
        return dataclasses.replace(state, **{field: value})

    def put(self, stage: str, key: str, state: PipelineState) -> None:
        """Store what ``stage`` produced in ``state``."""
        field, _, encode = _CODECS[stage]
        self._store(stage, key, encode(getattr(state, field)))


def _decode_cage(a: dict[str, np.ndarray], normalization: Normalization) -> Cage:
    return Cage(vertices=a["cage_vertices"], faces=a["cage_faces"], offset=float(a["offset"]),
                log=tuple(json.loads(str(a["log"]))), normalization=normalization)


def _encode_cage(cage: Cage) -> dict[str, np.ndarray]:
    return {"cage_vertices": cage.vertices, "cage_faces": cage.faces, "offset": np.array(cage.offset),
            "log": np.array(json.dumps(list(cage.log), default=float))}


def _decode_tets(a: dict[str, np.ndarray], normalization: Normalization) -> TetMesh:
    return TetMesh(vertices=a["tet_vertices"], tets=a["tets"], normalization=normalization)


def _encode_tets(tet_mesh: TetMesh) -> dict[str, np.ndarray]:
    return {"tet_vertices": tet_mesh.vertices, "tets": tet_mesh.tets}


def _decode_modes(a: dict[str, np.ndarray], normalization: Normalization) -> Modes:
    return Modes(U=a["U"], labels=a["labels"], cut=a["cut"], piece_counts=a["piece_counts"],
                 energies=a["energies"], iterations=a["iterations"], stats=json.loads(str(a["stats"])))


def _encode_modes(modes: Modes) -> dict[str, np.ndarray]:
    return {
        "U": modes.U, "labels": modes.labels, "cut": modes.cut, "piece_counts": modes.piece_counts,
        "energies": modes.energies, "iterations": modes.iterations,
        "stats": np.array(json.dumps(modes.stats, default=lambda v: v.tolist() if hasattr(v, "tolist") else str(v))),
    }


# Cached stage -> (PipelineState field, decode(arrays, normalization), encode(value)).
_CODECS: dict[str, tuple[str, Callable[[dict[str, np.ndarray], Normalization], Any], Callable[[Any], dict]]] = {
    "cage": ("cage", _decode_cage, _encode_cage),
    "tetra": ("tet_mesh", _decode_tets, _encode_tets),
    "modes": ("modes", _decode_modes, _encode_modes),
}
