"""Run load -> pieces in-process and measure how the pieces relate to the asset (docs/notes/realworld-diagnosis.md).

    .venv/bin/python tests/data/realworld/probe_pieces.py INPUT RECIPE [SECTION.KEY=VALUE ...]

Prints one JSON line: cage and tet counts, the share of the cage volume the
asset fills, the modes' CPU seconds and pieces per mode, the atomic and
merged piece counts, how many pieces hold no asset material (or less than
0.2% of it), and the piece counts the current merge would give at 0.5%, 1%
and 2% of the volume. A tet's material fraction is the pieces stage's own
estimate (``tet_material_fraction``: 20 lattice points per tet, open3d occupancy).
"""

from __future__ import annotations

import json
import logging
import sys
import time

import numpy as np

from fracture_cli.pipeline.recipe import load_recipe
from fracture_cli.stages.cage import cage
from fracture_cli.stages.load import load_surface
from fracture_cli.stages.material import material
from fracture_cli.stages.modes import modes as solve_modes
from fracture_cli.stages.pieces import PiecesOptions, tet_material_fraction
from fracture_cli.stages.pieces import pieces as atomic_pieces
from fracture_cli.stages.repair import repair
from fracture_cli.stages.tetra import tetra


def main() -> None:
    logging.basicConfig(level=logging.WARNING)
    path, recipe_name, overrides = sys.argv[1], sys.argv[2], sys.argv[3:]
    recipe = load_recipe(recipe_name, overrides)
    surface = repair(load_surface(path, recipe["load"]), recipe["repair"])
    cage_mesh = cage(surface, recipe["cage"])
    tet_mesh = tetra(cage_mesh, recipe["tetra"])
    eta = material(tet_mesh, surface, recipe["material"])
    t0 = time.process_time()
    modes = solve_modes(tet_mesh, recipe["modes"], eta=eta)
    modes_cpu = time.process_time() - t0
    merged = atomic_pieces(tet_mesh, modes, recipe["pieces"], surface=surface)
    atomic = atomic_pieces(tet_mesh, modes, PiecesOptions(min_fragment_fraction=0.0))
    volume = np.abs(tet_mesh.tet_volumes)
    inside = volume * tet_material_fraction(tet_mesh, surface)
    per_piece = np.bincount(merged.tet_piece, weights=inside, minlength=merged.volumes.size)
    print(json.dumps({
        "file": path, "recipe": recipe_name, "overrides": overrides,
        "input_triangles": len(surface.faces), "cage_faces": len(cage_mesh.faces), "tets": int(tet_mesh.num_tets),
        "input_share_of_cage": float(inside.sum() / volume.sum()),
        "modes_cpu_s": round(modes_cpu, 2), "mode_pieces": modes.piece_counts.tolist(),
        "atomic_pieces": int(atomic.volumes.size), "pieces_after_merge": int(merged.volumes.size),
        "pieces_without_input": int((per_piece < 1e-6 * inside.sum()).sum()),
        "pieces_below_0.2pct_input": int((per_piece < 0.002 * inside.sum()).sum()),
        "merged_at": {str(x): int(atomic_pieces(tet_mesh, modes, PiecesOptions(min_fragment_fraction=x),
                                                  surface=surface).volumes.size)
                      for x in (0.002, 0.005, 0.01, 0.02)},
    }))


if __name__ == "__main__":
    main()
