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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fracture_cli.errors import RuntimeFileError
from fracture_cli.runtime.gameready import GAMEREADY_LAYOUT, check_gameready
from fracture_cli.runtime.header import parse_header
from fracture_cli.runtime.stress import CRITERIA, STRESS_LAYOUT, check_stress, header_features

FORMAT_NAME = "fracture-modes-runtime"
FORMAT_VERSION = 1  # what a bake without any version-2 feature writes (byte-identical to before version 2)
MAX_VERSION = 2  # the newest version this reader reads (docs/notes/runtime-format-v2.md)
ALIGNMENT = 16
JSON_SUFFIX = ".fracture.json"
BIN_SUFFIX = ".fracture.bin"
UNITS_NOTE = (
    "sites are in the input asset's model space and units; edge_areas in those units squared; "
    "impulse and threshold share one (any) unit; radius is a fraction of the bounding-box diagonal"
)

# name -> (dtype, number of dimensions); also the order of arrays in the .bin file.
ARRAY_LAYOUT: dict[str, tuple[str, int]] = {
    "sites": ("float32", 2),
    "B": ("float32", 3),
    "W": ("float32", 3),
    "edges": ("int32", 2),
    "edge_areas": ("float32", 1),
}
_DTYPES = {"float32": np.dtype("<f4"), "int32": np.dtype("<i4")}


@dataclass(frozen=True, eq=False)
class RuntimeData:
    """Everything the realtime impact projection needs (ALGORITHM.md section 4).

    Attributes
    ----------
    sites : (s, 3) float32
        Contact sites (the tet mesh's boundary vertices), input asset units.
    B : (s, k, d) float32
        Site-to-mode coefficients; an impulse ``n`` at site ``v`` excites mode
        ``i`` by ``alpha_i = B[v, i, 0] * |n|`` (d = 1) or ``B[v, i] . n`` (d = 3).
    W : (k, p, d) float32
        Piece modes: displacement of fragment ``j`` in mode ``i``.
    edges : (e, 2) int32
        Fragment-graph edges ``(P, Q)``, ``P < Q``, sorted.
    edge_areas : (e,) float32
        Interface area of each edge, input asset units squared.
    fragment_names : tuple of str
        Name of fragment ``j`` (``p`` names), as in the fragments file.
    transform : (4, 4) float64
        Map from the normalized bake coordinates to the asset's units
        (``world = transform @ [x, y, z, 1]``); informational.
    default_threshold : float
        Toughness used when the caller gives none (same unit as the impulse).
    radius : float
        Impact radius baked into ``B``, as a fraction of the bounding-box diagonal.
    units : str
        Human-readable note on units.
    gameready : dict of str -> array
        The optional arrays of :data:`GAMEREADY_LAYOUT` (mass properties and
        collision parts per fragment, model space), all or none.
    criterion : str
        ``"modes"`` (version 1) or ``"stress"`` (version 2 with feature ``"stress"``).
    stress : dict of str -> array
        The arrays of :data:`fracture_cli.runtime.stress.STRESS_LAYOUT` (criterion ``"stress"`` only).
    stress_info : dict
        The stress criterion's material parameters (header key ``stress``; informational).
    """

    sites: np.ndarray
    B: np.ndarray
    W: np.ndarray
    edges: np.ndarray
    edge_areas: np.ndarray
    fragment_names: tuple[str, ...]
    transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    default_threshold: float = 1.0
    radius: float = 0.05
    units: str = UNITS_NOTE
    gameready: dict[str, np.ndarray] = field(default_factory=dict)
    criterion: str = "modes"
    stress: dict[str, np.ndarray] = field(default_factory=dict)
    stress_info: dict = field(default_factory=dict)

    @property
    def features(self) -> tuple[str, ...]:
        """The format-2 features the data needs (sorted; empty: a version-1 file)."""
        return ("stress",) if self.stress else ()

    @property
    def version(self) -> int:
        """The format version the data is written as: 1 without features, 2 with."""
        return 2 if self.features else FORMAT_VERSION

    @property
    def dim(self) -> int:
        """Displacement dimension ``d`` (1 or 3)."""
        return int(self.W.shape[2])

    @property
    def k(self) -> int:
        """Number of modes."""
        return int(self.W.shape[0])

    @property
    def p(self) -> int:
        """Number of fragments (atomic pieces)."""
        return int(self.W.shape[1])

    @property
    def num_sites(self) -> int:
        return int(self.sites.shape[0])

    @property
    def num_edges(self) -> int:
        return int(self.edges.shape[0])

    def arrays(self) -> dict[str, np.ndarray]:
        """The binary arrays in file order, converted to their file dtypes."""
        arrays = {name: np.ascontiguousarray(getattr(self, name), dtype=_DTYPES[dtype])
                  for name, (dtype, _) in ARRAY_LAYOUT.items()}
        for name, (dtype, _) in GAMEREADY_LAYOUT.items():
            if name in self.gameready:
                arrays[name] = np.ascontiguousarray(self.gameready[name], dtype=_DTYPES[dtype])
        for name, (dtype, _) in STRESS_LAYOUT.items():
            if name in self.stress:
                arrays[name] = np.ascontiguousarray(self.stress[name], dtype=_DTYPES[dtype])
        return arrays

    def counts(self) -> dict[str, int]:
        """The header's ``counts``."""
        counts = {"sites": self.num_sites, "modes": self.k, "fragments": self.p, "edges": self.num_edges}
        if self.gameready:
            counts["collision_parts"] = int(len(self.gameready["collision_part_offsets"]) - 1)
            counts["collision_vertices"] = int(len(self.gameready["collision_vertices"]))
        if self.stress:
            counts["site_bonds"] = int(len(self.stress["site_bonds"]))
        return counts


def check_runtime(data: RuntimeData) -> str | None:
    """Return why ``data`` is inconsistent, or None if it is usable."""
    W = np.asarray(data.W)
    if W.ndim != 3 or W.shape[2] not in (1, 3):
        return f"W must have shape (k, p, d) with d = 1 or 3, got {W.shape}"
    k, p, d = W.shape
    s = np.asarray(data.sites).shape[0] if np.asarray(data.sites).ndim == 2 else -1
    expected = {
        "sites": (s, 3),
        "B": (s, k, d),
        "W": (k, p, d),
        "edges": (np.asarray(data.edges).shape[0] if np.asarray(data.edges).ndim == 2 else -1, 2),
    }
    expected["edge_areas"] = (expected["edges"][0],)
    for name, shape in expected.items():
        got = np.asarray(getattr(data, name)).shape
        if got != shape or min(shape) < 0:
            return f"array {name} has shape {list(got)}, expected {list(shape)}"
    if s < 1:
        return "there are no contact sites"
    if k < 1 or p < 1:
        return f"need at least one mode and one fragment, got k = {k}, p = {p}"
    if len(data.fragment_names) != p:
        return f"{len(data.fragment_names)} fragment names for {p} fragments"
    edges = np.asarray(data.edges)
    if len(edges) and (edges.min() < 0 or edges.max() >= p or np.any(edges[:, 0] >= edges[:, 1])):
        return f"edges must be pairs (P, Q) with 0 <= P < Q < {p}"
    for name in ("sites", "B", "W", "edge_areas"):
        if not np.all(np.isfinite(getattr(data, name))):
            return f"array {name} has non-finite values"
    if not (np.isfinite(data.default_threshold) and data.default_threshold >= 0):
        return f"default threshold must be a finite number >= 0, got {data.default_threshold!r}"
    if np.asarray(data.transform).shape != (4, 4):
        return "transform must be a 4x4 matrix"
    if data.gameready:
        problem = check_gameready(data.gameready, p)
        if problem:
            return problem
    if not (np.all(np.isfinite(data.transform)) and np.isfinite(data.radius)):
        return "transform and impact radius must be finite numbers"
    if data.criterion not in CRITERIA:
        return f"unknown criterion {data.criterion!r}"
    if (data.criterion == "stress") != bool(data.stress):
        return "the stress criterion and the stress arrays come together"
    if data.stress:
        return check_stress(data.stress, s, expected["edges"][0])
    return None


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
            "dtype": {**ARRAY_LAYOUT, **GAMEREADY_LAYOUT, **STRESS_LAYOUT}[name][0],
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
        header["stress"] = {key: data.stress_info[key] for key in sorted(data.stress_info)}
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
    info: dict = header["stress"] if isinstance(header.get("stress"), dict) else {}
    data = RuntimeData(fragment_names=names, transform=transform, default_threshold=threshold,
                       radius=radius, units=units, gameready=gameready, criterion=criterion, stress=stress,
                       stress_info=dict(info), **arrays)
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
    return np.frombuffer(binary, dtype=_DTYPES[dtype], count=nbytes // 4, offset=offset).reshape(shape)


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
