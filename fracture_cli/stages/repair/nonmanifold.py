"""Split non-manifold edges and vertices into closed, edge-manifold bodies.

Where more than two faces meet at an edge (two bodies touching along a line,
teeth sharing an edge with a hub, cells sharing an internal wall), the faces
are paired up by their angular order around the edge and their orientation:
going around the edge, each face has material on one side, so consecutive
faces bound alternately a wedge of material and a wedge of empty space. The
two faces of each material wedge belong to the same body and are glued across
the edge; the others are not. Vertices are then copied once per fan of faces
glued around them, which also separates bodies that touch only at a point.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fracture_cli.geometry import tolerances as tol
from fracture_cli.geometry.edges import EdgeTable, corner_fans, edge_table, face_bodies, signed_volume
from fracture_cli.stages.repair.records import RepairRecord
from fracture_cli.system import detmath

# Rounds of doubling internal walls (faces with material on both sides) before giving up.
_MAX_WALL_ROUNDS = 4


@dataclass(frozen=True)
class NonManifoldSplit:
    """Result of :func:`split_nonmanifold`.

    Attributes
    ----------
    vertices : (n2, 3) float64
        Positions of the output vertices: the input's (same ids), then the
        extra copies of split vertices.
    source_vertex : (n2,) int64
        The input vertex each output vertex is a copy of.
    faces : (m2, 3) int64
        Output faces: every input face once, in input order, then reversed
        copies of internal-wall faces.
    source_corner : (m2, 3) int64
        For every output corner, the input corner ``3 f + k`` it comes from
        (to carry per-corner attributes such as UVs).
    body : (m2,) int64
        Body id of every output face (faces glued across edges).
    body_closed : (b,) bool
        Whether every edge of the body has exactly two of its faces.
    body_volume : (b,) float64
        Signed volume of each body (meaningful where closed).
    unresolved_edges : (k, 2) int64
        Input vertex pairs of edges whose faces do not alternate between
        material and empty wedges even after doubling walls: no inside there.
    records : list of RepairRecord
    """

    vertices: np.ndarray
    source_vertex: np.ndarray
    faces: np.ndarray
    source_corner: np.ndarray
    body: np.ndarray
    body_closed: np.ndarray
    body_volume: np.ndarray
    unresolved_edges: np.ndarray
    records: list[RepairRecord] = field(default_factory=list)
    edges: EdgeTable | None = None  # edge_table(faces)

    @property
    def source_face(self) -> np.ndarray:
        """Input face (m2,) of every output face."""
        return self.source_corner[:, 0] // 3


def _edge_fan(V: np.ndarray, F: np.ndarray, table: EdgeTable, sides: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sides of one edge sorted by angle around it, and their orientation (+1: the side runs ends[0] -> ends[1]).

    A +1 face has its outside towards increasing angle (right-handed about
    ends[0] -> ends[1]) and its material behind; a -1 face the reverse.
    Coincident faces (equal angles) are ordered +1 first, so the wedge between
    them is empty.
    """
    a, b = table.ends[table.edge[sides[0]]]
    axis = V[b] - V[a]
    axis = axis / np.linalg.norm(axis)
    faces = F[table.face[sides]]
    third = faces[(faces != a) & (faces != b)]
    w = V[third] - V[a]
    w = w - np.outer(w @ axis, axis)
    u = w[0] / max(np.linalg.norm(w[0]), tol.SMALLEST_DIVISOR)
    angle = detmath.atan2(w @ np.cross(axis, u), w @ u)
    angle = np.where(angle < 0, angle + 2 * np.pi, angle)
    # Faces around the edge whose angles differ by less than TIE (radians) are coincident: the wedge between them
    # is taken to be empty (two bodies touching face to face), never a sheet of material of zero thickness.
    angle = np.where(angle > 2 * np.pi - tol.TIE, 0.0, angle)
    sign = np.where(table.forward[sides], 1, -1)
    # Angles within TIE are one angle; there the +1 face comes first.
    order = np.lexsort((-sign, np.round(angle / tol.TIE)))
    return sides[order], sign[order]


def _pair_fan(sides: np.ndarray, sign: np.ndarray) -> tuple[list[tuple[int, int]], list[int]]:
    """Material-wedge side pairs of one sorted fan, and the sides that must be walls (material on both sides)."""
    k = len(sides)
    pairs, walls = [], []
    for i in range(k):
        j = (i + 1) % k
        if sign[i] == -1 and sign[j] == 1:
            pairs.append((int(sides[i]), int(sides[j])))
        elif sign[i] == sign[j]:
            walls.append(int(sides[i] if sign[i] == 1 else sides[j]))
    return pairs, walls


def _pair_within_patches(sides: np.ndarray, sign: np.ndarray, patch: np.ndarray) -> list[tuple[int, int]] | None:
    """Side pairs gluing each patch's own two faces at an edge, or None unless every patch has one of each sign.

    Used where the wedges around an edge overlap (two closed bodies that
    interpenetrate there, e.g. fragments of a baked GLB after rounding): each
    body stays closed on its own and the union resolves the overlap.
    """
    pairs = []
    for p in np.unique(patch).tolist():
        mine = patch == p
        if mine.sum() != 2 or sign[mine].sum() != 0:
            return None
        a, b = sides[mine]
        pairs.append((int(a), int(b)))
    return pairs


def _glue(V: np.ndarray, F: np.ndarray, table: EdgeTable) -> tuple[np.ndarray, set[int], list[int]]:
    """Glued side pairs (g, 2) of every edge, the wall faces found, and the unresolved many-face edges."""
    glued = [table.manifold_pairs()]
    order, start = table.sides_of_edges()
    patch = None  # the manifold patches, found when a fan has a wall
    walls: set[int] = set()
    unresolved = []
    for e in np.flatnonzero(table.count > 2).tolist():
        sides, sign = _edge_fan(V, F, table, order[start[e]:start[e + 1]])
        pairs, wall_sides = _pair_fan(sides, sign)
        if wall_sides:
            patch = face_bodies(table) if patch is None else patch
            own = _pair_within_patches(sides, sign, patch[table.face[sides]])
            if own is not None:
                glued.append(np.array(own, dtype=np.int64))
                continue
            walls.update(int(table.face[s]) for s in wall_sides)
            unresolved.append(e)
        elif pairs:
            glued.append(np.array(pairs, dtype=np.int64))
    return np.vstack(glued), walls, unresolved


def split_nonmanifold(vertices: np.ndarray, faces: np.ndarray, table: EdgeTable | None = None) -> NonManifoldSplit:
    """Split edges with more than two faces, and vertices with several fans, into closed manifold bodies.

    Parameters
    ----------
    vertices : (n, 3) float
        Positions, welded (one vertex per position).
    faces : (m, 3) int
        Triangles, each body oriented outward (its faces' normals point away
        from its material); degenerate faces removed.
    table : EdgeTable, optional
        ``edge_table(faces)`` if the caller has it.

    Returns
    -------
    NonManifoldSplit
        Every output body is edge- and vertex-manifold; it is closed when its
        faces around every split edge paired up. Faces shared by two cells
        (internal walls: material on both sides) are doubled, one copy per
        cell. Bodies left open, and edges that cannot be paired, have no
        well-defined inside and are listed in ``records``.

    Notes
    -----
    Around an edge, sorted by angle, a face oriented along the edge has its
    outside towards increasing angle, one oriented against it towards
    decreasing angle. A valid solid alternates: (-1, +1) pairs bound material
    and are glued, (+1, -1) pairs bound empty space. Two +1 faces in a row mean
    the first has material on both sides (an internal wall), two -1 faces in a
    row the second; such faces, with their whole manifold patch, get a
    reversed copy, and the pairing is redone.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F_in = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    F = F_in.copy()
    source_corner = np.arange(3 * len(F), dtype=np.int64).reshape(-1, 3)
    doubled = np.zeros(len(F), dtype=bool)  # input faces that have a reversed copy
    given = table
    for _ in range(_MAX_WALL_ROUNDS):
        table = given if given is not None and len(F) == len(F_in) else edge_table(F)  # no walls doubled yet
        glued, walls, unresolved = _glue(V, F, table)
        if not walls:
            break
        # A wall is a whole manifold patch (its faces joined across two-face edges); each gets one copy.
        patch = face_bodies(table)
        wall = np.isin(patch[:len(F_in)], patch[sorted(walls)]) & ~doubled
        if not wall.any():
            break
        doubled |= wall
        F = np.vstack([F, F_in[wall][:, ::-1]])
        source_corner = np.vstack([source_corner, source_corner[:len(F_in)][wall][:, ::-1]])
    else:
        table = edge_table(F)
        glued, walls, unresolved = _glue(V, F, table)
    return _assemble(V, F, source_corner, table, glued, unresolved, int(doubled.sum()))


def _assemble(V: np.ndarray, F: np.ndarray, source_corner: np.ndarray, table: EdgeTable, glued: np.ndarray,
              unresolved: list[int], doubled: int) -> NonManifoldSplit:
    """Copy vertices per fan, find bodies, and write the records."""
    fans = corner_fans(F, table, glued)
    _, first, fan = np.unique(fans, return_index=True, return_inverse=True)
    fan_vertex = F.reshape(-1)[first]
    # A vertex's first fan keeps its id; further fans get new ids after the input's vertices.
    primary = np.zeros(len(first), dtype=bool)
    primary[np.unique(fan_vertex, return_index=True)[1]] = True
    fan_id = np.where(primary, fan_vertex, 0)
    fan_id[~primary] = len(V) + np.arange(int((~primary).sum()))
    faces_out = fan_id[fan.reshape(-1)].reshape(-1, 3)
    source_vertex = np.concatenate([np.arange(len(V)), fan_vertex[~primary]])
    vertices_out = V[source_vertex]
    body = face_bodies(table, glued)
    num_bodies = int(body.max()) + 1 if len(body) else 0
    # Without copied vertices the output faces are the input's: so is their edge table.
    out_table = table if primary.all() and np.array_equal(faces_out, F) else edge_table(faces_out)
    open_edge_faces = out_table.face[out_table.count[out_table.edge] != 2]
    body_closed = np.ones(num_bodies, dtype=bool)
    body_closed[body[open_edge_faces]] = False
    body_volume = np.array([signed_volume(vertices_out, faces_out[body == i]) for i in range(num_bodies)])
    split_edges = int((table.count > 2).sum()) - len(unresolved)
    copies = np.bincount(fan_vertex, minlength=len(V))
    records = []
    if split_edges:
        records.append(RepairRecord("split_nonmanifold_edges", f"split {split_edges} edges shared by more than two "
                                    "faces (bodies touching along an edge) into closed bodies", count=split_edges))
    if (copies > 1).any():
        records.append(RepairRecord("split_nonmanifold_vertices", f"separated bodies touching at "
                                    f"{int((copies > 1).sum())} vertices (one copy of each per body)",
                                    count=int((copies > 1).sum())))
    if doubled:
        records.append(RepairRecord("doubled_wall_faces", f"doubled {doubled} faces of internal walls (material on "
                                    "both sides): one copy for each cell", count=doubled))
    for i in np.flatnonzero(~body_closed).tolist():
        where = tuple(float(x) for x in vertices_out[np.unique(faces_out[body == i])].mean(axis=0))
        records.append(RepairRecord("unclosed_body", f"body {i} ({int((body == i).sum())} faces) is not closed after "
                                    "splitting: it has no inside", count=int((body == i).sum()), where=where))
    ends = table.ends[np.asarray(unresolved, dtype=np.int64)] if unresolved else np.zeros((0, 2), dtype=np.int64)
    if len(ends):
        records.append(RepairRecord("unresolved_nonmanifold_edges", f"{len(ends)} edges shared by more than two faces "
                                    "whose faces do not bound alternating solid and empty wedges", count=len(ends),
                                    where=tuple(float(x) for x in V[ends[0]].mean(axis=0))))
    return NonManifoldSplit(vertices=vertices_out, source_vertex=source_vertex, faces=faces_out,
                            source_corner=source_corner, body=body, body_closed=body_closed, body_volume=body_volume,
                            unresolved_edges=ends, records=records, edges=out_table)
