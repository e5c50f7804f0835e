"""The ``load`` stage's work: probe, read, join and check a mesh file.

:func:`fracture_cli.stages.load.load_surface` is the stage's entry point (its docstring says what is read);
this module reads, so that the package itself loads none of the readers.
"""

from __future__ import annotations

import logging
import os
import stat
from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.errors import InputError
from fracture_cli.geometry.rows import group_rows, unique_inverse, unique_rows, used_vertices
from fracture_cli.io.inputs import file_kind
from fracture_cli.io.parts import read_parts
from fracture_cli.io.probe import probe_triangles
from fracture_cli.stages.load.options import READERS, LoadOptions
from fracture_cli.types import Material, Normalization, SurfaceMesh

if TYPE_CHECKING:
    import trimesh

log = logging.getLogger(__name__)

# Warn when 32-bit coordinates are coarser than this fraction of the model's bounding-box diagonal.
_PRECISION_WARNING = 1e-5


def _float32_precision(v: np.ndarray) -> tuple[float, float, float]:
    """(step / bbox diagonal, step, largest |coordinate|) if all of ``v`` are float32 values, else zeros.

    Positions far from the origin in a 32-bit file (GLB, binary STL, or text
    written from float32) keep only 24 bits: at 1e6 the step is 1/16 unit.
    The loader works in float64 from here on, but cannot restore what the
    file lost.
    """
    if len(v) == 0:
        return (0.0, 0.0, 0.0)
    largest = float(np.abs(v).max())
    if largest == 0.0 or not np.array_equal(v.astype(np.float32).astype(np.float64), v):
        return (0.0, 0.0, 0.0)
    step = float(np.spacing(np.float32(largest)))
    diagonal = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    return (step / diagonal if diagonal > 0 else np.inf, step, largest)


# The outputs hold float32 (GLB positions, the runtime file): sizes whose mass properties or coordinates
# cannot be stored there are refused before any work. Inertia (units^5) of a body in a box of diagonal D
# is at most D^5 / (3 sqrt 3); the margin covers the cage and a thickened shell reaching past the input.
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_FLOAT32_TINY = float(np.finfo(np.float32).tiny)
_MARGIN = 4.0


def _diagonal(lo: np.ndarray, hi: np.ndarray) -> float:
    """Length of ``hi - lo`` (3,) without overflow (scaled by its largest component first)."""
    extent = np.abs(np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64))
    largest = float(extent.max())
    if not 0.0 < largest < np.inf:
        return largest
    unit = extent / largest
    return largest * float(np.sqrt(np.dot(unit, unit)))


def _fifth(d: float) -> float:
    return d * d * d * d * d


def size_limits() -> tuple[float, float]:
    """(smallest, largest) bounding-box diagonal whose outputs float32 holds: about (4e-8, 5e7) units."""
    # Solve D^5 * k = limit by bisection on IEEE products only (no libm: the same bounds on every CPU).
    def solve(target: float) -> float:
        lo, hi = 1e-30, 1e30
        for _ in range(400):
            mid = float(np.sqrt(lo * hi))
            if _fifth(mid) < target:
                lo = mid
            else:
                hi = mid
        return lo

    return solve(_FLOAT32_TINY * _MARGIN * 5.2), solve(_FLOAT32_MAX * 5.2 / _MARGIN)


def check_representable(points: np.ndarray, path: str) -> None:
    """Refuse an input whose outputs cannot be written as float32, before any work is done on it.

    Parameters
    ----------
    points : (n, 3) float64
        The used vertices, in file units.
    path : str

    Raises
    ------
    InputError
        The bounding-box diagonal is so large that the fragments' inertia
        (units^5) overflows float32 (above about 5e7 units: a 1e9-unit sphere),
        so small that it underflows (below about 4e-8 units), or a coordinate
        is beyond float32's range.
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    diagonal = _diagonal(lo, hi)
    reach = float(np.abs(points).max()) + diagonal
    smallest, largest = size_limits()
    if reach > _FLOAT32_MAX / _MARGIN or diagonal > largest:
        raise InputError(f"is too large for the outputs: it is {diagonal:.3g} units across (coordinates up to "
                         f"{float(np.abs(points).max()):.3g}), and its inertia (units^5) and positions must fit the "
                         f"32-bit floats of the GLB and runtime file, which hold assets up to about {largest:.2g} "
                         "units across; export it in larger units (e.g. metres instead of millimetres) or scale it "
                         "down", path=path)
    if 0.0 < diagonal < smallest:
        raise InputError(f"is too small for the outputs: it is {diagonal:.3g} units across, and its inertia "
                         f"(units^5) would underflow 32-bit floats below about {smallest:.2g} units across; export "
                         "it in smaller units or scale it up", path=path)


def smooth_normals_welded(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (n, 3) computed over positions, not vertex ids.

    Vertices split at UV seams share a position; averaging per position keeps the
    shading continuous across seams, which per-id normals would not.
    """
    pos_id = group_rows(vertices)  # which vertices share a position (the sums do not depend on the ids)
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    fn = np.cross(b - a, c - a)  # length = 2 * area: area weighting for free
    num = pos_id.max() + 1 if len(pos_id) else 0
    # bincount adds in array order, as np.add.at corner by corner did (same sums, bit for bit), much faster.
    corner_pos = pos_id[faces.T.reshape(-1)]
    acc = np.stack([np.bincount(corner_pos, weights=np.tile(fn[:, axis], 3), minlength=num) for axis in range(3)],
                   axis=1) if len(faces) else np.zeros((num, 3))
    n = acc[pos_id]
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    out = np.zeros_like(n)
    ok = norm[:, 0] > 0
    out[ok] = n[ok] / norm[ok]
    out[~ok] = (0.0, 0.0, 1.0)
    return out


def double_sided_back_faces(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Which triangles (m,) bool are the second side of a double-sided surface.

    Parameters
    ----------
    V : (n, 3) float
    F : (m, 3) int

    Returns
    -------
    (m,) bool
        In every connected part (vertices welded by position) whose every
        non-degenerate triangle has a coincident copy facing the other way,
        all triangles but the first (in file order) on each set of three
        corners. Elsewhere False: a face shared by two touching solids (two
        stacked boxes) is such a pair too, but its part has unpaired faces,
        and repair removes both copies there, as it should.

    Notes
    -----
    Without this, the two sides cancel: repair drops coincident opposite
    pairs as internal walls and nothing is left of a double-sided closed
    surface (exported with "double-sided" baked into the geometry).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    drop = np.zeros(len(F), dtype=bool)
    if len(F) < 2:
        return drop
    weld = group_rows(V)  # any ids: what is dropped depends only on which corners share a position
    W = weld[F]
    ok = (W[:, 0] != W[:, 1]) & (W[:, 1] != W[:, 2]) & (W[:, 0] != W[:, 2])
    corners = np.sort(W, axis=1)
    first = np.argmin(W, axis=1)  # rotate each triangle to start at its smallest corner: orientation = next < last
    rows = np.arange(len(W))
    facing = W[rows, (first + 1) % 3] < W[rows, (first + 2) % 3]
    key = _row_ids(corners)
    up = np.bincount(key[ok & facing], minlength=key.max() + 1)
    down = np.bincount(key[ok & ~facing], minlength=key.max() + 1)
    paired = (up[key] > 0) & (down[key] > 0)
    if not (ok & paired).any():
        return drop  # no face has a copy facing the other way (the usual case): no parts to find
    n = int(weld.max()) + 1
    edges = np.concatenate([W[:, [0, 1]], W[:, [1, 2]]])
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, part = connected_components(graph, directed=False)
    face_part = part[W[:, 0]]
    unpaired = np.bincount(face_part[ok & ~paired], minlength=part.max() + 1)
    whole = unpaired[face_part] == 0
    if not (whole & paired).any():
        return drop
    # Keep the first triangle of each corner set in the double-sided parts, drop the rest.
    order = np.lexsort((rows, key))
    repeat = np.zeros(len(F), dtype=bool)
    repeat[order[1:]] = key[order[1:]] == key[order[:-1]]
    return whole & ok & repeat


def _row_ids(rows: np.ndarray) -> np.ndarray:
    """Id (m,) of each row of ``rows`` (m, 3) of ints in [0, n) among the sorted distinct rows (as ``np.unique``)."""
    n = int(rows.max()) + 1
    if n * n * n < 2 ** 62:  # the three ids packed into one integer sort in the rows' order
        return unique_inverse((rows[:, 0] * n + rows[:, 1]) * n + rows[:, 2])[1]
    return unique_rows(rows, return_inverse=True)[1].reshape(-1)


def read_surface(path: str | os.PathLike, options: LoadOptions) -> SurfaceMesh:
    """The stage's work (:func:`fracture_cli.stages.load.load_surface`)."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in READERS:
        raise InputError(
            f"unsupported file type '{ext or '(none)'}'; pick one of {', '.join(sorted(READERS))}", path=path
        )
    if not os.path.exists(path):
        raise InputError("no such file", path=path)
    if os.path.isdir(path):
        raise InputError("is a directory, not a mesh file", path=path)
    mode = os.stat(path).st_mode
    if not stat.S_ISREG(mode):  # a FIFO would block the first read; a device never ends
        raise InputError(f"is {file_kind(mode)}, not a regular mesh file", path=path)
    if os.path.getsize(path) == 0:
        raise InputError("file is empty (0 bytes)", path=path)

    # Refuse what is over the limit, truncated or mislabelled before decoding anything.
    declared = probe_triangles(path, READERS[ext])
    if declared is not None and declared > options.max_triangles:
        raise InputError(
            f"has {declared:,} {'face lines' if ext == '.obj' else 'triangles'}, more than the limit of "
            f"{options.max_triangles:,} (raise it with --max-triangles or --set load.max_triangles=N, or decimate "
            "the asset first)", path=path)

    parts = read_parts(path, READERS[ext])
    if not parts:
        raise InputError("contains no triangles (a point cloud, lines, or an empty scene)", path=path)
    total = sum(len(p.faces) for p in parts)
    if total > options.max_triangles:
        raise InputError(
            f"has {total:,} triangles, more than the limit of {options.max_triangles:,} "
            "(raise it with --max-triangles or --set load.max_triangles=N, or decimate the asset first)",
            path=path,
        )

    vertices: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    uvs: list[np.ndarray] = []
    normals: list[np.ndarray] = []
    colors: list[np.ndarray] = []
    mat_ids: list[np.ndarray] = []
    materials: list[Material] = []
    mat_index: dict = {}  # material_key -> slot: two glTF materials with one name stay two slots
    any_uv = any(p.uvs is not None for p in parts)
    any_normals = all(p.normals is not None for p in parts)
    any_colors = any(p.colors is not None for p in parts)
    offset = 0
    worst_precision = (0.0, 0.0, 0.0)  # (relative step, step, largest coordinate)
    for part in parts:
        v = part.vertices
        if not np.all(np.isfinite(v)):
            raise InputError("has non-finite vertex coordinates (NaN or inf)", path=path)
        worst_precision = max(worst_precision, _float32_precision(part.raw_vertices if part.raw_vertices is not None
                                                                  else v))
        vertices.append(v)
        faces.append(part.faces + offset)
        offset += len(v)
        if any_uv:
            uvs.append(part.uvs if part.uvs is not None else np.zeros((len(v), 2)))
        if any_normals and part.normals is not None:
            normals.append(part.normals)
        if any_colors:
            colors.append(part.colors if part.colors is not None else np.ones((len(v), 4)))
        if part.material_key not in mat_index:
            mat_index[part.material_key] = len(materials)
            materials.append(part.material)
        mat_ids.append(np.full(len(part.faces), mat_index[part.material_key], dtype=np.int32))

    if worst_precision[0] > _PRECISION_WARNING:
        relative, step, largest = worst_precision
        log.warning("load: %s: coordinates reach %.3g from the origin and are stored as 32-bit floats, so positions "
                    "are only precise to %.3g (%.2g of the model's size): small features are distorted and may be "
                    "merged by repair; export the mesh centred on its origin and place it with a node transform",
                    path, largest, step, relative)
    V = np.concatenate(vertices)
    F = np.concatenate(faces)
    M = np.concatenate(mat_ids)
    back = double_sided_back_faces(V, F)
    if back.any():
        log.warning("load: %s: %d triangles are the back sides of a double-sided surface (each has a coincident "
                    "copy facing the other way); one side is kept", path, int(back.sum()))
        F, M = F[~back], M[~back]
    used = used_vertices(F, len(V))
    if not np.all(np.isfinite(V[used])):
        raise InputError("has non-finite vertex coordinates (NaN or inf)", path=path)
    check_representable(V[used], path)
    normalization = Normalization.from_points(V[used])
    if normalization.scale <= 0 or not np.isfinite(normalization.scale):
        raise InputError("has no extent (all vertices at one point)", path=path)
    Vn = normalization.to_normalized(V)
    if normals:
        N: np.ndarray = np.concatenate(normals)
    else:
        N = smooth_normals_welded(Vn, F)
    surface = SurfaceMesh(
        vertices=Vn,
        faces=F,
        uvs=np.concatenate(uvs) if uvs else None,
        normals=N,
        colors=np.concatenate(colors) if colors else None,
        material_ids=M,
        materials=tuple(materials),
        normalization=normalization,
        name=os.path.basename(path),
    )
    log.info("load: %s: %d vertices, %d triangles, %d material(s)%s", surface.name, surface.num_vertices,
             surface.num_faces, len(materials), ", UVs" if surface.uvs is not None else "")
    return surface


def surface_from_trimesh(mesh: trimesh.Trimesh, name: str = "mesh") -> SurfaceMesh:
    """Wrap an in-memory ``trimesh.Trimesh`` (world units) as a normalized SurfaceMesh.

    Used by tests and benchmarks that build shapes in code.
    """
    V = np.asarray(mesh.vertices, dtype=np.float64)
    F = np.asarray(mesh.faces, dtype=np.int64)
    normalization = Normalization.from_points(V)
    Vn = normalization.to_normalized(V)
    uv = getattr(mesh.visual, "uv", None)
    return SurfaceMesh(
        vertices=Vn,
        faces=F,
        uvs=np.asarray(uv, dtype=np.float64)[:, :2] if uv is not None else None,
        normals=smooth_normals_welded(Vn, F),
        colors=None,
        material_ids=np.zeros(len(F), dtype=np.int32),
        materials=(Material(name="material_0"),),
        normalization=normalization,
        name=name,
    )
