"""What the pattern kinds share: sites in the solid, nearest-site cells, one connected body per cell.

Everything here is made of uniform draws, ``+ - * /``, ``sqrt``, sorting and
sequential sums (``bincount``, ``cumsum``), so a pattern is the same bytes on
every CPU (STYLE.md, determinism).
"""

from __future__ import annotations

import numpy as np

from fracture_cli.geometry.edges import components, renumber_by_first
from fracture_cli.stages.pieces import tet_material_fraction
from fracture_cli.types import SurfaceMesh, TetMesh

AXES = {"x": 0, "y": 1, "z": 2}
# Tet centroids per block of the nearest-site search (memory: block x sites x 3 doubles).
_BLOCK = 4096


def held_volumes(tet_mesh: TetMesh, surface: SurfaceMesh | None) -> np.ndarray:
    """Asset volume (t,) each tet holds: its volume times its share inside ``surface`` (or its volume)."""
    volumes = np.abs(np.asarray(tet_mesh.tet_volumes, dtype=np.float64))
    if surface is None:
        return volumes
    return volumes * tet_material_fraction(tet_mesh, surface)


# An axis-aligned box: its lowest and highest corners (3,) each.
Box = tuple[np.ndarray, np.ndarray]


def solid_box(tet_mesh: TetMesh, surface: SurfaceMesh | None) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box ``(lo (3,), hi (3,))`` of the asset (the surface, else the tet mesh), normalized units."""
    points = tet_mesh.vertices if surface is None else surface.vertices
    return np.asarray(points.min(axis=0), dtype=np.float64), np.asarray(points.max(axis=0), dtype=np.float64)


def box_point(box: Box, fractions: object) -> np.ndarray:
    """The point (3,) at ``fractions`` (3,) of ``box`` per axis."""
    lo, hi = box
    return lo + np.asarray(fractions, dtype=np.float64).reshape(3) * (hi - lo)


def sites_in_solid(rng: np.random.Generator, tet_mesh: TetMesh, held: np.ndarray, count: int) -> np.ndarray:
    """``count`` points (count, 3) uniform in the solid: a tet by the asset volume it holds, then a point in it.

    The point's barycentric weights are the gaps of three sorted uniforms
    (uniform on the simplex).
    """
    cdf = np.cumsum(held)
    if not cdf[-1] > 0:
        cdf = np.cumsum(np.abs(tet_mesh.tet_volumes))
    tets = np.searchsorted(cdf, rng.uniform(0.0, cdf[-1], count), side="right")
    tets = np.minimum(tets, len(cdf) - 1)
    cuts = np.sort(rng.uniform(0.0, 1.0, (count, 3)), axis=1)
    weights = np.diff(np.concatenate([np.zeros((count, 1)), cuts, np.ones((count, 1))], axis=1), axis=1)
    corners = tet_mesh.vertices[tet_mesh.tets[tets]]  # (count, 4, 3)
    return (weights[:, 0:1] * corners[:, 0] + weights[:, 1:2] * corners[:, 1]
            + weights[:, 2:3] * corners[:, 2] + weights[:, 3:4] * corners[:, 3])


def nearest_site(points: np.ndarray, sites: np.ndarray) -> np.ndarray:
    """Index (n,) of the nearest of ``sites`` (s, 3) to every point (n, 3); ties go to the lowest index.

    Squared distances are summed per axis in a fixed order (no matrix product, whose rounding depends
    on the BLAS kernel).
    """
    out = np.empty(len(points), dtype=np.int64)
    for start in range(0, len(points), _BLOCK):
        block = points[start:start + _BLOCK]
        dx = block[:, None, 0] - sites[None, :, 0]
        dy = block[:, None, 1] - sites[None, :, 1]
        dz = block[:, None, 2] - sites[None, :, 2]
        out[start:start + _BLOCK] = np.argmin(dx * dx + dy * dy + dz * dz, axis=1)
    return out


def label_rows(keys: np.ndarray) -> np.ndarray:
    """One label (n,) per distinct row of the integer array ``keys`` (n, m)."""
    _, inverse = np.unique(np.asarray(keys, dtype=np.int64).reshape(len(keys), -1), axis=0, return_inverse=True)
    return inverse.reshape(-1)


def connected_cells(tet_mesh: TetMesh, raw: np.ndarray, held: np.ndarray) -> np.ndarray:
    """Cells (t,) that are each one face-connected set of tets, numbered by lowest tet.

    A cell the tet mesh splits into several parts keeps the part holding the
    most asset volume; every other part (an island) joins the neighbouring
    cell it shares the largest face area with, smallest island first, so each
    fragment is cut from one body. An island without neighbours (a separate
    component of the tet mesh) stays a cell of its own.

    Parameters
    ----------
    tet_mesh : TetMesh
    raw : (t,) int
        The pattern's cell of every tet.
    held : (t,) float
        Asset volume of every tet (:func:`held_volumes`).
    """
    face_tets = tet_mesh.interior_face_tets
    areas = np.asarray(tet_mesh.interior_face_areas, dtype=np.float64)
    raw = np.asarray(raw, dtype=np.int64)
    same = raw[face_tets[:, 0]] == raw[face_tets[:, 1]]
    parts = components(len(raw), face_tets[same])
    p = int(parts.max()) + 1
    part_cell = np.zeros(p, dtype=np.int64)
    part_cell[parts] = raw
    part_held = np.bincount(parts, weights=held, minlength=p)
    # The main part of a cell: most asset volume, then most tets, then lowest id.
    sizes = np.bincount(parts, minlength=p)
    order = np.lexsort((np.arange(p), -sizes, -part_held, part_cell))
    first = np.ones(p, dtype=bool)
    first[1:] = part_cell[order][1:] != part_cell[order][:-1]
    island = np.ones(p, dtype=bool)
    island[order[first]] = False
    labels = parts.copy()
    stuck: set[int] = set()
    while True:
        live = [int(q) for q in np.lexsort((np.arange(p), part_held)) if island[q] and int(q) not in stuck]
        if not live:
            break
        q = live[0]
        a, b = labels[face_tets[:, 0]], labels[face_tets[:, 1]]
        touching = (a != b) & ((a == q) | (b == q))
        if not touching.any():
            stuck.add(q)
            continue
        other = np.where(a[touching] == q, b[touching], a[touching])
        shared = np.bincount(other, weights=areas[touching], minlength=p)
        target = int(np.argmax(shared))
        labels[labels == q] = target
        part_held[target] += part_held[q]
        part_held[q] = 0.0
        island[q] = False
    return renumber_by_first(labels)
