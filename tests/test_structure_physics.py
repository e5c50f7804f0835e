"""A baked structure in a real physics engine: the sample pillar, anchored at its base, hit at mid-height.

The pillar is baked with the ``stone_structure`` recipe (ground anchors, stone's damage) and a coarser cage
so that the bake takes seconds. Its fragments GLB (read with trimesh) and runtime file go into Bullet
(pybullet, the ``test`` extra): a static body per fragment of a group the world holds, a dynamic body per
free group made of its fragments' convex collision parts. One hard hit breaks through and the pieces above
fall while the base stays; a quarter of that hit, repeated on one damage state, cracks the pillar first and
breaks through after as many hits as stone's crack level and damage rate allow (docs/FORMAT.md section 12.4).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from structure_support import (
    BREAK_SPEED,
    HARD,
    bake_pillar,
    breaking_magnitude,
    fragment_meshes,
    mid_height_hit,
    struck_fragment,
)

from fracture_cli.geometry.mass import principal_axes, quaternion_xyzw
from fracture_cli.runtime.damage import hit, new_state
from fracture_cli.runtime.format import RuntimeData
from fracture_cli.runtime.impact import ImpactResult, project_impact

DENSITY = 2400.0  # kg/m^3, stone; the pillar is in metres, +Y up
GRAVITY = 9.81
STEP = 1.0 / 240.0  # Bullet's default step
SECONDS = 2.0


@pytest.fixture(scope="module")
def pillar(tmp_path_factory) -> tuple[str, RuntimeData]:
    return bake_pillar(tmp_path_factory.mktemp("pillar"))


def test_pillar_is_anchored_at_its_base_and_carries_damage_and_cracks(pillar):
    stem, data = pillar
    assert data.features == ("anchors", "damage")
    assert data.anchors_info == {"ground": True, "up": "+y", "tolerance": 0.01}
    assert data.damage == {"crack_level": 0.5, "damage_rate": 0.25}
    com = np.asarray(data.gameready["fragment_center_of_mass"], dtype=np.float64)
    anchored = np.asarray(data.anchored) == 1
    # The base (0.3 m tall) is held, the shaft and the capital are not.
    assert anchored.any() and np.all(com[anchored, 1] < 0.3) and np.all(com[~anchored, 1] > 0.3)
    ptr = data.cracks["crack_ptr"]
    assert len(ptr) == data.num_edges + 1 and np.all(np.diff(ptr) > 0)  # every bond of the pillar reaches its surface


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_pillar_falls_where_it_is_broken_and_its_base_stays(pillar, tmp_path):
    pybullet = pytest.importorskip("pybullet", reason="needs pybullet (pip install -e '.[test]', or pip install "
                                                      "pybullet) for the physics test")
    stem, data = pillar
    meshes = fragment_meshes(stem, data)
    assert sorted(meshes) == sorted(data.fragment_names)
    point, direction = mid_height_hit(data)
    struck = struck_fragment(meshes, data, point)
    breaking = breaking_magnitude(data, point, direction, struck)
    magnitude = HARD * breaking
    result = project_impact(data, point, direction * magnitude)
    assert not result.anchored[struck] and np.all(result.anchored[np.asarray(data.anchored) == 1])
    world = _World(pybullet, data, meshes, tmp_path)
    try:
        bodies = world.build(result)
        free = {group: body for group, body in bodies.items() if not body.static}
        assert free and all(not np.any(np.asarray(data.anchored)[body.fragments] == 1) for body in free.values())
        # The game's impulse: the runtime's, in newton-seconds by the calibration (the least breaking hit
        # would set the struck piece's group moving at BREAK_SPEED).
        hit_body = next(b for b in free.values() if struck in b.fragments)
        newton_seconds = magnitude * hit_body.mass * BREAK_SPEED / breaking
        world.apply_impulse(hit_body, point, direction * newton_seconds)
        start = {group: body.position() for group, body in bodies.items()}
        world.run(SECONDS)
        moved = {group: body.position() - start[group] for group, body in bodies.items()}
    finally:
        world.close()
    above = [g for g, body in free.items() if body.top > point[1]]
    assert above, "no free group reaches above the hit"
    falls = {g: -moved[g][1] for g in above}
    base_motion = max(float(np.linalg.norm(moved[g])) for g, body in bodies.items() if body.static)
    print(f"pillar: hit {magnitude:.4g} units ({newton_seconds:.4g} N s) at {np.round(point, 3).tolist()}; "
          f"falls {[round(v, 3) for v in falls.values()]} m; base moved {base_motion:.2e} m")
    assert all(fall > 0.5 for fall in falls.values()), falls
    assert base_motion < 1e-3


def test_quarter_hits_crack_first_and_break_through_within_the_bound(pillar):
    stem, data = pillar
    meshes = fragment_meshes(stem, data)
    point, direction = mid_height_hit(data)
    struck = struck_fragment(meshes, data, point)
    breaking = breaking_magnitude(data, point, direction, struck)
    light = direction * HARD * breaking / 4.0
    c, r = data.damage["crack_level"], data.damage["damage_rate"]
    q = r / (1.0 - c)
    # Every bond of the cut that freed the struck piece had its strength reached at or below `breaking`, so a
    # quarter of the hard hit loads it to at least 0.92 (HARD / 4): it loses at least q (0.92 - c) a hit.
    bound = math.ceil(1.0 / (q * (HARD / 4.0 - c)))
    state = new_state(data)
    results: list[ImpactResult] = []
    while len(results) <= bound and (not results or results[-1].anchored[struck]):
        results.append(hit(data, state, point, light))
    hits = len(results)
    print(f"pillar: {hits} hits of {np.linalg.norm(light):.4g} units break through (bound {bound}, c {c}, r {r})")
    assert not results[-1].anchored[struck], f"no break-through within {bound} hits"
    assert 2 <= hits <= bound
    # The first hit cracks what holds the struck piece, and never breaks through (one quarter hit alone holds it).
    assert results[0].cracked.any() and results[0].anchored[struck]
    assert project_impact(data, point, light).anchored[struck]
    for before, after in zip(results, results[1:]):
        # A bond that breaks on a later hit was cracked by the hits before it.
        assert np.all(before.cracked[after.broken & ~before.broken])


class _Body:
    """A rigid body in the Bullet world: one group of fragments, static or dynamic."""

    def __init__(self, pybullet, uid: int, fragments: list[int], static: bool, mass: float, top: float):
        self.pybullet, self.uid, self.fragments, self.static, self.mass, self.top = (
            pybullet, uid, fragments, static, mass, top)

    def position(self) -> np.ndarray:
        return np.array(self.pybullet.getBasePositionAndOrientation(self.uid)[0], dtype=np.float64)


class _World:
    """Bullet (DIRECT mode) with the pillar's groups: static where the world holds them, dynamic elsewhere."""

    def __init__(self, pybullet, data: RuntimeData, meshes: dict[str, trimesh.Trimesh], folder):
        self.p, self.data, self.meshes, self.folder = pybullet, data, meshes, folder
        self.client = pybullet.connect(pybullet.DIRECT)
        pybullet.setGravity(0.0, -GRAVITY, 0.0, physicsClientId=self.client)
        pybullet.setTimeStep(STEP, physicsClientId=self.client)
        ground_y = float(np.asarray(data.gameready["collision_vertices"])[:, 1].min())
        plane = pybullet.createCollisionShape(pybullet.GEOM_PLANE, planeNormal=[0, 1, 0],
                                              physicsClientId=self.client)
        pybullet.createMultiBody(0.0, plane, basePosition=[0.0, ground_y, 0.0], physicsClientId=self.client)

    def close(self) -> None:
        self.p.disconnect(physicsClientId=self.client)

    def _parts(self, fragment: int) -> list[np.ndarray]:
        """The fragment's convex parts (k, 3) from the runtime file, or the hull of its GLB mesh without them."""
        g = self.data.gameready
        vertices, part_ptr, fragment_ptr = (np.asarray(g[k]) for k in ("collision_vertices", "collision_part_offsets",
                                                                         "collision_fragment_offsets"))
        parts = [vertices[part_ptr[i]:part_ptr[i + 1]].astype(np.float64)
                 for i in range(fragment_ptr[fragment], fragment_ptr[fragment + 1])]
        return parts or [np.asarray(self.meshes[self.data.fragment_names[fragment]].convex_hull.vertices)]

    def _mass(self, fragments: list[int]) -> tuple[float, np.ndarray, np.ndarray]:
        """Mass, centre of mass (3,) and inertia tensor (3, 3) about it of a group, from the runtime file."""
        g = self.data.gameready
        volume = np.asarray(g["fragment_volume"], dtype=np.float64)[fragments]
        centres = np.asarray(g["fragment_center_of_mass"], dtype=np.float64)[fragments]
        six = np.asarray(g["fragment_inertia"], dtype=np.float64)[fragments]
        mass = DENSITY * volume
        com = (mass[:, None] * centres).sum(axis=0) / mass.sum()
        inertia = np.zeros((3, 3))
        for m, c, (xx, yy, zz, xy, xz, yz) in zip(mass, centres, six):
            own = DENSITY * np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
            d = c - com
            inertia += own + m * (d @ d * np.eye(3) - np.outer(d, d))  # parallel axes
        return float(mass.sum()), com, inertia

    def build(self, result: ImpactResult) -> dict[int, _Body]:
        """One body per group of ``result``: static (a body per fragment) where anchored, else dynamic."""
        bodies: dict[int, _Body] = {}
        for group in np.unique(result.groups).tolist():
            members = np.flatnonzero(result.groups == group).tolist()
            if result.anchored[members[0]]:
                for j in members:  # the world holds them: static, each where it was baked
                    bodies[-1 - j] = self._body([j], static=True)
            else:
                bodies[group] = self._body(members, static=False)
        return bodies

    def _body(self, fragments: list[int], static: bool) -> _Body:
        mass, com, inertia = self._mass(fragments)
        # The parts as one OBJ with one object per part: Bullet makes a compound of their convex hulls.
        path = self.folder / f"body_{'_'.join(map(str, fragments))}.obj"
        lines, base = [], 1
        for k, part in enumerate(p for j in fragments for p in self._parts(j)):
            hull = trimesh.convex.convex_hull(part - com)
            lines.append(f"o part{k}")
            lines += [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in hull.vertices.tolist()]
            lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in hull.faces.tolist()]
            base += len(hull.vertices)
        path.write_text("\n".join(lines) + "\n")
        shape = self.p.createCollisionShape(self.p.GEOM_MESH, fileName=str(path), physicsClientId=self.client)
        moments, axes = principal_axes(inertia)
        uid = self.p.createMultiBody(0.0 if static else mass, shape, basePosition=com.tolist(),
                                     baseInertialFrameOrientation=quaternion_xyzw(axes).tolist(),
                                     physicsClientId=self.client)
        if not static:
            self.p.changeDynamics(uid, -1, localInertiaDiagonal=moments.tolist(), physicsClientId=self.client)
        top = max(float(p[:, 1].max()) for j in fragments for p in self._parts(j))
        return _Body(self.p, uid, fragments, static, mass, top)

    def apply_impulse(self, body: _Body, point: np.ndarray, impulse: np.ndarray) -> None:
        """The hit: its impulse at ``point`` (N s), as a force over the next step."""
        self.p.applyExternalForce(body.uid, -1, (impulse / STEP).tolist(), point.tolist(), self.p.WORLD_FRAME,
                                  physicsClientId=self.client)

    def run(self, seconds: float) -> None:
        for _ in range(int(round(seconds / STEP))):
            self.p.stepSimulation(physicsClientId=self.client)

