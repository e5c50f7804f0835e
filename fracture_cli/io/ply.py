"""Read a PLY file's triangles: ASCII and binary, faces and triangle strips.

Follows the PLY format as Greg Turk described it (and as scanners and
MeshLab write it): a header of ``element`` and ``property`` lines, then the
elements in order. Read here:

* ``vertex``: ``x y z``, and if present ``nx ny nz``, ``red green blue
  [alpha]`` (integers scaled by 255, floats kept) and texture coordinates
  (``u v``, ``s t`` or ``texture_u texture_v``);
* ``face``: ``vertex_indices`` (or ``vertex_index``) lists of any length,
  triangulated as fans, and per-corner ``texcoord`` lists;
* ``tristrips``: ``vertex_indices`` lists holding triangle strips separated by
  ``-1`` (the alternate winding of a strip is undone);
* ``comment TextureFile <name>``: the base-colour texture.

Other elements are skipped. Every problem is one
:class:`~fracture_cli.errors.InputError` line.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import InputError

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_UV_NAMES = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"))


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    properties: tuple[tuple[str, str, str | None], ...]  # (name, value type, list count type or None)


@dataclass(frozen=True)
class PlyMesh:
    """What a PLY file holds, in file units.

    Attributes
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    normals, colors, uvs : (n, 3), (n, 4), (n, 2) float64 or None
    texture : str or None
        File name from a ``comment TextureFile`` line.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    colors: np.ndarray | None
    uvs: np.ndarray | None
    texture: str | None


def read_ply(path: str) -> PlyMesh:
    """Read a PLY file (see the module docstring).

    Raises
    ------
    InputError
        Not a PLY file, an unknown format or property type, data shorter than
        the header promises, or an index past the vertices.
    """
    # on first use: reading or writing one format loads only what it needs
    from fracture_cli.io.inputs import read_input

    raw = read_input(path)
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise InputError("is not a PLY file: it does not start with 'ply' or has no 'end_header'", path=path)
    body_start = raw.index(b"\n", end) + 1 if b"\n" in raw[end:] else len(raw)
    fmt, elements, texture = _header(raw[:end].decode("latin-1"), path)
    body = raw[body_start:]
    try:
        data = _read_ascii(body, elements) if fmt == "ascii" else _read_binary(body, elements, fmt)
    except (ValueError, IndexError, OverflowError) as exc:
        raise InputError(f"could not be read as PLY: the data does not match the header ({str(exc)[:120]})",
                         path=path) from None
    return _assemble(data, texture, path)


def _header(text: str, path: str) -> tuple[str, list[_Element], str | None]:
    fmt, texture = None, None
    declared: list[tuple[str, int, list]] = []
    for line in text.splitlines()[1:]:
        words = line.split()
        if not words:
            continue
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "comment" and len(words) >= 3 and words[1] == "TextureFile":
            texture = " ".join(words[2:])
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            declared.append((words[1], int(words[2]), []))
        elif words[0] == "property" and declared:
            if len(words) == 5 and words[1] == "list" and words[2] in _TYPES and words[3] in _TYPES:
                declared[-1][2].append((words[4], _TYPES[words[3]], _TYPES[words[2]]))
            elif len(words) == 3 and words[1] in _TYPES:
                declared[-1][2].append((words[2], _TYPES[words[1]], None))
            else:
                raise InputError(f"could not be read as PLY: unsupported property line '{line.strip()}'", path=path)
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(f"could not be read as PLY: unknown format {fmt!r}", path=path)
    return fmt, [_Element(name, count, tuple(props)) for name, count, props in declared], texture


def _read_binary(body: bytes, elements: list[_Element], fmt: str) -> dict[str, dict[str, object]]:
    order = "<" if fmt == "binary_little_endian" else ">"
    offset, out = 0, {}
    for element in elements:
        columns, offset = _binary_uniform(body, offset, element, order)
        if columns is None:
            columns, offset = _binary_rows(body, offset, element, order)
        out[element.name] = columns
    if offset > len(body):
        raise ValueError("the file ends before the last element")
    return out


def _binary_uniform(body: bytes, offset: int, element: _Element, order: str) -> tuple[dict | None, int]:
    """All rows of the element at once, if every list in it has the length of the first row's (the usual case)."""
    fields: list[tuple] = []
    lengths: dict[str, int] = {}
    probe = offset
    for name, value_type, count_type in element.properties:
        if count_type is not None:
            if element.count == 0 or probe + np.dtype(count_type).itemsize > len(body):
                return None, offset
            n = int(_scalar(body, probe, order + count_type))
            lengths[name] = n
            fields.append((f"{name}#n", order + count_type))
            fields.append((name, order + value_type, (n,)))
            probe += np.dtype(count_type).itemsize + n * np.dtype(value_type).itemsize
        else:
            fields.append((name, order + value_type))
            probe += np.dtype(value_type).itemsize
    dtype = np.dtype(fields)
    if offset + dtype.itemsize * element.count > len(body):
        if lengths:
            return None, offset
        raise ValueError(f"element {element.name}: the file ends early")
    table = np.frombuffer(body, dtype=dtype, count=element.count, offset=offset)
    if any(np.any(table[f"{name}#n"] != n) for name, n in lengths.items()):
        return None, offset
    return {name: table[name] for name, _, _ in element.properties}, offset + dtype.itemsize * element.count


def _binary_rows(body: bytes, offset: int, element: _Element, order: str) -> tuple[dict, int]:
    """The element row by row (lists of different lengths, e.g. triangles and quads, or strips)."""
    columns: dict[str, list] = {n: [] for n, _, _ in element.properties}
    for _ in range(element.count):
        for name, value_type, count_type in element.properties:
            if count_type is None:
                value = _scalar(body, offset, order + value_type)
                offset += np.dtype(value_type).itemsize
            else:
                n = int(_scalar(body, offset, order + count_type))
                offset += np.dtype(count_type).itemsize
                size = n * np.dtype(value_type).itemsize
                if offset + size > len(body):
                    raise ValueError(f"element {element.name}: the file ends early")
                value = np.frombuffer(body, dtype=order + value_type, count=n, offset=offset)
                offset += size
            columns[name].append(value)
    return columns, offset


def _scalar(body: bytes, offset: int, dtype: str):
    if offset + np.dtype(dtype).itemsize > len(body):
        raise ValueError("the file ends early")
    return np.frombuffer(body, dtype=dtype, count=1, offset=offset)[0]


def _read_ascii(body: bytes, elements: list[_Element]) -> dict[str, dict[str, object]]:
    tokens = body.split()
    pos, out = 0, {}
    for element in elements:
        columns, pos = _ascii_uniform(tokens, pos, element)
        if columns is None:
            columns, pos = _ascii_rows(tokens, pos, element)
        out[element.name] = columns
    return out


def _ascii_uniform(tokens: list[bytes], pos: int, element: _Element) -> tuple[dict | None, int]:
    """All rows at once if every list has the first row's length; None otherwise."""
    widths, cursor = [], pos
    for _, _, count_type in element.properties:
        if count_type is None:
            widths.append(1)
            cursor += 1
        else:
            if cursor >= len(tokens):
                return None, pos
            n = int(float(tokens[cursor]))
            widths.append(1 + n)
            cursor += 1 + n
    row = sum(widths)
    values = tokens[pos:pos + row * element.count]
    if len(values) != row * element.count:
        if any(p[2] is not None for p in element.properties):
            return None, pos
        raise ValueError(f"element {element.name}: {len(values)} values, expected {row * element.count}")
    block = np.array(values, dtype=np.float64).reshape(element.count, row)
    columns, start = {}, 0
    for (name, _, count_type), width in zip(element.properties, widths):
        if count_type is None:
            columns[name] = block[:, start]
        else:
            if np.any(block[:, start] != width - 1):
                return None, pos
            columns[name] = block[:, start + 1:start + width]
        start += width
    return columns, pos + row * element.count


def _ascii_rows(tokens: list[bytes], pos: int, element: _Element) -> tuple[dict, int]:
    columns: dict[str, list] = {n: [] for n, _, _ in element.properties}
    for _ in range(element.count):
        for name, _, count_type in element.properties:
            if count_type is None:
                columns[name].append(float(tokens[pos]))
                pos += 1
            else:
                n = int(float(tokens[pos]))
                values = np.array(tokens[pos + 1:pos + 1 + n], dtype=np.float64)
                if len(values) != n:
                    raise ValueError(f"element {element.name} ends early")
                columns[name].append(values)
                pos += 1 + n
    return columns, pos


def _assemble(data: dict, texture: str | None, path: str) -> PlyMesh:
    vertex = data.get("vertex", {})
    if not all(k in vertex for k in "xyz"):
        raise InputError("could not be read as PLY: its vertices have no x, y, z", path=path)
    V = np.stack([np.asarray(vertex[k], dtype=np.float64) for k in "xyz"], axis=1)
    faces, corner_uv = _faces(data.get("face", {}), path)
    strips = _strip_triangles(data.get("tristrips", {}).get("vertex_indices", []))
    F = np.concatenate([faces, strips]).astype(np.int64) if len(strips) else faces
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise InputError("has faces that reference missing vertices", path=path)
    normals = np.stack([np.asarray(vertex[k], np.float64) for k in ("nx", "ny", "nz")], 1) \
        if all(k in vertex for k in ("nx", "ny", "nz")) else None
    colors = None
    if all(k in vertex for k in ("red", "green", "blue")):
        channels = [np.asarray(vertex[k]) for k in ("red", "green", "blue", "alpha") if k in vertex]
        scale = 255.0 if np.issubdtype(channels[0].dtype, np.integer) or max(c.max(initial=0) for c in channels) > 1 \
            else 1.0
        colors = np.ones((len(V), 4))
        colors[:, :len(channels)] = np.stack(channels, axis=1) / scale
    uvs = next((np.stack([np.asarray(vertex[a], np.float64), np.asarray(vertex[b], np.float64)], 1)
                for a, b in _UV_NAMES if a in vertex and b in vertex), None)
    if corner_uv is not None and len(faces) and not len(strips):
        # Texture coordinates per triangle corner: one vertex per corner (repair welds by position).
        corners = faces.reshape(-1)
        V, uvs, F = V[corners], corner_uv, np.arange(len(corners), dtype=np.int64).reshape(-1, 3)
        normals = None if normals is None else normals[corners]
        colors = None if colors is None else colors[corners]
    return PlyMesh(vertices=V, faces=F, normals=normals, colors=colors, uvs=uvs, texture=texture)


def _faces(face: dict, path: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Polygons as fan triangles (m, 3) and, if present, their per-corner UVs (3m, 2)."""
    polygons = face.get("vertex_indices", face.get("vertex_index"))
    if polygons is None:
        return np.zeros((0, 3), dtype=np.int64), None
    texcoords = face.get("texcoord")
    if isinstance(polygons, np.ndarray):  # every polygon has the same size
        rows = [polygons] if polygons.ndim == 2 else []
        uv_rows = [texcoords] if isinstance(texcoords, np.ndarray) else None
    else:
        rows = [np.asarray(p).reshape(1, -1) for p in polygons]
        uv_rows = [np.asarray(t).reshape(1, -1) for t in texcoords] if texcoords is not None else None
    tris, uvs = [], []
    for i, poly in enumerate(rows):
        poly = poly.astype(np.int64)
        size = poly.shape[1]
        if size < 3:
            continue
        k = np.arange(1, size - 1)
        tris.append(np.stack([np.repeat(poly[:, :1], len(k), 1), poly[:, k], poly[:, k + 1]], axis=2).reshape(-1, 3))
        if uv_rows is not None:
            tc = np.asarray(uv_rows[i], dtype=np.float64).reshape(len(poly), -1, 2)
            if tc.shape[1] != size:
                raise InputError("could not be read as PLY: a face's texcoord list does not match its corners",
                                 path=path)
            uvs.append(np.stack([np.repeat(tc[:, :1], len(k), 1), tc[:, k], tc[:, k + 1]], axis=2).reshape(-1, 2))
    if not tris:
        return np.zeros((0, 3), dtype=np.int64), None
    return np.concatenate(tris), (np.concatenate(uvs) if uv_rows is not None and uvs else None)


def _strip_triangles(strips) -> np.ndarray:
    """Triangles (m, 3) of triangle strips; ``-1`` starts a new strip; every second triangle's order is swapped."""
    out = []
    for row in strips:
        row = np.asarray(row, dtype=np.int64)
        cuts = np.flatnonzero(row < 0)
        for strip in np.split(row, cuts):
            strip = strip[strip >= 0]
            n = len(strip) - 2
            if n <= 0:
                continue
            i = np.arange(n)
            even = i % 2 == 0
            a = strip[i]
            b = np.where(even, strip[i + 1], strip[i + 2])
            c = np.where(even, strip[i + 2], strip[i + 1])
            out.append(np.stack([a, b, c], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 3), dtype=np.int64)


def texture_path(path: str, mesh: PlyMesh) -> str | None:
    """The texture file a PLY names, in its folder or below.

    Raises
    ------
    InputError
        The name is absolute, a URL or climbs out of the PLY's folder.
    """
    # on first use: reading or writing one format loads only what it needs
    from fracture_cli.io.inputs import EscapingReference, companion_path

    if not mesh.texture:
        return None
    try:
        return companion_path(os.path.dirname(path), mesh.texture)
    except EscapingReference as exc:
        raise InputError(f"names the texture '{mesh.texture}' ({exc}); only files in the asset's folder or below "
                         "it are read (copy the file beside the asset)", path=path) from None
