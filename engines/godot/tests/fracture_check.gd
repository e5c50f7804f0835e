# fracture_check.gd - conformance driver of the GDScript reader (used by the fracture tests).
#
#   godot3-server --path PROJECT --script res://fracture_check.gd -- JOBS
#
# JOBS has one job per line, tab-separated: name, header path, binary path, impacts path (or "-")
# and flags ("--names", "--skip-crc", space-separated). For each job it prints "job <name>", then
# the same lines as engines/c/tools/fracture_check.c ("load-error <message>", or an optional
# "names ..." line and one answer per impact), then "end"; "done" after the last job. One Godot
# start for all jobs: starting the engine costs more than the jobs.
#
# Damage states (docs/FORMAT.md section 12), as engines/web/fracture_check.mjs: an impacts line "state -"
# starts a sequence on a fresh state, "state <e healths as 16 hex digits>" on that state ("state-error
# <reason>" if refused); the impacts after it are hits on the state, each answer followed by
# "health <e hex healths>". On a file with "anchors" or "damage", and in a sequence, every "ok" line is
# followed by "more c <cracked bond indices...> n <anchored flag of each fragment...>".
#
# Levels (docs/FORMAT.md section 14): the "body", "object" and "hit" lines and the "--children" flag of
# tests/levels_support.py (hit_piece, object_pieces).
#
# MIT licence, Copyright (c) fracture developers.
extends SceneTree

const FractureRuntimeScript = preload("res://addons/fracture/fracture_runtime.gd")
const HexBits = preload("res://hex_bits.gd")


func _read(path: String) -> PoolByteArray:
	var file := File.new()
	if file.open(path, File.READ) != OK:
		return PoolByteArray()
	var data := file.get_buffer(file.get_len())
	file.close()
	return data


func _init() -> void:
	var jobs_path := ""
	var after_dashes := false
	for arg in OS.get_cmdline_args():
		if after_dashes and jobs_path == "":
			jobs_path = arg
		after_dashes = after_dashes or arg == "--"
	var jobs := File.new()
	if jobs.open(jobs_path, File.READ) == OK:
		while not jobs.eof_reached():
			var fields: PoolStringArray = jobs.get_line().split("\t")
			if fields.size() >= 5:
				print("job " + fields[0])
				for line in _run_job(fields[1], fields[2], fields[3], fields[4].split(" ", false)):
					print(line)
				print("end")
	print("done")
	quit()


func _run_job(header: String, binary: String, impacts_path: String, flags: PoolStringArray) -> Array:
	var runtime = FractureRuntimeScript.new()
	if runtime.load_bytes(_read(header), _read(binary), not "--skip-crc" in flags) != OK:
		return ["load-error " + runtime.error_message]
	var lines := []
	if "--names" in flags:
		var names := "names"
		for name in runtime.fragment_names:
			var hex: String = (name as String).to_utf8().hex_encode()
			names += " " + (hex if hex != "" else "-")
		lines.append(names)
	if "--children" in flags:
		var children := "children"
		for g in range(runtime.fragments, runtime.all_fragments()):
			var hex: String = runtime.any_fragment_name(g).to_utf8().hex_encode()
			children += " " + (hex if hex != "" else "-")
		lines.append(children)
	var object_state: Array = runtime.new_object_state()
	var structured: bool = runtime.has_damage or not runtime.anchored.empty()
	var state = null  # an Array during a sequence
	var impacts := File.new()
	if impacts_path != "-" and impacts.open(impacts_path, File.READ) == OK:
		while not impacts.eof_reached():
			var t: PoolStringArray = impacts.get_line().split(" ", false)
			if t.size() >= 2 and t[0] == "state":
				state = runtime.new_state() if t[1] == "-" else _doubles(t, 1, t.size())
				var problem: String = runtime.check_state(state)
				if problem != "":
					lines.append("state-error " + problem)
					state = null
				continue
			if t.size() >= 2 and t[0] == "object":
				var next: Array = runtime.new_object_state() if t[1] == "new" else _doubles(t, 1, t.size())
				if runtime.check_object_state(next) == "":
					object_state = next
				else:
					lines.append("object-error " + runtime.check_object_state(next))
				continue
			if t.size() == 9 and t[0] == "hit":
				lines.append(_piece(runtime, t, object_state))
				continue
			if t.size() == 9 and t[0] == "body":
				var view = runtime.body(int(t[1]))
				var rest := PoolStringArray()
				for i in range(2, 9):
					rest.append(t[i])
				var body_hit: Dictionary = view.project(HexBits.from_bits(rest[0]), HexBits.from_bits(rest[1]),
						HexBits.from_bits(rest[2]), HexBits.from_bits(rest[3]), HexBits.from_bits(rest[4]),
						HexBits.from_bits(rest[5]), view.default_threshold if rest[6] == "-" else HexBits.from_bits(rest[6]))
				lines.append(_answer(body_hit))
				if body_hit["ok"] and (view.has_damage or not view.anchored.empty()):
					lines.append(_more(body_hit))
				continue
			if t.size() < 7:
				continue
			var threshold: float = runtime.default_threshold if t[6] == "-" else HexBits.from_bits(t[6])
			var v := _doubles(t, 0, 6)
			var hit: Dictionary
			var quick: Dictionary
			if state == null:
				hit = runtime.project(v[0], v[1], v[2], v[3], v[4], v[5], threshold)
				quick = runtime.project(v[0], v[1], v[2], v[3], v[4], v[5], threshold, false)
			else:
				quick = runtime.hit(state.duplicate(), v[0], v[1], v[2], v[3], v[4], v[5], threshold, false)
				hit = runtime.hit(state, v[0], v[1], v[2], v[3], v[4], v[5], threshold)
			if hit["ok"] and not (quick["ok"] and quick["site"] == hit["site"] and quick["groups"] == hit["groups"]
					and quick["broken"] == hit["broken"] and quick["num_groups"] == hit["num_groups"]
					and quick["cracked"] == hit["cracked"] and quick["anchored"] == hit["anchored"]):
				lines.append("error inconsistent")
			else:
				lines.append(_answer(hit))
				if hit["ok"] and (structured or state != null):
					lines.append(_more(hit))
			if state != null:
				var health := PoolStringArray(["health"])
				for h in state:
					health.append(HexBits.to_bits(h))
				lines.append(health.join(" "))
	return lines


# A "hit" line: hit_piece on the object state, then every piece of the object.
func _piece(runtime, t: PoolStringArray, state: Array) -> String:
	var v := _doubles(t, 2, 8)
	var threshold = null if t[8] == "-" else HexBits.from_bits(t[8])
	var res: Dictionary = runtime.hit_piece(state, int(t[1]), v[0], v[1], v[2], v[3], v[4], v[5], threshold)
	var parts := PoolStringArray(["piece"])
	if not res["ok"]:
		parts.append("error")
		parts.append(res["error"].replace(" ", "_"))
	else:
		var child = res["child_result"]
		parts.append_array(PoolStringArray(["ok", str(res["body"]), str(res["result"]["site"]), str(res["child_body"]),
				str(child["site"] if child != null else -1), "1" if res["split"] else "0", "b"]))
		for m in range(res["result"]["broken"].size()):
			if res["result"]["broken"][m]:
				parts.append(str(m))
		parts.append("c")
		if child != null:
			for m in range(child["broken"].size()):
				if child["broken"][m]:
					parts.append(str(m))
		var pieces: Array = runtime.object_pieces(state)
		parts.append("p")
		for piece in pieces:
			var members := PoolStringArray()
			for g in piece["fragments"]:
				members.append(str(g))
			parts.append(members.join(","))
		parts.append("y")
		for piece in pieces:
			parts.append("1" if piece["anchored"] else "0")
	parts.append("h")
	for h in state:
		parts.append(HexBits.to_bits(h))
	return parts.join(" ")


# The doubles of the hex tokens t[begin] .. t[end - 1].
func _doubles(t: PoolStringArray, begin: int, end: int) -> Array:
	var out := []
	for i in range(begin, end):
		out.append(HexBits.from_bits(t[i]))
	return out


func _more(hit: Dictionary) -> String:
	var parts := PoolStringArray(["more", "c"])
	for m in range(hit["cracked"].size()):
		if hit["cracked"][m]:
			parts.append(str(m))
	parts.append("n")
	for a in hit["anchored"]:
		parts.append(str(a))
	return parts.join(" ")


func _answer(hit: Dictionary) -> String:
	if not hit["ok"]:
		return "error " + hit["error"].replace(" ", "_")
	var parts := PoolStringArray(["ok", str(hit["site"]), str(hit["num_groups"]), "g"])
	for g in hit["groups"]:
		parts.append(str(g))
	parts.append("b")
	for m in range(hit["broken"].size()):
		if hit["broken"][m]:
			parts.append(str(m))
	parts.append("a")
	for a in hit["alpha"]:
		parts.append(HexBits.to_bits(a))
	parts.append("d")
	for x in hit["displacement"]:
		parts.append(HexBits.to_bits(x))
	return parts.join(" ")
