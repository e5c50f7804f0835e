"""A small, deterministic glTF 2.0 (GLB) writer.

We write GLB ourselves rather than through trimesh so that (a) one node and one
mesh hold all primitives of a fragment (outer materials + interior), (b) the
bytes are reproducible (no generator timestamps, fixed key order), and (c) the
layout is exactly what the format doc promises.
"""

from __future__ import annotations

import io
import json
import logging
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fracture_cli import __version__
from fracture_cli.errors import InputError
from fracture_cli.io.glb_chunks import misaligned_warning, next_chunk
from fracture_cli.types import Material

log = logging.getLogger(__name__)

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
FLOAT = 5126
UINT16 = 5123
UINT32 = 5125
ARRAY_BUFFER = 34962
ELEMENT_ARRAY_BUFFER = 34963


@dataclass(frozen=True)
class MaterialSource:
    """What :func:`glb_bytes` carries over from an input material besides its name and colour.

    The readers of this package fill it (trimesh's material objects have the
    same attributes, so they are carried over as well).

    Attributes
    ----------
    baseColorTexture : PIL.Image.Image or None
        Written as an embedded PNG.
    metallicFactor, roughnessFactor : float
    """

    baseColorTexture: object = None
    metallicFactor: float = 1.0
    roughnessFactor: float = 1.0


@dataclass(frozen=True)
class Primitive:
    """One glTF primitive: triangles of a single material.

    Attributes
    ----------
    positions : (n, 3) float
    normals : (n, 3) float
    uvs : (n, 2) float or None
        OpenGL convention (v up); flipped to glTF's (v down) on write.
    indices : (m, 3) int
    material : int
        Index into the material list passed to :func:`glb_bytes`.
    """

    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray | None
    indices: np.ndarray
    material: int


def _material_json(material: Material, texture_index: int | None) -> dict:
    pbr = {
        "baseColorFactor": [round(float(c), 6) for c in material.base_color],
        "metallicFactor": 0.0,
        "roughnessFactor": 1.0,
    }
    src = material.source
    for key, attr in (("metallicFactor", "metallicFactor"), ("roughnessFactor", "roughnessFactor")):
        value = getattr(src, attr, None)
        if value is not None:
            pbr[key] = round(float(value), 6)
    if texture_index is not None:
        pbr["baseColorTexture"] = {"index": texture_index, "texCoord": 0}
    out = {"name": material.name, "pbrMetallicRoughness": pbr}
    if material.base_color[3] < 1.0:
        out["alphaMode"] = "BLEND"
    return out


def _texture_png(material: Material) -> bytes | None:
    image = getattr(material.source, "baseColorTexture", None)
    if image is None:
        image = getattr(material.source, "image", None)
    if image is None or not hasattr(image, "save"):
        return None
    buf = io.BytesIO()
    image.save(buf, format="PNG", optimize=False)
    return buf.getvalue()


class GlbBuffer:
    """The binary chunk of a GLB being written, with its buffer views and accessors."""

    def __init__(self) -> None:
        self.binary = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def add_view(self, data: bytes, target: int | None) -> int:
        """Append ``data`` (4-byte aligned) as a buffer view; returns its index."""
        while len(self.binary) % 4:
            self.binary.append(0)
        view = {"buffer": 0, "byteOffset": len(self.binary), "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.binary.extend(data)
        self.views.append(view)
        return len(self.views) - 1

    def add_accessor(self, array: np.ndarray, kind: str, component: int, target: int | None,
                     bounds: bool = False) -> int:
        """Append ``array`` (already in its file dtype) as a view and an accessor; returns the accessor index."""
        view = self.add_view(array.tobytes(), target)
        acc = {"bufferView": view, "componentType": component, "count": int(array.shape[0]), "type": kind}
        if bounds:
            acc["min"] = [float(x) for x in array.min(axis=0)]
            acc["max"] = [float(x) for x in array.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def glb_bytes(meshes: Sequence[tuple[str, list[Primitive]] | tuple[str, list[Primitive], np.ndarray]],
              materials: tuple[Material, ...], extend=None) -> bytes:
    """Encode meshes as a GLB file, one node per mesh.

    Parameters
    ----------
    meshes : list of (name, list of Primitive[, translation (3,)])
        Node/mesh names, their primitives and optionally the node's
        translation (positions are relative to it), in output order.
    materials : tuple of Material
        Material slots referenced by ``Primitive.material``.
    extend : callable, optional
        ``extend(doc, buffer)`` may add to the document before it is packed
        (child nodes, extensions, extras; data through ``buffer``'s
        :meth:`GlbBuffer.add_accessor`). Node ``i`` is ``meshes[i]``.

    Returns
    -------
    bytes
        A complete, deterministic GLB file.
    """
    buffer = GlbBuffer()
    add_view, add_accessor = buffer.add_view, buffer.add_accessor

    images: list[dict] = []
    textures: list[dict] = []
    samplers: list[dict] = []
    material_json = []
    for material in materials:
        png = _texture_png(material)
        tex = None
        if png is not None:
            if not samplers:
                samplers.append({"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497})
            view = add_view(png, None)
            images.append({"bufferView": view, "mimeType": "image/png"})
            textures.append({"sampler": 0, "source": len(images) - 1})
            tex = len(textures) - 1
        material_json.append(_material_json(material, tex))

    gl_meshes, nodes = [], []
    for name, primitives, *rest in meshes:
        translation = rest[0] if rest else None
        prims = []
        for prim in primitives:
            if len(prim.indices) == 0:
                continue
            pos = np.ascontiguousarray(prim.positions, dtype="<f4")
            nrm = np.ascontiguousarray(prim.normals, dtype="<f4")
            attributes = {
                "POSITION": add_accessor(pos, "VEC3", FLOAT, ARRAY_BUFFER, bounds=True),
                "NORMAL": add_accessor(nrm, "VEC3", FLOAT, ARRAY_BUFFER),
            }
            if prim.uvs is not None:
                uv = np.array(prim.uvs, dtype=np.float64)
                uv[:, 1] = 1.0 - uv[:, 1]
                attributes["TEXCOORD_0"] = add_accessor(np.ascontiguousarray(uv, dtype="<f4"), "VEC2", FLOAT,
                                                        ARRAY_BUFFER)
            idx = np.ascontiguousarray(prim.indices, dtype="<u4").reshape(-1)
            indices = add_accessor(idx, "SCALAR", UINT32, ELEMENT_ARRAY_BUFFER)
            prims.append({"attributes": attributes, "indices": indices, "material": int(prim.material), "mode": 4})
        gl_meshes.append({"name": name, "primitives": prims})
        node = {"name": name, "mesh": len(gl_meshes) - 1}
        if translation is not None and np.any(np.asarray(translation) != 0):
            node["translation"] = [float(x) for x in translation]
        nodes.append(node)

    doc = {
        "asset": {"version": "2.0", "generator": f"fracture {__version__}"},
        "scene": 0,
        "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes,
        "meshes": gl_meshes,
        "materials": material_json,
        # Filled in below, once ``extend`` has added its data (kept here for a stable key order).
        "accessors": buffer.accessors,
        "bufferViews": buffer.views,
        "buffers": [],
    }
    if images:
        doc["images"] = images
        doc["textures"] = textures
        doc["samplers"] = samplers
    if extend is not None:
        extend(doc, buffer)
    while len(buffer.binary) % 4:
        buffer.binary.append(0)
    doc["buffers"] = [{"byteLength": len(buffer.binary)}]
    return pack_glb(doc, buffer.binary)


def pack_glb(doc: dict, binary: bytes | bytearray | None) -> bytes:
    """A GLB container: the JSON chunk (space-padded) and the binary chunk (zero-padded), if any."""
    text = json.dumps(doc, separators=(",", ":"), sort_keys=False).encode("utf-8")
    text += b" " * ((4 - len(text) % 4) % 4)
    parts: list[bytes | bytearray] = [struct.pack("<II", len(text), _CHUNK_JSON), text]
    if binary is not None:
        pad = (4 - len(binary) % 4) % 4
        parts += [struct.pack("<II", len(binary) + pad, _CHUNK_BIN), binary, b"\0" * pad]
    # One join: the binary chunk (tens of MB for a big asset) is copied once, not once per concatenation.
    return b"".join([struct.pack("<4sII", _GLB_MAGIC, 2, 12 + sum(len(p) for p in parts)), *parts])


def read_glb_chunks(path: str) -> tuple[dict, bytes | None]:
    """The JSON document and binary chunk of a GLB file.

    Raises
    ------
    InputError
        Missing file, not a GLB, unsupported version, truncated, no JSON chunk.
    """
    # on first use: reading or writing one format loads only what it needs
    from fracture_cli.io.inputs import read_input

    try:
        raw = read_input(path)
    except FileNotFoundError:
        raise InputError("no such file", path=path) from None
    except OSError as exc:
        raise InputError(f"cannot be read ({exc.strerror})", path=path) from None
    if len(raw) < 20 or raw[:4] != _GLB_MAGIC:
        raise InputError("not a binary glTF (.glb) file", path=path)
    _, version, total = struct.unpack_from("<4sII", raw, 0)
    if version != 2 or total > len(raw):
        raise InputError(f"unsupported or truncated GLB (version {version}, {len(raw)} of {total} bytes)", path=path)
    offset, doc, binary = 12, None, None
    while offset + 8 <= total:
        length, kind = struct.unpack_from("<II", raw, offset)
        chunk = raw[offset + 8: offset + 8 + length]
        if len(chunk) != length:
            raise InputError("truncated GLB chunk", path=path)
        if kind == _CHUNK_JSON and doc is None:
            doc = json.loads(chunk.decode("utf-8"))
        elif kind == _CHUNK_BIN and binary is None:
            binary = chunk
        # A chunk not padded to 4 bytes (against the specification): the next one where the file has it.
        offset, misaligned = next_chunk(lambda at: raw[at:at + 8], offset + 8 + length, total)
        if misaligned and kind == _CHUNK_JSON:
            log.warning("load: %s: %s", path, misaligned_warning(length))
    if doc is None:
        raise InputError("GLB has no JSON chunk", path=path)
    return doc, binary


@dataclass(frozen=True)
class GlbMesh:
    """One node of a GLB file as read back by :func:`read_glb`."""

    name: str
    primitives: tuple[Primitive, ...]


def read_glb(path: str) -> tuple[list[GlbMesh], list[str]]:
    """Read the meshes of a GLB file as written by :func:`glb_bytes`.

    Returns
    -------
    meshes : list of GlbMesh
        One per node with a mesh, in node order.
    material_names : list of str
    """
    doc, binary = read_glb_chunks(path)
    return glb_meshes(doc, binary), [m.get("name", "") for m in doc.get("materials", [])]


def glb_meshes(doc: dict, binary: bytes | None) -> list[GlbMesh]:
    """The meshes of a GLB document, one per top-level node with a mesh, in node order.

    A deliberately small reader (float32 positions/normals/UVs, uint32 or uint16
    indices, node translations applied; no rotation or scale, which our writer
    never emits; child nodes, which hold collision parts, skipped) for previews
    and tests of our own output.
    """
    binary = binary or b""

    def accessor(index: int) -> np.ndarray:
        acc = doc["accessors"][index]
        view = doc["bufferViews"][acc["bufferView"]]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[acc["type"]]
        dtype = {5126: "<f4", 5125: "<u4", 5123: "<u2"}[acc["componentType"]]
        offset = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        arr = np.frombuffer(binary, dtype=dtype, count=acc["count"] * width, offset=offset)
        return arr.reshape(acc["count"], width) if width > 1 else arr

    meshes = []
    # Child nodes are a fragment's collision parts (Godot -convcolonly / Unreal UCX_ meshes), not fragments.
    children = {int(c) for node in doc.get("nodes", []) for c in node.get("children", [])}
    for index, node in enumerate(doc.get("nodes", [])):
        if "mesh" not in node or index in children:
            continue
        offset = np.asarray(node.get("translation", (0.0, 0.0, 0.0)), dtype=np.float64)
        prims = []
        for prim in doc["meshes"][node["mesh"]]["primitives"]:
            attrs = prim["attributes"]
            pos = accessor(attrs["POSITION"]).astype(np.float64) + offset
            nrm = accessor(attrs["NORMAL"]).astype(np.float64) if "NORMAL" in attrs else np.zeros_like(pos)
            uv = None
            if "TEXCOORD_0" in attrs:
                uv = accessor(attrs["TEXCOORD_0"]).astype(np.float64).copy()
                uv[:, 1] = 1.0 - uv[:, 1]
            idx = accessor(prim["indices"]).astype(np.int64).reshape(-1, 3)
            prims.append(Primitive(pos, nrm, uv, idx, int(prim.get("material", 0))))
        meshes.append(GlbMesh(node.get("name", ""), tuple(prims)))
    return meshes
