"""Every reader's output: the triangle parts of a file, in its own units, one material each.

:func:`read_parts` picks the reader by extension: the project's own readers
for glTF/GLB (:mod:`.gltf_read`), PLY (:mod:`.ply`) and STL (:mod:`.stl`),
trimesh for OBJ (after :mod:`.obj` made relative indices absolute) and OFF.
:func:`fracture_cli.stages.load.load_surface` joins the parts into one surface.
"""

from __future__ import annotations

import functools
import io
import logging
import os

import numpy as np

from fracture_cli.errors import InputError
from fracture_cli.io.meshpart import MeshPart
from fracture_cli.types import Material

log = logging.getLogger(__name__)





def read_parts(path: str, file_type: str) -> list[MeshPart]:
    """The triangle parts of ``path`` (``file_type``: obj, ply, stl, off, glb, gltf); empty if none.

    Raises
    ------
    InputError
        The file cannot be read as its type.
    """
    if file_type in ("glb", "gltf"):
        # each format's reader loads when a file of its type is read
        from fracture_cli.io.gltf_read import read_gltf

        return read_gltf(path)
    if file_type == "stl":
        # each format's reader loads when a file of its type is read
        from fracture_cli.io.stl import read_stl

        V, F = read_stl(path)
        return [MeshPart(V, F, None, None, None, Material("material_0"), ("stl",))]
    if file_type == "ply":
        return _ply_parts(path)
    return _trimesh_parts(path, file_type)


def _ply_parts(path: str) -> list[MeshPart]:
    # each format's reader loads when a file of its type is read
    from fracture_cli.io.gltf import MaterialSource
    from fracture_cli.io.ply import read_ply, texture_path

    mesh = read_ply(path)
    if not len(mesh.faces):
        return []
    image = None
    texture = texture_path(path, mesh)
    if texture is not None:
        image = _open_image(texture, path)
    material = Material("material_0", base_color=(1.0, 1.0, 1.0, 1.0) if image is not None else (0.8, 0.8, 0.8, 1.0),
                        source=MaterialSource(baseColorTexture=image, metallicFactor=0.0, roughnessFactor=1.0))
    return [MeshPart(mesh.vertices, mesh.faces, mesh.uvs, mesh.normals, mesh.colors, material, ("ply",))]


def _open_image(file: str, path: str):
    """A texture decoded with Pillow, or None with a warning (a missing texture costs colour, not geometry).

    Raises
    ------
    InputError
        The name is a FIFO, a device or a folder (never opened in a way that could block).
    """
    # each format's reader loads when a file of its type is read
    from fracture_cli.io.inputs import NotRegularFile, read_input

    try:
        from PIL import Image

        image = Image.open(io.BytesIO(read_input(file)))
        image.load()
        return image
    except NotRegularFile as exc:
        raise InputError(f"the texture '{os.path.basename(file)}' is {exc.strerror}; only regular files are read",
                         path=path) from None
    except Exception as exc:  # noqa: BLE001 (Pillow raises many types)
        log.warning("load: %s: texture %s not read (%s)", path, os.path.basename(file), str(exc)[:120])
        return None


@functools.cache
def _folder_resolver_class() -> type:
    """A ``trimesh.resolvers.Resolver`` that reads what trimesh asks for besides an OBJ from the OBJ's folder only.

    trimesh asks it for ``mtllib`` files and their textures. Names that escape
    the folder are refused by name; only regular files are read, without
    blocking, and every read is recorded for the input's key
    (:func:`fracture_cli.io.inputs.read_input`). trimesh treats any error of
    a resolver as "material not found", so the refusal is also kept in
    ``refused`` for the caller to raise. Defined on first use so that importing
    this module does not import trimesh.
    """
    import trimesh

    class FolderResolver(trimesh.resolvers.Resolver):
        def __init__(self, path: str):
            self.path = path
            self.folder = os.path.dirname(os.path.abspath(path))
            self.refused: InputError | None = None

        def get(self, name: str) -> bytes:
            # each format's reader loads when a file of its type is read
            from fracture_cli.io.inputs import EscapingReference, NotRegularFile, companion_path, read_input

            try:
                return read_input(companion_path(self.folder, str(name)))
            except EscapingReference as exc:
                self.refused = self.refused or InputError(
                    f"references '{name}' ({exc}); only files in the asset's folder or below it are read (copy the "
                    "file beside the asset)", path=self.path)
            except NotRegularFile as exc:
                self.refused = self.refused or InputError(
                    f"references '{name}', which is {exc.strerror}; only regular files are read", path=self.path)
            raise self.refused

        def keys(self):
            return iter(())

        def namespaced(self, namespace: str):
            return self

        def write(self, name: str, data) -> None:
            raise OSError(f"read-only resolver: cannot write {name}")

    return FolderResolver


def _trimesh_source(path: str, file_type: str) -> bytes:
    """The bytes trimesh parses: the file as read (recorded), an OBJ with its whitespace and indices made plain."""
    # each format's reader loads when a file of its type is read
    from fracture_cli.io.inputs import NotRegularFile, read_input
    from fracture_cli.io.obj import absolute_indices, plain_whitespace

    try:
        data = read_input(path)
    except NotRegularFile as exc:
        raise InputError(f"is {exc.strerror}", path=path) from None
    except OSError as exc:
        raise InputError(f"cannot be read ({exc.strerror})", path=path) from None
    if file_type == "obj":
        data = plain_whitespace(data)
        data = absolute_indices(data, path) or data
    return data


def _trimesh_parts(path: str, file_type: str) -> list[MeshPart]:
    import trimesh

    data = _trimesh_source(path, file_type)
    resolver = _folder_resolver_class()(path)
    try:
        scene = trimesh.load_scene(io.BytesIO(data), file_type=file_type, process=False, resolver=resolver)
    except InputError:
        raise
    except Exception as exc:  # trimesh raises many types; all mean "unreadable"
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if isinstance(exc, IndexError):
            raise InputError(f"has faces that reference missing vertices ({reason[:200]})", path=path) from exc
        raise InputError(f"could not be read as {file_type.upper()}: {reason[:200]}", path=path) from exc
    if resolver.refused is not None:
        raise resolver.refused
    parts = []
    for node in sorted(scene.graph.nodes_geometry):
        transform, geom_name = scene.graph[node]
        geom = scene.geometry.get(geom_name)
        if isinstance(geom, trimesh.Trimesh) and len(geom.faces):
            parts.append(_trimesh_part(geom, np.asarray(transform, dtype=np.float64), path))
    return parts


def _trimesh_part(geom, transform: np.ndarray, path: str) -> MeshPart:
    raw = np.asarray(geom.vertices, dtype=np.float64)
    faces = np.asarray(geom.faces, dtype=np.int64)
    if faces.min() < 0 or faces.max() >= len(raw):
        raise InputError("has faces that reference missing vertices", path=path)
    if not np.all(np.isfinite(raw)):
        raise InputError("has non-finite vertex coordinates (NaN or inf)", path=path)
    linear = transform[:3, :3]
    if np.linalg.det(linear) < 0:  # a mirroring node transform turns triangles inside out
        faces = faces[:, ::-1]
    uv = getattr(geom.visual, "uv", None)
    uvs = np.asarray(uv, dtype=np.float64)[:, :2] if uv is not None and len(uv) == len(raw) else None
    normals = None
    if "vertex_normals" in geom._cache.cache:  # only normals the file had, not ones trimesh would compute
        n = np.asarray(geom.vertex_normals, dtype=np.float64) @ np.linalg.inv(linear)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        normals = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    colors = None
    if getattr(geom.visual, "kind", None) == "vertex":
        colors = np.asarray(geom.visual.vertex_colors, dtype=np.float64)[:, :4] / 255.0
    material = _material_from_trimesh(geom.visual)
    return MeshPart(raw @ linear.T + transform[:3, 3], faces, uvs, normals, colors, material,
                    ("name", material.name), raw_vertices=raw)


def _material_from_trimesh(visual) -> Material:
    mat = getattr(visual, "material", None)
    if mat is None:
        return Material(name="material_0")
    name = getattr(mat, "name", None) or "material_0"
    color = None
    factor = getattr(mat, "baseColorFactor", None)
    if factor is not None:
        color = np.asarray(factor, dtype=np.float64).reshape(-1)
    elif getattr(mat, "diffuse", None) is not None:
        color = np.asarray(mat.diffuse, dtype=np.float64).reshape(-1)
    if color is not None and color.size >= 3:
        if color.max() > 1.0:
            color = color / 255.0
        rgba = tuple(float(c) for c in np.append(color[:4], [1.0] * (4 - min(color.size, 4))))
    else:
        rgba = (0.8, 0.8, 0.8, 1.0)
    return Material(name=str(name), base_color=rgba, source=mat)  # type: ignore[arg-type]
