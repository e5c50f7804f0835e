"""Read the geometry of a glTF 2.0 file (``.gltf`` or ``.glb``) exactly as the specification defines it.

What is honoured (glTF 2.0 specification, sections 3.6-3.9 and 5; the
extensions' own specifications):

* accessors of every component type, ``normalized`` integers
  (``max(c / 127, -1)``, ``c / 255``, ``max(c / 32767, -1)``, ``c / 65535``),
  ``byteStride``, accessors without a buffer view (zeros) and **sparse**
  accessors (values replaced at the listed indices);
* ``KHR_mesh_quantization`` (integer positions, normals and texture
  coordinates; the node transform dequantizes them) and
  ``KHR_texture_transform`` on the base-colour texture;
* the scene's **node hierarchy**: each node's ``matrix`` or TRS composed with
  its parents'; a mirroring transform (negative determinant) reverses the
  triangles' winding, normals use the inverse transpose;
* primitive modes 4, 5, 6 (triangles, strips, fans); points and lines are
  skipped;
* morph targets at their default ``weights`` (the node's, else the mesh's):
  POSITION and NORMAL deltas, sparse or not; skinned meshes placed by their
  joints in the scene's pose, their node transform ignored, as the
  specification says (:mod:`fracture_cli.io.gltf_scene`);
* buffers and images in the GLB binary chunk, in ``data:`` URIs or in files
  named by a percent-encoded relative ``uri`` inside the file's folder (an
  absolute path, a URL or a ``..`` that climbs out is refused by name; only
  regular files are opened, without blocking:
  :func:`fracture_cli.io.inputs.read_input`);
* one material slot per glTF material (two materials that share a name stay
  two), with base colour, metallic, roughness and the base-colour texture;
* engines' collision-only nodes (Unreal ``UCX_``, Godot ``-convcolonly``, ...)
  are skipped with a warning, and a GLB baked by fracture has its materials'
  stem prefix removed (:mod:`fracture_cli.io.gltf_conventions`).

``extensionsRequired`` lists extensions a reader must understand: any not in
:data:`SUPPORTED_EXTENSIONS` is refused by name (Draco and meshopt
compression among them: decompress the file first). ``EXT_mesh_gpu_instancing``
(when not required) is not applied: each instanced mesh is read once. Indices of
every kind are checked (``"mesh": -1`` is refused, not read as the last mesh),
and so are the accessor types the specification allows (float indices are
refused).

Every problem is one :class:`~fracture_cli.errors.InputError` line.
"""

from __future__ import annotations

import base64
import binascii
import io
import logging
import os

import numpy as np

from fracture_cli.errors import InputError
from fracture_cli.io.gltf import MaterialSource
from fracture_cli.io.gltf_conventions import baked_material_prefix, unprefixed
from fracture_cli.io.gltf_scene import Instance, Scene, index, morphed, placed, skinned
from fracture_cli.io.inputs import (
    EscapingReference,
    NotRegularFile,
    companion_path,
    external_uri,
    gltf_document,
    read_input,
)
from fracture_cli.io.meshpart import MeshPart
from fracture_cli.system import detmath
from fracture_cli.types import Material

log = logging.getLogger(__name__)

SUPPORTED_EXTENSIONS = frozenset({"KHR_mesh_quantization", "KHR_texture_transform"})
_HINTS = {
    "KHR_draco_mesh_compression": "Draco-compressed geometry; decompress it first (e.g. 'gltf-transform copy "
                                  "in.glb out.glb', or export without Draco)",
    "EXT_meshopt_compression": "meshopt-compressed buffers; decompress them first (e.g. 'gltf-transform copy "
                               "in.glb out.glb')",
    "EXT_mesh_gpu_instancing": "GPU instancing; export the instances as nodes",
}
_COMPONENTS: dict[int, np.dtype] = {5120: np.dtype("i1"), 5121: np.dtype("u1"), 5122: np.dtype("<i2"),
                                    5123: np.dtype("<u2"), 5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_INDEX_TYPES = {5121: "unsigned byte", 5123: "unsigned short", 5125: "unsigned int"}
_TYPE_NAMES = {5120: "byte", 5121: "unsigned byte", 5122: "short", 5123: "unsigned short", 5125: "unsigned int",
               5126: "float"}
# normalized integer -> float (glTF 2.0, section 3.11 "Animations" table / KHR_mesh_quantization)
_NORMALIZE = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}


def read_gltf(path: str) -> list[MeshPart]:
    """Read every triangle primitive a glTF or GLB file's scene draws.

    Parameters
    ----------
    path : str
        A ``.gltf`` or ``.glb`` file.

    Returns
    -------
    list of MeshPart
        One per primitive instance, in scene order (depth first through the
        node hierarchy), in world (file) units; ``material_key`` is the glTF
        material index (-1: none, a white ``default`` material).

    Raises
    ------
    InputError
        Unsupported required extension, missing or short buffer, an accessor
        or buffer view outside its buffer, an index past the vertices, a
        cyclic node hierarchy.
    """
    ext = os.path.splitext(path)[1].lower()
    if ext == ".glb":
        # on first use: reading or writing one format loads only what it needs
        from fracture_cli.io.gltf import read_glb_chunks

        doc, binary = read_glb_chunks(path)
    else:
        try:
            doc = gltf_document(path, ext, raw=read_input(path))
        except (ValueError, UnicodeDecodeError) as exc:
            raise InputError(f"is not valid glTF JSON ({str(exc)[:120]})", path=path) from None
        except OSError as exc:
            raise InputError(f"cannot be read ({exc.strerror})", path=path) from None
        binary = None
    reader = _Document(path, doc, binary)
    try:
        return reader.parts()
    except InputError:
        raise
    except (KeyError, IndexError, TypeError, ValueError, AttributeError) as exc:
        raise InputError(f"has a malformed glTF document ({type(exc).__name__}: {str(exc)[:120]})",
                         path=path) from None


def check_required_extensions(doc: dict, path: str) -> None:
    """Refuse a document whose ``extensionsRequired`` names an extension not in :data:`SUPPORTED_EXTENSIONS`.

    Raises
    ------
    InputError
        Naming the extension and what to do (e.g. decompress Draco first).
    """
    required = doc.get("extensionsRequired", []) or []
    for name in required if isinstance(required, list) else [required]:
        if name not in SUPPORTED_EXTENSIONS:
            hint = _HINTS.get(name, "this reader does not support it; export without it")
            raise InputError(f"requires the glTF extension {name} ({hint})", path=path)


def buffer_file(folder: str, uri: str, index: int, path: str, what: str = "buffer") -> str:
    """The file a buffer's or image's (percent-encoded) ``uri`` names, inside ``folder``.

    Raises
    ------
    InputError
        The uri is a URL, an absolute path or climbs out of ``folder`` with
        ``..`` (a build must not depend on the network or on files outside the
        asset's folder: a downloaded asset could embed any file of the machine).
    """
    try:
        return companion_path(folder, external_uri(uri) or "")
    except EscapingReference as exc:
        raise InputError(f"{what} {index} has the uri '{uri}' ({exc}); only files in the asset's folder or below "
                         "it are read (copy the file beside the asset)", path=path) from None


def _not_regular(kind: str, index: int, uri: str, exc: OSError) -> str:
    return f"{kind} {index}'s uri '{uri}' names {exc.strerror}; only regular files are read"


class _Document:
    """A parsed glTF document with lazily loaded buffers."""

    def __init__(self, path: str, doc: dict, glb_binary: bytes | None):
        self.path = path
        self.doc = doc
        self.glb_binary = glb_binary
        self.folder = os.path.dirname(os.path.abspath(path))
        self._buffers: dict[int, bytes] = {}
        self._materials: dict[int, Material] = {}
        check_required_extensions(doc, path)
        self.scene = Scene(doc, path)
        self.material_prefix = baked_material_prefix(doc)
        used = set(doc.get("extensionsUsed", []) or []) - SUPPORTED_EXTENSIONS
        if "EXT_mesh_gpu_instancing" in used:
            log.warning("load: %s: EXT_mesh_gpu_instancing is not applied; each instanced mesh is read once", path)

    def fail(self, message: str) -> InputError:
        return InputError(message, path=self.path)

    def index(self, kind: str, value, what: str) -> int:
        """``value`` checked as an index into ``doc[kind]`` (:func:`~fracture_cli.io.gltf_scene.index`)."""
        return index(self.doc, kind, value, what, self.path)

    # -- buffers and accessors -------------------------------------------------

    def buffer(self, index: int) -> bytes:
        if index in self._buffers:
            return self._buffers[index]
        spec = self.doc["buffers"][index]
        length = int(spec["byteLength"])
        uri = spec.get("uri")
        if uri is None:
            if index != 0 or self.glb_binary is None:
                raise self.fail(f"buffer {index} has no uri and there is no GLB binary chunk")
            data, where = self.glb_binary, "the GLB binary chunk"
        elif uri.startswith("data:"):
            data, where = self._data_uri(uri, index), f"buffer {index}'s data URI"
        else:
            file = buffer_file(self.folder, uri, index, self.path)
            try:
                data = read_input(file)
            except FileNotFoundError:
                raise self.fail(f"references the buffer file '{uri}', which is missing (keep it beside the "
                                "file, or export a single .glb)") from None
            except NotRegularFile as exc:
                raise self.fail(_not_regular("buffer", index, uri, exc)) from None
            except OSError as exc:
                raise self.fail(f"cannot read the buffer file '{uri}' ({exc.strerror})") from None
            where = f"the buffer file '{uri}'"
        if len(data) < length:
            raise self.fail(f"{where} has {len(data):,} bytes but buffer {index} needs {length:,} (truncated, or "
                            "from another export)")
        self._buffers[index] = data
        return data

    def _data_uri(self, uri: str, index: int) -> bytes:
        head, _, payload = uri.partition(",")
        if not head.endswith(";base64"):
            raise self.fail(f"buffer {index}'s data URI is not base64")
        try:
            return base64.b64decode(payload, validate=True)
        except (binascii.Error, ValueError):
            raise self.fail(f"buffer {index}'s data URI is not valid base64") from None

    def view_bytes(self, index: int) -> tuple[memoryview, int | None]:
        """(bytes of buffer view ``index``, its byteStride or None)."""
        view = self.doc["bufferViews"][index]
        data = self.buffer(self.index("buffers", view["buffer"], f"bufferView {index}'s buffer"))
        offset, length = int(view.get("byteOffset", 0)), int(view["byteLength"])
        if offset < 0 or length < 0 or offset + length > len(data):
            raise self.fail(f"bufferView {index} (bytes {offset:,}..{offset + length:,}) lies outside its buffer "
                            f"({len(data):,} bytes)")
        stride = view.get("byteStride")
        return memoryview(data)[offset:offset + length], (int(stride) if stride is not None else None)

    def _strided(self, view_index: int, byte_offset: int, dtype: np.dtype, width: int, count: int,
                 what: str) -> np.ndarray:
        view_index = self.index("bufferViews", view_index, f"{what}'s bufferView")
        data, stride = self.view_bytes(view_index)
        element = dtype.itemsize * width
        stride = stride or element
        if stride < element:
            raise self.fail(f"{what}: byteStride {stride} is smaller than its element ({element} bytes)")
        end = byte_offset + stride * (count - 1) + element if count else byte_offset
        if byte_offset < 0 or end > len(data):
            raise self.fail(f"{what} reads past the end of bufferView {view_index} (needs {end:,} bytes, has "
                            f"{len(data):,})")
        if count == 0:
            return np.zeros((0, width), dtype=dtype)
        raw = np.frombuffer(data, dtype=np.uint8, count=end - byte_offset, offset=byte_offset)
        rows = np.lib.stride_tricks.as_strided(raw, shape=(count, element), strides=(stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, width)

    def accessor(self, index: int, *, as_float: bool = True) -> np.ndarray:
        """Accessor ``index`` as a (count, width) array: float64 (normalized/dequantized) or int64."""
        spec = self.doc["accessors"][index]
        what = f"accessor {index}"
        component = int(spec["componentType"])
        if component not in _COMPONENTS or spec.get("type") not in _WIDTH:
            raise self.fail(f"{what} has an unsupported layout ({spec.get('type')}, componentType {component})")
        dtype, width, count = _COMPONENTS[component], _WIDTH[spec["type"]], int(spec["count"])
        if count < 0:
            raise self.fail(f"{what} has a negative count ({count})")
        if "bufferView" in spec:
            values = self._strided(spec["bufferView"], int(spec.get("byteOffset", 0)), dtype, width, count, what)
        else:
            values = np.zeros((count, width), dtype=dtype)
        sparse = spec.get("sparse")
        if sparse is not None:
            values = self._apply_sparse(values, sparse, dtype, width, what)
        if not as_float:
            return values.astype(np.int64)
        out = values.astype(np.float64)
        if spec.get("normalized") and component in _NORMALIZE:
            out = out / _NORMALIZE[component]
            if component in (5120, 5122):
                np.maximum(out, -1.0, out=out)
        return out

    def _apply_sparse(self, values: np.ndarray, sparse: dict, dtype: np.dtype, width: int, what: str) -> np.ndarray:
        n = int(sparse["count"])
        idx_spec, val_spec = sparse["indices"], sparse["values"]
        idx_type = int(idx_spec["componentType"])
        if idx_type not in (5121, 5123, 5125):
            raise self.fail(f"{what}: sparse indices have componentType {idx_type}")
        indices = self._strided(idx_spec["bufferView"], int(idx_spec.get("byteOffset", 0)),
                                _COMPONENTS[idx_type], 1, n, f"{what} (sparse indices)")[:, 0].astype(np.int64)
        replacement = self._strided(val_spec["bufferView"], int(val_spec.get("byteOffset", 0)), dtype, width, n,
                                    f"{what} (sparse values)")
        if n and (indices.min() < 0 or indices.max() >= len(values) or np.any(np.diff(indices) <= 0)):
            raise self.fail(f"{what}: sparse indices must increase strictly and stay below its count {len(values)}")
        values = values.copy()
        values[indices] = replacement
        return values

    # -- scene ----------------------------------------------------------------

    def attribute(self, attributes: dict, name: str, what: str, widths: tuple[int, ...] = (3,)) -> np.ndarray:
        """Attribute ``name`` of a primitive or morph target as float64 (count, width), its type checked."""
        acc = self.index("accessors", attributes[name], f"{what}'s {name}")
        kind = self.doc["accessors"][acc].get("type")
        if _WIDTH.get(kind) not in widths:
            raise self.fail(f"{what}'s {name} (accessor {acc}) is {kind}; glTF requires "
                            f"{' or '.join(k for k, w in _WIDTH.items() if w in widths)}")
        return self.accessor(acc)

    def parts(self) -> list[MeshPart]:
        meshes = self.doc.get("meshes", []) or []
        parts = []
        for instance in self.scene.instances():
            for p, prim in enumerate(meshes[instance.mesh].get("primitives", []) or []):
                part = self._primitive(prim, instance, f"mesh {instance.mesh} primitive {p}")
                if part is not None:
                    parts.append(part)
        return parts

    def _indices(self, prim: dict, count: int, what: str) -> np.ndarray:
        if "indices" not in prim:
            return np.arange(count, dtype=np.int64)
        acc = self.index("accessors", prim["indices"], f"{what}'s indices")
        spec = self.doc["accessors"][acc]
        component = spec.get("componentType")
        if component not in _INDEX_TYPES or spec.get("type") != "SCALAR" or spec.get("normalized"):
            kind = _TYPE_NAMES.get(component, f"componentType {component}")
            raise self.fail(f"{what}'s indices (accessor {acc}) are {spec.get('type')} {kind}"
                            f"{' normalized' if spec.get('normalized') else ''}; glTF indices are SCALAR unsigned "
                            "byte, short or int")
        indices = self.accessor(acc, as_float=False)[:, 0]
        if len(indices) and indices.max() >= count:
            raise self.fail(f"has faces that reference missing vertices ({what}: index {int(indices.max())} of "
                            f"{count} vertices)")
        return indices

    def _primitive(self, prim: dict, instance: Instance, what: str) -> MeshPart | None:
        mode = int(prim.get("mode", 4))
        if mode not in (4, 5, 6):
            return None  # points and lines have no inside
        attributes = prim["attributes"]
        if "POSITION" not in attributes:
            return None
        position_index = self.index("accessors", attributes["POSITION"], f"{what}'s POSITION")
        draco = "KHR_draco_mesh_compression" in (prim.get("extensions") or {})
        if draco and "bufferView" not in self.doc["accessors"][position_index]:
            raise self.fail(f"{what} is Draco-compressed without an uncompressed fallback ("
                            f"{_HINTS['KHR_draco_mesh_compression']})")
        raw = self.attribute(attributes, "POSITION", what)
        # VEC4 normals (a padded int8 layout some quantizers write) are read as their first three components.
        normals = self.attribute(attributes, "NORMAL", what, (3, 4))[:, :3] if "NORMAL" in attributes else None
        positions, normals = morphed(self, prim, raw, normals, instance.weights, what)
        if not np.all(np.isfinite(positions)):
            raise self.fail("has non-finite vertex coordinates (NaN or inf)")
        faces = _triangles(self._indices(prim, len(positions), what), mode)
        material = (self.index("materials", prim["material"], f"{what}'s material") if "material" in prim else -1)
        if instance.skin is not None:
            vertices, normals, faces = skinned(self, attributes, instance.skin, positions, normals, faces, what)
        else:
            vertices, normals, faces = placed(instance.world, positions, normals, faces)
        return MeshPart(vertices=vertices, faces=faces, uvs=self._uvs(attributes, material), normals=normals,
                        colors=self._colors(attributes), material=self.material(material),
                        material_key=("gltf", material), raw_vertices=raw)

    def _uvs(self, attributes: dict, material: int) -> np.ndarray | None:
        texture: dict = {}
        if material >= 0:
            texture = self.doc["materials"][material].get("pbrMetallicRoughness", {}).get("baseColorTexture") or {}
        transform = (texture.get("extensions") or {}).get("KHR_texture_transform") or {}
        channel = int(transform.get("texCoord", texture.get("texCoord", 0)))
        key: str | None = f"TEXCOORD_{channel}"
        if key not in attributes:
            key = "TEXCOORD_0" if "TEXCOORD_0" in attributes else None
        if key is None:
            return None
        uv = self.accessor(self.index("accessors", attributes[key], key))[:, :2]
        if transform:
            uv = _texture_transform(uv, transform)
        uv = uv.copy()
        uv[:, 1] = 1.0 - uv[:, 1]  # glTF's v points down; ours (OpenGL) up
        return uv

    def _colors(self, attributes: dict) -> np.ndarray | None:
        if "COLOR_0" not in attributes:
            return None
        c = self.accessor(self.index("accessors", attributes["COLOR_0"], "COLOR_0"))
        if c.shape[1] == 3:
            c = np.concatenate([c, np.ones((len(c), 1))], axis=1)
        return c[:, :4]

    # -- materials --------------------------------------------------------------

    def material(self, index: int) -> Material:
        """glTF material ``index`` (decoded once); -1: the spec's default (white, metallic 1, roughness 1)."""
        if index not in self._materials:
            if index < 0:
                self._materials[index] = Material(name="default", base_color=(1.0, 1.0, 1.0, 1.0),
                                                  source=MaterialSource())
            else:
                self._materials[index] = self._material(index, self.doc["materials"][index])  # index checked
        return self._materials[index]

    def _material(self, index: int, spec: dict) -> Material:
        pbr = spec.get("pbrMetallicRoughness", {}) or {}
        factor = [float(c) for c in pbr.get("baseColorFactor", (1.0, 1.0, 1.0, 1.0))][:4]
        image = None
        texture = pbr.get("baseColorTexture")
        if texture is not None:
            image = self._image(self.index("textures", texture["index"], f"material {index}'s baseColorTexture"))
        source = MaterialSource(baseColorTexture=image, metallicFactor=float(pbr.get("metallicFactor", 1.0)),
                                    roughnessFactor=float(pbr.get("roughnessFactor", 1.0)))
        return Material(name=unprefixed(str(spec.get("name") or f"material_{index}"), self.material_prefix),
                        base_color=tuple((factor + [1.0] * 4)[:4]), source=source)  # type: ignore[arg-type]

    def _image(self, texture_index: int):
        """The texture's image decoded with Pillow; None (with a warning) when it cannot be decoded."""
        texture = self.doc["textures"][texture_index]
        source = texture.get("source")
        for ext in (texture.get("extensions") or {}).values():  # EXT_texture_webp and friends name their own
            if isinstance(ext, dict) and "source" in ext:
                source = ext["source"]
        if source is None:
            return None
        source = self.index("images", source, f"texture {texture_index}'s source")
        spec = self.doc["images"][source]
        uri = spec.get("uri")
        file = None
        if "bufferView" not in spec and isinstance(uri, str) and uri and not uri.startswith("data:"):
            file = buffer_file(self.folder, uri, source, self.path, what="image")  # refuses what escapes the folder
        try:
            if "bufferView" in spec:
                raw = bytes(self.view_bytes(self.index("bufferViews", spec["bufferView"],
                                                       f"image {source}'s bufferView"))[0])
            elif isinstance(uri, str) and uri.startswith("data:"):
                raw = base64.b64decode(uri.partition(",")[2])
            elif file is not None:
                raw = self._image_file(file, source, uri)
            else:
                raise ValueError("it has neither a uri nor a bufferView")
            from PIL import Image

            image = Image.open(io.BytesIO(raw))
            image.load()
            return image
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 (Pillow raises many types) a bad texture costs colour, not geometry
            log.warning("load: %s: image %s not decoded (%s); its material keeps only its colour", self.path,
                        source, str(exc)[:120] or type(exc).__name__)
            return None

    def _image_file(self, file: str, source: int, uri: str) -> bytes:
        """An image file's bytes; a FIFO or device is refused (it would block or never end), not waited on."""
        try:
            return read_input(file)
        except NotRegularFile as exc:
            raise self.fail(_not_regular("image", source, uri, exc)) from None


def _triangles(indices: np.ndarray, mode: int) -> np.ndarray:
    """(m, 3) triangles of an index list in glTF mode 4 (list), 5 (strip) or 6 (fan)."""
    if mode == 4:
        n = len(indices) // 3 * 3
        return indices[:n].reshape(-1, 3)
    count = max(len(indices) - 2, 0)
    i = np.arange(count)
    if mode == 5:  # spec: p_i = {v_i, v_(i+(1+i%2)), v_(i+(2-i%2))}
        return np.stack([indices[i], indices[i + 1 + i % 2], indices[i + 2 - i % 2]], axis=1)
    return np.stack([indices[i + 1], indices[i + 2], np.full(count, indices[0] if count else 0)], axis=1)


def _texture_transform(uv: np.ndarray, transform: dict) -> np.ndarray:
    """KHR_texture_transform: ``uv' = T(offset) * R(rotation) * S(scale) * uv`` (the extension's GLSL, column-major)."""
    ox, oy = (float(c) for c in transform.get("offset", (0.0, 0.0)))
    angle = float(transform.get("rotation", 0.0))
    sx, sy = (float(c) for c in transform.get("scale", (1.0, 1.0)))
    s, c = detmath.sin_cos(angle)
    u, v = uv[:, 0] * sx, uv[:, 1] * sy
    return np.stack([c * u - s * v + ox, s * u + c * v + oy], axis=1)
