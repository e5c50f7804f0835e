"""Frozen dataclasses that flow through the pipeline.

Data flows one way: file -> SurfaceMesh -> Cage -> TetMesh -> Modes -> Pieces ->
Regions -> Fragments -> files. All geometry inside the pipeline is in
*normalized* coordinates (ALGORITHM.md section 0): centred on the bounding-box
centre and scaled to a unit bounding-box diagonal. :class:`Normalization` maps
back to the input's units on export.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # scipy only for annotations: importing it costs ~0.15 s of every start-up
    import scipy.sparse as sp


@dataclass(frozen=True)
class Normalization:
    """Similarity transform from normalized to input ("world") coordinates.

    ``world = normalized * scale + center``.

    Attributes
    ----------
    center : (3,) float
        Bounding-box centre of the input, in input units.
    scale : float
        Bounding-box diagonal of the input, in input units (> 0).
    """

    center: np.ndarray
    scale: float

    @classmethod
    def identity(cls) -> Normalization:
        return cls(center=np.zeros(3), scale=1.0)

    @classmethod
    def from_points(cls, points: np.ndarray) -> Normalization:
        """Normalization that centres ``points`` (n, 3) and gives them a unit diagonal."""
        lo, hi = points.min(axis=0), points.max(axis=0)
        diagonal = float(np.linalg.norm(hi - lo))
        return cls(center=(lo + hi) / 2.0, scale=diagonal if diagonal > 0 else 1.0)

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Map normalized points (n, 3) to input units."""
        return np.asarray(points, dtype=np.float64) * self.scale + self.center

    def to_normalized(self, points: np.ndarray) -> np.ndarray:
        """Map input-unit points (n, 3) to normalized coordinates."""
        return (np.asarray(points, dtype=np.float64) - self.center) / self.scale

    def matrix(self) -> np.ndarray:
        """The (4, 4) homogeneous matrix of :meth:`to_world`."""
        m = np.eye(4)
        m[:3, :3] *= self.scale
        m[:3, 3] = self.center
        return m


@dataclass(frozen=True)
class Material:
    """A surface material slot.

    Attributes
    ----------
    name : str
        Material name, unique within a mesh.
    base_color : (4,) float
        RGBA in [0, 1], used when no texture is carried.
    source : object, optional
        The loader's own material object (e.g. a trimesh PBRMaterial with its
        textures), passed through unchanged to writers of the same family.
    """

    name: str
    base_color: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0)
    source: Any = field(default=None, compare=False, repr=False)


INTERIOR_MATERIAL_NAME = "interior"


@dataclass(frozen=True)
class SurfaceMesh:
    """A triangle surface with per-vertex attributes, in normalized coordinates.

    Vertices are split wherever an attribute is discontinuous (UV seams, hard
    normals), as in glTF; topology-level welding is the job of the stages that
    need it.

    Attributes
    ----------
    vertices : (n, 3) float64
        Positions, normalized (see :class:`Normalization`).
    faces : (m, 3) int64
        Triangles, counter-clockwise seen from outside.
    uvs : (n, 2) float64 or None
        Texture coordinates per vertex.
    normals : (n, 3) float64 or None
        Unit shading normals per vertex (normalized space has no shear, so
        normals are the same in both spaces).
    colors : (n, 4) float64 or None
        RGBA vertex colours in [0, 1] (used by strength maps).
    material_ids : (m,) int32
        Index into ``materials`` per face.
    materials : tuple of Material
        Material slots; at least one.
    normalization : Normalization
        Map from these coordinates back to the input's units.
    name : str
        Source file name (for messages), without directories.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    normals: np.ndarray | None
    colors: np.ndarray | None
    material_ids: np.ndarray
    materials: tuple[Material, ...]
    normalization: Normalization
    name: str = "mesh"

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])

    def world_vertices(self) -> np.ndarray:
        """Vertex positions (n, 3) in the input's units."""
        return self.normalization.to_world(self.vertices)


@dataclass(frozen=True)
class Cage:
    """A closed, manifold surface that strictly contains the input (paper Algorithm 2).

    Attributes
    ----------
    vertices : (n, 3) float64
        Cage vertices, normalized coordinates.
    faces : (m, 3) int64
        Outward-oriented triangles.
    offset : float
        The offset ``d`` that produced it, relative to the unit diagonal.
    log : tuple of dict
        One entry per binary-search iteration: offset, faces, tets, ok, reason,
        and per-sub-step seconds.
    normalization : Normalization
        Carried over from the input surface.
    """

    vertices: np.ndarray
    faces: np.ndarray
    offset: float
    log: tuple[dict, ...] = ()
    normalization: Normalization = field(default_factory=Normalization.identity)


@dataclass(frozen=True, eq=False)
class TetMesh:
    """A tetrahedral mesh with the derived quantities later stages need.

    Derived quantities are computed on first use, vectorized, and cached.

    Attributes
    ----------
    vertices : (n, 3) float64
        Vertex positions, normalized coordinates.
    tets : (t, 4) int64
        Tetrahedra, positively oriented (all volumes > 0).
    normalization : Normalization
        Carried over from the input surface.
    """

    vertices: np.ndarray
    tets: np.ndarray
    normalization: Normalization = field(default_factory=Normalization.identity)

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_tets(self) -> int:
        return int(self.tets.shape[0])

    @cached_property
    def tet_volumes(self) -> np.ndarray:
        """(t,) float64 signed volumes; positive for a valid mesh."""
        # scipy loads on first use, not with the types
        from fracture_cli.geometry import tetgeom

        return tetgeom.tet_volumes(self.vertices, self.tets)

    @cached_property
    def _faces(self):
        # scipy loads on first use, not with the types
        from fracture_cli.geometry import tetgeom

        return tetgeom.tet_faces(self.tets)

    @property
    def interior_faces(self) -> np.ndarray:
        """(f, 3) int64 vertex ids of faces shared by two tets."""
        return self._faces[0]

    @property
    def interior_face_tets(self) -> np.ndarray:
        """(f, 2) int64 the two tets sharing each interior face (smaller id first)."""
        return self._faces[1]

    @property
    def boundary_faces(self) -> np.ndarray:
        """(b, 3) int64 vertex ids of faces with one tet, oriented outward."""
        return self._faces[2]

    @property
    def boundary_face_tets(self) -> np.ndarray:
        """(b,) int64 the tet owning each boundary face."""
        return self._faces[3]

    @cached_property
    def interior_face_areas(self) -> np.ndarray:
        """(f,) float64 areas of the interior faces."""
        # scipy loads on first use, not with the types
        from fracture_cli.geometry import tetgeom

        return tetgeom.triangle_areas(self.vertices, self.interior_faces)

    @cached_property
    def interior_face_normals(self) -> np.ndarray:
        """(f, 3) float64 unit normals of interior faces, pointing from tet 0 to tet 1."""
        # scipy loads on first use, not with the types
        from fracture_cli.geometry import tetgeom

        return tetgeom.interior_face_normals(self.vertices, self.tets, self.interior_faces, self.interior_face_tets)

    @cached_property
    def boundary_vertices(self) -> np.ndarray:
        """(s,) int64 sorted ids of vertices on the boundary."""
        return np.unique(self.boundary_faces)

    @cached_property
    def stiffness(self) -> sp.csr_matrix:
        """(n, n) positive semi-definite cotangent stiffness matrix ``K``."""
        # scipy loads on first use, not with the types
        from fracture_cli.geometry import tetgeom

        return tetgeom.stiffness_matrix(self.vertices, self.tets)

    @cached_property
    def vertex_mass(self) -> sp.dia_matrix:
        """(n, n) lumped (diagonal) vertex mass matrix ``M_V``."""
        # scipy loads on first use, not with the types
        from fracture_cli.geometry import tetgeom

        return tetgeom.lumped_mass(self.vertices, self.tets)

    @cached_property
    def tet_from_vertex(self) -> sp.csr_matrix:
        """(t, n) averaging operator ``C``: each tet takes the mean of its 4 vertices."""
        # scipy loads on first use, not with the types
        from fracture_cli.geometry import tetgeom

        return tetgeom.tet_from_vertex(self.tets, self.num_vertices)

    @cached_property
    def tet_centroids(self) -> np.ndarray:
        """(t, 3) float64 centroids."""
        return self.vertices[self.tets].mean(axis=1)


@dataclass(frozen=True, eq=False)
class Modes:
    """The fracture modes of a tet mesh (ALGORITHM.md section 2).

    Attributes
    ----------
    U : (k, t, d) float64
        Mode ``i`` gives one displacement in R^d per tet; M_T-orthonormal.
    labels : (k, t) int32
        Piece id of each tet in each mode (connected components without cut faces).
    cut : (k, f) bool
        Whether interior face ``f`` is cut in mode ``i``.
    piece_counts : (k,) int32
        Number of pieces per mode.
    energies : (k,) float64
        Discontinuity energy of each mode.
    iterations : (k,) int32
        ICCM rounds per mode.
    stats : dict
        Solver statistics (name, seconds per mode, inner iterations, ...).
    """

    U: np.ndarray
    labels: np.ndarray
    cut: np.ndarray
    piece_counts: np.ndarray
    energies: np.ndarray
    iterations: np.ndarray
    stats: dict = field(default_factory=dict)

    @property
    def num_modes(self) -> int:
        return int(self.U.shape[0])

    @property
    def dim(self) -> int:
        return int(self.U.shape[2])


@dataclass(frozen=True, eq=False)
class Pieces:
    """Atomic pieces and their graph (ALGORITHM.md section 3).

    Attributes
    ----------
    tet_piece : (t,) int32
        Atomic piece of every tet, ``0..p-1``.
    W : (k, p, d) float64
        Piece modes: volume-weighted mean of each mode over each piece.
    volumes : (p,) float64
        Cage volume of each piece.
    centroids : (p, 3) float64
        Volume-weighted centroid of each piece.
    edges : (e, 2) int32
        Piece-graph edges ``(P, Q)`` with ``P < Q``, sorted.
    edge_areas : (e,) float64
        Shared interface area of each edge.
    edge_centroids : (e, 3) float64
        Area-weighted centroid of each shared interface.
    edge_normals : (e, 3) float64
        Area-weighted unit normal of each interface, pointing from P to Q.
    max_deviation : float
        Worst deviation of any mode from its atomic piece's mean (before tiny
        pieces are merged), relative to the mode's largest magnitude (a check
        that modes are piecewise constant).
    """

    tet_piece: np.ndarray
    W: np.ndarray
    volumes: np.ndarray
    centroids: np.ndarray
    edges: np.ndarray
    edge_areas: np.ndarray
    edge_centroids: np.ndarray
    edge_normals: np.ndarray
    max_deviation: float = 0.0

    @property
    def num_pieces(self) -> int:
        return int(self.volumes.shape[0])


@dataclass(frozen=True, eq=False)
class Regions:
    """Closed regions of space, one per atomic piece, that partition the cage.

    Attributes
    ----------
    meshes : tuple of (vertices (n_i, 3) float64, faces (m_i, 3) int64)
        Closed, edge-manifold, outward-oriented boundary of each piece's region.
    smoothing : float
        The ``lambda`` used (0 = tet-aligned faults).
    vanished : tuple of int
        Pieces whose smoothed field never won and that kept their own tets.
    """

    meshes: tuple[tuple[np.ndarray, np.ndarray], ...]
    smoothing: float = 0.0
    vanished: tuple[int, ...] = ()


@dataclass(frozen=True, eq=False)
class Fragment:
    """One closed fragment mesh cut from the input, normalized coordinates.

    Attributes
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    uvs : (n, 2) float64 or None
    normals : (n, 3) float64
    material_ids : (m,) int32
        Index into :attr:`Fragments.materials`; the last slot is the interior.
    piece : int
        Atomic piece this fragment comes from.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    normals: np.ndarray
    material_ids: np.ndarray
    piece: int


@dataclass(frozen=True, eq=False)
class Fragments:
    """All fragments of an asset plus what export needs.

    Attributes
    ----------
    fragments : tuple of Fragment
        In stable export order (see :func:`fracture_cli.stages.fragments.fragments`).
    materials : tuple of Material
        The input's materials followed by the interior material.
    normalization : Normalization
        Map back to the input's units.
    input_volume : float
        Volume of the (repaired) input solid, normalized units.
    pivot : {"center_of_mass", "bbox"}
        Where each fragment's node origin goes when written (``fragments.pivot``);
        the checks of the written meshes use the same.
    """

    fragments: tuple[Fragment, ...]
    materials: tuple[Material, ...]
    normalization: Normalization
    input_volume: float
    pivot: str = "center_of_mass"

    @property
    def interior_slot(self) -> int:
        """Index of the ``interior`` material (the fault faces'); the last slot when none is named so."""
        names = [m.name for m in self.materials]
        return names.index(INTERIOR_MATERIAL_NAME) if INTERIOR_MATERIAL_NAME in names else len(names) - 1


@dataclass(frozen=True, eq=False)
class Anchors:
    """The fragments held by the world (the ``anchors`` stage; docs/FORMAT.md section 12).

    Attributes
    ----------
    anchored : (p,) int32
        1 where the fragment is bonded to the world, in the fragments' order; all 0 when no rule picked one.
    info : dict
        How they were chosen, as the runtime header's ``anchors`` object records it (``ground``, ``up``,
        ``tolerance``, ``boxes``, ``color``: only the rules in use).
    rules : dict of str -> (p,) bool
        Which fragments each rule picked (``ground``, ``box <name>``, ``color``), for the report.
    """

    anchored: np.ndarray
    info: dict = field(default_factory=dict)
    rules: dict = field(default_factory=dict)

    @property
    def any(self) -> bool:
        """Whether at least one fragment is anchored (only then does the runtime file get feature ``anchors``)."""
        return bool(np.any(self.anchored == 1))
