"""The impact-projection file: ``<stem>.fracture.json`` + ``<stem>.fracture.bin``.

The JSON header says what is in the binary file (counts, fragment names, units,
the baked impact radius, the default threshold, and the dtype, shape, byte offset
and byte length of every array); the binary file holds little-endian arrays, each
starting at a multiple of 16 bytes. ``docs/FORMAT.md`` is the specification an
engine programmer reads; this module is its reference implementation.

Depends on numpy and the standard library only (see :mod:`fracture_cli.runtime`).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from fracture_cli.errors import RuntimeFileError
from fracture_cli.runtime.data import (  # noqa: F401  (UNITS_NOTE, GAMEREADY_LAYOUT: re-exported, where callers look)
    ALL_LAYOUTS,
    ARRAY_LAYOUT,
    FILE_DTYPES,
    FORMAT_VERSION,
    GAMEREADY_LAYOUT,
    UNITS_NOTE,
    RuntimeData,
    check_runtime,
)
from fracture_cli.runtime.header import parse_header
from fracture_cli.runtime.levels import ALL_LEVEL_LAYOUTS
from fracture_cli.runtime.stress import SHARING_LAYOUT, STRESS_LAYOUT, header_features
from fracture_cli.runtime.structure import ANCHOR_LAYOUT, CRACK_LAYOUT, DAMAGE_KEYS, check_damage

FORMAT_NAME = "fracture-modes-runtime"
MAX_VERSION = 2  # the newest version this reader reads (docs/notes/runtime-format-v2.md)
ALIGNMENT = 16
JSON_SUFFIX = ".fracture.json"
BIN_SUFFIX = ".fracture.bin"


def bin_path_for(json_path: str | os.PathLike) -> Path:
    """The ``.fracture.bin`` file that goes with a ``.fracture.json`` file."""
    json_path = Path(json_path)
    name = json_path.name
    stem = name[: -len(JSON_SUFFIX)] if name.endswith(JSON_SUFFIX) else Path(name).stem
    return json_path.with_name(stem + BIN_SUFFIX)


def _aligned(n: int) -> int:
    return (n + ALIGNMENT - 1) // ALIGNMENT * ALIGNMENT


def encode(data: RuntimeData, bin_name: str) -> tuple[bytes, bytes]:
    """Serialize ``data`` to (header JSON bytes, binary bytes); deterministic.

    Parameters
    ----------
    data : RuntimeData
    bin_name : str
        File name (no directories) of the binary file, recorded in the header.
    """
    problem = check_runtime(data)
    if problem:
        raise ValueError(f"cannot write runtime data: {problem}")
    chunks, table, offset = [], {}, 0
    for name, array in data.arrays().items():
        raw = array.tobytes(order="C")
        table[name] = {
            "dtype": ALL_LAYOUTS[name][0],
            "shape": list(array.shape),
            "byte_offset": offset,
            "byte_length": len(raw),
        }
        padded = _aligned(len(raw))
        chunks.append(raw + b"\0" * (padded - len(raw)))
        offset += padded
    binary = b"".join(chunks)
    header = {
        "format": FORMAT_NAME,
        "version": data.version,
        "dim": data.dim,
        "counts": data.counts(),
        "fragment_names": list(data.fragment_names),
        "units": data.units,
        "transform": [float(x) for x in np.asarray(data.transform, dtype=np.float64).reshape(-1)],
        "default_threshold": float(data.default_threshold),
        "impact_radius": float(data.radius),
        "buffer": {"uri": bin_name, "byte_length": len(binary), "crc32": zlib.crc32(binary)},
        "arrays": table,
    }
    if data.features:  # version 2 (docs/FORMAT.md section 11); a version-1 header stays as it was
        header["features"] = list(data.features)
        header["criterion"] = data.criterion
        if data.stress:
            header["stress"] = {key: data.stress_info[key] for key in sorted(data.stress_info)}
        if data.sharing:
            header["sharing"] = {"concentration": float(data.sharing["concentration"])}
        if data.damage:
            header["damage"] = {key: float(data.damage[key]) for key in DAMAGE_KEYS}
        if data.anchored is not None and data.anchors_info:
            header["anchors"] = {key: data.anchors_info[key] for key in sorted(data.anchors_info)}
        if data.levels:  # docs/FORMAT.md section 14
            header["child_names"] = list(data.child_names)
            header["levels"] = {key: data.levels_info[key] for key in sorted(data.levels_info)}
    text = json.dumps(header, sort_keys=True, indent=2, ensure_ascii=True, allow_nan=False) + "\n"
    return text.encode("ascii"), binary


def _write_atomic(path: Path, payload: bytes) -> None:
    # Temp file in the same directory so os.replace is an atomic rename.
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        umask = os.umask(0o022)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; readable like the GLB (0644 with the usual umask)
        with os.fdopen(fd, "wb") as handle:
            handle.write(payload)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_runtime(data: RuntimeData, json_path: str | os.PathLike) -> tuple[Path, Path]:
    """Write ``data`` as ``<stem>.fracture.json`` and ``<stem>.fracture.bin``.

    Parameters
    ----------
    data : RuntimeData
    json_path : path
        Where the header goes; the binary file is written next to it with the
        same stem and the suffix ``.fracture.bin``.

    Returns
    -------
    (json_path, bin_path) : tuple of Path

    Notes
    -----
    Both files are written atomically (temp file + rename), binary first, so a
    reader never sees a header that points at a half-written binary file.
    Output bytes depend only on ``data``: no timestamps, no absolute paths.
    """
    json_path = Path(json_path)
    bin_path = bin_path_for(json_path)
    header, binary = encode(data, bin_path.name)
    _write_atomic(bin_path, binary)
    _write_atomic(json_path, header)
    return json_path, bin_path


def _fail(message: str, path) -> RuntimeFileError:
    return RuntimeFileError(message, path=str(path))


def _count(value, what: str) -> int:
    """``value`` if it is a JSON integer >= 0 (not a bool, float or string), else ValueError naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{what} must be a whole number >= 0, got {value!r}")
    return value


def decode(header_bytes: bytes, binary: bytes, path: str = "<memory>") -> RuntimeData:
    """Parse a header and its binary payload (see :func:`load_runtime`)."""
    try:
        header = parse_header(header_bytes)
    except ValueError as exc:
        raise _fail(f"not a JSON runtime file ({exc})", path) from None
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        raise _fail(f"not a fracture runtime file (expected \"format\": \"{FORMAT_NAME}\")", path)
    version = header.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1 or version > MAX_VERSION:
        raise _fail(f"runtime file version {version!r} is not supported (this reader knows 1..{MAX_VERSION}); "
                    "re-bake the asset or update fracture", path)
    try:
        features, criterion = header_features(header, version)
    except ValueError as exc:
        raise _fail(str(exc), path) from None
    try:
        buffer = header["buffer"]
        table = header["arrays"]
        names = tuple(str(x) for x in header["fragment_names"])
        counts = dict(header["counts"])
        dim = _count(header["dim"], "dim")
        transform = np.asarray(header["transform"], dtype=np.float64).reshape(4, 4)
        threshold = float(header["default_threshold"])
        radius = float(header["impact_radius"])
        units = str(header.get("units", ""))
        byte_length = _count(buffer["byte_length"], "buffer.byte_length")
        crc = _count(buffer["crc32"], "buffer.crc32") if "crc32" in buffer else None
        if not isinstance(table, dict):
            raise TypeError("arrays must be an object")
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise _fail(f"runtime header is missing or has a malformed entry ({exc!r})", path) from None
    if len(binary) != byte_length:
        raise _fail(f"binary file has {len(binary)} bytes but the header says {byte_length} "
                    "(truncated or from another bake); re-bake the asset", path)
    if crc is not None and zlib.crc32(binary) != crc:
        raise _fail("binary file does not match its header (crc32 differs; from another bake?)", path)
    arrays = {name: _array(table, name, binary, path) for name in ARRAY_LAYOUT}
    # Optional arrays: read when any is listed (check_runtime then wants all of them).
    gameready = {name: _array(table, name, binary, path, GAMEREADY_LAYOUT) for name in GAMEREADY_LAYOUT
                 if name in table}
    stress = ({name: _array(table, name, binary, path, STRESS_LAYOUT) for name in STRESS_LAYOUT}
              if "stress" in features else {})
    sharing: dict = {}
    if "sharing" in features:  # docs/FORMAT.md section 11.1
        stress.update({name: _array(table, name, binary, path, SHARING_LAYOUT) for name in SHARING_LAYOUT})
        sharing = header["sharing"] if isinstance(header.get("sharing"), dict) else {"concentration": None}
    info: dict = header["stress"] if isinstance(header.get("stress"), dict) else {}
    structure: dict[str, Any] = _decode_structure(header, features, table, binary, path) if version >= 2 else {}
    data = RuntimeData(fragment_names=names, transform=transform, default_threshold=threshold,
                       radius=radius, units=units, gameready=gameready, criterion=criterion, stress=stress,
                       stress_info=dict(info), sharing=dict(sharing), sites=arrays["sites"], B=arrays["B"],
                       W=arrays["W"],
                       edges=arrays["edges"], edge_areas=arrays["edge_areas"], **structure)
    problem = check_runtime(data)
    if problem is None and data.dim != dim:
        problem = f"header says dim = {dim} but W has d = {data.dim}"
    if problem is None:
        want = data.counts()
        if {key: counts.get(key) for key in want} != want:
            problem = f"header counts {counts} do not match the arrays {want}"
    if problem:
        raise _fail(f"inconsistent runtime file: {problem}", path)
    return data


def _decode_structure(header: dict, features: tuple[str, ...], table: dict, binary: bytes, path) -> dict:
    """The ``RuntimeData`` fields of docs/FORMAT.md section 12 from a version-2 header and its binary."""
    fields: dict = {}
    if "anchors" in features:
        fields["anchored"] = _array(table, "anchored", binary, path, ANCHOR_LAYOUT)
        info = header.get("anchors")
        fields["anchors_info"] = dict(info) if isinstance(info, dict) else {}
    if "damage" in features:
        damage = header.get("damage")
        problem = ("the feature 'damage' needs a header object 'damage'" if not isinstance(damage, dict)
                   else check_damage(damage))
        if problem or not isinstance(damage, dict):
            raise _fail(f"inconsistent runtime file: {problem}", path)
        fields["damage"] = {key: float(damage[key]) for key in DAMAGE_KEYS}
    if any(name in table for name in CRACK_LAYOUT):  # drawing only; check_runtime wants both
        fields["cracks"] = {name: _array(table, name, binary, path, CRACK_LAYOUT) for name in CRACK_LAYOUT
                            if name in table}
    if "levels" in features:  # section 14: every levels array the table lists (check_runtime says which belong)
        info, names = header.get("levels"), header.get("child_names")
        if not isinstance(info, dict) or not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise _fail("inconsistent runtime file: the feature 'levels' needs a header object 'levels' and a list "
                        "of strings 'child_names'", path)
        fields["levels"] = {name: _array(table, name, binary, path, ALL_LEVEL_LAYOUTS) for name in ALL_LEVEL_LAYOUTS
                            if name in table}
        fields["levels_info"], fields["child_names"] = dict(info), tuple(names)
    return fields


def _array(table: dict, name: str, binary: bytes, path, layout: dict = ARRAY_LAYOUT) -> np.ndarray:
    """The array ``name`` of the header's table, as a read-only view of ``binary``; RuntimeFileError if malformed.

    Shapes, offsets and lengths are checked with Python integers (no int64
    overflow), so a tampered header cannot reach numpy with a size it rejects.
    """
    dtype, ndim = layout[name]
    entry = table.get(name)
    if not isinstance(entry, dict):
        raise _fail(f"runtime header has no entry for array '{name}'", path)
    try:
        if entry.get("dtype") != dtype:
            raise ValueError(f"dtype {entry.get('dtype')!r}, expected {dtype!r}")
        shape = entry["shape"]
        if not isinstance(shape, list):
            raise TypeError(f"shape must be a list, got {shape!r}")
        shape = tuple(_count(x, "shape entry") for x in shape)
        offset = _count(entry["byte_offset"], "byte_offset")
        length = _count(entry["byte_length"], "byte_length")
    except (KeyError, TypeError, ValueError) as exc:
        raise _fail(f"array '{name}' entry is malformed ({exc})", path) from None
    nbytes = math.prod(shape) * 4
    if len(shape) != ndim or length != nbytes:
        raise _fail(f"array '{name}' has shape {list(shape)} and {length} bytes, which do not agree", path)
    if offset % ALIGNMENT or offset + length > len(binary):
        raise _fail(f"array '{name}' lies outside the binary file (offset {offset}, length {length})", path)
    return np.frombuffer(binary, dtype=FILE_DTYPES[dtype], count=nbytes // 4, offset=offset).reshape(shape)


def load_runtime(path: str | os.PathLike) -> RuntimeData:
    """Read a ``<stem>.fracture.json`` file and its binary file.

    Parameters
    ----------
    path : path
        The JSON header; the binary file is found through its ``buffer.uri``
        (a file name in the same directory).

    Returns
    -------
    RuntimeData
        Arrays are read-only views of the file's bytes, in file dtypes.

    Raises
    ------
    RuntimeFileError
        (an :class:`~fracture_cli.errors.InputError` and a :class:`ValueError`)
        if either file is missing, truncated, of another format or version, or
        inconsistent (shapes, counts, indices, checksum).
    """
    path = Path(path)
    try:
        header_bytes = path.read_bytes()
    except FileNotFoundError:
        raise _fail("runtime file not found (expected <stem>.fracture.json written by 'fracture bake')", path) from None
    except OSError as exc:
        raise _fail(f"cannot read runtime file ({exc.strerror})", path) from None
    try:
        uri = parse_header(header_bytes)["buffer"]["uri"]
    except Exception:
        uri = None
    if not isinstance(uri, str) or not uri or os.path.basename(uri) != uri or uri in (".", "..") or "\0" in uri:
        # Let decode() report what is wrong with the header itself.
        return decode(header_bytes, b"", str(path)) if uri is None else _raise_bad_uri(uri, path)
    bin_path = path.with_name(uri)
    try:
        binary = bin_path.read_bytes()
    except FileNotFoundError:
        raise _fail(f"binary file '{uri}' not found next to the header; copy both files together", path) from None
    except OSError as exc:
        raise _fail(f"cannot read binary file '{uri}' ({exc.strerror})", path) from None
    return decode(header_bytes, binary, str(path))


def runtime_files(path: str | os.PathLike) -> list[str]:
    """The files :func:`load_runtime` reads for ``path``: the header and the binary file it names.

    The binary file is the header's ``buffer.uri`` when the header can be read
    and names a plain file, else :func:`bin_path_for` (what a bake writes). Never
    raises: the reader reports a bad header. Commands that write next to a
    runtime file give these to their output guard.
    """
    path = Path(path)
    try:
        uri = parse_header(path.read_bytes())["buffer"]["uri"]
    except Exception:
        uri = None
    ok = isinstance(uri, str) and uri and os.path.basename(uri) == uri and uri not in (".", "..") and "\0" not in uri
    binary = path.with_name(uri) if ok else bin_path_for(path)
    return [str(path), str(binary)]


def _raise_bad_uri(uri, path):
    raise _fail(f"buffer.uri must be a plain file name next to the header, got {uri!r}", path)
