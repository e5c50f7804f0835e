# structure_scene.gd - a FractureBody of a structure (anchors, damage) hit, then left to fall (used by the tests).
#
#   godot3-server --fixed-fps 60 --path PROJECT --script res://structure_scene.gd -- SCENE.glb RUNTIME.json \
#       HITS FRAMES IMPULSE_SCALE DENSITY GROUND_Y
#
# HITS: one hit per line as break_scene.gd reads them (point and impulse as 16-hex-digit doubles, the index of
# the body hit); a floor (a static plane, +Y up) lies at GROUND_Y. Every hit goes through the body's damage state. After setup and after each hit it prints every
# body as "body <index> <class> <12 numbers> <fragment names...>" (its global transform: the basis's columns x, y,
# z, then the origin; a free piece's origin is its centre of mass, fracture_body.gd) and
# "cracks <index> <segments drawn>", then "step"; after the last hit it runs FRAMES physics frames (with
# --fixed-fps 60 a frame is 1/60 s of simulated time, whatever the machine's speed) and prints the bodies once
# more, then "done".
#
# MIT licence, Copyright (c) fracture developers.
extends SceneTree

const FractureBodyScript = preload("res://addons/fracture/fracture_body.gd")
const HexBits = preload("res://hex_bits.gd")

var _args := []
var _body = null
var _frames_left := -1


func _init() -> void:
	var after_dashes := false
	for arg in OS.get_cmdline_args():
		if after_dashes:
			_args.append(arg)
		after_dashes = after_dashes or arg == "--"


# The first frame sets up and hits (the root viewport is in the tree then); the next FRAMES frames simulate.
func _idle(_delta: float) -> bool:
	if _body == null:
		_setup_and_hit()
		return _frames_left < 0
	if _frames_left > 0:
		_frames_left -= 1
		return false
	_report()
	print("done")
	quit()
	return true


func _setup_and_hit() -> void:
	_body = FractureBodyScript.new()
	_body.add_child(load(_args[0]).instance())
	_body.runtime_path = _args[1]
	_body.impulse_scale = float(_args[4])
	_body.density = float(_args[5])
	get_root().add_child(_body)  # _ready() runs setup()
	var floor_shape := CollisionShape.new()
	floor_shape.shape = PlaneShape.new()  # the plane y = 0, facing +Y
	var ground := StaticBody.new()
	ground.add_child(floor_shape)
	ground.translation = Vector3(0.0, float(_args[6]), 0.0)
	get_root().add_child(ground)
	if _body.runtime == null or _body.error_message != "":
		print("setup-error " + _body.error_message)
		print("done")
		quit()
		return
	_report()
	var hits := File.new()
	if hits.open(_args[2], File.READ) == OK:
		while not hits.eof_reached():
			var t: PoolStringArray = hits.get_line().split(" ", false)
			if t.size() < 7:
				continue
			var v := []
			for i in range(6):
				v.append(HexBits.from_bits(t[i]))
			_body.hit(Vector3(v[0], v[1], v[2]), Vector3(v[3], v[4], v[5]), _body.bodies()[int(t[6])])
			_report()
	_frames_left = int(_args[3])


func _report() -> void:
	var all: Array = _body.bodies()
	for index in range(all.size()):
		var t: Transform = all[index].global_transform
		var line := PoolStringArray(["body", str(index), all[index].get_class()])
		for v in [t.basis.x, t.basis.y, t.basis.z, t.origin]:
			line.append_array(PoolStringArray([str(v.x), str(v.y), str(v.z)]))
		for j in _body.members_of(index):
			line.append(_body.runtime.fragment_names[j])
		print(line.join(" "))
		var lines = all[index].get_node_or_null("cracks")
		print("cracks %d %d" % [index, lines.get_meta("segments") if lines != null else 0])
	print("step")
