"""Every file an input asset is read from: the asset and its companion files.

A ``.gltf`` keeps its buffers and images in other files (``uri``), a ``.glb``
may too, an OBJ names ``.mtl`` material libraries that name texture maps, and
a PLY may name a texture in a ``comment TextureFile`` line. The cache key
hashes all of them (:func:`fracture_cli.pipeline.cache.input_digest`), and the output
preflight refuses to replace any of them.

A companion is read only from the asset's folder or below it
(:func:`companion_path`: absolute names, URLs and ``..`` that climbs out are
refused by name), and only when it is a regular file: :func:`read_input`
opens without blocking and checks the kind of the opened file, so a FIFO or a
device named as a texture is refused instead of hanging the bake. Every file
read that way is hashed as it is read and recorded in the active
:func:`recording_reads` log: the bake's cache and batch keys are the hashes of
the bytes the readers used, not of a listing taken before or after.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import hashlib
import json
import os
import posixpath
import re
import stat
import struct
import time
from collections.abc import Iterator
from dataclasses import dataclass
from urllib.parse import unquote

_IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".webp", ".ktx2", ".tga", ".bmp", ".gif", ".tif", ".tiff")
# MTL statements whose last word is a texture file (filenames with spaces are not portable in MTL anyway).
_MTL_MAPS = ("map_", "bump", "disp", "decal", "refl", "norm")


# RFC 3986 scheme ("http:", "file:", "c:"): a relative reference never starts with one.
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")
_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def file_sha256(path: str) -> str:
    """Hex SHA-256 of a file's bytes (a regular file, opened without blocking: see :func:`read_input`)."""
    h = hashlib.sha256()
    with open_regular(path) as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


class NotRegularFile(OSError):
    """A path that names a FIFO, a device, a socket or a folder where a file's bytes are wanted."""


def file_kind(mode: int) -> str:
    """What a non-regular ``st_mode`` is, for messages (``"a FIFO"``, ``"a directory"`` ...)."""
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


@contextlib.contextmanager
def open_regular(path: str) -> Iterator:
    """A binary file object of ``path``, opened with O_NONBLOCK and refused unless it is a regular file.

    A FIFO opened for reading without O_NONBLOCK waits for a writer forever; with
    it the open returns at once, and the kind of what was opened (not of what the
    name pointed to a moment before) decides.
    """
    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOCTTY", 0)
    fd = os.open(path, flags)
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise NotRegularFile(errno.EINVAL, f"{file_kind(mode)}, not a regular file", path)
        fh = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with fh:
        yield fh


@dataclass(frozen=True)
class FileRead:
    """One file as a reader saw it.

    Attributes
    ----------
    path : str
        Absolute, normalized.
    sha256 : str
        Hex digest of the bytes read, or ``missing`` / ``not-a-file``.
    size, mtime_ns : int
        The file's ``fstat`` when it was opened; -1 when it changed while it
        was read (or is missing), so no later run trusts these bytes by their
        size and time.
    started_ns : int
        ``time.time_ns()`` before it was opened.
    """

    path: str
    sha256: str
    size: int
    mtime_ns: int
    started_ns: int


class ReadLog:
    """The files read while :func:`recording_reads` is active, by absolute path."""

    def __init__(self) -> None:
        self.files: dict[str, FileRead] = {}
        self.started_ns = time.time_ns()

    def add(self, read: FileRead) -> None:
        old = self.files.get(read.path)
        if old is not None and old.sha256 != read.sha256:
            # on first use: reading or writing one format loads only what it needs
            from fracture_cli.errors import InputError

            raise InputError("changed while it was being read (two reads gave different bytes); run again when "
                             "it is no longer being written", path=read.path)
        if old is None or read.mtime_ns < 0:
            self.files[read.path] = read

    def as_read(self, files: list[str]) -> tuple[FileRead, ...]:
        """``files`` (an :func:`input_files` list), then every other file read, each as read or hashed now.

        A listed file the readers did not open (a normal map nobody reads,
        a missing texture) does not shape the output; it is hashed from disk
        now, so that editing it still changes the key.
        """
        out: dict[str, FileRead] = {}
        for path in [_absolute(p) for p in files] + sorted(self.files):
            if path not in out:
                out[path] = self.files.get(path) or hash_file(path)
        return tuple(out.values())


_LOG: contextvars.ContextVar[ReadLog | None] = contextvars.ContextVar("fracture_read_log", default=None)


@contextlib.contextmanager
def recording_reads() -> Iterator[ReadLog]:
    """Record every :func:`read_input` of this thread's code until the block ends."""
    log = ReadLog()
    token = _LOG.set(log)
    try:
        yield log
    finally:
        _LOG.reset(token)


def _absolute(path: str) -> str:
    return os.path.normpath(os.path.abspath(path))


def read_input(path: str) -> bytes:
    """The bytes of an input file (the asset or a companion), recorded in the active read log.

    Raises
    ------
    OSError
        As ``open`` does; :class:`NotRegularFile` for a FIFO, device, socket
        or folder (never blocks on one).
    """
    started = time.time_ns()
    with open_regular(path) as fh:
        before = os.fstat(fh.fileno())
        data = fh.read()
        after = os.fstat(fh.fileno())
    stable = (before.st_size, before.st_mtime_ns) == (after.st_size, after.st_mtime_ns) == (len(data),
                                                                                           after.st_mtime_ns)
    log = _LOG.get()
    if log is not None:
        log.add(FileRead(_absolute(path), hashlib.sha256(data).hexdigest(), len(data) if stable else -1,
                         before.st_mtime_ns if stable else -1, started))
    return data


def read_regular(path: str) -> bytes:
    """The bytes of a regular file, opened without blocking (not recorded: for files that are not inputs).

    Raises
    ------
    OSError
        As ``open`` does; :class:`NotRegularFile` for anything but a regular file.
    """
    with open_regular(path) as fh:
        return fh.read()


def hash_file(path: str) -> FileRead:
    """A file hashed from disk now (``missing`` / ``not-a-file`` without reading what is not a regular file)."""
    started = time.time_ns()
    try:
        with open_regular(path) as fh:
            before = os.fstat(fh.fileno())
            h = hashlib.sha256()
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
            after = os.fstat(fh.fileno())
    except FileNotFoundError:
        return FileRead(_absolute(path), "missing", -1, -1, started)
    except NotRegularFile:
        return FileRead(_absolute(path), "not-a-file", -1, -1, started)
    stable = (before.st_size, before.st_mtime_ns) == (after.st_size, after.st_mtime_ns)
    return FileRead(_absolute(path), h.hexdigest(), after.st_size if stable else -1,
                    after.st_mtime_ns if stable else -1, started)


def digest_of(reads: tuple[FileRead, ...]) -> str:
    """Hex SHA-256 of an input as read: as :func:`fracture_cli.pipeline.cache.input_digest` of the same bytes."""
    if len(reads) == 1:
        return reads[0].sha256
    folder = os.path.dirname(reads[0].path)
    lines = [f"{r.sha256}  {os.path.relpath(r.path, folder or '.')}\n" for r in reads]
    return hashlib.sha256("".join(lines).encode("utf-8", "surrogateescape")).hexdigest()


class EscapingReference(ValueError):
    """A companion's name that is absolute, a URL or climbs out of the asset's folder."""


def companion_path(folder: str, name: str) -> str:
    """The file a companion's (decoded) relative name ``name`` names, inside ``folder``.

    Parameters
    ----------
    folder : str
        The asset's folder.
    name : str
        A relative file name, ``/`` separated (glTF uris after percent-decoding,
        OBJ ``mtllib`` and map names, PLY ``TextureFile``).

    Raises
    ------
    EscapingReference
        An empty or absolute name, a URL (any ``scheme:``), a NUL byte, or a
        name whose ``..`` parts climb out of ``folder``: a build must not
        depend on the network or on files outside the asset's folder (a
        downloaded asset could otherwise embed any file of the machine into
        the baked GLB).
    """
    if not name or "\0" in name:
        raise EscapingReference("an empty file name" if not name else "a NUL byte")
    if _SCHEME.match(name) and not name.lower().startswith("data:"):
        raise EscapingReference("a URL, not a file name")
    if os.path.isabs(name) or name.startswith(("/", "\\")):
        raise EscapingReference("an absolute path")
    clean = posixpath.normpath(name.replace(os.sep, "/"))
    if clean == ".." or clean.startswith("../"):
        raise EscapingReference("outside the asset's folder")
    return os.path.join(folder, *clean.split("/"))


def companion_or_none(folder: str, name: str) -> str | None:
    """:func:`companion_path`, or None for a name it refuses."""
    try:
        return companion_path(folder, name)
    except EscapingReference:
        return None


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
        it references by a relative file name inside its folder
        (:func:`companion_path`), in file order. A companion that is missing
        is still listed (its absence changes the cache key); a name that
        escapes the folder is not (the reader refuses it by name, and nothing
        outside the folder is ever read or hashed); an unreadable asset has
        no companions (the loader reports it).
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
        inside = companion_or_none(folder, name)
        full = os.path.normpath(inside) if inside is not None else None
        if full is not None and full not in out:
            out.append(full)
    return out


def gltf_document(path: str, ext: str, raw: bytes | None = None) -> dict:
    """The JSON document of a ``.gltf`` or the JSON chunk of a ``.glb`` (ValueError if malformed).

    ``raw``, when given, is the file's bytes (already read); otherwise the file
    is read here (regular files only, without blocking).
    """
    if raw is None:
        with open_regular(path) as fh:
            raw = fh.read(20) if ext == ".glb" else fh.read()
            if ext == ".glb" and len(raw) == 20 and raw[:4] == b"glTF":
                raw += fh.read(struct.unpack_from("<I", raw, 12)[0])
    if ext == ".glb":
        if len(raw) < 20 or raw[:4] != b"glTF":
            raise ValueError("not a GLB")
        (length,) = struct.unpack_from("<I", raw, 12)
        raw = raw[20:20 + length]
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


def obj_words(line: bytes) -> list[str]:
    """The words of an OBJ or MTL line (spaces or tabs between them, any indentation)."""
    return line.decode("utf-8", "replace").split()


def mtl_texture_names(text: str, mtl_name: str) -> list[str]:
    """Texture files an MTL names (the last word of its map statements), relative to the OBJ's folder."""
    out = []
    for line in text.splitlines():
        words = line.split()
        if len(words) >= 2 and words[0].lower().startswith(_MTL_MAPS):
            out.append(posixpath.join(posixpath.dirname(mtl_name.replace(os.sep, "/")), words[-1]))
    return out


def _obj_companions(path: str) -> list[str]:
    folder = os.path.dirname(path)
    names: list[str] = []
    with open_regular(path) as fh:
        for raw in fh:
            words = obj_words(raw) if b"mtllib" in raw else []
            if words and words[0] == "mtllib":
                names += words[1:]
    textures = []
    for name in names:
        file = companion_or_none(folder, name)
        if file is None or not _is_regular(file):
            continue
        try:
            with open_regular(file) as fh:
                text = fh.read().decode("utf-8", "replace")
        except OSError:
            continue
        textures += mtl_texture_names(text, name)
    return names + textures


def _is_regular(path: str) -> bool:
    """Whether ``path`` is a regular file (following symlinks): the only kind read for companions."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return False


def _ply_companions(path: str) -> list[str]:
    with open_regular(path) as fh:
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
