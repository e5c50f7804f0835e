"""Every file an input asset is read from: the asset and its companion files.

A ``.gltf`` keeps its buffers and images in other files (``uri``), a ``.glb``
may too, an OBJ names ``.mtl`` material libraries that name texture maps, and
a PLY may name a texture in a ``comment TextureFile`` line. The cache key
hashes all of them (:func:`fracture_cli.cache.input_digest`), and the output
preflight refuses to replace any of them.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import struct
from urllib.parse import unquote

_IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".webp", ".ktx2", ".tga", ".bmp", ".gif", ".tif", ".tiff")
# MTL statements whose last word is a texture file (filenames with spaces are not portable in MTL anyway).
_MTL_MAPS = ("map_", "bump", "disp", "decal", "refl", "norm")


def file_sha256(path: str) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def input_files(path: str) -> list[str]:
    """The asset ``path`` followed by its companion files, as paths (existing or not), without repeats.

    Parameters
    ----------
    path : str
        An asset file (any extension; only glTF, GLB, OBJ and PLY have companions).

    Returns
    -------
    list of str
        ``path`` first, then every buffer, image, material library or texture
        it references by a relative file name, in file order. A companion
        that is missing is still listed (its absence changes the cache key);
        an unreadable asset has no companions (the loader reports it).
    """
    ext = os.path.splitext(path)[1].lower()
    if not _is_regular(path):  # the loader refuses it; a FIFO must not be opened here (it would block)
        return [path]
    try:
        if ext in (".gltf", ".glb"):
            names = _gltf_uris(path, ext)
        elif ext == ".obj":
            names = _obj_companions(path)
        elif ext == ".ply":
            names = _ply_companions(path)
        else:
            names = []
    except (OSError, ValueError, UnicodeDecodeError, struct.error):
        names = []
    folder = os.path.dirname(path)
    out = [path]
    for name in names:
        full = os.path.normpath(os.path.join(folder, name))
        if full not in out:
            out.append(full)
    return out


def gltf_document(path: str, ext: str) -> dict:
    """The JSON document of a ``.gltf`` or the JSON chunk of a ``.glb`` (ValueError if malformed)."""
    with open(path, "rb") as fh:
        if ext == ".glb":
            head = fh.read(20)
            if len(head) < 20 or head[:4] != b"glTF":
                raise ValueError("not a GLB")
            (length,) = struct.unpack_from("<I", head, 12)
            raw = fh.read(length)
        else:
            raw = fh.read()
    doc = json.loads(raw.decode("utf-8"))
    if not isinstance(doc, dict):
        raise ValueError("not a JSON object")
    return doc


def external_uri(uri) -> str | None:
    """The relative file name of a glTF ``uri`` (percent-decoded), or None for ``data:`` and absent URIs."""
    if not isinstance(uri, str) or not uri or uri.startswith("data:"):
        return None
    return unquote(uri)


def _gltf_uris(path: str, ext: str) -> list[str]:
    doc = gltf_document(path, ext)
    names = []
    for key in ("buffers", "images"):
        entries = doc.get(key, [])
        for entry in entries if isinstance(entries, list) else []:
            name = external_uri(entry.get("uri")) if isinstance(entry, dict) else None
            if name is not None:
                names.append(name)
    return names


def _obj_companions(path: str) -> list[str]:
    folder = os.path.dirname(path)
    names: list[str] = []
    with open(path, "rb") as fh:
        for raw in fh:
            if raw.startswith(b"mtllib"):
                names += raw.decode("utf-8", "replace").split()[1:]
    textures = []
    for name in names:
        if not _is_regular(os.path.join(folder, name)):
            continue
        try:
            with open(os.path.join(folder, name), "rb") as fh:
                text = fh.read().decode("utf-8", "replace")
        except OSError:
            continue
        for line in text.splitlines():
            words = line.split()
            if len(words) >= 2 and words[0].lower().startswith(_MTL_MAPS):
                textures.append(os.path.join(os.path.dirname(name), words[-1]))
    return names + textures


def _is_regular(path: str) -> bool:
    """Whether ``path`` is a regular file (following symlinks): the only kind read for companions."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return False


def _ply_companions(path: str) -> list[str]:
    with open(path, "rb") as fh:
        head = fh.read(64 * 1024)
    names = []
    for line in head.split(b"end_header")[0].splitlines():
        words = line.decode("latin-1").split()
        if len(words) >= 3 and words[0] == "comment" and words[1] == "TextureFile":
            names.append(" ".join(words[2:]))
    return names


def estimate_output_bytes(files: list[str]) -> int:
    """A generous estimate of a bake's output size from its input files, for the free-space preflight.

    Geometry is re-encoded once in the fragments (plus the new interior
    faces): twice the input's size covers it. Images are re-encoded as PNG,
    which can be several times larger than a JPEG: eight times. The runtime
    file and report fit in the 1 MiB added.
    """
    total = 1 << 20
    for path in files:
        try:
            size = os.path.getsize(path)
        except OSError:
            continue
        total += size * (8 if path.lower().endswith(_IMAGE_EXTENSIONS) else 2)
    return total
