"""The sample pillar as a structure in Godot 3 (headless): the add-on's FractureBody, real physics, a floor.

The same bake and hits as tests/test_structure_physics.py (Bullet through pybullet), here through the GDScript
reader and ``fracture_body.gd`` as a game uses them: anchored groups become StaticBodies, free ones RigidBodies,
every hit goes through the body's damage state. Godot runs with ``--fixed-fps 60``, so 120 frames are 2 s of
simulated time on any machine.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from engine_support import float_to_bits
from godot_harness import GodotProject
from structure_support import (
    BREAK_SPEED,
    HARD,
    bake_pillar,
    breaking_magnitude,
    fragment_meshes,
    mid_height_hit,
    struck_fragment,
)

from fracture_cli.runtime.damage import hit, new_state
from fracture_cli.runtime.format import RuntimeData
from fracture_cli.runtime.impact import project_impact

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE_SCRIPT = os.path.join(REPO, "engines", "godot", "tests", "structure_scene.gd")
DENSITY = 2400.0  # kg/m^3, stone; the pillar is in metres, +Y up
FRAMES = 120  # 2 s at 60 frames per second

@pytest.fixture(scope="module")
def pillar(tmp_path_factory) -> tuple[str, RuntimeData]:
    return bake_pillar(tmp_path_factory.mktemp("pillar"))


def _bodies(stdout: str) -> list[dict[int, tuple[str, np.ndarray, list[str], int]]]:
    """structure_scene.gd's report: per step, {body index: (class, transform (4, 4), fragment names, cracks)}."""
    steps: list[dict] = []
    current: dict = {}
    for line in stdout.splitlines():
        fields = line.split()
        if fields[:1] == ["body"]:
            columns = np.array([float(v) for v in fields[3:15]]).reshape(4, 3)
            transform = np.eye(4)
            transform[:3, :4] = columns.T
            current[int(fields[1])] = (fields[2], transform, fields[15:], 0)
        elif fields[:1] == ["cracks"]:
            kind, at, names, _ = current[int(fields[1])]
            current[int(fields[1])] = (kind, at, names, int(fields[2]))
        elif fields == ["step"]:
            steps.append(current)
            current = {}
    return steps


def _run(tmp_path, stem: str, data: RuntimeData, hits, frames: int, impulse_scale: float):
    """Bodies after setup, after each hit, and (last) after ``frames`` frames of physics."""
    project = GodotProject(tmp_path / "project")
    scene = project.add_file(stem + ".glb")
    runtime = project.add_file(stem + ".fracture.json")
    project.add_file(stem + ".fracture.bin")
    project.import_resources()
    lines = [" ".join([float_to_bits(float(c)) for c in (*point, *impulse)] + ["0"]) for point, impulse in hits]
    (tmp_path / "hits.txt").write_text("\n".join(lines) + "\n")
    ground_y = float(np.asarray(data.gameready["collision_vertices"])[:, 1].min())
    with open(SCENE_SCRIPT, encoding="utf-8") as fh:
        run = project.run_script(fh.read(), scene, runtime, str(tmp_path / "hits.txt"), str(frames),
                                 repr(impulse_scale), repr(DENSITY), repr(ground_y), name="structure_scene.gd",
                                 flags=("--fixed-fps", "60"))
    assert not run.lines("setup-error"), run.lines("setup-error")
    return _bodies(run.stdout)


def _hit_setup(stem: str, data: RuntimeData):
    meshes = fragment_meshes(stem, data)
    point, direction = mid_height_hit(data)
    struck = struck_fragment(meshes, data, point)
    return point, direction, struck, breaking_magnitude(data, point, direction, struck)


def _impulse_scale(data: RuntimeData, result, struck: int, breaking: float) -> float:
    """The game's calibration (docs/FORMAT.md section 5): the least breaking hit moves the struck group at
    BREAK_SPEED, its mass from the runtime file's volumes."""
    members = result.groups == result.groups[struck]
    mass = DENSITY * float(np.asarray(data.gameready["fragment_volume"], dtype=np.float64)[members].sum())
    return mass * BREAK_SPEED / breaking


@pytest.mark.slow
def test_godot_pillar_falls_where_it_is_broken_and_its_base_stays(pillar, tmp_path):
    stem, data = pillar
    point, direction, struck, breaking = _hit_setup(stem, data)
    magnitude = HARD * breaking
    result = project_impact(data, point, direction * magnitude)
    steps = _run(tmp_path, stem, data, [(point, direction * magnitude)], FRAMES,
                 _impulse_scale(data, result, struck, breaking))
    intact, after_hit, after_fall = steps
    assert [kind for kind, *_ in intact.values()] == ["StaticBody"]
    names = data.fragment_names
    anchored = {names[j] for j in np.flatnonzero(np.asarray(data.anchored) == 1)}
    # The bodies are the reference's groups; exactly the groups holding an anchored fragment are static.
    groups = {frozenset(names[j] for j in np.flatnonzero(result.groups == g)) for g in np.unique(result.groups)}
    assert {frozenset(n) for _, _, n, _ in after_hit.values()} == groups
    for kind, _, members, _ in after_hit.values():
        assert (kind == "StaticBody") == bool(anchored & set(members)), (kind, members)
    falls, base_motion = [], 0.0
    for index, (kind, start, members, _) in after_hit.items():
        # A free piece's origin is its centre of mass (the add-on puts it there); a static one does not move.
        moved = after_fall[index][1][:3, 3] - start[:3, 3]
        if kind == "StaticBody":
            base_motion = max(base_motion, float(np.linalg.norm(moved)))
        elif max(_tops(data, members)) > point[1]:
            falls.append(-float(moved[1]))
        print(f"godot pillar: {kind} {members}: top {max(_tops(data, members)):.3f} m, moved "
              f"{np.round(moved, 3).tolist()} m")
    print(f"godot pillar: falls {[round(f, 3) for f in falls]} m, base moved {base_motion:.2e} m")
    assert falls and all(fall > 0.5 for fall in falls), falls
    assert base_motion < 1e-3


def _tops(data: RuntimeData, members: list[str]) -> list[float]:
    """The highest collision-part corner of each named fragment (model space y)."""
    g = data.gameready
    vertices = np.asarray(g["collision_vertices"], dtype=np.float64)
    part_ptr, fragment_ptr = np.asarray(g["collision_part_offsets"]), np.asarray(g["collision_fragment_offsets"])
    tops = []
    for name in members:
        j = data.fragment_names.index(name)
        lo, hi = part_ptr[fragment_ptr[j]], part_ptr[fragment_ptr[j + 1]]
        tops.append(float(vertices[lo:hi, 1].max()))
    return tops


@pytest.mark.slow
def test_godot_quarter_hits_crack_first_and_break_through_like_the_reference(pillar, tmp_path):
    stem, data = pillar
    point, direction, struck, breaking = _hit_setup(stem, data)
    light = direction * HARD * breaking / 4.0
    state = new_state(data)
    reference = []
    while not reference or reference[-1].anchored[struck]:
        reference.append(hit(data, state, point, light))
        assert len(reference) < 20
    steps = _run(tmp_path, stem, data, [(point, light)] * len(reference), 0, 1.0)
    struck_name = data.fragment_names[struck]
    for k, (expected, bodies) in enumerate(zip(reference, steps[1:-1]), start=1):
        kind = next(kind for kind, _, members, _ in bodies.values() if struck_name in members)
        assert (kind == "StaticBody") == bool(expected.anchored[struck]), f"hit {k}: {kind}"
        assert sum(cracks for *_, cracks in bodies.values()) > 0 or not expected.cracked.any(), f"hit {k}"
    assert len(reference) >= 2  # the first quarter hit only cracks
    assert next(kind for kind, _, m, _ in steps[1].values() if struck_name in m) == "StaticBody"
