"""What a repair did, as one JSON-ready record per decision (report.json ``repairs``)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class RepairRecord:
    """One repair decision or action.

    Attributes
    ----------
    what : str
        A short machine-readable kind: ``filled_hole``, ``thickened_sheet``,
        ``split_nonmanifold_edges``, ``split_nonmanifold_vertices``,
        ``doubled_wall_faces``, ``unclosed_body``, ``open_surface``, ...
    detail : str
        One human-readable line (what a warning prints).
    count : int, optional (default 1)
        How many things it covers (edges, vertices, faces, holes).
    area : float, optional (default 0.0)
        Surface area concerned, in the mesh's units (fill area of a hole, area
        of a thickened sheet); 0 when not applicable.
    where : tuple of float, optional (default ())
        A representative point (x, y, z) in the mesh's units, e.g. a hole's
        centroid, so an artist can find it.
    extra : dict, optional
        Further numbers (planarity, share of the surface, thickness, ...).
    """

    what: str
    detail: str
    count: int = 1
    area: float = 0.0
    where: tuple[float, ...] = ()
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """A JSON-ready dict (floats rounded to 9 significant digits, for stable reports)."""
        out: dict = {"what": self.what, "detail": self.detail, "count": int(self.count)}
        if self.area:
            out["area"] = float(f"{self.area:.9g}")
        if self.where:
            out["where"] = [float(f"{x:.9g}") for x in self.where]
        for key, value in sorted(self.extra.items()):
            out[key] = float(f"{value:.9g}") if isinstance(value, float) else value
        return out
