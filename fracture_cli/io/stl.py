"""Read an STL file's triangles, binary or ASCII, telling them apart by size rather than by the word "solid".

A binary STL is an 80-byte header, a little-endian uint32 triangle count and
50 bytes per triangle (normal, three corners as float32, a 2-byte attribute),
so its size is ``84 + 50 * n``. Many exporters start the free-form header
with ``solid``, and some write a wrong count. The rules, in order:

1. size is ``84 + 50 * count``: binary;
2. the file starts with ``solid`` and has ``vertex`` lines (either in any case): ASCII;
3. size is ``84 + 50 * n`` for some ``n >= 1``: binary with a wrong count in
   its header; ``n`` triangles are read and a warning says so;
4. otherwise it is not an STL file.
"""

from __future__ import annotations

import logging
import re

import numpy as np

from fracture_cli.errors import InputError

log = logging.getLogger(__name__)

HEADER = 84
RECORD = 50
_RECORD_DTYPE = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
# Keywords are case-insensitive in practice (exporters write SOLID / FACET / VERTEX too).
_VERTEX = re.compile(rb"\bvertex\s+(\S+)\s+(\S+)\s+(\S+)", re.IGNORECASE)


def read_stl(path: str) -> tuple[np.ndarray, np.ndarray]:
    """The triangles of an STL file.

    Returns
    -------
    vertices : (3m, 3) float64
        Three corners per triangle, unwelded.
    faces : (m, 3) int64
        ``[[0, 1, 2], [3, 4, 5], ...]``.

    Raises
    ------
    InputError
        Not an STL file (see the module docstring), or an ASCII facet
        without three corners.
    """
    # on first use: reading or writing one format loads only what it needs
    from fracture_cli.io.inputs import read_input

    raw = read_input(path)
    size = len(raw)
    count = header_count(raw)
    if count is not None and size == HEADER + RECORD * count:
        return _binary(raw, count)
    if raw.lstrip()[:5].lower() == b"solid":
        corners = _VERTEX.findall(raw)
        if corners:
            if len(corners) % 3:
                raise InputError(f"could not be read as STL: {len(corners)} ASCII vertex lines is not three per "
                                 "facet", path=path)
            try:
                V = np.array(corners, dtype=np.float64)
            except ValueError:
                raise InputError("could not be read as STL: an ASCII vertex line has a value that is not a number",
                                 path=path) from None
            return V, np.arange(len(V), dtype=np.int64).reshape(-1, 3)
    n = size_count(size)
    if n is not None:
        log.warning("load: %s: binary STL header says %s triangles but the file holds %d; reading %d", path,
                    f"{count:,}", n, n)
        return _binary(raw, n)
    raise not_stl(path, size, count)


def header_count(head: bytes) -> int | None:
    """The triangle count in a binary STL header (bytes 80..84), None if the file is shorter."""
    return int.from_bytes(head[80:84], "little") if len(head) >= HEADER else None


def size_count(size: int) -> int | None:
    """Triangles of a binary STL of ``size`` bytes (rule 3), None if no count fits."""
    if size > HEADER and (size - HEADER) % RECORD == 0:
        return (size - HEADER) // RECORD
    return None


def not_stl(path: str, size: int, count: int | None) -> InputError:
    """The refusal of a file that no rule reads."""
    expected = f" ({count:,} triangles, {HEADER + RECORD * count:,} bytes)" if count is not None else ""
    return InputError(f"could not be read as STL: not a valid STL file: it does not start with 'solid' (ASCII STL), "
                      f"and its size ({size:,} bytes) does not match the triangle count in its binary header"
                      f"{expected}", path=path)


def _binary(raw: bytes, count: int) -> tuple[np.ndarray, np.ndarray]:
    records = np.frombuffer(raw, dtype=_RECORD_DTYPE, count=count, offset=HEADER)
    V = records["corners"].reshape(-1, 3).astype(np.float64)
    return V, np.arange(len(V), dtype=np.int64).reshape(-1, 3)
