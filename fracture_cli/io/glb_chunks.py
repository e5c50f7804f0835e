"""Where the next chunk of a GLB file starts, for files that follow the specification and files that do not.

The glTF 2.0 specification pads every chunk to a multiple of 4 bytes and counts
the padding in the chunk's length, so the next chunk starts right after it.
Some exporters write a JSON chunk whose length is not a multiple of 4: most
put the binary chunk right after it (no padding at all), a few pad without
counting the padding. The probe (:mod:`fracture_cli.io.probe`) and the reader
(:func:`fracture_cli.io.gltf.read_glb_chunks`) both locate the next chunk with
:func:`next_chunk`, so they never disagree about a file: one that every
accessor fits is read, with a warning when it breaks the alignment rule.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
_KNOWN = (CHUNK_JSON, CHUNK_BIN)


def next_chunk(header_at: Callable[[int], bytes], end: int, total: int) -> tuple[int, bool]:
    """Offset of the chunk that follows a chunk ending at byte ``end``, and whether the file is misaligned there.

    Parameters
    ----------
    header_at : callable
        ``header_at(offset)`` returns the (up to) 8 bytes of the file at ``offset``.
    end : int
        Offset just past the previous chunk's data (its header's length counted).
    total : int
        The file's length as its header states it.

    Returns
    -------
    offset : int
        ``end`` when it is a multiple of 4 (as the specification requires) or
        when a known chunk (JSON or BIN) starts there; otherwise the next
        multiple of 4 if a known chunk that fits in the file starts there;
        else ``end`` (the caller then finds no valid chunk and says so).
    misaligned : bool
        Whether ``end`` is not a multiple of 4 (the file breaks the rule).
    """
    aligned = end + (-end % 4)
    if aligned == end:
        return end, False
    for candidate in (end, aligned):
        head = header_at(candidate)
        if len(head) == 8:
            length, kind = struct.unpack("<II", head)
            if kind in _KNOWN and candidate + 8 + length <= total:
                return candidate, True
    return end, True


def misaligned_warning(length: int) -> str:
    """The warning for a JSON chunk of ``length`` bytes that is not padded to a multiple of 4."""
    return (f"its JSON chunk is {length:,} bytes, not padded to a multiple of 4 as the glTF specification "
            "requires; read anyway (the binary chunk and every accessor fit), but other tools may refuse it")
