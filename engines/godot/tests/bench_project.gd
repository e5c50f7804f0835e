# bench_project.gd - time FractureRuntime.project() per call (used by bench/bench_runtime.py).
#
#   godot3-server --path PROJECT --script res://bench_project.gd -- RUNTIME.json HITS
#
# HITS: one hit per line in fracture_check's protocol (7 hex doubles, "-" for the default
# threshold). Prints "median_us <x> p99_us <x> calls <n>", then "done".
#
# MIT licence, Copyright (c) fracture developers.
extends SceneTree

const FractureRuntimeScript = preload("res://addons/fracture/fracture_runtime.gd")
const HexBits = preload("res://hex_bits.gd")


func _init() -> void:
	var args := []
	var after_dashes := false
	for arg in OS.get_cmdline_args():
		if after_dashes:
			args.append(arg)
		after_dashes = after_dashes or arg == "--"
	var runtime = FractureRuntimeScript.new()
	if runtime.load_file(args[0]) != OK:
		print("load-error " + runtime.error_message)
	else:
		var hits := []
		var file := File.new()
		if file.open(args[1], File.READ) == OK:
			while not file.eof_reached():
				var t: PoolStringArray = file.get_line().split(" ", false)
				if t.size() >= 7:
					var hit := []
					for i in range(6):
						hit.append(HexBits.from_bits(t[i]))
					hit.append(runtime.default_threshold if t[6] == "-" else HexBits.from_bits(t[6]))
					hits.append(hit)
		var times := []
		for hit in hits:
			var start := OS.get_ticks_usec()
			runtime.project(hit[0], hit[1], hit[2], hit[3], hit[4], hit[5], hit[6], false)
			times.append(OS.get_ticks_usec() - start)
		times.sort()
		if not times.empty():
			print("median_us %d p99_us %d calls %d" % [times[times.size() / 2], times[int(0.99 * (times.size() - 1))],
					times.size()])
	print("done")
	quit()
