# fracture_body.gd - a baked `fracture` asset that breaks where it is hit (Godot 3.x).
#
# Put the fragments scene (the baked <stem>.glb) under a FractureBody, set runtime_path to its
# <stem>.fracture.json, and call hit() with a world-space point and impulse (from a collision, a
# ray cast, an explosion). The fragments that break off become RigidBodies with the fragments'
# collision shapes; the largest remaining piece stays static (or, with static_rest off, becomes
# one more RigidBody). Hitting a detached piece again breaks that piece further.
#
# Structures and damage (runtime format version 2, features "anchors" and "damage"): the body keeps
# one damage state for the whole object and every hit goes through FractureRuntime.hit(), so damage
# adds up and a bond broken by any hit stays broken (every body splits where its bonds broke). Pieces
# whose group holds an anchored fragment (bonded to the world) stay StaticBodies, only free pieces
# become RigidBodies; cracked bonds are drawn as lines along the file's crack segments.
#
# Load sharing (feature "sharing", docs/FORMAT.md section 11.1) needs nothing here: FractureRuntime's hits
# apply it (the struck fragment's bonds share the load of its broken ones) whenever the file says so.
#
# Levels (runtime format version 2, feature "levels", docs/FORMAT.md section 14): the body keeps one object
# state and every hit goes through FractureRuntime.hit_piece() on the fragment struck (pass it as `struck`, e.g.
# the "fragment" metadata of the CollisionShape the physics engine reports; default: the body's fragment
# nearest the point). The level-2 nodes of the GLB (children of their parent's node) are taken out of the scene
# at setup and come back when their parent splits: its node leaves its body and each new piece of its children
# becomes a RigidBody (the body it split from keeps its largest remaining piece, or, left empty, the largest
# piece of the children). A hit on any body breaks only that body and the fragment struck (section 14.5).
#
# Collision shapes per fragment, first match wins: the fragment's imported "-convcolonly" parts
# (StaticBody children Godot's importer makes from nodes named "<fragment>-convcolonly" or
# "<fragment>_<nn>-convcolonly"), then Unreal-style "UCX_<fragment>_<nn>" meshes, then a convex
# hull of the fragment's own mesh.
#
# MIT licence, Copyright (c) fracture developers (see LICENSE next to this file).
extends Spatial
class_name FractureBody

signal fractured(new_bodies)

const FractureRuntimeScript = preload("fracture_runtime.gd")

export(String, FILE, "*.json") var runtime_path := ""
export(float) var threshold := -1.0  # toughness in your impulse unit; < 0: the file's default_threshold
export(bool) var static_rest := true  # the largest piece of the intact object stays static
export(float) var density := 1000.0  # mass per cubic unit (bounding boxes of the fragment meshes)
export(float) var impulse_scale := 1.0  # physics impulse per unit of hit impulse for detached pieces
export(NodePath) var scene_path := NodePath("")  # the fragments scene; default: the first Spatial child
export(Color) var crack_color := Color(0.12, 0.08, 0.06)  # lines drawn along cracked bonds

var runtime = null  # FractureRuntime
var error_message := ""
# The damage state of a file with "anchors" or "damage" (an Array of bond healths, see FractureRuntime.hit);
# null for other files, whose hits are judged one by one. Save it with runtime.state_to_bytes(state) and
# restore it with runtime.state_from_bytes() before the first hit (bodies split at the next hit). With levels it
# is the object state (FractureRuntime.new_object_state()); restoring one is not supported.
var state = null
# The last hit's inputs and answer: {"point", "impulse"} (the asset's model space, what the reader got), with
# levels also "struck" and "result" (FractureRuntime.hit_piece()'s answer).
var last_hit := {}

var _scene: Spatial
var _meshes := []  # MeshInstance of each fragment
var _rest := []  # Transform of each fragment mesh in the model frame (the scene root at setup)
var _shapes := []  # per fragment: Array of [Shape, Transform in the model frame]
var _volumes := []  # per fragment: bounding-box volume of its mesh (for masses)
var _body_of := []  # body index of each fragment (global index with levels), -1 while it is not shown
var _levels := false  # the file has levels: fragments are every level's, the state an object state
var _bodies := []  # PhysicsBody nodes
var _model_to_body := []  # per body: Transform from the model frame to the body's local frame


func _ready() -> void:
	if runtime == null and runtime_path != "":
		if setup() != OK:
			push_error("FractureBody: " + error_message)


# Load the runtime file and turn the fragments scene into one body. OK or an error code.
func setup() -> int:
	runtime = FractureRuntimeScript.new()
	var status: int = runtime.load_file(runtime_path)
	if status != OK:
		error_message = runtime.error_message
		return status
	_scene = get_node(scene_path) if not scene_path.is_empty() else _first_spatial_child()
	if _scene == null:
		error_message = "no fragments scene under the FractureBody"
		return ERR_DOES_NOT_EXIST
	_levels = runtime.body_count() > 1
	for g in range(runtime.all_fragments()):
		var name: String = runtime.any_fragment_name(g)
		var mesh := _find_named(_scene, name) as MeshInstance
		if mesh == null:
			error_message = "fragment '%s' of the runtime file is not in the scene" % name
			return ERR_DOES_NOT_EXIST
		_meshes.append(mesh)
		_rest.append(_relative(mesh))
		_shapes.append(_collect_shapes(mesh, name))
		var box: AABB = mesh.get_aabb()
		_volumes.append(box.size.x * box.size.y * box.size.z)
		_body_of.append(0 if g < runtime.fragments else -1)
	_remove_collision_helpers(_scene)
	for g in range(runtime.fragments, _meshes.size()):  # level 2 and deeper: hidden until the parent splits
		_meshes[g].get_parent().remove_child(_meshes[g])
	var anchors: bool = not runtime.anchored.empty()
	if _levels:
		state = runtime.new_object_state()
	else:
		state = runtime.new_state() if anchors or runtime.has_damage else null
	var intact: PhysicsBody = StaticBody.new() if static_rest or anchors else RigidBody.new()
	intact.name = "intact"
	_add_body(intact, _scene.global_transform, _scene.global_transform, range(runtime.fragments))
	return OK


# Hidden fragment nodes (out of the scene tree) are freed with the FractureBody.
func _notification(what: int) -> void:
	if what == NOTIFICATION_PREDELETE:
		for mesh in _meshes:
			if is_instance_valid(mesh) and mesh.get_parent() == null:
				mesh.free()


func _first_spatial_child():
	for child in get_children():
		if child is Spatial and not child is PhysicsBody:
			return child
	return null


func _find_named(node: Node, name: String):
	if node.name == name:
		return node
	for child in node.get_children():
		var found = _find_named(child, name)
		if found != null:
			return found
	return null


func _descendants(node: Node) -> Array:
	var out := []
	for child in node.get_children():
		out.append(child)
		out += _descendants(child)
	return out


# A node's transform in the model frame (relative to the scene root).
func _relative(node: Spatial) -> Transform:
	return _scene.global_transform.affine_inverse() * node.global_transform


# "<fragment>" or "<fragment>_<digits>" (Godot's importer drops the "-convcolonly" suffix).
func _is_part_name(node_name: String, fragment: String) -> bool:
	if node_name == fragment:
		return true
	var rest := node_name.trim_prefix(fragment + "_")
	return rest != node_name and rest.is_valid_integer()


func _shapes_of(body: Node) -> Array:
	var parts := []
	for child in body.get_children():
		if child is CollisionShape and child.shape != null:
			parts.append([child.shape, _relative(child)])
	return parts


# [Shape, Transform in the model frame] for every collision part of one fragment.
func _collect_shapes(mesh: MeshInstance, fragment: String) -> Array:
	var parts := []
	for child in mesh.get_children():  # "-convcolonly" children, imported as StaticBodies
		if child is StaticBody:
			parts += _shapes_of(child)
	if parts.empty():  # "-convcolonly" nodes elsewhere in the scene
		for node in _descendants(_scene):
			if node is StaticBody and _is_part_name(node.name, fragment):
				parts += _shapes_of(node)
	if parts.empty():  # Unreal's UCX_<fragment>_<nn> meshes
		for node in _descendants(_scene):
			if node is MeshInstance and node.name.begins_with("UCX_") and _is_part_name(node.name.substr(4), fragment):
				parts.append([node.mesh.create_convex_shape(), _relative(node)])
	if parts.empty():  # no exported parts: the convex hull of the fragment
		parts.append([mesh.mesh.create_convex_shape(), _relative(mesh)])
	return parts


# The imported collision-only nodes are replaced by the bodies' own CollisionShapes.
func _remove_collision_helpers(node: Node) -> void:
	for child in node.get_children():
		if child is StaticBody or (child is MeshInstance and child.name.begins_with("UCX_")):
			node.remove_child(child)
			child.queue_free()
		else:
			_remove_collision_helpers(child)


# Place `body` at `at` and give it the fragments `members`, whose model frame is at `model_frame`
# in world space.
func _add_body(body: PhysicsBody, at: Transform, model_frame: Transform, members: Array) -> void:
	add_child(body)
	body.global_transform = at
	_bodies.append(body)
	_model_to_body.append(at.affine_inverse() * model_frame)
	_attach(_bodies.size() - 1, members)


# Give body `index` the meshes and collision shapes of the fragments `members` (RigidBody: mass from all of its).
func _attach(index: int, members: Array) -> void:
	var body: PhysicsBody = _bodies[index]
	var model_to_body: Transform = _model_to_body[index]
	for j in members:
		_body_of[j] = index
		var mesh: MeshInstance = _meshes[j]
		if mesh.get_parent() != null:
			mesh.get_parent().remove_child(mesh)
		body.add_child(mesh)
		mesh.transform = model_to_body * _rest[j]
		for part in _shapes[j]:
			var shape := CollisionShape.new()
			shape.shape = part[0]
			shape.transform = model_to_body * part[1]
			shape.set_meta("fragment", j)
			body.add_child(shape)
	if body is RigidBody:
		var volume := 0.0
		for j in members_of(index):
			volume += _volumes[j]
		body.mass = max(volume * density, 0.001)


# Fragments of body `index`, in increasing order.
func members_of(index: int) -> Array:
	var out := []
	for j in range(_body_of.size()):
		if _body_of[j] == index:
			out.append(j)
	return out


# Every body, the intact one first.
func bodies() -> Array:
	return _bodies.duplicate()


# Where the asset's model frame is for `body` (world space): every body keeps the model frame, so a model-space
# point p of its fragments is at model_frame_of(body).xform(p).
func model_frame_of(body: PhysicsBody) -> Transform:
	var index := _bodies.find(body)
	return body.global_transform * _model_to_body[index] if index >= 0 else Transform()


# The GLB node name of fragment `g` (a global index with levels).
func fragment_name(g: int) -> String:
	return runtime.any_fragment_name(g)


# Break where hit: world point and impulse (any unit; the threshold's). `body` is the piece that
# was hit (default: the intact object). Returns the new bodies (empty when nothing breaks): RigidBodies,
# and with "anchors" StaticBodies for pieces that broke apart but are each still held by the world.
# With levels, `struck` is the fragment hit (a global index, shown in `body`; the CollisionShape's "fragment"
# metadata), default -1: the body's fragment nearest the point.
func hit(world_point: Vector3, world_impulse: Vector3, body: PhysicsBody = null, hit_threshold := -1.0,
		struck := -1) -> Array:
	if runtime == null:
		return []
	var index := 0 if body == null else _bodies.find(body)
	if index < 0:
		return []
	var target: PhysicsBody = _bodies[index]
	var model_frame: Transform = target.global_transform * _model_to_body[index]
	var to_model: Transform = model_frame.affine_inverse()
	var point: Vector3 = to_model.xform(world_point)
	var impulse: Vector3 = model_frame.basis.orthonormalized().xform_inv(world_impulse)  # rotate only
	last_hit = {"point": point, "impulse": impulse}
	if _levels:
		return _hit_levels(index, point, impulse, world_point, world_impulse, hit_threshold, struck)
	var t: float = hit_threshold if hit_threshold >= 0.0 else (threshold if threshold >= 0.0 else runtime.default_threshold)
	var result: Dictionary
	if state != null:
		result = runtime.hit(state, point.x, point.y, point.z, impulse.x, impulse.y, impulse.z, t, false)
	else:
		result = runtime.project(point.x, point.y, point.z, impulse.x, impulse.y, impulse.z, t, false)
	if not result["ok"]:
		error_message = result["error"]
		return []
	var new_bodies := []
	# Without a state only the hit body can split (other bodies' bonds broken by this hit are forgotten);
	# with one, any body whose bonds are now broken splits, so bodies stay the groups of the state.
	for i in range(_bodies.size()):
		if i == index or state != null:
			var pieces := _split(i, result["broken"])
			if pieces.size() > 1:
				var shared: Vector3 = world_impulse * impulse_scale if i == index else Vector3.ZERO
				new_bodies += _break_body(i, pieces, result["anchored"], world_point, shared)
	if state != null:
		_draw_cracks(result["cracked"])
	if not new_bodies.empty():
		emit_signal("fractured", new_bodies)
	return new_bodies


# A hit on body `index` of a file with levels (docs/FORMAT.md section 14.5), model-space point and impulse.
func _hit_levels(index: int, point: Vector3, impulse: Vector3, world_point: Vector3, world_impulse: Vector3,
		hit_threshold: float, struck: int) -> Array:
	var t = hit_threshold if hit_threshold >= 0.0 else (threshold if threshold >= 0.0 else null)  # null: per level
	if struck < 0:
		var members := members_of(index)
		var singles := []
		for g in members:
			singles.append([g])
		struck = members[_nearest_piece(singles, point)]
	elif struck >= _body_of.size() or _body_of[struck] != index:
		error_message = "fragment %d is not shown in the body hit" % struck
		return []
	var answer: Dictionary = runtime.hit_piece(state, struck, point.x, point.y, point.z, impulse.x, impulse.y,
			impulse.z, t)
	last_hit["struck"] = struck
	last_hit["result"] = answer
	if not answer["ok"]:
		error_message = answer["error"]
		return []
	# What the struck body became: its own body's pieces (the largest first, as _split()), then the children's.
	var own := []
	var children := []
	var anchored := {}
	for piece in answer["pieces"]:
		if piece["body"] == answer["body"]:
			own.append(piece["fragments"])
		else:
			children.append(piece["fragments"])
		for g in piece["fragments"]:
			anchored[g] = 1 if piece["anchored"] else 0
	own.sort_custom(self, "_larger_first")
	children.sort_custom(self, "_larger_first")
	var new_bodies := []
	if answer["split"]:  # the struck fragment's node leaves; its children's come in
		_detach(index, [struck])
		_body_of[struck] = -1
	if own.size() + children.size() > 1:
		new_bodies = _break_body(index, own + children, anchored, world_point, world_impulse * impulse_scale)
	_draw_level_cracks()
	if not new_bodies.empty():
		emit_signal("fractured", new_bodies)
	return new_bodies


# Split body `index` into `pieces` (from _split(): the largest first). A static body keeps its largest
# anchored piece (without anchors: its largest piece); every other piece gets a new body: a StaticBody
# when anchored, else a RigidBody whose origin is the piece's centre of mass (Godot 3 turns a RigidBody
# about its origin; each fragment node's origin is its centre of mass, docs/FORMAT.md section 10).
# `impulse` at `world_point` goes to the free piece that was struck (the one nearest the point); when
# the struck piece stays held, the free ones share it. `anchored[j]` is 1 for every fragment j of an anchored
# piece (an Array over the fragments, or with levels a Dictionary over the pieces' fragments).
func _break_body(index: int, pieces: Array, anchored, world_point: Vector3, impulse: Vector3) -> Array:
	var target: PhysicsBody = _bodies[index]
	var model_frame: Transform = target.global_transform * _model_to_body[index]
	var keep := 0
	if target is StaticBody:
		for k in range(pieces.size()):
			if anchored[pieces[k][0]] == 1:
				keep = k
				break
	var free := 0
	for k in range(pieces.size()):
		if k != keep and anchored[pieces[k][0]] == 0:
			free += 1
	var struck := _nearest_piece(pieces, model_frame.affine_inverse().xform(world_point))
	var struck_free: bool = struck != keep and anchored[pieces[struck][0]] == 0
	var out := []
	for k in range(pieces.size()):
		if k == keep:
			continue
		_detach(index, pieces[k])
		var held: bool = anchored[pieces[k][0]] == 1
		var piece_body: PhysicsBody = StaticBody.new() if held else RigidBody.new()
		piece_body.name = "piece_%d" % _bodies.size()
		var at: Transform = target.global_transform
		if not held:
			at = model_frame * Transform(Basis(), _centre_of(pieces[k]))
		_add_body(piece_body, at, model_frame, pieces[k])
		if not held and target is RigidBody:  # a flying piece's pieces fly on with it
			var arm: Vector3 = piece_body.global_transform.origin - target.global_transform.origin
			piece_body.linear_velocity = target.linear_velocity + target.angular_velocity.cross(arm)
			piece_body.angular_velocity = target.angular_velocity
		if not held and impulse != Vector3.ZERO and (k == struck or not struck_free):
			var share: Vector3 = impulse if struck_free else impulse / float(free)
			piece_body.apply_impulse(world_point - piece_body.global_transform.origin, share)
		out.append(piece_body)
	if _body_of[pieces[keep][0]] != index:  # levels: the body's fragment split, it keeps a piece of its children
		_attach(index, pieces[keep])
	elif target is RigidBody:
		var volume := 0.0
		for j in pieces[keep]:
			volume += _volumes[j]
		target.mass = max(volume * density, 0.001)
	return out


# Centre of mass of `members` in the model frame: their nodes' origins (each a fragment's centre of mass)
# weighted by the fragments' volumes (bounding boxes, as the masses).
func _centre_of(members: Array) -> Vector3:
	var sum := Vector3.ZERO
	var weight := 0.0
	for j in members:
		sum += _rest[j].origin * _volumes[j]
		weight += _volumes[j]
	return sum / weight if weight > 0.0 else _rest[members[0]].origin


# The piece (index into `pieces`) holding the fragment nearest `point` (model frame): the smallest distance
# from the point to a fragment mesh's bounding box, then to the box's centre (a point inside several boxes).
func _nearest_piece(pieces: Array, point: Vector3) -> int:
	var best := 0
	var best_key := [INF, INF]
	for k in range(pieces.size()):
		for j in pieces[k]:
			var box: AABB = _rest[j].xform(_meshes[j].get_aabb())
			var outside: Vector3 = (box.position - point).abs() + (point - box.end).abs() - box.size
			var key := [max(outside.length() * 0.5, 0.0), point.distance_to(box.position + box.size * 0.5)]
			if key[0] < best_key[0] or (key[0] == best_key[0] and key[1] < best_key[1]):
				best_key = key
				best = k
	return best


# Lines along the crack segments of every cracked bond, in the body that holds the bond (a cracked bond
# holds, so both its fragments are in one body), drawn by a "cracks" child in the model frame whose
# "segments" metadata says how many it drew. Nothing without the file's crack arrays.
func _draw_cracks(cracked: Array) -> void:
	if runtime.crack_ptr.empty():
		return
	var segments := []  # per body: the vertices of its lines
	for _i in range(_bodies.size()):
		segments.append([])
	for m in range(runtime.edges_count):
		if cracked[m]:
			segments[_body_of[runtime.edges[2 * m]]] += runtime.crack_segments_of(m)
	_draw_lines(segments)


# With levels: the cracked bonds (0 < health < 1) of every body whose two fragments are shown in one body.
func _draw_level_cracks() -> void:
	var segments := []
	for _i in range(_bodies.size()):
		segments.append([])
	var any := false
	var offset := 0
	for b in range(runtime.body_count()):
		var view = runtime.body(b)
		var first: int = runtime.body_first(b)
		if not view.crack_ptr.empty():
			any = true
			for m in range(view.edges_count):
				var health: float = state[offset + m]
				var i: int = _body_of[first + view.edges[2 * m]]
				if health > 0.0 and health < 1.0 and i >= 0 and i == _body_of[first + view.edges[2 * m + 1]]:
					segments[i] += view.crack_segments_of(m)
		offset += view.edges_count
	if any:
		_draw_lines(segments)


# Draw `segments[i]` (pairs of model-space points) in body i's "cracks" child.
func _draw_lines(segments: Array) -> void:
	var material := SpatialMaterial.new()
	material.flags_unshaded = true
	material.albedo_color = crack_color
	for i in range(_bodies.size()):
		var lines: ImmediateGeometry = _bodies[i].get_node_or_null("cracks")
		if lines == null:
			lines = ImmediateGeometry.new()
			lines.name = "cracks"
			_bodies[i].add_child(lines)
		lines.transform = _model_to_body[i]
		lines.material_override = material
		lines.clear()
		lines.begin(Mesh.PRIMITIVE_LINES)
		for v in segments[i]:
			lines.add_vertex(v)
		lines.end()
		lines.set_meta("segments", segments[i].size() / 2)


# Fragments of body `index` grouped by the unbroken edges between them; the largest group first
# (ties: the one with the smallest fragment), then the others by their smallest fragment.
func _split(index: int, broken: Array) -> Array:
	var parent := {}
	for j in members_of(index):
		parent[j] = j
	for m in range(runtime.edges_count):
		var P: int = runtime.edges[2 * m]
		var Q: int = runtime.edges[2 * m + 1]
		if broken[m] or not parent.has(P) or not parent.has(Q):
			continue
		var a := _root(parent, P)
		var b := _root(parent, Q)
		if a < b:  # not min()/max(): ints must stay ints as dictionary keys
			parent[b] = a
		elif b < a:
			parent[a] = b
	var groups := {}
	var roots := []
	for j in members_of(index):
		var r := _root(parent, j)
		if not groups.has(r):
			groups[r] = []
			roots.append(r)
		groups[r].append(j)
	var pieces := []
	for r in roots:
		pieces.append(groups[r])
	pieces.sort_custom(self, "_larger_first")
	return pieces


func _root(parent: Dictionary, a: int) -> int:
	while parent[a] != a:
		a = parent[a]
	return a


func _larger_first(a: Array, b: Array) -> bool:
	if a.size() != b.size():
		return a.size() > b.size()
	return a[0] < b[0]


# Take the meshes and collision shapes of `members` out of body `index`.
func _detach(index: int, members: Array) -> void:
	var body: PhysicsBody = _bodies[index]
	for child in body.get_children():
		if child is CollisionShape and child.has_meta("fragment") and child.get_meta("fragment") in members:
			body.remove_child(child)
			child.queue_free()
	for j in members:
		if _meshes[j].get_parent() == body:
			body.remove_child(_meshes[j])
