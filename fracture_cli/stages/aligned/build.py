"""The ``aligned`` stage's work: the convex pieces with their triangles, and the fracture patterns, as arrays.

:func:`fracture_cli.stages.aligned.aligned` is the stage's entry point (its docstring says what is made);
this module builds the data, so that the package itself loads nothing heavy.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.io.write import prefixed_materials
from fracture_cli.runtime.aligned_data import AlignedData
from fracture_cli.stages.aligned.options import STAGE, AlignedOptions
from fracture_cli.stages.aligned.pattern import dodecahedron_planes, fracture_pattern
from fracture_cli.stages.aligned.pieces import (
    assign_triangles,
    bounding_sphere,
    convex_piece,
    face_triangles,
    inner_faces,
)

if TYPE_CHECKING:
    from fracture_cli.types import Fragments

log = logging.getLogger(__name__)


def aligned_data(fragments: Fragments, parts: tuple | None, options: AlignedOptions, *,
                 uv_scale: float, stem: str | None) -> AlignedData | None:
    """The stage's work (:func:`fracture_cli.stages.aligned.aligned`)."""
    if not options.enabled:
        return None
    if parts is None or any(len(p) == 0 for p in parts):
        raise StageError("aligned fracture needs the collision parts of every fragment; "
                         "set collision.glb to omi, godot or unreal", stage=STAGE)
    norm = fragments.normalization
    size = float(norm.scale)
    interior = fragments.interior_slot
    pieces = [convex_piece(corners, j) for j, frag_parts in enumerate(parts) for corners in frag_parts]
    first = np.cumsum([0] + [len(p) for p in parts])
    inner = inner_faces(pieces, size)
    per_piece: list[list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]] = [[] for _ in pieces]
    for j, frag in enumerate(fragments.fragments):
        world = norm.to_world(frag.vertices)
        tri_pos = world[frag.faces]
        tri_nrm = frag.normals[frag.faces]
        tri_uv = frag.uvs[frag.faces] if frag.uvs is not None else np.zeros((len(frag.faces), 3, 2))
        owners = assign_triangles(pieces[first[j]:first[j + 1]], tri_pos.mean(axis=1))
        for local in range(first[j + 1] - first[j]):
            mask = owners == local
            per_piece[first[j] + local].append((tri_pos[mask], tri_nrm[mask], tri_uv[mask],
                                                frag.material_ids[mask].astype(np.int32)))
    for k, piece in enumerate(pieces):
        pos, nrm, uvs = face_triangles(piece, inner[k], uv_scale)
        per_piece[k].append((pos, nrm, uvs, np.full(len(pos), interior, dtype=np.int32)))
    arrays = _piece_arrays(pieces, per_piece)
    arrays.update(_pattern_arrays(options))
    arrays["settings"] = np.array([uv_scale, options.scale * size], dtype=np.float32)
    materials = tuple(m.name for m in prefixed_materials(fragments.materials, stem))
    data = AlignedData(arrays=arrays, materials=materials, interior_material=interior,
                       patterns=tuple({"sites": options.sites, "grading": options.grading, "spacing": options.spacing,
                                       "seed": options.seed + q} for q in range(options.patterns)))
    log.info("%s: %d convex pieces, %d triangles, %d patterns of %d sites", STAGE, len(pieces),
             len(arrays["triangle_materials"]), options.patterns, options.sites)
    return data


def _offsets(counts: list[int]) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)


def _piece_arrays(pieces: list, per_piece: list) -> dict[str, np.ndarray]:
    """The piece and triangle arrays of the file (docs/FORMAT.md section 13.2)."""
    positions, normals, uvs, materials, spheres = [], [], [], [], []
    for piece, chunks in zip(pieces, per_piece):
        pos = np.concatenate([c[0] for c in chunks]).reshape(-1, 3, 3)
        positions.append(pos)
        normals.append(np.concatenate([c[1] for c in chunks]).reshape(-1, 3, 3))
        uvs.append(np.concatenate([c[2] for c in chunks]).reshape(-1, 3, 2))
        materials.append(np.concatenate([c[3] for c in chunks]).astype(np.int32))
        spheres.append(bounding_sphere(piece.vertices))
    loops = [loop for piece in pieces for loop in piece.loops]
    return {
        "piece_fragment": np.array([p.fragment for p in pieces], dtype=np.int32),
        "piece_sphere": np.array(spheres, dtype=np.float32),
        "piece_vertex_offsets": _offsets([len(p.vertices) for p in pieces]),
        "piece_vertices": np.vstack([p.vertices for p in pieces]).astype(np.float32),
        "piece_face_offsets": _offsets([len(p.loops) for p in pieces]),
        "face_planes": np.vstack([p.planes for p in pieces]).astype(np.float32),
        "face_loop_offsets": _offsets([len(loop) for loop in loops]),
        "face_loops": np.array([v for loop in loops for v in loop], dtype=np.int32),
        "piece_triangle_offsets": _offsets([len(m) for m in materials]),
        "triangle_positions": np.concatenate(positions).astype(np.float32),
        "triangle_normals": np.concatenate(normals).astype(np.float32),
        "triangle_uvs": np.concatenate(uvs).astype(np.float32),
        "triangle_materials": np.concatenate(materials).astype(np.int32),
    }


def _pattern_arrays(options: AlignedOptions) -> dict[str, np.ndarray]:
    """The pattern arrays of the file: ``options.patterns`` patterns, pattern q from seed ``seed + q``."""
    boundary = dodecahedron_planes().astype(np.float32) if options.bounded else np.zeros((0, 4), np.float32)
    patterns = [fracture_pattern(options.sites, options.grading, options.spacing, options.seed + q,
                                 boundary.astype(np.float64)) for q in range(options.patterns)]
    neighbors = [nb for p in patterns for nb in p.neighbors]
    walls = [b for p in patterns for b in p.boundary]
    return {
        "pattern_site_offsets": _offsets([len(p.sites) for p in patterns]),
        "pattern_sites": np.vstack([p.sites for p in patterns]).astype(np.float32),
        "cell_neighbor_offsets": _offsets([len(nb) for nb in neighbors]),
        "cell_neighbors": np.concatenate(neighbors).astype(np.int32) if neighbors else np.zeros(0, np.int32),
        "cell_planes": np.vstack([p.planes() for p in patterns]).astype(np.float32),
        "boundary_planes": boundary,
        "cell_boundary_offsets": _offsets([len(b) for b in walls]),
        "cell_boundary": np.concatenate(walls).astype(np.int32) if walls else np.zeros(0, np.int32),
    }
