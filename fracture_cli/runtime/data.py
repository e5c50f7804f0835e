"""What a runtime file holds, in memory: :class:`RuntimeData` and its consistency checks.

:mod:`fracture_cli.runtime.format` reads and writes it (docs/FORMAT.md). Depends on numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fracture_cli.runtime.gameready import GAMEREADY_LAYOUT, check_gameready
from fracture_cli.runtime.levels import ALL_LEVEL_LAYOUTS, body_view, check_level_structure, level_counts, num_bodies
from fracture_cli.runtime.stress import CRITERIA, SHARING_LAYOUT, STRESS_LAYOUT, check_sharing, check_stress
from fracture_cli.runtime.structure import ANCHOR_LAYOUT, CRACK_LAYOUT, check_anchored, check_cracks, check_damage

FORMAT_VERSION = 1  # what a bake without any version-2 feature writes (byte-identical to before version 2)
UNITS_NOTE = (
    "sites are in the input asset's model space and units; edge_areas in those units squared; "
    "impulse and threshold share one (any) unit; radius is a fraction of the bounding-box diagonal"
)

# name -> (dtype, number of dimensions); also the order of arrays in the .bin file.
ARRAY_LAYOUT: dict[str, tuple[str, int]] = {
    "sites": ("float32", 2),
    "B": ("float32", 3),
    "W": ("float32", 3),
    "edges": ("int32", 2),
    "edge_areas": ("float32", 1),
}
FILE_DTYPES = {"float32": np.dtype("<f4"), "int32": np.dtype("<i4")}
ALL_LAYOUTS = {**ARRAY_LAYOUT, **GAMEREADY_LAYOUT, **STRESS_LAYOUT, **SHARING_LAYOUT, **ANCHOR_LAYOUT,
               **CRACK_LAYOUT, **ALL_LEVEL_LAYOUTS}


@dataclass(frozen=True, eq=False)
class RuntimeData:
    """Everything the realtime impact projection needs (ALGORITHM.md section 4).

    Attributes
    ----------
    sites : (s, 3) float32
        Contact sites (the tet mesh's boundary vertices), input asset units.
    B : (s, k, d) float32
        Site-to-mode coefficients; an impulse ``n`` at site ``v`` excites mode
        ``i`` by ``alpha_i = B[v, i, 0] * |n|`` (d = 1) or ``B[v, i] . n`` (d = 3).
    W : (k, p, d) float32
        Piece modes: displacement of fragment ``j`` in mode ``i``.
    edges : (e, 2) int32
        Fragment-graph edges ``(P, Q)``, ``P < Q``, sorted.
    edge_areas : (e,) float32
        Interface area of each edge, input asset units squared.
    fragment_names : tuple of str
        Name of fragment ``j`` (``p`` names), as in the fragments file.
    transform : (4, 4) float64
        Map from the normalized bake coordinates to the asset's units
        (``world = transform @ [x, y, z, 1]``); informational.
    default_threshold : float
        Toughness used when the caller gives none (same unit as the impulse).
    radius : float
        Impact radius baked into ``B``, as a fraction of the bounding-box diagonal.
    units : str
        Human-readable note on units.
    gameready : dict of str -> array
        The optional arrays of :data:`GAMEREADY_LAYOUT` (mass properties and
        collision parts per fragment, model space), all or none.
    criterion : str
        ``"modes"`` (version 1) or ``"stress"`` (version 2 with feature ``"stress"``).
    stress : dict of str -> array
        The arrays of :data:`fracture_cli.runtime.stress.STRESS_LAYOUT` (criterion ``"stress"`` only), and with
        ``sharing`` the one of :data:`~fracture_cli.runtime.stress.SHARING_LAYOUT` (``site_fragment (s,)``).
    stress_info : dict
        The stress criterion's material parameters (header key ``stress``; informational).
    sharing : dict
        ``{"concentration": kappa}`` (feature ``"sharing"``, docs/FORMAT.md section 11.1): the struck fragment's
        bonds share the load of its broken ones; empty: they do not.
    anchored : (p,) int32 or None
        1 where the fragment is bonded to the world (feature ``"anchors"``, docs/FORMAT.md section 12).
    damage : dict
        ``{"crack_level": c, "damage_rate": r}`` (feature ``"damage"``): hits below a bond's strength crack it
        and lower its health (:mod:`fracture_cli.runtime.damage`); empty: every hit is judged alone.
    cracks : dict of str -> array
        ``crack_ptr (e+1,)`` int32 and ``crack_segments (n, 2, 3)`` float32, both or none: where each bond's
        fault meets the outer surface, model space (for drawing cracked bonds).
    anchors_info : dict
        How the bake chose the anchored fragments (header key ``anchors``; informational).
    levels : dict of str -> array
        Feature ``"levels"`` (docs/FORMAT.md section 14): the arrays of
        :data:`fracture_cli.runtime.levels.ALL_LEVEL_LAYOUTS` that the file has (``parent (p_all,)``, the
        ``body_*`` arrays of every body below the whole asset, the ``child_*`` game-ready arrays); empty: one level.
    child_names : tuple of str
        With levels: the names of fragments ``p .. p_all - 1`` (GLB nodes below their parent's node).
    levels_info : dict
        With levels: the header's ``levels`` object (``count``, ``thresholds`` per level, informational keys).
    """

    sites: np.ndarray
    B: np.ndarray
    W: np.ndarray
    edges: np.ndarray
    edge_areas: np.ndarray
    fragment_names: tuple[str, ...]
    transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    default_threshold: float = 1.0
    radius: float = 0.05
    units: str = UNITS_NOTE
    gameready: dict[str, np.ndarray] = field(default_factory=dict)
    criterion: str = "modes"
    stress: dict[str, np.ndarray] = field(default_factory=dict)
    stress_info: dict = field(default_factory=dict)
    sharing: dict = field(default_factory=dict)
    anchored: np.ndarray | None = None
    damage: dict = field(default_factory=dict)
    cracks: dict[str, np.ndarray] = field(default_factory=dict)
    anchors_info: dict = field(default_factory=dict)
    levels: dict[str, np.ndarray] = field(default_factory=dict)
    child_names: tuple[str, ...] = ()
    levels_info: dict = field(default_factory=dict)

    @property
    def features(self) -> tuple[str, ...]:
        """The format-2 features the data needs (sorted; empty: a version-1 file)."""
        present = {"anchors": self.anchored is not None, "damage": bool(self.damage), "stress": bool(self.stress),
                   "levels": bool(self.levels), "sharing": bool(self.sharing)}
        return tuple(name for name in sorted(present) if present[name])

    @property
    def version(self) -> int:
        """The format version the data is written as: 1 without features, 2 with."""
        return 2 if self.features else FORMAT_VERSION

    @property
    def dim(self) -> int:
        """Displacement dimension ``d`` (1 or 3)."""
        return int(self.W.shape[2])

    @property
    def k(self) -> int:
        """Number of modes."""
        return int(self.W.shape[0])

    @property
    def p(self) -> int:
        """Number of fragments (atomic pieces)."""
        return int(self.W.shape[1])

    @property
    def num_sites(self) -> int:
        return int(self.sites.shape[0])

    @property
    def num_edges(self) -> int:
        return int(self.edges.shape[0])

    def arrays(self) -> dict[str, np.ndarray]:
        """The binary arrays in file order, converted to their file dtypes."""
        arrays = {name: np.ascontiguousarray(getattr(self, name), dtype=FILE_DTYPES[dtype])
                  for name, (dtype, _) in ARRAY_LAYOUT.items()}
        for name, (dtype, _) in GAMEREADY_LAYOUT.items():
            if name in self.gameready:
                arrays[name] = np.ascontiguousarray(self.gameready[name], dtype=FILE_DTYPES[dtype])
        for name, (dtype, _) in STRESS_LAYOUT.items():
            if name in self.stress:
                arrays[name] = np.ascontiguousarray(self.stress[name], dtype=FILE_DTYPES[dtype])
        for name, (dtype, _) in SHARING_LAYOUT.items():
            if name in self.stress:
                arrays[name] = np.ascontiguousarray(self.stress[name], dtype=FILE_DTYPES[dtype])
        if self.anchored is not None:
            arrays["anchored"] = np.ascontiguousarray(self.anchored, dtype=FILE_DTYPES["int32"])
        for name, (dtype, _) in CRACK_LAYOUT.items():
            if name in self.cracks:
                arrays[name] = np.ascontiguousarray(self.cracks[name], dtype=FILE_DTYPES[dtype])
        for name, (dtype, _) in ALL_LEVEL_LAYOUTS.items():
            if name in self.levels:
                arrays[name] = np.ascontiguousarray(self.levels[name], dtype=FILE_DTYPES[dtype])
        return arrays

    def counts(self) -> dict[str, int]:
        """The header's ``counts``."""
        counts = {"sites": self.num_sites, "modes": self.k, "fragments": self.p, "edges": self.num_edges}
        if self.gameready:
            counts["collision_parts"] = int(len(self.gameready["collision_part_offsets"]) - 1)
            counts["collision_vertices"] = int(len(self.gameready["collision_vertices"]))
        if self.stress:
            counts["site_bonds"] = int(len(self.stress["site_bonds"]))
        if self.cracks:
            counts["crack_segments"] = int(len(self.cracks["crack_segments"]))
        counts.update(level_counts(self))
        return counts


def check_runtime(data: RuntimeData) -> str | None:
    """Return why ``data`` is inconsistent, or None if it is usable."""
    W = np.asarray(data.W)
    if W.ndim != 3 or W.shape[2] not in (1, 3):
        return f"W must have shape (k, p, d) with d = 1 or 3, got {W.shape}"
    k, p, d = W.shape
    s = np.asarray(data.sites).shape[0] if np.asarray(data.sites).ndim == 2 else -1
    expected = {
        "sites": (s, 3),
        "B": (s, k, d),
        "W": (k, p, d),
        "edges": (np.asarray(data.edges).shape[0] if np.asarray(data.edges).ndim == 2 else -1, 2),
    }
    expected["edge_areas"] = (expected["edges"][0],)
    for name, shape in expected.items():
        got = np.asarray(getattr(data, name)).shape
        if got != shape or min(shape) < 0:
            return f"array {name} has shape {list(got)}, expected {list(shape)}"
    if s < 1:
        return "there are no contact sites"
    if k < 1 or p < 1:
        return f"need at least one mode and one fragment, got k = {k}, p = {p}"
    if len(data.fragment_names) != p:
        return f"{len(data.fragment_names)} fragment names for {p} fragments"
    edges = np.asarray(data.edges)
    if len(edges) and (edges.min() < 0 or edges.max() >= p or np.any(edges[:, 0] >= edges[:, 1])):
        return f"edges must be pairs (P, Q) with 0 <= P < Q < {p}"
    for name in ("sites", "B", "W", "edge_areas"):
        if not np.all(np.isfinite(getattr(data, name))):
            return f"array {name} has non-finite values"
    if not (np.isfinite(data.default_threshold) and data.default_threshold >= 0):
        return f"default threshold must be a finite number >= 0, got {data.default_threshold!r}"
    if np.asarray(data.transform).shape != (4, 4):
        return "transform must be a 4x4 matrix"
    if data.gameready:
        problem = check_gameready(data.gameready, p)
        if problem:
            return problem
    if not (np.all(np.isfinite(data.transform)) and np.isfinite(data.radius)):
        return "transform and impact radius must be finite numbers"
    if data.criterion not in CRITERIA:
        return f"unknown criterion {data.criterion!r}"
    if (data.criterion == "stress") != bool(data.stress):
        return "the stress criterion and the stress arrays come together"
    if data.stress:
        problem = check_stress(data.stress, s, expected["edges"][0])
        if problem:
            return problem
    if data.sharing:
        problem = ("the feature 'sharing' needs criterion 'stress'" if data.criterion != "stress"
                   else check_sharing(data.sharing, data.stress.get("site_fragment"), s, p))
        if problem:
            return problem
    elif "site_fragment" in data.stress:
        return "site_fragment without the feature 'sharing'"
    return _check_structure(data) or _check_levels(data)


def _check_levels(data: RuntimeData) -> str | None:
    """The checks of docs/FORMAT.md section 14.2: the structure, then every body's view as a runtime file."""
    if not data.levels:
        return None
    problem = check_level_structure(data)
    if problem:
        return problem
    for body in range(1, num_bodies(data)):
        problem = check_runtime(body_view(data, body))
        if problem:
            return f"body {body}: {problem}"
    return None


def _check_structure(data: RuntimeData) -> str | None:
    """The checks of docs/FORMAT.md section 12.2 (anchors, damage, crack arrays)."""
    if data.anchored is not None:
        problem = check_anchored(data.anchored, data.p)
        if problem:
            return problem
    if data.damage:
        problem = check_damage(data.damage)
        if problem:
            return problem
    return check_cracks(data.cracks, data.num_edges)
