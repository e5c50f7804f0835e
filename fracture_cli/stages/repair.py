"""Repair: turn any loaded surface into one closed, outward-oriented solid.

The cage (section 1) and the fragments (section 6) must agree on what the solid
is, so the input is made a solid once, right after loading, and both use the
result.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import manifold3d
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components

from fracture_cli.errors import StageError
from fracture_cli.options import option
from fracture_cli.types import INTERIOR_MATERIAL_NAME, Material, SurfaceMesh

log = logging.getLogger(__name__)

STAGE = "repair"

# Vertex property columns carried through manifold3d: position, uv, normal, colour.
_POS, _UV, _NORMAL, _COLOR = slice(0, 3), slice(3, 5), slice(5, 8), slice(8, 12)
_NUM_COLUMNS = 12
# Column count of :func:`surface_solid` (no colours: fragments do not carry them).
SOLID_COLUMNS = 8
# A solid of a unit-diagonal box enclosing less than this has no inside.
_MIN_VOLUME = 1e-9
# Smallest / largest singular value of the centred positions below which they are coplanar.
_FLAT = 1e-9
# Shell thickness: at most this fraction of the free distance along the inward normal
# (to the opposite wall or the next fold), and the floor below which shelling fails.
_RAY_FRACTION = 0.45
_MIN_THICKNESS_FRACTION = 1e-3
# Closed components compared for nesting (cavities) only when their bounding boxes nest;
# at most this many sample vertices per component.
_NESTING_SAMPLES = 32
_INTERIOR_COLOR = (0.55, 0.5, 0.45, 1.0)

FLAT_HINT = ("give it thickness in your modelling tool, or use --set repair.open_surface=shell to thicken it "
             "into a thin solid")


@dataclass(frozen=True)
class RepairOptions:
    """Options of :func:`repair`."""

    open_surface: str = option(
        "auto",
        "what to do with a surface that is open after welding: 'fill' closes each hole with a fan of interior "
        "faces, 'shell' thickens the sheet into a thin solid, 'auto' fills small holes (total hole area at most "
        "max_fill_ratio of the surface area) and shells otherwise, 'error' stops",
        choices=("auto", "fill", "shell", "error"),
    )
    shell_thickness: float = option(
        0.01,
        "thickness of a shelled sheet, relative to the bounding-box diagonal (thinner where the sheet folds "
        "tighter than that)",
        min=0.0,
        max=0.5,
        min_exclusive=True,
    )
    max_fill_ratio: float = option(
        0.02,
        "open_surface='auto' fills holes whose total area is at most this fraction of the surface area",
        min=0.0,
        max=1.0,
    )


def repair(surface: SurfaceMesh, options: RepairOptions = RepairOptions()) -> SurfaceMesh:
    """Make a surface a closed, edge-manifold, outward-oriented solid.

    Parameters
    ----------
    surface : SurfaceMesh
        The loaded input, normalized coordinates. May have UV seams (vertices
        split at one position), degenerate and duplicated faces, inconsistent
        winding, several overlapping closed bodies, cavities, and holes.
    options : RepairOptions, optional
        ``open_surface`` (default ``'auto'``), ``shell_thickness`` (default
        0.01 of the bounding-box diagonal) and ``max_fill_ratio`` (default 0.02).

    Returns
    -------
    SurfaceMesh
        Closed when its vertices are welded by position, every edge in exactly
        two faces of opposite orientation, positive volume. Vertices stay split
        where their attributes differ (seams keep their UVs and normals);
        positions are the input's (vertices merged within manifold3d's
        tolerance are snapped to one position). Faces added to close the
        surface carry an ``interior`` material slot (appended, or the input's
        own slot of that name), because they are not part of the artist's
        surface. ``normalization`` and ``name`` are unchanged. A surface that
        needs no repair is returned as it is.

    Raises
    ------
    StageError
        If the surface has no inside (flat, or nothing left after removing
        degenerate faces), is open and ``open_surface='error'``, has edges
        shared by more than two faces, or cannot be shelled or filled into a
        valid solid.

    Notes
    -----
    ALGORITHM.md sections 1 and 6: the cage must contain the solid that the
    fragments partition, so both read this stage's result. Steps, each logged:

    1. Weld: vertices at exactly the same position are one vertex
       topologically, and open edges are merged within manifold3d's tolerance
       (``MeshGL.merge``); attributes stay per split vertex.
    2. Remove degenerate faces (two corners welded together) and duplicated
       faces (same welded corners: one copy of a repeated face is kept; a face
       and its reverse enclose nothing and both go).
    3. Orient consistently: winding is propagated across edges shared by two
       faces; each closed component is then flipped to positive volume, unless
       it lies entirely inside another closed component (a cavity: negative).
       Shading normals that point against their faces are flipped too.
    4. Close open components (``open_surface``):

       * ``fill``: each boundary loop is closed by a fan around its centroid.
         Right for small, roughly planar holes from modelling mistakes; a very
         twisted hole can give a cap that crosses the surface.
       * ``shell``: the sheet is thickened along its area-weighted vertex
         normals, towards the side the normals point away from (an outward
         oriented sheet keeps its outside; the winding of an open sheet follows
         its shading normals). The offset copy is joined to the sheet along the
         boundary loops by a strip. Thickness is ``shell_thickness`` but at most
         0.45 of the free distance along the inward normal (ray cast to the
         opposite wall or next fold), and halved where an offset face would
         flip; if it must drop below 1e-3 of the request the stage fails.
       * ``auto``: fill if the holes' fan area is at most ``max_fill_ratio`` of
         the surface area, else shell. A flat input (all vertices in one plane)
         is refused rather than guessed; ask for ``shell`` explicitly.

    5. Union: several closed bodies stored as one mesh may overlap; the solid
       is the union of the positive ones minus the cavities (manifold3d).
    """
    t0 = time.perf_counter()
    V = np.asarray(surface.vertices, dtype=np.float64)
    F = np.asarray(surface.faces, dtype=np.int64)
    material_ids = np.asarray(surface.material_ids, dtype=np.int32)
    props = vertex_properties(surface, _NUM_COLUMNS)
    materials = tuple(surface.materials)
    did: list[str] = []

    # 1. Weld.
    weld = weld_map(props[:, :3], F)
    num_welded = int((weld != np.arange(len(V))).sum())
    snapped = np.any(props[weld, _POS] != props[:, _POS], axis=1)
    if snapped.any():
        props[:, _POS] = props[weld, _POS]  # vertices merged within tolerance get one position
        did.append(f"snapped {int(snapped.sum())} nearly coincident vertices together")

    # 2. Degenerate and duplicated faces.
    W = weld[F]
    degenerate = (W[:, 0] == W[:, 1]) | (W[:, 1] == W[:, 2]) | (W[:, 2] == W[:, 0])
    if degenerate.any():
        did.append(f"removed {int(degenerate.sum())} degenerate faces")
    F, W, material_ids = F[~degenerate], W[~degenerate], material_ids[~degenerate]
    keep, num_duplicates, num_back_to_back = _unique_faces(W)
    if num_duplicates:
        did.append(f"removed {num_duplicates} duplicated faces")
    if num_back_to_back:
        did.append(f"removed {num_back_to_back} back-to-back face pairs")
    F, W, material_ids = F[keep], W[keep], material_ids[keep]
    flat = _is_flat(props[np.unique(F), :3]) if len(F) else True
    if len(F) == 0:
        raise StageError("no faces are left after removing degenerate and duplicated faces: "
                         + ("flat: all vertices lie in one plane, so it has no inside; " + FLAT_HINT if flat
                            else "the mesh encloses nothing"), stage=STAGE)
    if _nonmanifold_edges(W):
        props, F, material_ids, weld, leftover, note = _split_nonmanifold(props, F, W, material_ids, weld)
        W = weld[F]
        did.append(note)
        if leftover:
            raise StageError(
                f"{leftover} edges are shared by more than two faces after welding vertices by position, and the "
                "faces around them do not split into closed bodies (two bodies touching along an edge, or cells "
                "sharing an internal wall, are handled), so the mesh has no well-defined inside there; separate the "
                "touching parts in your modelling tool", stage=STAGE)

    # 3a. Consistent winding within each edge-connected patch.
    flip, patch = _propagate_winding(W)
    if flip.any():
        did.append(f"re-wound {int(flip.sum())} faces")
    F[flip] = F[flip][:, ::-1]
    W[flip] = W[flip][:, ::-1]

    # 4. Close what is open; open sheets entirely inside a closed body are internal faces and go first.
    boundary = _boundary_edges(W)
    if len(boundary):
        inside = _internal_open_faces(props[:, _POS], W, weld)
        if inside.any():
            did.append(f"removed {int(inside.sum())} internal faces (open sheets inside the solid)")
            F, W, material_ids, patch = F[~inside], W[~inside], material_ids[~inside], patch[~inside]
            _, patch = np.unique(patch, return_inverse=True)
            patch = patch.reshape(-1)
            boundary = _boundary_edges(W)
    interior_material = None
    if len(boundary):
        loops = _boundary_loops(boundary)
        mode = options.open_surface
        hole_area = sum(_fan_area(props[loop, :3]) for loop in loops)
        surface_area = float(_face_areas(props[:, :3], F).sum())
        ratio = hole_area / surface_area if surface_area > 0 else np.inf
        where = (f"the mesh is open at {len(loops)} boundary loop(s) ({len(boundary)} boundary edges, holes "
                 f"{100 * ratio:.3g}% of the surface area) after welding vertices by position")
        if mode == "error":
            raise StageError(f"{where}; close it in your modelling tool, or use --set repair.open_surface=fill "
                             "(close small holes) or --set repair.open_surface=shell (thicken the sheet)",
                             stage=STAGE)
        if mode == "auto":
            if flat:
                raise StageError("flat: all vertices lie in one plane, so it has no inside; " + FLAT_HINT,
                                 stage=STAGE)
            mode = "fill" if ratio <= options.max_fill_ratio else "shell"
            log.info("%s: %s; auto: %s (fill limit %.3g%%)", STAGE, where, mode, 100 * options.max_fill_ratio)
        interior_material, materials = _interior_slot(materials)
        if mode == "fill":
            props, F, W, material_ids, weld = _fill(props, F, W, material_ids, weld, loops, interior_material)
            did.append(f"filled {len(loops)} hole(s)")
        else:
            patch_open = np.zeros(patch.max() + 1, dtype=bool)
            edge_face = _boundary_edge_faces(W, boundary)
            patch_open[patch[edge_face]] = True
            sheet = patch_open[patch]
            sheet_flip = _sheet_orientation(props, F, patch, sheet)
            F[sheet_flip] = F[sheet_flip][:, ::-1]
            W[sheet_flip] = W[sheet_flip][:, ::-1]
            boundary = _boundary_edges(W)
            props, F, W, material_ids, weld, thinned = _shell(props, F, W, material_ids, weld, sheet, boundary,
                                                              options.shell_thickness, interior_material)
            did.append(f"shelled {int(len(np.unique(patch[sheet])))} open sheet(s) "
                       f"(thickness {options.shell_thickness:g}" + (f", thinner at {thinned} vertices)"
                                                                    if thinned else ")"))

    # 3b. Each closed component outward (cavities inward).
    component = _components(W, len(props))
    flip_component = _component_orientation(props[:, :3], F, component)
    flip = flip_component[component]
    if flip.any():
        did.append(f"flipped {int(flip_component.sum())} inside-out component(s)")
    F[flip] = F[flip][:, ::-1]
    W[flip] = W[flip][:, ::-1]
    num_normals = _fix_shading_normals(props, F)
    if num_normals and surface.normals is not None:
        did.append(f"flipped {num_normals} shading normals")

    # 5. Manifold check and union of overlapping bodies.
    solid, id_to_material = _manifold(props, F, material_ids, weld, len(materials))
    if solid.status() != manifold3d.Error.NoError:
        raise StageError(f"the repaired mesh is not a valid manifold ({solid.status().name}); fix the mesh in "
                         "your modelling tool", stage=STAGE)
    solid, bodies, cavities = _union_bodies(solid)
    if bodies > 1:
        did.append(f"unioned {bodies} overlapping bodies" + (f" minus {cavities} cavities" if cavities else ""))
        props, F, material_ids = _from_manifold(solid, id_to_material)
    volume = float(solid.volume())
    if volume <= _MIN_VOLUME:
        if flat:
            raise StageError("flat: all vertices lie in one plane, so it has no inside; " + FLAT_HINT, stage=STAGE)
        raise StageError(f"the repaired mesh encloses no volume ({volume:.3g} of a unit-diagonal box); it needs a "
                         "closed, solid shape", stage=STAGE)

    welded = f"welded {num_welded} seam vertices by position"
    if not did:
        log.info("%s: %s: %s; a closed solid, nothing to repair (volume %.6g, %.2f s)", STAGE, surface.name,
                 welded, volume, time.perf_counter() - t0)
        return surface
    props, F = _compact(props, F)
    log.info("%s: %s: %s, %s; %d faces, volume %.6g (%.2f s)", STAGE, surface.name, welded, ", ".join(did), len(F),
             volume, time.perf_counter() - t0)
    normals = props[:, _NORMAL]
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > 1e-12, normals / np.maximum(length, 1e-300), 0.0)
    return SurfaceMesh(
        vertices=np.ascontiguousarray(props[:, _POS]),
        faces=np.ascontiguousarray(F, dtype=np.int64),
        uvs=np.ascontiguousarray(props[:, _UV]) if surface.uvs is not None else None,
        normals=np.ascontiguousarray(normals) if surface.normals is not None else None,
        colors=np.ascontiguousarray(props[:, _COLOR]) if surface.colors is not None else None,
        material_ids=np.ascontiguousarray(material_ids, dtype=np.int32),
        materials=materials,
        normalization=surface.normalization,
        name=surface.name,
    )


# ----------------------------------------------------------------------------
# Shared with the fragments stage

def vertex_properties(surface: SurfaceMesh, columns: int = SOLID_COLUMNS) -> np.ndarray:
    """Per-vertex properties (n, columns): position, uv, normal (and RGBA colour if ``columns`` is 12).

    Missing UVs are zero, missing colours white, missing normals area-weighted
    normals averaged over vertices sharing a position.
    """
    V = np.asarray(surface.vertices, dtype=np.float64)
    n = len(V)
    props = np.zeros((n, columns))
    props[:, _POS] = V
    if surface.uvs is not None:
        props[:, _UV] = surface.uvs
    if surface.normals is not None:
        props[:, _NORMAL] = surface.normals
    else:
        props[:, _NORMAL] = _normals_by_position(V, np.asarray(surface.faces, dtype=np.int64))
    if columns > SOLID_COLUMNS:
        props[:, _COLOR] = surface.colors if surface.colors is not None else 1.0
    return props


def weld_map(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Representative vertex (n,) of each vertex: exact position weld, then manifold3d's open-edge merge."""
    n = len(V)
    _, first, inverse = np.unique(V, axis=0, return_index=True, return_inverse=True)
    target = first[inverse.reshape(-1)]
    src = np.flatnonzero(target != np.arange(n))
    mesh = manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(V, dtype=np.float64),
        tri_verts=np.ascontiguousarray(F, dtype=np.uint64).reshape(-1, 3),
        merge_from_vert=np.ascontiguousarray(src, dtype=np.uint64),
        merge_to_vert=np.ascontiguousarray(target[src], dtype=np.uint64),
    )
    mesh.merge()
    target = np.arange(n)
    src = np.asarray(mesh.merge_from_vert, dtype=np.int64)
    target[src] = np.asarray(mesh.merge_to_vert, dtype=np.int64)
    for _ in range(64):  # chains a -> b -> c collapse to their end
        nxt = target[target]
        if np.array_equal(nxt, target):
            break
        target = nxt
    # The smallest referenced index of each group represents it (stable under input order).
    key = np.arange(n) + n
    key[np.unique(F)] -= n
    smallest = np.full(n, 2 * n, dtype=np.int64)
    np.minimum.at(smallest, target, key)
    return smallest[target] % n


def surface_solid(surface: SurfaceMesh, *, stage: str):
    """A closed surface as a manifold3d solid with uv/normal properties and one run id per material.

    Parameters
    ----------
    surface : SurfaceMesh
        A closed surface, normally the result of :func:`repair`; vertices are
        welded by position, attributes kept per split vertex.
    stage : str
        The calling stage, for error messages.

    Returns
    -------
    solid : manifold3d.Manifold
        Vertex properties (:data:`SOLID_COLUMNS`): position, uv, normal.
        Several overlapping positive bodies are united.
    id_to_material : dict of int -> int
        manifold3d run id -> index into ``surface.materials``.

    Raises
    ------
    StageError
        If the surface is not closed and manifold.
    """
    props = vertex_properties(surface, SOLID_COLUMNS)
    F = np.asarray(surface.faces, dtype=np.int64)
    weld = weld_map(props[:, :3], F)
    material_ids = np.asarray(surface.material_ids)
    if _nonmanifold_edges(weld[F]):
        # Bodies touching along an edge (a union result): weld each only within itself.
        patch = _manifold_patches(weld[F])[0]
        bodies = [np.flatnonzero(patch == p) for p in range(int(patch.max()) + 1)]
        props, F, material_ids, weld = _split_bodies(props, F, material_ids, weld, bodies)
    solid, id_to_material = _manifold(props, F, material_ids, weld, len(surface.materials))
    if solid.status() != manifold3d.Error.NoError:
        W = weld[F]
        boundary = len(_boundary_edges(W))
        raise StageError(
            f"the surface is not a closed solid ({solid.status().name}"
            + (f", {boundary} open edges" if boundary else "") + "); run the 'repair' stage on it first "
            "(e.g. 'fracture load IN repair cage ...'); 'bake' does this itself", stage=stage)
    solid, bodies, _ = _union_bodies(solid)
    if bodies > 1:
        log.info("%s: the surface has %d overlapping bodies; using their union", stage, bodies)
    return solid, id_to_material


def _union_bodies(solid):
    """Union the positive bodies of ``solid`` and subtract its cavities (negative-volume shells).

    Overlapping closed bodies stored as one mesh are resolved this way;
    manifold3d does not resolve them inside a single Manifold.

    Returns
    -------
    solid : manifold3d.Manifold
        Unchanged when it has at most one positive body.
    bodies : int
        How many positive bodies it had.
    cavities : int
        How many cavities were subtracted (0 when there was nothing to union).
    """
    parts = solid.decompose()
    positive = [p for p in parts if p.volume() > 0]
    if len(positive) <= 1:
        return solid, len(positive), 0
    cavities = [_reversed(p) for p in parts if p.volume() < 0]
    solid = manifold3d.Manifold.batch_boolean(positive, manifold3d.OpType.Add)
    if cavities:
        solid = solid - manifold3d.Manifold.batch_boolean(cavities, manifold3d.OpType.Add)
    return solid, len(positive), len(cavities)


# ----------------------------------------------------------------------------
# Topology

def _unique_faces(W: np.ndarray):
    """Keep mask (m,) without repeats of a face; a face and its reverse both go. Returns (keep, dups, pairs)."""
    m = len(W)
    if m == 0:
        return np.ones(0, dtype=bool), 0, 0
    key = np.sort(W, axis=1)
    # Orientation parity of each face relative to its sorted corners.
    rot = np.argmin(W, axis=1)
    rolled = np.stack([W[np.arange(m), (rot + k) % 3] for k in range(3)], axis=1)
    positive = rolled[:, 1] < rolled[:, 2]
    _, group, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    if counts.max() == 1:
        return np.ones(m, dtype=bool), 0, 0
    net = np.bincount(group, weights=np.where(positive, 1.0, -1.0))
    # Keep the first face of each group that has the group's majority orientation (none if balanced).
    candidate = (net[group] != 0) & ((net[group] > 0) == positive)
    first = np.full(len(counts), m, dtype=np.int64)
    np.minimum.at(first, group[candidate], np.flatnonzero(candidate))
    keep = np.zeros(m, dtype=bool)
    keep[first[first < m]] = True
    pairs = int(np.minimum(np.bincount(group, weights=positive), np.bincount(group, weights=~positive)).sum())
    duplicates = m - int(keep.sum()) - 2 * pairs
    return keep, duplicates, pairs


def _undirected_edges(W: np.ndarray):
    """Per corner edge (3m, 2) directed, its undirected id (3m,), and the face (3m,) it belongs to."""
    directed = np.concatenate([W[:, [0, 1]], W[:, [1, 2]], W[:, [2, 0]]])
    face = np.tile(np.arange(len(W)), 3)
    # One int64 key per undirected edge: 1-d unique is ~10x faster than unique over rows, same order.
    n = int(W.max()) + 1 if len(W) else 1
    key = np.minimum(directed[:, 0], directed[:, 1]) * n + np.maximum(directed[:, 0], directed[:, 1])
    _, edge_id = np.unique(key, return_inverse=True)
    return directed, edge_id.reshape(-1), face


def _nonmanifold_edges(W: np.ndarray) -> int:
    _, edge_id, _ = _undirected_edges(W)
    return int((np.bincount(edge_id) > 2).sum())


def _manifold_patches(W: np.ndarray):
    """Patch id (m,) of each face (faces joined across edges with exactly two faces), and edge data."""
    m = len(W)
    directed, edge_id, face = _undirected_edges(W)
    counts = np.bincount(edge_id)
    order = np.argsort(edge_id, kind="stable")
    pair = order[counts[edge_id[order]] == 2].reshape(-1, 2)
    graph = sp.coo_matrix((np.ones(len(pair)), (face[pair[:, 0]], face[pair[:, 1]])), shape=(m, m)).tocsr()
    _, patch = connected_components(graph, directed=False)
    return patch, edge_id, face, counts


def _split_bodies(props: np.ndarray, F: np.ndarray, material_ids: np.ndarray, weld: np.ndarray,
                  bodies: list[np.ndarray]):
    """Copy each body (an array of face indices) with its own vertices, welded only within the body.

    A face may belong to several bodies (it is copied); vertices of different
    bodies are never welded, so bodies that touch along an edge stay separate.
    """
    new_props, new_faces, new_ids, new_weld = [], [], [], []
    n = 0
    for faces in bodies:
        corners = F[faces]
        used, local = np.unique(corners, return_inverse=True)
        _, first, group = np.unique(weld[used], return_index=True, return_inverse=True)
        new_props.append(props[used])
        new_faces.append(n + local.reshape(-1, 3))
        new_weld.append(n + first[group.reshape(-1)])
        new_ids.append(material_ids[faces])
        n += len(used)
    return (np.vstack(new_props), np.vstack(new_faces), np.concatenate(new_ids).astype(np.int32),
            np.concatenate(new_weld))


def _split_nonmanifold(props, F, W, material_ids, weld):
    """Split edge fans of more than two faces into closed bodies that are united later.

    Faces are grouped into patches joined across two-face edges. A patch in
    which every edge has two of its faces is a closed body (two boxes touching
    along an edge). Open patches whose boundary runs only along edges of more
    than two faces, and which share that boundary exactly, close each other
    in consecutive pairs (cells sharing an internal wall: left + wall, wall +
    right). Returns the new props, faces, material ids and weld map, the
    number of many-face edges left touching unclosed patches, and a log note.
    """
    patch, edge_id, face, counts = _manifold_patches(W)
    num_patches = int(patch.max()) + 1
    many = counts > 2
    # Faces of each (patch, edge): 2 everywhere means the patch is closed.
    key = patch[face] * len(counts) + edge_id
    uniq, per = np.unique(key, return_counts=True)
    key_patch, key_edge = uniq // len(counts), uniq % len(counts)
    boundary_of = [[] for _ in range(num_patches)]
    for p, e in zip(key_patch[per == 1].tolist(), key_edge[per == 1].tolist()):
        boundary_of[p].append(e)
    odd = np.zeros(num_patches, dtype=bool)
    odd[key_patch[(per != 2)]] = True
    bodies, groups, leftover_patches = [], {}, []
    for p in range(num_patches):
        faces_p = np.flatnonzero(patch == p)
        if not odd[p]:
            bodies.append(faces_p)
        elif boundary_of[p] and all(many[e] for e in boundary_of[p]) and np.all(np.isin(
                key_edge[(key_patch == p) & (per != 2)], boundary_of[p])):
            groups.setdefault(tuple(sorted(boundary_of[p])), []).append(p)
        else:
            leftover_patches.append(p)
    paired = 0
    for members in groups.values():
        if len(members) < 2:
            leftover_patches += members
            continue
        for a, b in zip(members[:-1], members[1:]):
            bodies.append(np.concatenate([np.flatnonzero(patch == a), np.flatnonzero(patch == b)]))
            paired += 1
    touched = set()
    for p in leftover_patches:
        bodies.append(np.flatnonzero(patch == p))
        touched.update(e for e in key_edge[key_patch == p].tolist() if many[e])
    props, F, material_ids, weld = _split_bodies(props, F, material_ids, weld, bodies)
    note = (f"split {int(many.sum())} edges shared by more than two faces into {len(bodies)} bodies"
            + (f" ({paired} closed by pairing open patches along internal walls)" if paired else ""))
    return props, F, material_ids, weld, len(touched), note


def _internal_open_faces(V: np.ndarray, W: np.ndarray, weld: np.ndarray) -> np.ndarray:
    """Mask (m,) of faces of open components lying entirely inside a closed component (internal faces)."""
    m = len(W)
    component = _components(W, len(weld))
    num = int(component.max()) + 1
    directed, edge_id, face = _undirected_edges(W)
    open_face = np.bincount(edge_id)[edge_id] == 1
    is_open = np.zeros(num, dtype=bool)
    is_open[component[face[open_face]]] = True
    closed = np.flatnonzero(~is_open)
    inside = np.zeros(m, dtype=bool)
    if not len(closed):
        return inside
    for c in np.flatnonzero(is_open).tolist():
        verts = np.unique(W[component == c])
        samples = V[verts[np.linspace(0, len(verts) - 1, min(_NESTING_SAMPLES, len(verts))).astype(int)]]
        for k in closed.tolist():
            if np.all(np.abs(_winding_numbers(samples, V, W[component == k])) > 0.5):
                inside[component == c] = True
                break
    return inside


def _propagate_winding(W: np.ndarray):
    """Flip mask (m,) making winding consistent across edges shared by two faces, and patch id (m,) per face.

    A breadth-first spanning forest of the faces (edges: shared manifold
    edges) gives each face a path to its patch's root; the face is flipped when
    an odd number of steps on that path join faces that run their shared edge
    the same way. The parities are summed by pointer jumping (vectorized,
    O(m log m)). Each patch then keeps the winding most of its faces had.
    """
    m = len(W)
    directed, edge_id, face = _undirected_edges(W)
    counts = np.bincount(edge_id)
    order = np.argsort(edge_id, kind="stable")
    pair = order[counts[edge_id[order]] == 2].reshape(-1, 2)
    fa, fb = face[pair[:, 0]], face[pair[:, 1]]
    # Two faces agree when they run the shared edge in opposite directions.
    same = directed[pair[:, 0], 0] == directed[pair[:, 1], 0]
    graph = sp.coo_matrix((np.ones(len(fa)), (fa, fb)), shape=(m, m)).tocsr()
    num_patches, patch = connected_components(graph, directed=False)
    # A virtual root (node m) joined to the first face of every patch makes the forest one tree.
    first_face = np.full(num_patches, m, dtype=np.int64)
    np.minimum.at(first_face, patch, np.arange(m))
    rows = np.concatenate([fa, fb, np.full(num_patches, m)])
    cols = np.concatenate([fb, fa, first_face])
    tree = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(m + 1, m + 1)).tocsr()
    _, parent = breadth_first_order(tree, m, directed=True, return_predecessors=True)
    parent = parent.astype(np.int64)
    parent[m] = m
    # Parity of each tree step (face, parent).
    code = np.concatenate([fa * (m + 1) + fb, fb * (m + 1) + fa])
    step_same = np.concatenate([same, same])
    parity = np.zeros(m + 1, dtype=bool)
    if len(code):
        sorter = np.argsort(code, kind="stable")
        wanted = np.arange(m) * (m + 1) + parent[:m]
        at = np.minimum(np.searchsorted(code[sorter], wanted), len(code) - 1)
        parity[:m] = (code[sorter[at]] == wanted) & step_same[sorter[at]]
    jump = parent.copy()
    while np.any(jump != m):
        parity = parity ^ parity[jump]
        jump = jump[jump]
    flip = parity[:m]
    # Keep the winding most faces of the patch already have.
    flipped = np.bincount(patch, weights=flip, minlength=num_patches)
    sizes = np.bincount(patch, minlength=num_patches)
    flip = flip ^ (2 * flipped > sizes)[patch]
    return flip, patch


def _boundary_edges(W: np.ndarray) -> np.ndarray:
    """Directed edges (b, 2) used by exactly one face."""
    directed, edge_id, _ = _undirected_edges(W)
    return directed[np.bincount(edge_id)[edge_id] == 1]


def _boundary_edge_faces(W: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """The face (b,) of each boundary edge."""
    directed, _, face = _undirected_edges(W)
    n = int(W.max()) + 1
    code = directed[:, 0] * n + directed[:, 1]
    order = np.argsort(code, kind="stable")
    at = np.searchsorted(code[order], boundary[:, 0] * n + boundary[:, 1])
    return face[order[at]]


def _boundary_loops(boundary: np.ndarray) -> list[np.ndarray]:
    """Chain directed boundary edges (b, 2) into closed loops of vertex ids, in edge direction."""
    nxt: dict[int, list[int]] = {}
    for a, b in boundary.tolist():
        nxt.setdefault(a, []).append(b)
    loops = []
    visited = set()
    for a0, b0 in boundary.tolist():
        if (a0, b0) in visited:
            continue
        loop = [a0]
        a, b = a0, b0
        while True:
            visited.add((a, b))
            if b == a0:
                break
            loop.append(b)
            following = [c for c in nxt.get(b, []) if (b, c) not in visited]
            if not following:
                raise StageError("the mesh's holes are not simple loops (a boundary vertex is pinched or the "
                                 "winding is not orientable); close the mesh in your modelling tool", stage=STAGE)
            a, b = b, following[0]
        loops.append(np.array(loop, dtype=np.int64))
    return loops


def _components(W: np.ndarray, n: int) -> np.ndarray:
    """Component id (m,) of each face: faces sharing a welded vertex are connected."""
    m = len(W)
    incidence = sp.coo_matrix((np.ones(3 * m), (np.repeat(np.arange(m), 3), W.reshape(-1))), shape=(m, n))
    graph = sp.bmat([[None, incidence], [incidence.T, None]])
    _, labels = connected_components(graph, directed=False)
    _, component = np.unique(labels[:m], return_inverse=True)
    return component.reshape(-1)


# ----------------------------------------------------------------------------
# Geometry

def _face_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)


def _fan_area(P: np.ndarray) -> float:
    """Area of the fan closing a loop (k, 3) around its centroid."""
    c = P.mean(axis=0)
    return float(0.5 * np.linalg.norm(np.cross(P - c, np.roll(P, -1, axis=0) - c), axis=1).sum())


def _is_flat(P: np.ndarray) -> bool:
    if len(P) < 4:
        return True
    s = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    return bool(s[0] == 0 or s[2] <= _FLAT * s[0])


def _tet_volumes(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0


def _normals_by_position(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted normals (n, 3) averaged over vertices sharing a position."""
    _, pos = np.unique(V, axis=0, return_inverse=True)
    pos = pos.reshape(-1)
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    acc = np.zeros((pos.max() + 1 if len(pos) else 0, 3))
    for k in range(3):
        np.add.at(acc, pos[F[:, k]], fn)
    n = acc[pos]
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def _welded_normals(V: np.ndarray, W: np.ndarray, n: int) -> np.ndarray:
    """Unit area-weighted normals (n, 3) at welded vertices of faces W."""
    fn = np.cross(V[W[:, 1]] - V[W[:, 0]], V[W[:, 2]] - V[W[:, 0]])
    acc = np.zeros((n, 3))
    for k in range(3):
        np.add.at(acc, W[:, k], fn)
    return acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-300)


def _winding_numbers(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Generalized winding number (p,) of points with respect to a triangle set (solid angles / 4 pi)."""
    out = np.zeros(len(points))
    for i, p in enumerate(points):
        a, b, c = V[F[:, 0]] - p, V[F[:, 1]] - p, V[F[:, 2]] - p
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
        num = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb
               + np.einsum("ij,ij->i", b, c) * la)
        out[i] = 2.0 * np.arctan2(num, den).sum() / (4.0 * np.pi)
    return out


def _component_orientation(V: np.ndarray, F: np.ndarray, component: np.ndarray) -> np.ndarray:
    """Flip flag (c,) per closed component: positive volume, or negative when nested in another (a cavity)."""
    num = int(component.max()) + 1
    volume = np.bincount(component, weights=_tet_volumes(V, F), minlength=num)
    depth = np.zeros(num, dtype=np.int64)
    container = np.full(num, -1, dtype=np.int64)  # the smallest component containing each
    if num > 1:
        lo = np.full((num, 3), np.inf)
        hi = np.full((num, 3), -np.inf)
        for k in range(3):
            np.minimum.at(lo, component, V[F[:, k]])
            np.maximum.at(hi, component, V[F[:, k]])
        for i in range(num):
            inside_box = np.all((lo <= lo[i]) & (hi >= hi[i]), axis=1)
            inside_box[i] = False
            candidates = np.flatnonzero(inside_box)
            if not len(candidates):
                continue
            verts = np.unique(F[component == i])
            samples = V[verts[np.linspace(0, len(verts) - 1, min(_NESTING_SAMPLES, len(verts))).astype(int)]]
            for j in candidates.tolist():
                w = _winding_numbers(samples, V, F[component == j])
                if np.all(np.abs(w) > 0.5):
                    depth[i] += 1
                    if container[i] < 0 or abs(volume[j]) < abs(volume[container[i]]):
                        container[i] = j
    # A nested component wound against its container (as given) is a cavity; wound like it, it is
    # internal geometry of the same solid (the union absorbs it). Outermost components are positive.
    order = np.argsort(depth, kind="stable")
    positive = np.ones(num, dtype=bool)
    for i in order.tolist():
        if container[i] >= 0:
            j = container[i]
            same = (volume[i] > 0) == (volume[j] > 0)
            positive[i] = positive[j] if same else not positive[j]
    return (volume > 0) != positive


def _fix_shading_normals(props: np.ndarray, F: np.ndarray) -> int:
    """Flip vertex normals (in place) that point against their own faces; returns how many."""
    V = props[:, _POS]
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    acc = np.zeros((len(props), 3))
    for k in range(3):
        np.add.at(acc, F[:, k], fn)
    against = np.einsum("ij,ij->i", acc, props[:, _NORMAL]) < 0
    props[against, _NORMAL] *= -1.0
    return int(against.sum())


def _sheet_orientation(props: np.ndarray, F: np.ndarray, patch: np.ndarray, sheet: np.ndarray) -> np.ndarray:
    """Flip mask (m,) orienting each open patch so its winding agrees with its shading normals."""
    V = props[:, _POS]
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    shading = props[F[:, 0], _NORMAL] + props[F[:, 1], _NORMAL] + props[F[:, 2], _NORMAL]
    agreement = np.bincount(patch, weights=np.einsum("ij,ij->i", fn, shading) * sheet, minlength=patch.max() + 1)
    return sheet & (agreement[patch] < 0)


# ----------------------------------------------------------------------------
# Closing

def _interior_slot(materials: tuple[Material, ...]):
    """Index of the interior material (the input's own, or a new last slot) and the material tuple."""
    for i, m in enumerate(materials):
        if m.name == INTERIOR_MATERIAL_NAME:
            return i, materials
    return len(materials), materials + (Material(INTERIOR_MATERIAL_NAME, base_color=_INTERIOR_COLOR),)


def _plane_uvs(P: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Planar UVs (k, 2) of points on a plane with unit ``normal``."""
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    return np.column_stack([P @ u, P @ v])


def _axis_uvs(P: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """UVs (k, 2) projecting each point along its normal's dominant axis."""
    axis = np.argmax(np.abs(normals), axis=1)
    u_axis = np.array([1, 0, 0])[axis]
    v_axis = np.array([2, 2, 1])[axis]
    rows = np.arange(len(P))
    return np.column_stack([P[rows, u_axis], P[rows, v_axis]])


def _fill(props, F, W, material_ids, weld, loops, interior_material):
    """Close each loop with a fan around its centroid; cap vertices are copies welded to the loop's."""
    new_props, new_faces, new_weld = [], [], []
    n = len(props)
    for loop in loops:
        P = props[loop, _POS]
        centre = P.mean(axis=0)
        following = np.roll(loop, -1)
        # Boundary edges run loop[j] -> loop[j+1] in the surface; the cap runs them the other way.
        area_vector = np.cross(props[following, _POS] - centre, P - centre).sum(axis=0)
        normal = area_vector / max(np.linalg.norm(area_vector), 1e-300)
        k = len(loop)
        block = np.zeros((k + 1, _NUM_COLUMNS))
        block[:k, _POS] = P
        block[k, _POS] = centre
        block[:, _NORMAL] = normal
        block[:, _UV] = _plane_uvs(block[:, _POS], normal)
        block[:k, _COLOR] = props[loop, _COLOR]
        block[k, _COLOR] = props[loop, _COLOR].mean(axis=0)
        ids = n + np.arange(k + 1)
        local = np.arange(k)
        new_faces.append(np.stack([ids[np.roll(local, -1)], ids[local], np.full(k, ids[k])], axis=1))
        new_weld.append(np.append(loop, ids[k]))
        new_props.append(block)
        n += k + 1
    cap_faces = np.concatenate(new_faces)
    weld = np.concatenate([weld] + new_weld)
    props = np.vstack([props] + new_props)
    F = np.vstack([F, cap_faces])
    W = np.vstack([W, weld[cap_faces]])
    material_ids = np.concatenate([material_ids, np.full(len(cap_faces), interior_material, np.int32)])
    return props, F, W, material_ids, weld


def _free_distance(V: np.ndarray, F: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance (k,) along each ray to the first face hit (inf if none)."""
    from fracture_cli._open3d import open3d as _import_open3d

    o3d = _import_open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    rays = np.hstack([origins, directions]).astype(np.float32)
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)


def _shell(props, F, W, material_ids, weld, sheet, boundary, thickness, interior_material):
    """Thicken the sheet faces (mask ``sheet``) into a closed slab on their inner side."""
    n = len(props)
    V = props[:, _POS]
    sheet_faces = F[sheet]
    sheet_welded = W[sheet]
    normal = _welded_normals(V, sheet_welded, n)
    used = np.unique(sheet_welded)
    # Free distance behind each sheet vertex: to the opposite wall, or to where the sheet folds back.
    eps = 1e-6
    free = _free_distance(V, W, V[used] - eps * normal[used], -normal[used]) + eps
    t = np.zeros(n)
    t[used] = np.minimum(thickness, _RAY_FRACTION * free)
    original_fn = np.cross(V[sheet_welded[:, 1]] - V[sheet_welded[:, 0]], V[sheet_welded[:, 2]] - V[sheet_welded[:, 0]])
    for _ in range(12):
        offset = V - t[:, None] * normal
        fn = np.cross(offset[sheet_welded[:, 1]] - offset[sheet_welded[:, 0]],
                      offset[sheet_welded[:, 2]] - offset[sheet_welded[:, 0]])
        bad = np.einsum("ij,ij->i", fn, original_fn) <= 0
        if not bad.any():
            break
        t[np.unique(sheet_welded[bad])] *= 0.5
    else:
        raise StageError(f"cannot thicken the open sheet by {thickness:g}: it folds too tightly (offset faces "
                         "keep flipping); use --set repair.open_surface=fill, or a smaller repair.shell_thickness",
                         stage=STAGE)
    if t[used].min() < _MIN_THICKNESS_FRACTION * thickness:
        raise StageError(f"cannot thicken the open sheet by {thickness:g}: at some vertices it has only "
                         f"{t[used].min():.2g} of free space behind it (touching or folded parts); separate them, "
                         "or use --set repair.open_surface=fill", stage=STAGE)
    thinned = int((t[used] < thickness * (1 - 1e-9)).sum())

    # Offset copy of every split vertex of the sheet: same attributes, normal reversed, interior material.
    split_used = np.unique(sheet_faces)
    offset_index = np.full(n, -1, dtype=np.int64)
    offset_index[split_used] = n + np.arange(len(split_used))
    offset_props = props[split_used].copy()
    rep = weld[split_used]
    offset_props[:, _POS] = V[rep] - t[rep, None] * normal[rep]
    offset_props[:, _NORMAL] *= -1.0
    # Copies weld to the first copy made at their position.
    _, first = np.unique(rep, return_index=True)
    group_offset = np.full(n, -1, dtype=np.int64)
    group_offset[rep[first]] = offset_index[split_used[first]]
    offset_weld = group_offset[rep]
    offset_faces = offset_index[sheet_faces][:, ::-1]

    # Strip along the boundary: its own vertex copies (normals across the strip), welded to sheet and offset.
    m0 = n + len(split_used)
    a, b = boundary[:, 0], boundary[:, 1]
    ends = np.unique(boundary)
    strip_index = np.full(n, -1, dtype=np.int64)
    strip_index[ends] = m0 + np.arange(len(ends))
    strip_offset_index = np.full(n, -1, dtype=np.int64)
    strip_offset_index[ends] = m0 + len(ends) + np.arange(len(ends))
    strip_props = np.zeros((2 * len(ends), _NUM_COLUMNS))
    strip_props[: len(ends), _POS] = V[ends]
    strip_props[len(ends):, _POS] = V[ends] - t[ends, None] * normal[ends]
    strip_props[:, _COLOR] = np.tile(props[ends, _COLOR], (2, 1))
    sa, sb = strip_index[a], strip_index[b]
    oa, ob = strip_offset_index[a], strip_offset_index[b]
    strip_faces = np.concatenate([np.stack([sb, sa, oa], axis=1), np.stack([sb, oa, ob], axis=1)])
    strip_weld = np.concatenate([ends, group_offset[ends]])

    props = np.vstack([props, offset_props, strip_props])
    P = props[:, _POS]
    fn = np.cross(P[strip_faces[:, 1]] - P[strip_faces[:, 0]], P[strip_faces[:, 2]] - P[strip_faces[:, 0]])
    acc = np.zeros((len(props), 3))
    for k in range(3):
        np.add.at(acc, strip_faces[:, k], fn)
    strip_rows = slice(m0, len(props))
    props[strip_rows, _NORMAL] = acc[strip_rows] / np.maximum(np.linalg.norm(acc[strip_rows], axis=1,
                                                                             keepdims=True), 1e-300)
    props[strip_rows, _UV] = _axis_uvs(props[strip_rows, _POS], props[strip_rows, _NORMAL])
    weld = np.concatenate([weld, offset_weld, strip_weld])
    added = np.vstack([offset_faces, strip_faces])
    F = np.vstack([F, added])
    W = np.vstack([W, weld[added]])
    material_ids = np.concatenate([material_ids, np.full(len(added), interior_material, np.int32)])
    return props, F, W, material_ids, weld, thinned


# ----------------------------------------------------------------------------
# manifold3d

def _manifold(props: np.ndarray, F: np.ndarray, material_ids: np.ndarray, weld: np.ndarray, num_materials: int):
    """A manifold3d solid from split vertices, their weld map, and one run (original id) per material."""
    order = np.argsort(material_ids, kind="stable")
    F = F[order]
    material_ids = np.asarray(material_ids)[order]
    first_id = manifold3d.Manifold.reserve_ids(num_materials)
    id_to_material = {first_id + i: i for i in range(num_materials)}
    used = np.unique(material_ids)
    run_index = np.append(np.searchsorted(material_ids, used), len(F)) * 3
    src = np.flatnonzero(weld != np.arange(len(weld)))
    mesh = manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(props, dtype=np.float64),
        tri_verts=np.ascontiguousarray(F, dtype=np.uint64),
        merge_from_vert=np.ascontiguousarray(src, dtype=np.uint64),
        merge_to_vert=np.ascontiguousarray(weld[src], dtype=np.uint64),
        run_index=np.ascontiguousarray(run_index, dtype=np.uint64),
        run_original_id=np.ascontiguousarray(first_id + used, dtype=np.uint32),
    )
    return manifold3d.Manifold(mesh), id_to_material


def _reversed(part):
    """The same manifold3d body with every triangle reversed (a cavity as a positive solid)."""
    mesh = part.to_mesh64()
    tris = np.asarray(mesh.tri_verts, dtype=np.uint64).reshape(-1, 3)[:, ::-1]
    flipped = manifold3d.Mesh64(
        vert_properties=np.asarray(mesh.vert_properties, dtype=np.float64),
        tri_verts=np.ascontiguousarray(tris),
        merge_from_vert=np.asarray(mesh.merge_from_vert, dtype=np.uint64),
        merge_to_vert=np.asarray(mesh.merge_to_vert, dtype=np.uint64),
        run_index=np.asarray(mesh.run_index, dtype=np.uint64),
        run_original_id=np.asarray(mesh.run_original_id, dtype=np.uint32),
    )
    return manifold3d.Manifold(flipped)


def _from_manifold(solid, id_to_material: dict):
    """Split-vertex properties (n, 12), faces (m, 3) and material ids (m,) of a manifold3d result."""
    mesh = solid.to_mesh64()
    props = np.array(mesh.vert_properties, dtype=np.float64)
    F = np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)
    run_index = np.asarray(mesh.run_index, dtype=np.int64) // 3
    run_ids = np.asarray(mesh.run_original_id, dtype=np.int64)
    material_ids = np.empty(len(F), dtype=np.int32)
    for r, original in enumerate(run_ids.tolist()):
        material_ids[run_index[r]:run_index[r + 1]] = id_to_material[original]
    # Merge vectors mark vertices that are one point: give them one position exactly.
    src = np.asarray(mesh.merge_from_vert, dtype=np.int64)
    props[src, _POS] = props[np.asarray(mesh.merge_to_vert, dtype=np.int64), _POS]
    return props, F, material_ids


def _compact(props: np.ndarray, F: np.ndarray):
    """Drop unreferenced vertices, keeping order."""
    used = np.unique(F)
    if len(used) == len(props):
        return props, F
    remap = np.full(len(props), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return props[used], remap[F]
