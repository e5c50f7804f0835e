# levels_scene.gd - a FractureBody of a bake with levels, hit, left to fly, hit again (used by the tests).
#
#   godot3-server --fixed-fps 60 --path PROJECT --script res://levels_scene.gd -- SCENE.glb RUNTIME.json HITS FRAMES
#
# HITS has one hit per line: point x y z and impulse x y z in the asset's model space (16-hex-digit doubles),
# then the fragment struck (global index), optionally the threshold (hex; default each level's). The hit goes
# to the body showing that fragment, wherever it is ("~<fragment>": that body, but the add-on picks the
# fragment struck, FractureBody.hit()'s default): the script moves the point and impulse to world space through
# the body's model frame (what a physics engine reports), and FractureBody.hit() moves them back. Between two
# hits it runs FRAMES physics frames (1/60 s each with --fixed-fps 60). After setup, before each hit and after
# each hit it prints every body:
#   body <index> <class> <model frame: 12 numbers, basis columns x, y, z, then origin> f <fragments...>
#     n <names of its fragment meshes...> s <collision shapes per fragment...>
# then "shown <every MeshInstance under the FractureBody that is visible, by name, sorted>" and "step"; each
# hit prints "hit <split 0/1> <fragment struck> used <model-space point and impulse the reader got, hex bits>"
# (or "hit-error ...").
# "done" at the end.
#
# MIT licence, Copyright (c) fracture developers.
extends SceneTree

const FractureBodyScript = preload("res://addons/fracture/fracture_body.gd")
const HexBits = preload("res://hex_bits.gd")

var _args := []
var _body = null
var _hits := []  # [point, impulse, struck]
var _next := 0
var _wait := 0


func _init() -> void:
	var after_dashes := false
	for arg in OS.get_cmdline_args():
		if after_dashes:
			_args.append(arg)
		after_dashes = after_dashes or arg == "--"


func _idle(_delta: float) -> bool:
	if _body == null:
		return _setup()
	if _wait > 0:
		_wait -= 1
		return false
	if _next >= _hits.size():
		print("done")
		quit()
		return true
	_report()  # where the pieces flew
	_hit(_hits[_next])
	_report()
	_next += 1
	_wait = int(_args[3])
	return false


func _setup() -> bool:
	_body = FractureBodyScript.new()
	_body.add_child(load(_args[0]).instance())
	_body.runtime_path = _args[1]
	get_root().add_child(_body)  # _ready() runs setup()
	if _body.runtime == null or _body.error_message != "":
		print("setup-error " + _body.error_message)
		print("done")
		quit()
		return true
	var file := File.new()
	file.open(_args[2], File.READ)
	while not file.eof_reached():
		var t: PoolStringArray = file.get_line().split(" ", false)
		if t.size() < 7:
			continue
		var v := []
		for i in range(6):
			v.append(HexBits.from_bits(t[i]))
		var threshold: float = HexBits.from_bits(t[7]) if t.size() > 7 else -1.0
		var pick: bool = t[6].begins_with("~")
		_hits.append([Vector3(v[0], v[1], v[2]), Vector3(v[3], v[4], v[5]), int(t[6].trim_prefix("~")), threshold,
				pick])
	_report()
	return false


func _hit(h: Array) -> void:
	var struck: int = h[2]
	var target = null
	for body in _body.bodies():
		if struck in _body.members_of(_body.bodies().find(body)):
			target = body
	if target == null:
		print("hit-error fragment %d is in no body" % struck)
		return
	var frame: Transform = _body.model_frame_of(target)
	_body.error_message = ""
	_body.hit(frame.xform(h[0]), frame.basis.xform(h[1]), target, h[3], -1 if h[4] else struck)
	if _body.error_message != "":
		print("hit-error " + _body.error_message)
		return
	var used := PoolStringArray()
	for v in [_body.last_hit["point"], _body.last_hit["impulse"]]:
		used.append_array(PoolStringArray([HexBits.to_bits(v.x), HexBits.to_bits(v.y), HexBits.to_bits(v.z)]))
	print("hit %d %d used %s" % [1 if _body.last_hit["result"]["split"] else 0, _body.last_hit["struck"],
			used.join(" ")])


func _report() -> void:
	var all: Array = _body.bodies()
	for index in range(all.size()):
		var t: Transform = _body.model_frame_of(all[index])
		var line := PoolStringArray(["body", str(index), all[index].get_class()])
		for v in [t.basis.x, t.basis.y, t.basis.z, t.origin]:
			line.append_array(PoolStringArray([str(v.x), str(v.y), str(v.z)]))
		var members: Array = _body.members_of(index)
		line.append("f")
		for g in members:
			line.append(str(g))
		line.append("n")
		var shapes := {}
		for child in all[index].get_children():
			if child is MeshInstance:
				line.append(child.name)
			if child is CollisionShape:
				shapes[child.get_meta("fragment")] = shapes.get(child.get_meta("fragment"), 0) + 1
		line.append("s")
		for g in members:
			line.append(str(shapes.get(g, 0)))
		print(line.join(" "))
	var shown := []
	var todo := [_body]
	while not todo.empty():  # every mesh under the FractureBody, wherever it is
		var node: Node = todo.pop_back()
		todo += node.get_children()
		if node is MeshInstance and node.is_visible_in_tree():
			shown.append(node.name)
	shown.sort()
	print("shown " + PoolStringArray(shown).join(" "))
	print("step")
