"""Is a mesh, as written, a closed manifold body? Checked on positions welded by exact equality.

The bake writes each fragment's positions as float32 relative to the
fragment's pivot. Two vertices that differ in float64 can become one there
(and a face degenerate, or an edge shared by four faces), so the check runs on
the positions exactly as they will be stored: :func:`as_written` makes them,
:func:`check_mesh` checks them. The report may say ``watertight: true`` only
when :attr:`MeshCheck.closed` holds for every fragment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fracture_cli.geometry.edges import corner_fans, edge_table, face_bodies, signed_volume, weld_by_position
from fracture_cli.geometry.rows import unique_inverse


@dataclass(frozen=True)
class MeshCheck:
    """Topology and volume of one mesh welded by position.

    Attributes
    ----------
    faces : int
        Triangles checked.
    open_edges : int
        Edges with one face.
    pinched_edges : int
        Edges with more than two faces (typically four: two bodies, or one body
        touching itself, along a line).
    misoriented_edges : int
        Two-face edges run in the same direction by both faces.
    degenerate_faces : int
        Faces with two corners at one position.
    pinched_vertices : int
        Vertices whose faces form several fans (bodies touching at a point).
    bodies : int
        Groups of faces connected across two-face edges.
    volume : float
        Signed enclosed volume (in the positions' units cubed).
    """

    faces: int
    open_edges: int
    pinched_edges: int
    misoriented_edges: int
    degenerate_faces: int
    pinched_vertices: int
    bodies: int
    volume: float

    @property
    def watertight(self) -> bool:
        """Every edge in exactly two faces of opposite orientation, no degenerate face, positive volume.

        Bodies touching only at a vertex pass; several separate bodies pass
        too (see :attr:`bodies` and :attr:`closed`).
        """
        return (self.open_edges == 0 and self.pinched_edges == 0 and self.misoriented_edges == 0
                and self.degenerate_faces == 0 and self.volume > 0)

    @property
    def closed(self) -> bool:
        """Closed, edge-manifold, consistently oriented, one body, positive volume (pinched vertices allowed)."""
        return (self.open_edges == 0 and self.pinched_edges == 0 and self.misoriented_edges == 0
                and self.degenerate_faces == 0 and self.bodies == 1 and self.volume > 0)

    def problems(self) -> list[str]:
        """Short phrases naming what is wrong (empty when :attr:`closed`)."""
        out = [f"{n} {label}" for n, label in ((self.open_edges, "open edges"),
                                                (self.pinched_edges, "edges shared by more than two faces"),
                                                (self.misoriented_edges, "edges with inconsistent winding"),
                                                (self.degenerate_faces, "degenerate faces")) if n]
        if self.bodies != 1:
            out.append(f"{self.bodies} separate bodies")
        if not self.volume > 0:
            out.append(f"volume {self.volume:.3g}")
        return out


def as_written(world: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Positions (n, 3) float64 exactly as a GLB stores them: ``world - origin`` rounded to float32.

    ``origin`` is the node's translation (the fragment's pivot), subtracted in
    float64 as the writer does.
    """
    local = np.asarray(world, dtype=np.float64) - np.asarray(origin, dtype=np.float64)
    return local.astype(np.float32).astype(np.float64)


def collapsed(W: np.ndarray) -> np.ndarray:
    """Faces (m,) bool of ``W`` (m, 3) with two corners at one (welded) vertex."""
    return (W[:, 0] == W[:, 1]) | (W[:, 1] == W[:, 2]) | (W[:, 2] == W[:, 0])


def check_mesh(positions: np.ndarray, faces: np.ndarray,
               welded: tuple[np.ndarray, np.ndarray] | None = None) -> MeshCheck:
    """Check a mesh welded by exact position.

    Parameters
    ----------
    positions : (n, 3) float
        Vertex positions; vertices with equal coordinates are one vertex.
    faces : (m, 3) int
        Triangles; all of a fragment's primitives together.
    welded : (unique (u, 3) float, index (n,) int), optional
        ``weld_by_position(positions)`` when the caller has it already (default: computed here).

    Returns
    -------
    MeshCheck
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    unique, index = welded if welded is not None else weld_by_position(positions)
    W = index[faces]
    degenerate = collapsed(W)
    W = W[~degenerate]
    if len(W) == 0:
        return MeshCheck(len(faces), 0, 0, 0, int(degenerate.sum()), 0, 0, 0.0)
    table = edge_table(W)
    two = table.count == 2
    fans = corner_fans(W, table)
    # Distinct (vertex, fan) pairs as one number each (fan ids are small non-negative integers): a row-wise
    # np.unique of the pairs took seconds per million corners.
    stride = int(fans.max()) + 1
    vertex_fans = unique_inverse(W.reshape(-1).astype(np.int64) * stride + fans)[0] // stride
    return MeshCheck(
        faces=len(faces),
        open_edges=int((table.count == 1).sum()),
        pinched_edges=int((table.count > 2).sum()),
        misoriented_edges=int((two & (table.balance() != 0)).sum()),
        degenerate_faces=int(degenerate.sum()),
        pinched_vertices=int((np.bincount(vertex_fans) > 1).sum()),
        bodies=int(face_bodies(table).max()) + 1,
        volume=signed_volume(unique, W),
    )
