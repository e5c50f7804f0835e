"""A content-addressed cache of expensive stage results (cage + tets, modes).

``fracture bake --cache DIR`` stores the cage with its tet mesh and the modes,
keyed by a hash of everything they depend on: the tool version, every byte
of the input (the asset and its companion files: glTF buffers and images,
OBJ material libraries and textures; :func:`input_digest`) and the options of every stage up to and including that one. A
bake that only changes later options (smoothing, fragments, runtime, export)
then skips the cage search and the modes solve. Entries are written atomically;
an unreadable entry is reported and recomputed, never trusted.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import logging
import os

import numpy as np

from fracture_cli import __version__
from fracture_cli.io.atomic import atomic_path
from fracture_cli.types import Cage, Modes, Normalization, TetMesh

log = logging.getLogger(__name__)


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
    from fracture_cli.io.outputs import file_sha256

    if len(files) == 1:
        return file_sha256(files[0])
    folder = os.path.dirname(files[0])
    lines = []
    for path in files:
        try:
            digest = file_sha256(path)
        except FileNotFoundError:
            digest = "missing"
        lines.append(f"{digest}  {os.path.relpath(path, folder or '.')}\n")
    return hashlib.sha256("".join(lines).encode("utf-8", "surrogateescape")).hexdigest()


def cache_key(*parts) -> str:
    """Hex SHA-256 of the JSON encoding of ``parts`` (dataclasses as their fields)."""

    def encode(value):
        if dataclasses.is_dataclass(value):
            return {f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, (list, tuple)):
            return [encode(v) for v in value]
        if isinstance(value, dict):
            return {str(k): encode(v) for k, v in sorted(value.items())}
        return value

    text = json.dumps([__version__] + [encode(p) for p in parts], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


class StageCache:
    """Cache folder for stage results; see the module docstring."""

    def __init__(self, directory: str):
        self.directory = directory
        os.makedirs(directory, exist_ok=True)
        self.events: dict[str, str] = {}

    def _path(self, kind: str, key: str) -> str:
        return os.path.join(self.directory, f"{kind}-{key[:32]}.npz")

    def _load(self, kind: str, key: str):
        path = self._path(kind, key)
        if not os.path.exists(path):
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

    def _store(self, kind: str, key: str, arrays: dict) -> None:
        buf = io.BytesIO()
        np.savez(buf, key=np.array(key), **arrays)
        with atomic_path(self._path(kind, key)) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(buf.getvalue())

    def get_cage(self, key: str, normalization: Normalization):
        """Return ``(Cage, TetMesh)`` or None."""
        a = self._load("cage", key)
        if a is None:
            return None
        cage = Cage(vertices=a["cage_vertices"], faces=a["cage_faces"], offset=float(a["offset"]),
                    log=tuple(json.loads(str(a["log"]))), normalization=normalization)
        return cage, TetMesh(vertices=a["tet_vertices"], tets=a["tets"], normalization=normalization)

    def put_cage(self, key: str, cage: Cage, tet_mesh: TetMesh) -> None:
        self._store("cage", key, {
            "cage_vertices": cage.vertices, "cage_faces": cage.faces, "offset": np.array(cage.offset),
            "log": np.array(json.dumps(list(cage.log), default=float)),
            "tet_vertices": tet_mesh.vertices, "tets": tet_mesh.tets,
        })

    def get_modes(self, key: str):
        """Return ``Modes`` or None."""
        a = self._load("modes", key)
        if a is None:
            return None
        return Modes(U=a["U"], labels=a["labels"], cut=a["cut"], piece_counts=a["piece_counts"],
                     energies=a["energies"], iterations=a["iterations"], stats=json.loads(str(a["stats"])))

    def put_modes(self, key: str, modes: Modes) -> None:
        self._store("modes", key, {
            "U": modes.U, "labels": modes.labels, "cut": modes.cut, "piece_counts": modes.piece_counts,
            "energies": modes.energies, "iterations": modes.iterations,
            "stats": np.array(json.dumps(modes.stats, default=lambda v: v.tolist() if hasattr(v, "tolist") else str(v))),
        })
