"""The sample pillar baked as a structure, and the hit that breaks it through: shared by the physics tests.

tests/test_structure_physics.py (Bullet) and tests/test_structure_godot.py (Godot 3) put the same bake into two
engines and hit it the same way.
"""

from __future__ import annotations

import os

import numpy as np
import trimesh

from fracture_cli.pipeline.bake import bake
from fracture_cli.pipeline.recipe import load_recipe
from fracture_cli.runtime.format import RuntimeData, load_runtime
from fracture_cli.runtime.impact import project_impact

from conftest import SAMPLE_ASSETS

# A coarser cage, faults as cut and at most four parts per fragment: a few seconds, and the same structure
# (a base of anchored fragments, a shaft, a capital).
FAST = ["cage.target_faces=600", "simplify.tolerance=0", "collision.max_parts=4"]
# The game's one factor per material (docs/FORMAT.md section 5): a hit that just frees a piece leaves it at
# this speed. Only this calibration turns the runtime file's impulse unit into newton-seconds.
BREAK_SPEED = 1.0  # m/s
# The hard hit is this many times the impulse that just breaks through: four times 0.92, so a quarter of it
# loads every bond that held the struck piece to at least 0.92 of its strength (above stone's crack level,
# and below the strength, so no single quarter hit breaks through).
HARD = 4.0 * 0.92


def bake_pillar(out) -> tuple[str, RuntimeData]:
    """Bake the sample pillar as ``stone_structure`` (with :data:`FAST`) into ``out``: (GLB stem, runtime data)."""
    bake(os.path.join(SAMPLE_ASSETS, "pillar.glb"), str(out), load_recipe("stone_structure", FAST))
    return str(out / "pillar"), load_runtime(str(out / "pillar.fracture.json"))


def fragment_meshes(stem: str, data: RuntimeData) -> dict[str, trimesh.Trimesh]:
    """Every fragment of the GLB as one mesh in model space, by node name (trimesh splits primitives)."""
    scene = trimesh.load(stem + ".glb")
    parents = scene.graph.transforms.parents
    found: dict[str, list[trimesh.Trimesh]] = {}
    for node in scene.graph.nodes_geometry:
        transform, geometry = scene.graph[node]
        owner = node
        while owner not in data.fragment_names and owner in parents:
            owner = parents[owner]
        if owner in data.fragment_names:
            found.setdefault(owner, []).append(scene.geometry[geometry].copy().apply_transform(transform))
    return {name: trimesh.util.concatenate(parts) for name, parts in found.items()}


def mid_height_hit(data: RuntimeData) -> tuple[np.ndarray, np.ndarray]:
    """The contact site at mid-height on the +X side, and a unit direction into the pillar (-X)."""
    sites = np.asarray(data.sites, dtype=np.float64)
    middle = (sites[:, 1].min() + sites[:, 1].max()) / 2.0
    near = np.flatnonzero(np.abs(sites[:, 1] - middle) < 0.05 * np.ptp(sites[:, 1]))
    return sites[near[np.argmax(sites[near, 0])]], np.array([-1.0, 0.0, 0.0])


def struck_fragment(meshes: dict[str, trimesh.Trimesh], data: RuntimeData, point: np.ndarray) -> int:
    """The fragment whose surface is nearest to ``point`` (the one the hit lands on)."""
    nearest = [float(np.linalg.norm(meshes[name].vertices - point, axis=1).min()) for name in data.fragment_names]
    return int(np.argmin(nearest))


def breaking_magnitude(data: RuntimeData, point, direction, struck: int) -> float:
    """The least impulse (runtime units) whose stateless hit frees the struck fragment from the world."""
    lo, hi = 0.0, 1.0
    while project_impact(data, point, direction * hi).anchored[struck]:
        lo, hi = hi, hi * 2.0
    for _ in range(60):
        middle = (lo + hi) / 2.0
        if project_impact(data, point, direction * middle).anchored[struck]:
            lo = middle
        else:
            hi = middle
    return hi
