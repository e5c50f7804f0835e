"""Engine proof: collision parts exported as ``UCX_`` meshes keep touching fragments at rest in Godot 3.

Two fragments share a ridge-shaped fault, so their plain convex hulls overlap. One rigid body per
fragment, gravity off, one second of physics: with each fragment's convex hull the bodies push each
other apart; with the exported parts (``ConvexPolygonShape`` from the part's exact corners, shape
margin 1e-4) they stay still. Skipped without ``godot3-server`` (.ci/run installs it).
"""

from __future__ import annotations

import manifold3d
import numpy as np
import pytest

from fracture_cli.geometry.mass import mass_properties
from fracture_cli.geometry.trigeom import vertex_normals
from fracture_cli.io.gltf import glb_bytes
from fracture_cli.io.names import fragment_name
from fracture_cli.io.physics import FragmentPhysics, physics_extender
from fracture_cli.io.write import split_by_material
from fracture_cli.stages.collision.convex import collision_shapes
from fracture_cli.types import Material, Normalization

REST_SCRIPT = """extends SceneTree
# One RigidBody per fragment node: its UCX_ parts (mode "parts") or its mesh's hull (mode "hull").
var bodies := []
var frames := 0

func _initialize():
	var args := OS.get_cmdline_args()
	var scene: Spatial = load(args[args.size() - 2]).instance()
	var mode: String = args[args.size() - 1]
	root.add_child(scene)
	for node in scene.get_children():
		if not (node is MeshInstance):
			continue
		var body := RigidBody.new()
		body.gravity_scale = 0.0
		body.transform = node.global_transform
		for child in node.get_children():
			if mode == "parts" and child is MeshInstance and child.name.begins_with("UCX_"):
				body.add_child(_shape(child.mesh.surface_get_arrays(0)[Mesh.ARRAY_VERTEX], child.transform))
		if body.get_child_count() == 0:
			body.add_child(_shape(node.mesh.get_faces(), Transform()))
		bodies.append(body)
	for node in scene.get_children():
		scene.remove_child(node)
		node.queue_free()
	for body in bodies:
		root.add_child(body)

func _shape(points, at: Transform) -> CollisionShape:
	var shape := ConvexPolygonShape.new()
	shape.points = points
	shape.margin = 0.0001
	var node := CollisionShape.new()
	node.shape = shape
	node.transform = at
	return node

func _iteration(_delta):
	frames += 1
	if frames == 60:
		var fastest := 0.0
		for body in bodies:
			fastest = max(fastest, body.linear_velocity.length())
		print("max_speed ", fastest)
		print("bodies ", bodies.size())
		print("done")
		quit()
	return false
"""


def _ridge_pair():
    """A 2 x 1 x 1 box cut by a ridge-shaped fault (the right piece wraps around the left one's ridge)."""
    box = manifold3d.Manifold.cube([2.0, 1.0, 1.0])
    left = box.trim_by_plane([-1.0, 0.6, 0.0], -1.0).trim_by_plane([-1.0, -0.6, 0.0], -1.6)
    out = []
    for solid in (left, box - left):
        mesh = solid.to_mesh64()
        out.append((np.array(mesh.vert_properties)[:, :3].copy(), np.array(mesh.tri_verts, dtype=np.int64)))
    return out


@pytest.mark.slow
def test_exported_parts_keep_fragments_at_rest_in_godot(tmp_path):
    from godot_harness import GodotProject

    project = GodotProject(tmp_path / "godot")  # skips when Godot 3 is missing
    meshes = _ridge_pair()
    shapes = collision_shapes(meshes)
    nodes, physics = [], []
    identity = Normalization.identity()
    for k, (V, F) in enumerate(meshes):
        mass = mass_properties(V, F)
        prims = split_by_material(V, F, vertex_normals(V, F), None, np.zeros(len(F), np.int32), identity,
                                  mass.center)
        nodes.append((fragment_name(k), prims, mass.center))
        physics.append(FragmentPhysics(mass=mass, origin=mass.center, parts=shapes.parts[k]))
    glb = tmp_path / "ridge.glb"
    glb.write_bytes(glb_bytes(nodes, (Material("stone"),), extend=physics_extender(physics, "unreal")))
    scene = project.add_file(glb)
    project.import_resources()
    speed = {}
    for mode in ("hull", "parts"):
        run = project.run_script(REST_SCRIPT, scene, mode)
        speed[mode] = float(run.lines("max_speed ")[0].split()[1])
    print("godot max speed after 1 s", speed)
    assert speed["hull"] > 0.1, speed  # the overlapping hulls push the pieces apart
    assert speed["parts"] < 0.05, speed  # the parts only touch: nothing moves


# Sample assets and their recipes (sample_assets/manifest.toml): about 3 CPU minutes for the three.
_SAMPLES = {"chair.glb": "wood", "pillar.glb": "stone", "vase.obj": "ceramic"}


@pytest.mark.slow
@pytest.mark.parametrize("asset", sorted(_SAMPLES))
def test_baked_sample_rests_in_godot(asset, tmp_path):
    """The real bake with UCX_ parts, imported by Godot 3: one rigid body per fragment, still after 1 s."""
    import json
    import os

    from click.testing import CliRunner
    from godot_harness import GodotProject

    from fracture_cli.cli import cli

    from conftest import SAMPLE_ASSETS

    project = GodotProject(tmp_path / "godot")  # skips when Godot 3 is missing
    out = tmp_path / "bake"
    result = CliRunner().invoke(cli, ["bake", os.path.join(SAMPLE_ASSETS, asset), "-o", str(out), "--recipe",
                                      _SAMPLES[asset], "--set", "collision.glb=unreal", "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    fragments = report["counts"]["fragments"]
    assert report["checks"]["connected"] and report["checks"]["collision_max_overlap"] < 0.01, report["checks"]
    stem = os.path.splitext(asset)[0]
    scene = project.add_file(out / f"{stem}.glb")
    project.import_resources()
    speed = {}
    for mode in ("hull", "parts"):
        run = project.run_script(REST_SCRIPT, scene, mode)
        assert int(run.lines("bodies ")[0].split()[1]) == fragments
        speed[mode] = float(run.lines("max_speed ")[0].split()[1])
    print(f"baked {asset}: godot max speed after 1 s {speed}, {fragments} fragments, "
          f"max overlap {report['checks']['collision_max_overlap']}")
    assert speed["parts"] < 0.05, speed
