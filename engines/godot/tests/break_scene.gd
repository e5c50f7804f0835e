# break_scene.gd - a FractureBody in a headless scene, hit as the tests say (used by the fracture tests).
#
#   godot3-server --path PROJECT --script res://break_scene.gd -- SCENE.glb RUNTIME.json HITS
#
# HITS has one hit per line: point x y z and impulse x y z as 16-hex-digit IEEE-754 doubles, then
# the index of the body hit (0: the intact object, then detached pieces in creation order), then
# optionally the threshold (16 hex digits; default: the file's). After setup and after each hit it
# prints every body: "body <index> <class> <fragment names...>", "shapes <index> <fragment>:<number
# of collision shapes>..." and "cracks <index> <crack segments drawn>", then "step"; "done" at the end.
#
# MIT licence, Copyright (c) fracture developers.
extends SceneTree

const FractureBodyScript = preload("res://addons/fracture/fracture_body.gd")
const HexBits = preload("res://hex_bits.gd")

var _args := []
var _started := false


func _init() -> void:
	var after_dashes := false
	for arg in OS.get_cmdline_args():
		if after_dashes:
			_args.append(arg)
		after_dashes = after_dashes or arg == "--"


# The work happens on the first frame, once the root viewport is in the tree.
func _idle(_delta: float) -> bool:
	if _started:
		return false
	_started = true
	var body = FractureBodyScript.new()
	body.add_child(load(_args[0]).instance())
	body.runtime_path = _args[1]
	get_root().add_child(body)  # _ready() runs setup()
	if body.runtime == null or body.error_message != "":
		print("setup-error " + body.error_message)
	else:
		_report(body)
		var hits := File.new()
		if hits.open(_args[2], File.READ) == OK:
			while not hits.eof_reached():
				var t: PoolStringArray = hits.get_line().split(" ", false)
				if t.size() < 7:
					continue
				var target = body.bodies()[int(t[6])]
				var v := []
				for i in range(6):
					v.append(HexBits.from_bits(t[i]))
				var threshold: float = HexBits.from_bits(t[7]) if t.size() > 7 else -1.0
				body.hit(Vector3(v[0], v[1], v[2]), Vector3(v[3], v[4], v[5]), target, threshold)
				_report(body)
	print("done")
	quit()
	return true


func _report(body) -> void:
	var all: Array = body.bodies()
	for index in range(all.size()):
		var names := PoolStringArray(["body", str(index), all[index].get_class()])
		var shapes := PoolStringArray(["shapes", str(index)])
		for j in body.members_of(index):
			names.append(body.runtime.fragment_names[j])
			var count := 0
			for child in all[index].get_children():
				if child is CollisionShape and child.get_meta("fragment") == j:
					count += 1
			shapes.append("%s:%d" % [body.runtime.fragment_names[j], count])
		var lines = all[index].get_node_or_null("cracks")
		print(names.join(" "))
		print(shapes.join(" "))
		print("cracks %d %d" % [index, lines.get_meta("segments") if lines != null else 0])
	print("step")
