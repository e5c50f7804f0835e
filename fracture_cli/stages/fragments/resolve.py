"""Fragments as written: split where they pinch, so every fragment the GLB stores is one closed body.

A cut can leave a fragment that is closed in float64 but not as the GLB stores
it (float32 about its pivot): two parts touching along an edge or at a point
(a tooth against the hub, a wheel against the chassis, two chips of a region
that meet where the input's bodies touched), or vertices a rounding step apart
that become one. The repair stage resolves the same configurations on the
input (:mod:`fracture_cli.stages.repair.nonmanifold`); here the same pairing of
faces around an edge of more than two faces runs on each fragment welded by
its *written* positions: the faces of each material wedge are glued, vertices
are copied per fan, and every closed body becomes a fragment of its own (same
piece). Bodies that enclose nothing (slivers of rounding) are left out.
Fragments this cannot make closed are left as they are, for the checks to
refuse with their location.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.edges import corner_fans, edge_table
from fracture_cli.geometry.mass import mass_properties
from fracture_cli.geometry.solids import SplitMesh
from fracture_cli.geometry.weld_check import MeshCheck, as_written, check_mesh, collapsed, weld_by_position
from fracture_cli.stages.repair.carry import after_split
from fracture_cli.stages.repair.nonmanifold import split_nonmanifold
from fracture_cli.system import parallel
from fracture_cli.types import Fragment, Fragments


def written_check(frag: Fragment, fragments: Fragments) -> MeshCheck:
    """:func:`~fracture_cli.geometry.weld_check.check_mesh` of a fragment on its positions as the GLB stores them."""
    stored = _stored(frag, fragments)
    return check_mesh(stored, frag.faces, weld_by_position(stored))


def _stored(frag: Fragment, fragments: Fragments) -> np.ndarray:
    """The fragment's positions (n, 3) exactly as written: world units, float32 about its pivot."""
    # numba kernels load on first use (the physics module imports the writer's helpers)
    from fracture_cli.io.physics import fragment_physics

    origin = fragment_physics(dataclasses.replace(fragments, fragments=(frag,)), pivot=fragments.pivot)[0].origin
    return as_written(fragments.normalization.to_world(frag.vertices), origin)


def needs_split(check: MeshCheck) -> bool:
    """Whether a fragment, as written, pinches (edges of more than two faces) or falls into several bodies."""
    return check.pinched_edges > 0 or check.bodies > 1


def split_at_pinches(frag: Fragment, fragments: Fragments) -> tuple[list[Fragment], int] | None:
    """The closed bodies of a fragment welded by its written positions, split where it pinches.

    Parameters
    ----------
    frag : Fragment
        A fragment of ``fragments`` (normalized coordinates).
    fragments : Fragments
        For the normalization, the pivot rule and the input's volume.

    Returns
    -------
    (list of Fragment, int) or None
        One fragment per closed body with volume (largest first; each keeps
        ``frag.piece``), their positions those of the first float64 vertex of
        each written position (so the float64 mesh has the topology the GLB
        will have), and how many slivers (bodies of no volume) were left out;
        None when some edge cannot be paired or a body stays open.
    """
    stored = _stored(frag, fragments)
    unique, index = weld_by_position(stored)
    degenerate = collapsed(index[frag.faces])
    faces = frag.faces[~degenerate]
    first = np.full(len(unique), len(index), dtype=np.int64)
    np.minimum.at(first, index, np.arange(len(index)))
    rep = first[index]  # the first split vertex at each written position
    V = frag.vertices[rep]
    uvs = frag.uvs if frag.uvs is not None else np.zeros((len(V), 2))
    mesh = SplitMesh(np.column_stack([V, uvs, frag.normals]), faces, frag.material_ids[~degenerate], rep)
    split = split_nonmanifold(V, mesh.welded)
    if len(split.unresolved_edges) or not split.body_closed.all():
        return None
    out = after_split(mesh, split)
    volume = np.array([mass_properties(out.props[:, :3], out.faces[split.body == b]).volume
                       for b in range(len(split.body_closed))])
    keep = np.flatnonzero(volume > tol.SLIVER_VOLUME * fragments.input_volume)
    if not len(keep):
        return None
    bodies = []
    for b in sorted(keep.tolist(), key=lambda b: (-volume[b], b)):
        mine = split.body == b
        used, local = np.unique(out.faces[mine], return_inverse=True)
        props = out.props[used]
        bodies.append(Fragment(vertices=props[:, :3], faces=local.reshape(-1, 3),
                               uvs=props[:, 3:5] if frag.uvs is not None else None, normals=props[:, 5:8],
                               material_ids=out.material_ids[mine], piece=frag.piece))
    return bodies, len(volume) - len(keep)


@dataclass(frozen=True)
class Resolved:
    """What :func:`resolve_pinches` did.

    Attributes
    ----------
    split : int
        Fragments split where they pinched, as written.
    bodies : int
        Fragments they became.
    slivers : int
        Bodies of no volume left out.
    unresolved : tuple of int
        Fragments (indices in the result) still not closed as written.
    """

    split: int
    bodies: int
    slivers: int
    unresolved: tuple[int, ...]


def resolve_pinches(fragments: Fragments) -> tuple[Fragments, Resolved]:
    """Split every fragment that pinches as written into its closed bodies (see the module docstring).

    Returns
    -------
    fragments : Fragments
        The same fragments (the same object when none pinches), split ones
        replaced by their bodies (the caller re-sorts them).
    Resolved
    """
    checks = parallel.ordered_map(_check_one, range(len(fragments.fragments)), fragments)
    bad = [i for i, c in enumerate(checks) if needs_split(c)]
    if not bad:
        return fragments, Resolved(0, 0, 0, ())
    out: list[Fragment] = []
    unresolved = []
    split = bodies = slivers = 0
    for i, frag in enumerate(fragments.fragments):
        found = split_at_pinches(frag, fragments) if i in bad else ([frag], 0)
        if found is None:
            unresolved.append(len(out))
            found = ([frag], 0)
        elif i in bad:
            split += 1
            bodies += len(found[0])
            slivers += found[1]
        out.extend(found[0])
    return dataclasses.replace(fragments, fragments=tuple(out)), Resolved(split, bodies, slivers, tuple(unresolved))


def _check_one(fragments: Fragments, index: int) -> MeshCheck:
    return written_check(fragments.fragments[index], fragments)


# How far a fan's copy of a pinched vertex moves into its own material (fractions of the bounding-box diagonal),
# smallest first: 1e-6 is about 8 float32 steps of a fragment's pivot-relative coordinates, so the copies stay
# apart as written, far below any modelled feature; the fragment loses a third of this times the fan's area of
# volume (1.8e-6 of a box cut by three coarse profiles at 1e-5, over issue 32's 1e-6 volume target), so the
# larger gap is only taken where float32 storage would merge the smaller one.
PINCH_GAPS = (1e-6, 1e-5)


def separate_pinched_vertices(fragments: Fragments) -> tuple[Fragments, int]:
    """Move apart the places where a fragment touches itself at a single vertex, as written.

    Parameters
    ----------
    fragments : Fragments

    Returns
    -------
    fragments : Fragments
        The same object when no fragment pinches at a vertex; otherwise, at
        every vertex of a fragment whose faces form several fans (cones of one
        body meeting at a point, as a region of the cut can touch itself), the
        second and later fans get their own copy of the vertex, moved by
        the first of :data:`PINCH_GAPS` that keeps the copies apart as written into the fan's
        own material (against its faces' mean
        normal). A fragment the move would not leave closed and free of
        pinched vertices, as written, keeps its vertex.
    moved : int
        Vertex copies moved.

    Notes
    -----
    Moving into the fan's own material only shrinks that fragment there, so
    no fragment comes to overlap another; its neighbours keep their faces
    (a gap of :data:`PINCH_GAPS` at a point). Run after the faults are
    simplified: the simplify stage welds the fragments into one complex and
    wants both sides of a fault to coincide.
    """
    checks = parallel.ordered_map(_check_one, range(len(fragments.fragments)), fragments)
    pinched = [i for i, c in enumerate(checks) if c.pinched_vertices and c.closed]
    if not pinched:
        return fragments, 0
    out = list(fragments.fragments)
    moved = 0
    for i in pinched:
        for gap in PINCH_GAPS:
            frag, count = _separate(out[i], fragments, gap)
            if count and _separated(written_check(frag, fragments)):
                out[i] = frag
                moved += count
                break
    return dataclasses.replace(fragments, fragments=tuple(out)), moved


def _separated(check: MeshCheck) -> bool:
    return check.closed and check.pinched_vertices == 0


def _separate(frag: Fragment, fragments: Fragments, gap: float) -> tuple[Fragment, int]:
    """``frag`` with each pinched vertex's later fans moved into their material (:func:`separate_pinched_vertices`)."""
    stored = _stored(frag, fragments)
    _, index = weld_by_position(stored)
    W = index[frag.faces]
    fans = corner_fans(W, edge_table(W))
    corner_vertex = W.reshape(-1)
    _, fan = np.unique(fans, return_inverse=True)
    fan = fan.reshape(-1)
    # Fans per welded vertex, in order of their first corner: the first keeps the vertex.
    first_corner = np.full(int(fan.max()) + 1, len(fan))
    np.minimum.at(first_corner, fan, np.arange(len(fan)))
    fan_vertex = corner_vertex[first_corner]
    order = np.lexsort((first_corner, fan_vertex))
    later = np.zeros(len(first_corner), dtype=bool)
    later[order[1:]] = fan_vertex[order[1:]] == fan_vertex[order[:-1]]
    if not later.any():
        return frag, 0
    V = frag.vertices
    normal = np.cross(V[frag.faces[:, 1]] - V[frag.faces[:, 0]], V[frag.faces[:, 2]] - V[frag.faces[:, 0]])
    faces = frag.faces.reshape(-1).copy()
    vertices, uvs, normals = [V], [frag.uvs] if frag.uvs is not None else None, [frag.normals]
    count = len(V)
    for f in np.flatnonzero(later).tolist():
        corners = np.flatnonzero(fan == f)
        inward = -normal[corners // 3].sum(axis=0)
        length = float(np.linalg.norm(inward))
        if length == 0.0:
            continue
        source = faces[corners[0]]
        vertices.append(V[source][None] + gap * inward / length)
        normals.append(frag.normals[source][None])
        if uvs is not None and frag.uvs is not None:
            uvs.append(frag.uvs[source][None])
        faces[corners] = count
        count += 1
    moved = count - len(V)
    return dataclasses.replace(frag, vertices=np.vstack(vertices), faces=faces.reshape(-1, 3),
                               uvs=None if uvs is None else np.vstack(uvs), normals=np.vstack(normals)), moved
