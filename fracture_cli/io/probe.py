"""Cheap checks of a mesh file before it is decoded: container sanity and triangle count.

:func:`probe_triangles` reads only headers (GLB/glTF JSON, binary STL count,
PLY and OFF headers) or scans bytes (OBJ ``f`` lines, ASCII STL facets), so an
input over the triangle limit, truncated, or not of its extension's format is
refused before memory is spent on its buffers.
"""

from __future__ import annotations

import json
import os
import stat
import struct

from fracture_cli.errors import InputError
from fracture_cli.io.glb_chunks import next_chunk
from fracture_cli.io.gltf_read import buffer_file, check_required_extensions
from fracture_cli.io.inputs import external_uri, file_kind, open_regular

_GLB_MAGIC = b"glTF"
_GLB_JSON = 0x4E4F534A
_CHUNK = 1 << 24
# glTF primitive modes: points, lines, line loop, line strip, triangles, strip, fan.
_TRIANGLE_MODES = {4: "list", 5: "strip", 6: "fan"}


def probe_triangles(path: str, file_type: str) -> int | None:
    """Triangles a file declares (int), or None when the format has no cheap count.

    Parameters
    ----------
    path : str
        An existing, non-empty file.
    file_type : str
        One of ``obj``, ``ply``, ``stl``, ``off``, ``glb``, ``gltf``.

    Returns
    -------
    int or None
        For OBJ, the number of face lines (a lower bound: polygons give more
        triangles); for the others the count in the file's header.

    Raises
    ------
    InputError
        Truncated GLB, a file that is not of its extension's format (GLB
        without its magic, binary STL whose size does not match its count,
        a PLY or OFF without its header), or a glTF whose external buffer is
        missing.
    """
    probe = {"glb": _probe_glb, "gltf": _probe_gltf, "stl": _probe_stl, "obj": _probe_obj, "ply": _probe_ply,
             "off": _probe_off}[file_type]
    return probe(path)


def _gltf_triangles(doc: dict) -> int:
    """Triangles drawn by a glTF document's node hierarchy (every mesh instance counts)."""
    accessors = doc.get("accessors", [])
    meshes = doc.get("meshes", [])

    def count(index) -> int:
        try:
            return int(accessors[index].get("count", 0))
        except (IndexError, TypeError, AttributeError):
            return 0

    def mesh_triangles(m) -> int:
        total = 0
        try:
            primitives = meshes[m].get("primitives", [])
        except (IndexError, TypeError, AttributeError):
            return 0
        for prim in primitives:
            mode = prim.get("mode", 4)
            if mode not in _TRIANGLE_MODES:
                continue
            n = count(prim["indices"]) if "indices" in prim else count(prim.get("attributes", {}).get("POSITION"))
            total += n // 3 if mode == 4 else max(n - 2, 0)
        return total

    nodes = [n for n in doc.get("nodes", []) if isinstance(n, dict) and "mesh" in n]
    if nodes:
        return sum(mesh_triangles(n["mesh"]) for n in nodes)
    return sum(mesh_triangles(m) for m in range(len(meshes)))


def _probe_glb(path: str) -> int:
    size = os.path.getsize(path)
    with open_regular(path) as fh:
        head = fh.read(20)
        if len(head) < 12 or head[:4] != _GLB_MAGIC:
            raise InputError("could not be read as GLB: it does not start with 'glTF' (not a binary glTF file)",
                             path=path)
        version, length = struct.unpack_from("<II", head, 4)
        if version != 2:
            raise InputError(f"is a glTF {version}.x binary; only glTF 2.0 is supported", path=path)
        if length > size:
            raise InputError(f"is truncated: its header says {length:,} bytes, the file has {size:,}", path=path)
        if len(head) < 20:
            raise InputError("is truncated: no JSON chunk after the GLB header", path=path)
        chunk_length, chunk_type = struct.unpack_from("<II", head, 12)
        if chunk_type != _GLB_JSON or 20 + chunk_length > size:
            raise InputError("is truncated or corrupt: its first chunk is not a complete JSON chunk", path=path)
        try:
            doc = json.loads(fh.read(chunk_length))
        except (ValueError, UnicodeDecodeError) as exc:
            raise InputError(f"has a corrupt JSON chunk ({exc})", path=path) from exc
    if not isinstance(doc, dict):
        raise InputError("has a corrupt JSON chunk (not an object)", path=path)
    check_required_extensions(doc, path)
    needed = sum(int(b.get("byteLength", 0)) for b in doc.get("buffers", [])[:1] if "uri" not in b)
    if needed:
        available = _binary_chunk_length(path, 20 + chunk_length, min(length, size))
        if available < needed:
            raise InputError(f"is truncated: its binary chunk needs {needed:,} bytes, the file has {available:,} "
                             "after the JSON", path=path)
    return _gltf_triangles(doc)


def _binary_chunk_length(path: str, end: int, total: int) -> int:
    """Bytes of the binary chunk after a JSON chunk ending at ``end``, located as the reader locates it
    (:func:`~fracture_cli.io.glb_chunks.next_chunk`: an unpadded JSON chunk is read), at most what the file holds."""
    with open_regular(path) as fh:
        def header_at(offset: int) -> bytes:
            fh.seek(offset)
            return fh.read(8)

        start, _ = next_chunk(header_at, end, total)
        head = header_at(start)
    if len(head) < 8:
        return 0
    chunk_length, _ = struct.unpack("<II", head)
    return max(min(chunk_length, total - start - 8), 0)


def _probe_gltf(path: str) -> int:
    try:
        with open_regular(path) as fh:
            doc = json.loads(fh.read())
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"is not valid glTF JSON ({str(exc)[:120]})", path=path) from exc
    if not isinstance(doc, dict):
        raise InputError("is not valid glTF JSON (not an object)", path=path)
    check_required_extensions(doc, path)
    folder = os.path.dirname(os.path.abspath(path))
    for index, buffer in enumerate(doc.get("buffers", [])):
        if isinstance(buffer, dict) and external_uri(buffer.get("uri")) is not None:
            uri = buffer["uri"]
            try:
                mode = os.stat(buffer_file(folder, uri, index, path)).st_mode
            except OSError:
                raise InputError(f"references the buffer file '{uri}', which is missing (keep it beside the .gltf, "
                                 "or export a single .glb)", path=path) from None
            if not stat.S_ISREG(mode):
                raise InputError(f"buffer {index}'s uri '{uri}' names {file_kind(mode)}, not a regular file; only "
                                 "regular files are read", path=path)
    return _gltf_triangles(doc)


def _probe_stl(path: str) -> int:
    """Triangles by the rules of :mod:`fracture_cli.io.stl` (binary by size, not by the word 'solid')."""
    # on first use: reading or writing one format loads only what it needs
    from fracture_cli.io.stl import HEADER, RECORD, header_count, not_stl, size_count

    size = os.path.getsize(path)
    with open_regular(path) as fh:
        head = fh.read(HEADER)
    declared = header_count(head)
    if declared is not None and size == HEADER + RECORD * declared:
        return declared
    if head.lstrip()[:5].lower() == b"solid":
        facets = _count_bytes(path, b"endfacet", lower=True)  # keywords are case-insensitive (SOLID, ENDFACET)
        if facets:
            return facets
    fitted = size_count(size)
    if fitted is not None:
        return fitted
    raise not_stl(path, size, declared)


def _count_bytes(path: str, needle: bytes, line_start: bool = False, lower: bool = False) -> int:
    """Occurrences of ``needle`` in the file (at line starts only if ``line_start``; in any case if ``lower``,
    for a lowercase ``needle``), read in 16 MB chunks."""
    total = 0
    pattern = b"\n" + needle if line_start else needle
    carry = b"\n" if line_start else b""
    with open_regular(path) as fh:
        while True:
            block = fh.read(_CHUNK)
            if not block:
                break
            block = block.lower() if lower else block
            data = carry + block
            total += data.count(pattern)
            carry = data[-(len(pattern) - 1):] if len(pattern) > 1 else b""
    return total


def _probe_obj(path: str) -> int:
    return _count_bytes(path, b"f ", line_start=True) + _count_bytes(path, b"f\t", line_start=True)


def _header_lines(path: str, limit: int = 64 * 1024) -> list[str]:
    with open_regular(path) as fh:
        head = fh.read(limit)
    return head.decode("latin-1").splitlines()


def _probe_ply(path: str) -> int:
    lines = _header_lines(path)
    if not lines or lines[0].strip() != "ply":
        raise InputError("is not a PLY file: it does not start with 'ply'", path=path)
    for line in lines[1:]:
        words = line.split()
        if words[:2] == ["element", "face"] and len(words) == 3 and words[2].isdigit():
            return int(words[2])
        if words[:1] == ["end_header"]:
            break
    return 0


def _probe_off(path: str) -> int:
    words = []
    for line in _header_lines(path):
        words += line.split("#", 1)[0].split()
        if len(words) >= 4:
            break
    if not words or not words[0].endswith("OFF"):
        raise InputError("is not an OFF file: it does not start with 'OFF'", path=path)
    if len(words) >= 3 and words[2].isdigit():
        return int(words[2])
    return 0
