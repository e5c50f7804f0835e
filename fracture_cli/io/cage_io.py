"""Save cages and tet meshes for inspection and to resume a bake from them.

* :func:`save_cage` writes the cage surface as OBJ, PLY (binary), STL (binary)
  or OFF, chosen by the extension, **in the input's units**, so it overlays the
  input asset in any viewer.
* :func:`save_tetmesh` / :func:`load_tetmesh` use a NumPy ``.npz`` archive with
  these keys:

  ============== =============== ==============================================
  key            dtype, shape    meaning
  ============== =============== ==============================================
  format         int64 ()        format version, currently 1
  vertices       float64 (n, 3)  vertex positions, normalized coordinates
  tets           int64 (t, 4)    tetrahedra, positively oriented
  center         float64 (3,)    normalization centre (input units)
  scale          float64 ()      normalization scale: input bounding-box diagonal
  ============== =============== ==============================================

  World positions are ``vertices * scale + center``.

Every write is atomic (temporary file in the same directory, then ``os.replace``).
"""

from __future__ import annotations

import os

import numpy as np

from fracture_cli.errors import InputError
from fracture_cli.geometry import tolerances as tol
from fracture_cli.io.atomic import atomic_path
from fracture_cli.types import Cage, Normalization, TetMesh

TETMESH_FORMAT_VERSION = 1

CAGE_FORMATS = (".obj", ".ply", ".stl", ".off")


def save_cage(path: str | os.PathLike, cage: Cage) -> None:
    """Write the cage surface to ``path`` (``.obj``, ``.ply``, ``.stl`` or ``.off``), in the input's units.

    Parameters
    ----------
    path : str or path-like
        Output file; the extension picks the format.
    cage : Cage
        The cage to write.

    Raises
    ------
    InputError
        If the extension is not one of :data:`CAGE_FORMATS`.
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in CAGE_FORMATS:
        raise InputError(f"unknown cage format '{ext}'; pick one of {', '.join(CAGE_FORMATS)}", path=path)
    world = cage.normalization.to_world(cage.vertices)
    faces = np.asarray(cage.faces, dtype=np.int64)
    with atomic_path(path) as tmp:
        writer = {".obj": _write_obj, ".ply": _write_ply, ".stl": _write_stl, ".off": _write_off}[ext]
        writer(tmp, world, faces, cage.offset)


def _write_obj(path: str, vertices: np.ndarray, faces: np.ndarray, offset: float) -> None:
    lines = [f"# fracture cage, offset {offset:.6g} of the bounding-box diagonal",
             f"# {len(vertices)} vertices, {len(faces)} faces"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")


def _write_ply(path: str, vertices: np.ndarray, faces: np.ndarray, offset: float) -> None:
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment fracture cage\n"
        f"element vertex {len(vertices)}\nproperty double x\nproperty double y\nproperty double z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    face_records = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face_records["n"] = 3
    face_records["v"] = faces
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
        fh.write(face_records.tobytes())


def _write_stl(path: str, vertices: np.ndarray, faces: np.ndarray, offset: float) -> None:
    T = vertices[faces]
    normal = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), tol.SMALLEST_DIVISOR)
    records = np.zeros(len(faces), dtype=[("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    records["n"] = normal
    records["v"] = T
    header = f"fracture cage, offset {offset:.6g}".encode("ascii").ljust(80, b" ")
    with open(path, "wb") as fh:
        fh.write(header)
        fh.write(np.uint32(len(faces)).tobytes())
        fh.write(records.tobytes())


def _write_off(path: str, vertices: np.ndarray, faces: np.ndarray, offset: float) -> None:
    lines = ["OFF", f"# fracture cage, offset {offset:.6g}", f"{len(vertices)} {len(faces)} 0"]
    lines += [f"{x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
    lines += [f"3 {a} {b} {c}" for a, b, c in faces]
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")


def save_tetmesh(path: str | os.PathLike, tet_mesh: TetMesh) -> None:
    """Write a tet mesh to a ``.npz`` archive (keys in the module docstring), atomically."""
    path = os.fspath(path)
    norm = tet_mesh.normalization
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(
                fh,
                format=np.int64(TETMESH_FORMAT_VERSION),
                vertices=np.asarray(tet_mesh.vertices, dtype=np.float64),
                tets=np.asarray(tet_mesh.tets, dtype=np.int64),
                center=np.asarray(norm.center, dtype=np.float64).reshape(3),
                scale=np.float64(norm.scale),
            )


def load_tetmesh(path: str | os.PathLike) -> TetMesh:
    """Read a tet mesh written by :func:`save_tetmesh`.

    Raises
    ------
    InputError
        If the file is missing, not an archive of this format, or inconsistent.
    """
    path = os.fspath(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except FileNotFoundError:
        raise InputError("no such file", path=path) from None
    except (OSError, ValueError) as exc:
        raise InputError(f"not a tet mesh archive ({exc})", path=path) from None
    missing = [k for k in ("format", "vertices", "tets", "center", "scale") if k not in arrays]
    if missing:
        raise InputError(f"not a tet mesh archive: missing {', '.join(missing)}", path=path)
    version = int(arrays["format"])
    if version != TETMESH_FORMAT_VERSION:
        raise InputError(f"tet mesh format {version} is not supported (expected {TETMESH_FORMAT_VERSION})",
                         path=path)
    vertices = np.asarray(arrays["vertices"], dtype=np.float64)
    tets = np.asarray(arrays["tets"], dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or tets.ndim != 2 or tets.shape[1] != 4:
        raise InputError(f"bad shapes: vertices {vertices.shape}, tets {tets.shape}", path=path)
    if len(tets) and (tets.min() < 0 or tets.max() >= len(vertices)):
        raise InputError("tet indices out of range", path=path)
    scale = float(arrays["scale"])
    if not np.all(np.isfinite(vertices)) or not np.isfinite(scale) or scale <= 0:
        raise InputError("non-finite coordinates or non-positive scale", path=path)
    norm = Normalization(center=np.asarray(arrays["center"], dtype=np.float64).reshape(3), scale=scale)
    return TetMesh(vertices=vertices, tets=tets, normalization=norm)
