"""The aligned-fracture companion file: ``<stem>.aligned.json`` + ``<stem>.aligned.bin`` (seed 001).

:class:`AlignedData` is what the file holds: the asset's convex pieces (the collision parts of
every fragment, as planes, vertices and face loops) with the visual triangles that lie in each,
and one or more fracture patterns (Voronoi sites in a unit volume and each cell's neighbours).
:func:`encode` / :func:`decode` are the reference codec of docs/FORMAT.md section 13;
:func:`fracture_cli.runtime.aligned.aligned_fracture` uses the data at a hit.

Depends on numpy and the standard library only (see :mod:`fracture_cli.runtime`).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fracture_cli.errors import RuntimeFileError
from fracture_cli.runtime.header import parse_header

ALIGNED_FORMAT = "fracture-aligned"
ALIGNED_VERSION = 1
ALIGNMENT = 16
JSON_SUFFIX = ".aligned.json"
BIN_SUFFIX = ".aligned.bin"

# name -> (dtype, number of dimensions, trailing shape); also the order of the arrays in the .bin file.
ALIGNED_LAYOUT: dict[str, tuple[str, int, tuple[int, ...]]] = {
    "settings": ("float32", 1, ()),
    "piece_fragment": ("int32", 1, ()),
    "piece_sphere": ("float32", 2, (4,)),
    "piece_vertex_offsets": ("int32", 1, ()),
    "piece_vertices": ("float32", 2, (3,)),
    "piece_face_offsets": ("int32", 1, ()),
    "face_planes": ("float32", 2, (4,)),
    "face_loop_offsets": ("int32", 1, ()),
    "face_loops": ("int32", 1, ()),
    "piece_triangle_offsets": ("int32", 1, ()),
    "triangle_positions": ("float32", 3, (3, 3)),
    "triangle_normals": ("float32", 3, (3, 3)),
    "triangle_uvs": ("float32", 3, (3, 2)),
    "triangle_materials": ("int32", 1, ()),
    "pattern_site_offsets": ("int32", 1, ()),
    "pattern_sites": ("float32", 2, (3,)),
    "cell_neighbor_offsets": ("int32", 1, ()),
    "cell_neighbors": ("int32", 1, ()),
    "cell_planes": ("float32", 2, (4,)),
    "boundary_planes": ("float32", 2, (4,)),
    "cell_boundary_offsets": ("int32", 1, ()),
    "cell_boundary": ("int32", 1, ()),
}
_DTYPES = {"float32": np.dtype("<f4"), "int32": np.dtype("<i4")}
SETTINGS = ("uv_scale", "default_scale")  # the entries of the ``settings`` array, in order
MAX_LOOP = 1024  # corners of one face at most (a part has at most 255 corners)


@dataclass(frozen=True, eq=False)
class AlignedData:
    """Everything :func:`~fracture_cli.runtime.aligned.aligned_fracture` needs (docs/FORMAT.md section 13).

    Attributes
    ----------
    arrays : dict of str -> numpy array
        The arrays of :data:`ALIGNED_LAYOUT`, in file dtypes: ``P`` pieces, ``V`` piece vertices, ``F`` faces,
        ``L`` loop entries, ``T`` triangles, ``Q`` patterns, ``S`` sites, ``N`` neighbour entries:
        ``settings (2,)`` (uv_scale, default_scale), ``piece_fragment (P,)``, ``piece_sphere (P, 4)``,
        ``piece_vertex_offsets (P+1,)``, ``piece_vertices (V, 3)``, ``piece_face_offsets (P+1,)``,
        ``face_planes (F, 4)``, ``face_loop_offsets (F+1,)``, ``face_loops (L,)``,
        ``piece_triangle_offsets (P+1,)``, ``triangle_positions (T, 3, 3)``, ``triangle_normals (T, 3, 3)``,
        ``triangle_uvs (T, 3, 2)``, ``triangle_materials (T,)``, ``pattern_site_offsets (Q+1,)``,
        ``pattern_sites (S, 3)``, ``cell_neighbor_offsets (S+1,)``, ``cell_neighbors (N,)``,
        ``cell_planes (N, 4)``, ``boundary_planes (B, 4)`` (the convex region around the unit ball that
        the cells are cut to; everything beyond it is one more cell, the rest of the object; ``B = 0``: no
        boundary, the outer cells reach to infinity), ``cell_boundary_offsets (S+1,)``, ``cell_boundary (E,)``
        (per cell, the boundary planes that bound it).
    materials : tuple of str
        Material names (``<stem>_<material>``, as the fragments GLB's), indexed by ``triangle_materials``.
    interior_material : int
        The material of the new faces (``<stem>_interior``).
    patterns : tuple of dict
        Informational, per pattern: ``sites``, ``grading``, ``seed``.
    units : str
        Human-readable note on units.
    """

    arrays: dict[str, np.ndarray]
    materials: tuple[str, ...]
    interior_material: int
    patterns: tuple[dict, ...] = ()
    units: str = ("model space of the asset, its units; pattern sites in a unit volume "
                  "(world = point + scale * R * site)")

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    @property
    def num_pieces(self) -> int:
        return int(len(self.arrays["piece_fragment"]))

    @property
    def num_patterns(self) -> int:
        return int(len(self.arrays["pattern_site_offsets"]) - 1)

    @property
    def uv_scale(self) -> float:
        return float(self.arrays["settings"][0])

    @property
    def default_scale(self) -> float:
        return float(self.arrays["settings"][1])

    def counts(self) -> dict[str, int]:
        """The header's ``counts``."""
        a = self.arrays
        return {"pieces": self.num_pieces, "piece_vertices": int(len(a["piece_vertices"])),
                "faces": int(len(a["face_planes"])), "face_loops": int(len(a["face_loops"])),
                "triangles": int(len(a["triangle_materials"])), "patterns": self.num_patterns,
                "pattern_sites": int(len(a["pattern_sites"])), "cell_neighbors": int(len(a["cell_neighbors"])),
                "boundary_planes": int(len(a["boundary_planes"])), "cell_boundary": int(len(a["cell_boundary"])),
                "materials": len(self.materials)}


def _offsets_problem(name: str, offsets: np.ndarray, count: int, end: int) -> str | None:
    if offsets.shape != (count + 1,):
        return f"{name} has shape {list(offsets.shape)}, expected [{count + 1}]"
    if offsets[0] != 0 or offsets[-1] != end or np.any(np.diff(offsets) < 0):
        return f"{name} must start at 0, never decrease and end at {end}"
    return None


def check_aligned(data: AlignedData) -> str | None:
    """Why ``data`` is not a valid aligned-fracture file (docs/FORMAT.md section 13.2), or None."""
    a = data.arrays
    for name, (dtype, ndim, trailing) in ALIGNED_LAYOUT.items():
        array = a.get(name)
        if array is None:
            return f"array '{name}' is missing"
        if array.dtype != _DTYPES[dtype] or array.ndim != ndim or tuple(array.shape[1:]) != trailing:
            return f"array '{name}' has dtype {array.dtype} and shape {list(array.shape)}"
        if dtype == "float32" and not np.all(np.isfinite(array)):
            return f"array '{name}' has a value that is not finite"
    counts = data.counts()
    P, V, F, L = counts["pieces"], counts["piece_vertices"], counts["faces"], counts["face_loops"]
    T, Q, S, N = counts["triangles"], counts["patterns"], counts["pattern_sites"], counts["cell_neighbors"]
    if P < 1 or Q < 1:
        return "the file needs at least one piece and one pattern"
    if a["settings"].shape != (len(SETTINGS),) or not np.all(a["settings"] > 0):
        return f"settings must hold {len(SETTINGS)} values > 0 ({', '.join(SETTINGS)})"
    checks = (("piece_vertex_offsets", P, V), ("piece_face_offsets", P, F), ("face_loop_offsets", F, L),
              ("piece_triangle_offsets", P, T), ("pattern_site_offsets", Q, S), ("cell_neighbor_offsets", S, N))
    for name, count, end in checks:
        problem = _offsets_problem(name, a[name], count, end)
        if problem:
            return problem
    if not (len(data.materials) >= 1 and 0 <= data.interior_material < len(data.materials)):
        return "interior_material must index materials"
    if np.any((a["triangle_materials"] < 0) | (a["triangle_materials"] >= len(data.materials))):
        return "a triangle's material is out of range"
    if np.any(a["piece_fragment"] < 0) or np.any(a["piece_sphere"][:, 3] <= 0):
        return "piece_fragment must be >= 0 and every piece_sphere radius > 0"
    pv, pf, fl = a["piece_vertex_offsets"], a["piece_face_offsets"], a["face_loop_offsets"]
    for k in range(P):
        nv = int(pv[k + 1] - pv[k])
        if not 4 <= nv <= 255 or int(pf[k + 1] - pf[k]) < 4:
            return f"piece {k} needs 4 to 255 vertices and at least 4 faces"
        loops = a["face_loops"][fl[pf[k]]:fl[pf[k + 1]]]
        sizes = np.diff(fl[pf[k]:pf[k + 1] + 1])
        if np.any(sizes < 3) or np.any(sizes > MAX_LOOP) or np.any((loops < 0) | (loops >= nv)):
            return f"piece {k} has a face loop with fewer than 3 corners or a corner out of range"
    boundary = a["boundary_planes"].astype(np.float64)
    if len(boundary) and (len(boundary) < 4 or np.any(np.abs(np.linalg.norm(boundary[:, :3], axis=1) - 1) > 1e-5)
                          or np.any(a["pattern_sites"].astype(np.float64) @ boundary[:, :3].T >= boundary[:, 3])):
        return "boundary_planes must be none, or 4 or more unit normals with every site strictly inside"
    problem = _offsets_problem("cell_boundary_offsets", a["cell_boundary_offsets"], S, len(a["cell_boundary"]))
    if problem:
        return problem
    if np.any((a["cell_boundary"] < 0) | (a["cell_boundary"] >= len(boundary))):
        return "a cell's boundary plane is out of range"
    ps, cn = a["pattern_site_offsets"], a["cell_neighbor_offsets"]
    for q in range(Q):
        lo, hi = int(ps[q]), int(ps[q + 1])
        if hi - lo < 1:
            return f"pattern {q} has no sites"
        for i in range(lo, hi):
            nb = a["cell_neighbors"][cn[i]:cn[i + 1]]
            if np.any((nb < 0) | (nb >= hi - lo) | (nb == i - lo)):
                return f"pattern {q}: cell {i - lo} has a neighbour out of range"
        sites = a["pattern_sites"][lo:hi].astype(np.float64)
        if len(np.unique(sites, axis=0)) != hi - lo:
            return f"pattern {q} has two equal sites"
    return None


def _aligned(n: int) -> int:
    return (n + ALIGNMENT - 1) // ALIGNMENT * ALIGNMENT


def encode(data: AlignedData, bin_name: str) -> tuple[bytes, bytes]:
    """Serialize ``data`` to (header JSON bytes, binary bytes); deterministic.

    Parameters
    ----------
    data : AlignedData
    bin_name : str
        File name (no directories) of the binary file, recorded in the header.
    """
    problem = check_aligned(data)
    if problem:
        raise ValueError(f"cannot write aligned-fracture data: {problem}")
    chunks, table, offset = [], {}, 0
    for name, (dtype, _, _) in ALIGNED_LAYOUT.items():
        raw = np.ascontiguousarray(data.arrays[name], dtype=_DTYPES[dtype]).tobytes(order="C")
        table[name] = {"dtype": dtype, "shape": list(data.arrays[name].shape), "byte_offset": offset,
                       "byte_length": len(raw)}
        padded = _aligned(len(raw))
        chunks.append(raw + b"\0" * (padded - len(raw)))
        offset += padded
    binary = b"".join(chunks)
    header = {
        "format": ALIGNED_FORMAT,
        "version": ALIGNED_VERSION,
        "counts": data.counts(),
        "materials": list(data.materials),
        "interior_material": int(data.interior_material),
        "patterns": [dict(sorted(p.items())) for p in data.patterns],
        "units": data.units,
        "buffer": {"uri": bin_name, "byte_length": len(binary), "crc32": zlib.crc32(binary)},
        "arrays": table,
    }
    text = json.dumps(header, sort_keys=True, indent=2, ensure_ascii=True, allow_nan=False) + "\n"
    return text.encode("ascii"), binary


def _count(value, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{what} must be a whole number >= 0, got {value!r}")
    return value


def _array(table: dict, name: str, binary: bytes, path: str) -> np.ndarray:
    dtype, ndim, trailing = ALIGNED_LAYOUT[name]
    entry = table.get(name)
    if not isinstance(entry, dict):
        raise RuntimeFileError(f"aligned header has no entry for array '{name}'", path=path)
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
        raise RuntimeFileError(f"array '{name}' entry is malformed ({exc})", path=path) from None
    nbytes = math.prod(shape) * 4
    if len(shape) != ndim or tuple(shape[1:]) != trailing or length != nbytes:
        raise RuntimeFileError(f"array '{name}' has shape {list(shape)} and {length} bytes, which do not agree",
                               path=path)
    if offset % ALIGNMENT or offset + length > len(binary):
        raise RuntimeFileError(f"array '{name}' lies outside the binary file (offset {offset}, length {length})",
                               path=path)
    return np.frombuffer(binary, dtype=_DTYPES[dtype], count=nbytes // 4, offset=offset).reshape(shape)


def decode(header_bytes: bytes, binary: bytes, path: str = "<memory>") -> AlignedData:
    """Parse an aligned-fracture header and its binary payload; RuntimeFileError if either is bad."""
    try:
        header = parse_header(header_bytes)
    except ValueError as exc:
        raise RuntimeFileError(f"not a JSON aligned-fracture file ({exc})", path=path) from None
    if not isinstance(header, dict) or header.get("format") != ALIGNED_FORMAT:
        raise RuntimeFileError(f"not an aligned-fracture file (expected \"format\": \"{ALIGNED_FORMAT}\")", path=path)
    version = header.get("version")
    if isinstance(version, bool) or version != ALIGNED_VERSION:
        raise RuntimeFileError(f"aligned-fracture version {version!r} is not supported (this reader knows "
                               f"{ALIGNED_VERSION})", path=path)
    try:
        buffer, table = header["buffer"], header["arrays"]
        materials = tuple(str(m) for m in header["materials"])
        interior = _count(header["interior_material"], "interior_material")
        byte_length = _count(buffer["byte_length"], "buffer.byte_length")
        crc = _count(buffer["crc32"], "buffer.crc32") if "crc32" in buffer else None
        patterns = tuple(dict(p) for p in header.get("patterns", []))
        counts = dict(header["counts"])
        if not isinstance(table, dict):
            raise TypeError("arrays must be an object")
    except (KeyError, TypeError, ValueError) as exc:
        raise RuntimeFileError(f"aligned header is missing or has a malformed entry ({exc!r})", path=path) from None
    if len(binary) != byte_length:
        raise RuntimeFileError(f"binary file has {len(binary)} bytes but the header says {byte_length}", path=path)
    if crc is not None and zlib.crc32(binary) != crc:
        raise RuntimeFileError("binary file does not match its header (crc32 differs; from another bake?)",
                               path=path)
    arrays = {name: _array(table, name, binary, path) for name in ALIGNED_LAYOUT}
    data = AlignedData(arrays=arrays, materials=materials, interior_material=interior, patterns=patterns,
                       units=str(header.get("units", "")))
    problem = check_aligned(data)
    if problem is None and {k: counts.get(k) for k in data.counts()} != data.counts():
        problem = f"header counts {counts} do not match the arrays {data.counts()}"
    if problem:
        raise RuntimeFileError(f"inconsistent aligned-fracture file: {problem}", path=path)
    return data


def bin_path_for(json_path: str | os.PathLike) -> Path:
    """The ``.aligned.bin`` file that goes with an ``.aligned.json`` file."""
    json_path = Path(json_path)
    name = json_path.name
    stem = name[: -len(JSON_SUFFIX)] if name.endswith(JSON_SUFFIX) else Path(name).stem
    return json_path.with_name(stem + BIN_SUFFIX)


def _write_replacing(path: Path, payload: bytes) -> None:
    """Write ``payload`` to a temporary file beside ``path`` and rename it over ``path`` (atomic)."""
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        umask = os.umask(0o022)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as handle:
            handle.write(payload)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_aligned(data: AlignedData, json_path: str | os.PathLike) -> tuple[Path, Path]:
    """Write ``data`` as ``<stem>.aligned.json`` and ``<stem>.aligned.bin`` (binary first); returns both paths."""
    json_path = Path(json_path)
    bin_path = bin_path_for(json_path)
    header, binary = encode(data, bin_path.name)
    _write_replacing(bin_path, binary)
    _write_replacing(json_path, header)
    return json_path, bin_path


def load_aligned(path: str | os.PathLike) -> AlignedData:
    """Read an ``<stem>.aligned.json`` file and the binary file its ``buffer.uri`` names (beside it).

    Raises
    ------
    RuntimeFileError
        If either file is missing, of another format or version, or inconsistent.
    """
    path = Path(path)
    try:
        header_bytes = path.read_bytes()
        uri = parse_header(header_bytes)["buffer"]["uri"]
    except FileNotFoundError:
        raise RuntimeFileError("aligned-fracture file not found (a bake writes it with aligned.enabled = true)",
                               path=str(path)) from None
    except (OSError, ValueError, KeyError, TypeError):
        uri = None
    if not isinstance(uri, str) or not uri or os.path.basename(uri) != uri or uri in (".", "..") or "\0" in uri:
        raise RuntimeFileError(f"buffer.uri must be a plain file name next to the header, got {uri!r}",
                               path=str(path))
    try:
        binary = path.with_name(uri).read_bytes()
    except OSError as exc:
        raise RuntimeFileError(f"cannot read binary file '{uri}' ({exc.strerror})", path=str(path)) from None
    return decode(header_bytes, binary, str(path))
