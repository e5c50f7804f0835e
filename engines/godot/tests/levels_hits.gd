# levels_hits.gd - hits on a baked asset with levels, the second on a detached piece that flew (Godot 3.x).
#
#   godot3-server --path PROJECT --script res://levels_hits.gd -- HEADER HITS
#
# HITS has one hit per line: "hit <struck> <point x y z> <impulse x y z> <threshold or ->" (hex double
# bits, the asset's model space), or "flying <struck> <point> <impulse> <threshold> <12 numbers>": the same
# on a piece that has moved by the rigid transform of the 12 numbers (basis columns x, y, z, then origin).
# For a flying hit the script does what a game does with a contact from the physics engine: the contact
# point and impulse arrive in world space (here: the model-space ones moved by the transform, through
# Godot's 32-bit Transform), and it undoes the piece's transform before calling hit_piece(). Prints
#   used <point and impulse bits, model space>
#   piece ok <body> <split 0/1> s <struck's children, hex of each name...> p <pieces, comma-separated...>
#     h <health bits...>          (or "piece error <reason>")
# and "done" at the end.
#
# MIT licence, Copyright (c) fracture developers.
extends SceneTree

const FractureRuntimeScript = preload("res://addons/fracture/fracture_runtime.gd")
const HexBits = preload("res://hex_bits.gd")


func _init() -> void:
	var args := OS.get_cmdline_args()
	var header: String = args[args.size() - 2]
	var runtime = FractureRuntimeScript.new()
	if runtime.load_file(header) != OK:
		print("load-error " + runtime.error_message)
		print("done")
		quit()
		return
	var state: Array = runtime.new_object_state()
	var hits := File.new()
	hits.open(args[args.size() - 1], File.READ)
	while not hits.eof_reached():
		var t: PoolStringArray = hits.get_line().split(" ", false)
		if t.size() < 9:
			continue
		var v := []
		for i in range(2, 8):
			v.append(HexBits.from_bits(t[i]))
		if t[0] == "flying":
			var n := []
			for i in range(9, 21):
				n.append(float(t[i]))
			var moved := Transform(Vector3(n[0], n[1], n[2]), Vector3(n[3], n[4], n[5]), Vector3(n[6], n[7], n[8]),
					Vector3(n[9], n[10], n[11]))
			var world_point: Vector3 = moved.xform(Vector3(v[0], v[1], v[2]))  # what the physics engine reports
			var world_impulse: Vector3 = moved.basis.xform(Vector3(v[3], v[4], v[5]))
			var model_point: Vector3 = moved.affine_inverse().xform(world_point)  # the piece's transform undone
			var model_impulse: Vector3 = moved.basis.inverse().xform(world_impulse)
			v = [model_point.x, model_point.y, model_point.z, model_impulse.x, model_impulse.y, model_impulse.z]
		var used := PoolStringArray(["used"])
		for x in v:
			used.append(HexBits.to_bits(x))
		print(used.join(" "))
		var threshold = null if t[8] == "-" else HexBits.from_bits(t[8])
		var struck := int(t[1])
		var res: Dictionary = runtime.hit_piece(state, struck, v[0], v[1], v[2], v[3], v[4], v[5], threshold)
		if not res["ok"]:
			print("piece error " + res["error"])
			continue
		var parts := PoolStringArray(["piece", "ok", str(res["body"]), "1" if res["split"] else "0", "s"])
		if res["split"]:
			var child_body: int = res["child_body"]
			for g in range(runtime.body_first(child_body), runtime.body_first(child_body + 1)):
				parts.append(runtime.any_fragment_name(g).to_utf8().hex_encode())
		parts.append("p")
		for piece in runtime.object_pieces(state):
			var members := PoolStringArray()
			for g in piece["fragments"]:
				members.append(str(g))
			parts.append(members.join(","))
		parts.append("h")
		for h in state:
			parts.append(HexBits.to_bits(h))
		print(parts.join(" "))
	print("done")
	quit()
