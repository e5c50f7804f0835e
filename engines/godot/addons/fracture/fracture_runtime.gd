# fracture_runtime.gd - reader of the `fracture` impact-projection file (Godot 3.x GDScript).
#
# Loads `<stem>.fracture.json` + `<stem>.fracture.bin`, validates them and answers "which
# fragments break off" for a hit (docs/FORMAT.md of the fracture repository, format version 1, and
# version 2 with features "stress", the stress criterion of section 11, "sharing", its load sharing among the
# struck fragment's bonds (section 11.1), "anchors" and "damage", structures and damage that adds up, section 12,
# and "levels", fragments that break again, section 14).
# All arithmetic in GDScript floats (64-bit doubles); never through Vector3 (32-bit floats).
#
#   var runtime = FractureRuntime.new()
#   if runtime.load_file("res://chair.fracture.json") != OK:
#       push_error(runtime.error_message)
#   var hit = runtime.project(x, y, z, nx, ny, nz, runtime.default_threshold)
#   # hit.groups[j]: fragments with equal values move together; hit.groups[j] == j starts a group
#
# Damage that adds up (feature "damage"): keep one state per object, an Array of floats (doubles;
# never a PoolRealArray, whose values are 32-bit in Godot 3), and hit it:
#   var state: Array = runtime.new_state()
#   var res = runtime.hit(state, x, y, z, nx, ny, nz, runtime.default_threshold)  # updates state
#   # res.broken, res.cracked (per bond), res.anchored (per fragment: its group holds on to the world)
#
# MIT licence, Copyright (c) fracture developers (see LICENSE next to this file).
extends Reference
class_name FractureRuntime

const FORMAT_VERSION := 2  # the newest version this reader reads
# The version-2 features this reader implements.
const KNOWN_FEATURES := ["anchors", "damage", "levels", "sharing", "stress"]
# The five arrays of section 2, the four of the stress criterion (section 11, with feature "stress"),
# then those of section 12: anchored (feature "anchors") and the optional crack arrays; last site_fragment
# (section 11.1, feature "sharing").
const ARRAY_NAMES := ["sites", "B", "W", "edges", "edge_areas", "site_bonds_ptr", "site_bonds", "site_bond_gain",
		"bond_strength", "anchored", "crack_ptr", "crack_segments", "site_fragment"]
const ARRAY_RANKS := [2, 3, 3, 2, 1, 1, 1, 2, 1, 1, 1, 3, 1]
const INT_ARRAYS := [3, 5, 6, 9, 10, 12]
const ANCHORED := 9
const CRACK_PTR := 10
const CRACK_SEGMENTS := 11
const SITE_FRAGMENT := 12
const KD_LEAF := 16
const MAX_DEPTH := 64
const BOUND_SLACK := 1e-9  # far above the rounding of a k-term sum in double

var sites_count := 0
var modes := 0
var fragments := 0
var edges_count := 0
var dim := 1
var default_threshold := 0.0
var impact_radius := 0.0
var transform_values := []  # 16 numbers, row-major (informational)
var fragment_names := []
var edges := PoolIntArray()   # (e, 2): P < Q
var edge_areas := PoolRealArray()
var sites := PoolRealArray()  # float32 values, exact
var error_message := ""
# How a hit decides which bonds break: "modes" (section 4) or "stress" (section 11, with the arrays below).
var criterion := "modes"
var site_bonds_count := 0  # stress criterion: entries of the per-site bond lists (counts.site_bonds)
# Feature "sharing" (section 11.1): the struck fragment's bonds share the load of its broken ones. kappa
# (sharing.concentration) and the fragment each site loads; 0.0 and empty without the feature.
var sharing_concentration := 0.0
var site_fragment := PoolIntArray()  # (s,)
# Section 12 (version 2): the file's features, the fragments bonded to the world (1) or not (0), the damage
# parameters, and where each bond's fault meets the surface (drawing only). Empty or defaults without them.
var features := []
var anchored := PoolIntArray()  # (p,) with feature "anchors", else empty
var has_damage := false
var crack_level := 1.0  # c; a file without "damage" acts as c = 1, r = 0 (a state only remembers breaks)
var damage_rate := 0.0  # r
var crack_ptr := PoolIntArray()  # (e + 1,): bond e's segments are crack_ptr[e] .. crack_ptr[e + 1] - 1
var crack_segments := PoolRealArray()  # (n, 2, 3): segment i is values 6 i .. 6 i + 5, model space (float32)

var _B := PoolRealArray()
var _W := PoolRealArray()
var _kd_points := []   # sites in tree order (doubles)
var _kd_index := PoolIntArray()
var _kd_nodes := []    # per node: [begin, end, left, right, lo0, lo1, lo2, hi0, hi1, hi2]
var _whole := PoolIntArray()
var _whole_groups := 0
var _max_bound := 0.0  # largest per-edge bound, see _edge_bounds()
# Arrays copied (in C++) at the start of each projection instead of filled in GDScript loops.
var _identity := []   # 0, 1, ..., p - 1
var _no_edges := []   # e times false
var _zero_edges := [] # e times 0.0
var _zero_modes := [] # k times 0.0
var _no_anchors := [] # p times 0
# Criterion "stress": site v's bonds are entries _bond_ptr[v] .. _bond_ptr[v + 1] - 1 of _bond_edge and
# _bond_gain (G, 3 per entry, float32 values); _bond_strength (S) per edge.
var _bond_ptr := PoolIntArray()
var _bond_edge := PoolIntArray()
var _bond_gain := PoolRealArray()
var _bond_strength := PoolRealArray()
var _stress := false  # set by _parse_header for the file being loaded
var _sharing := false  # set by _parse_header: feature "sharing" (with criterion "stress")
var _incident := []  # with "sharing": per fragment, its bonds (P or Q is the fragment) by increasing index
var _features := []  # set by _parse_header for the file being loaded
var _view := false  # a body's view made by _read_levels (version 2 without features)
var _damage_factor := 0.0  # q = r / (1 - c) of section 12.4, once per file (0 when c = 1)

# JSON parsing state (a strict RFC 8259 parser over the header's bytes).
var _json := PoolByteArray()
var _at := 0
var _depth := 0


# ---------------------------------------------------------------- loading

# Read the header and the binary file it names (in the same folder). OK or an error code.
func load_file(json_path: String, check_crc := true) -> int:
	var file := File.new()
	if file.open(json_path, File.READ) != OK:
		error_message = "%s: cannot read the runtime file" % json_path
		return ERR_FILE_CANT_OPEN
	var header := file.get_buffer(file.get_len())
	file.close()
	var uri = header_uri(header)
	if uri == null:
		return ERR_PARSE_ERROR
	var bin_path: String = json_path.get_base_dir().plus_file(uri)
	if file.open(bin_path, File.READ) != OK:
		error_message = "%s: binary file '%s' not found next to the header" % [json_path, uri]
		return ERR_FILE_NOT_FOUND
	var binary := file.get_buffer(file.get_len())
	file.close()
	return load_bytes(header, binary, check_crc)


# The binary file name (buffer.uri) of a header, or null (error_message says why).
func header_uri(header: PoolByteArray):
	var top = _parse_header(header)
	if top == null:
		return null
	var buffer = top.get("buffer")
	var uri = buffer.get("uri") if buffer is Dictionary else null
	if not _uri_ok(uri):
		return _fail("buffer.uri must be a plain file name next to the header")
	return uri


func _uri_ok(uri) -> bool:
	if not uri is String or uri == "" or uri == "." or uri == "..":
		return false
	for bad in ["/", "\\", ":", char(0)]:
		if bad in uri:
			return false
	return true


func _fail(message: String):
	error_message = message
	return null


# Parse, validate and prepare a runtime file from its two files' bytes. OK or ERR_INVALID_DATA.
func load_bytes(header: PoolByteArray, binary: PoolByteArray, check_crc := true) -> int:
	error_message = ""
	return _load_parsed(_parse_header(header), binary, check_crc)


func _load_parsed(top, binary: PoolByteArray, check_crc: bool) -> int:
	if top == null or _check(top, binary, check_crc) == null:
		return ERR_INVALID_DATA
	_build_kd_tree()
	_whole_graph()
	_edge_bounds()
	if "levels" in _features and _read_levels(top, binary) == null:
		return ERR_INVALID_DATA
	return OK


func _parse_header(header: PoolByteArray):
	_json = header
	_at = 0
	_depth = 0
	var top = _value()
	_space()
	if top == null or _at != _json.size() or not top is Dictionary:
		return _fail("header is not valid JSON (near byte %d)" % _at)
	if top.get("format") != "fracture-modes-runtime":
		return _fail("not a fracture runtime file (expected \"format\": \"fracture-modes-runtime\")")
	var version = _integer(top.get("version"))
	if version == null or version < 1 or version > FORMAT_VERSION:
		return _fail("runtime file version is not supported (this reader knows 1..%d)" % FORMAT_VERSION)
	if _check_features(top, version) == null:
		return null
	return top


# Section 11: version 2 lists the features it needs (refused by name when unknown) and a criterion;
# version 1 ignores both keys. Like the reference reader, a file that lists "stress" must use
# criterion "stress" (the stress arrays come with the criterion), and "sharing" needs it. Sets _stress and
# _sharing; null on failure.
func _check_features(top: Dictionary, version: int):
	_stress = false
	_sharing = false
	_features = []
	if version < 2:
		return true
	var features = top.get("features", [])
	if not features is Array:
		return _fail("runtime header 'features' must be a list of strings")
	for name in features:
		if not name is String:
			return _fail("runtime header 'features' must be a list of strings")
	if features.empty() and not _view:
		return _fail("runtime file version %d lists no features; a file without any is version 1" % version)
	for name in features:
		if not name in KNOWN_FEATURES:
			return _fail("runtime file needs feature '%s', which this reader does not implement" % name)
	var crit = top.get("criterion", "modes")
	if not crit is String:
		return _fail("runtime header 'criterion' must be a string")
	if crit != "modes" and crit != "stress":
		return _fail("runtime file needs criterion '%s', which this reader does not implement" % crit)
	var has_stress: bool = "stress" in features
	if crit == "stress" and not has_stress:
		return _fail("runtime file has criterion 'stress' but does not list feature 'stress'")
	if crit != "stress" and has_stress:
		return _fail("runtime file lists feature 'stress' but its criterion is 'modes' (the stress arrays come " +
				"with criterion 'stress')")
	if "sharing" in features and crit != "stress":
		return _fail("runtime file has feature 'sharing' without criterion 'stress'")
	_stress = has_stress
	_sharing = "sharing" in features
	_features = features
	return true


# JSON integers are parsed as {"int": value}; other numbers as floats.
func _integer(value):
	return value["int"] if value is Dictionary and value.size() == 1 and value.has("int") else null


func _number(value):
	if value is float:
		return value
	var i = _integer(value)
	return i * 1.0 if i != null else null  # not float(i): Godot 3 rounds that to 32 bits


func _check(top: Dictionary, binary: PoolByteArray, check_crc: bool):
	var buffer = top.get("buffer")
	var counts = top.get("counts")
	var names = top.get("fragment_names")
	var table = top.get("arrays")
	var header_dim = _integer(top.get("dim"))
	var threshold = _number(top.get("default_threshold"))
	var radius = _number(top.get("impact_radius"))
	var transform = top.get("transform")
	if not buffer is Dictionary or not counts is Dictionary or not names is Array or not table is Dictionary \
			or header_dim == null or threshold == null or radius == null or not transform is Array \
			or transform.size() != 16:
		return _fail("runtime header is missing or has a malformed entry")
	if not _uri_ok(buffer.get("uri")):
		return _fail("buffer.uri must be a plain file name next to the header")
	var byte_length = _integer(buffer.get("byte_length"))
	if byte_length == null or byte_length != binary.size():
		return _fail("binary file has %d bytes but the header says %s (truncated or from another bake)" \
				% [binary.size(), str(byte_length)])
	if buffer.has("crc32"):
		var crc = _integer(buffer.get("crc32"))
		if crc == null or crc < 0 or crc > 0xFFFFFFFF:
			return _fail("buffer.crc32 must be a 32-bit unsigned integer")
		if check_crc and _crc32(binary) != crc:
			return _fail("binary file does not match its header (crc32 differs; from another bake?)")
	var shapes := []
	for i in range(9 if _stress else 5):
		var shape = _check_array(table.get(ARRAY_NAMES[i]), i, binary.size())
		if shape == null:
			return null
		shapes.append(shape)
	return _check_shapes(top, shapes, counts, names, header_dim, threshold, radius, transform, table, binary)


# One arrays entry: dtype, rank, byte_length = 4 * product(shape), inside the file, 16-byte aligned.
func _check_array(entry, i: int, size: int):
	return _check_entry(entry, ARRAY_NAMES[i], i in INT_ARRAYS, ARRAY_RANKS[i], size)


# An entry of the header's arrays table (the base arrays', the features', the levels'): its shape, or null.
func _check_entry(entry, name: String, is_int: bool, rank: int, size: int):
	if not entry is Dictionary or not entry.get("shape") is Array:
		return _fail("array '%s' entry is missing or malformed" % name)
	if entry.get("dtype") != ("int32" if is_int else "float32"):
		return _fail("array '%s' has the wrong dtype" % name)
	var shape := []
	var count := 1
	for n in entry["shape"]:
		var v = _integer(n)
		if v == null or v < 0:
			return _fail("array '%s' has a negative or non-integer size" % name)
		shape.append(v)
		count = (1 << 40) + 1 if v != 0 and count > (1 << 40) / v else count * v  # saturate
	if shape.size() != rank:
		return _fail("array '%s' has %d dimensions, expected %d" % [name, shape.size(), rank])
	var offset = _integer(entry.get("byte_offset"))
	var length = _integer(entry.get("byte_length"))
	if length == null or count * 4 != length:
		return _fail("array '%s': shape and byte_length do not agree" % name)
	if offset == null or offset < 0 or offset % 16 != 0 or offset > size or length > size - offset:
		return _fail("array '%s' lies outside the binary file or is not 16-byte aligned" % name)
	return shape


func _check_shapes(top, shapes, counts, names, header_dim, threshold, radius, transform, table, binary):
	var s = shapes[0]
	var b = shapes[1]
	var w = shapes[2]
	var e = shapes[3]
	var d = w[2]
	if d != 1 and d != 3:
		return _fail("W must have d = 1 or 3")
	if s[1] != 3 or b[0] != s[0] or b[1] != w[0] or b[2] != d or e[1] != 2 or shapes[4][0] != e[0]:
		return _fail("array shapes do not agree with each other")
	if s[0] < 1 or w[0] < 1 or w[1] < 1:
		return _fail("need at least one site, mode and fragment")
	if header_dim != d:
		return _fail("header says dim = %d but W has d = %d" % [header_dim, d])
	var want := [s[0], w[0], w[1], e[0]]
	var keys := ["sites", "modes", "fragments", "edges"]
	for i in range(4):
		if _integer(counts.get(keys[i])) != want[i]:
			return _fail("header counts do not match the arrays")
	if names.size() != w[1]:
		return _fail("fragment_names must be %d strings" % w[1])
	for name in names:
		if not name is String or char(0) in name:
			return _fail("fragment_names must be %d strings" % w[1])
	if is_nan(threshold) or is_inf(threshold) or threshold < 0:
		return _fail("default_threshold must be a finite number >= 0")
	if is_nan(radius) or is_inf(radius):
		return _fail("impact_radius must be finite")
	for value in transform:
		var v = _number(value)
		if v == null or is_nan(v) or is_inf(v):
			return _fail("transform must be 16 finite numbers")
	var peer := StreamPeerBuffer.new()
	peer.data_array = binary
	var arrays := []
	for i in range(5):
		var entry: Dictionary = table[ARRAY_NAMES[i]]
		var values = _read_array(peer, _integer(entry["byte_offset"]), _integer(entry["byte_length"]) / 4, i == 3)
		if values == null:
			return _fail("array '%s' has non-finite values" % ARRAY_NAMES[i])
		arrays.append(values)
	for m in range(e[0]):
		var P: int = arrays[3][2 * m]
		var Q: int = arrays[3][2 * m + 1]
		if P < 0 or P >= Q or Q >= w[1]:
			return _fail("edge %d is (%d, %d): edges must be (P, Q) with 0 <= P < Q < %d" % [m, P, Q, w[1]])
	if _stress and _check_stress(shapes, counts, table, peer, arrays) == null:
		return null
	var shared = _check_sharing(top, table, peer, binary.size(), s[0], w[1]) if _sharing else PoolIntArray()
	if shared == null:
		return null
	var structure = _check_structure(top, table, counts, peer, binary.size(), e[0], w[1])
	if structure == null:
		return null
	features = _features.duplicate()
	anchored = structure["anchored"]
	has_damage = structure["damage"] != null
	crack_level = structure["damage"][0] if has_damage else 1.0
	damage_rate = structure["damage"][1] if has_damage else 0.0
	_damage_factor = damage_rate / (1.0 - crack_level) if has_damage and crack_level != 1.0 else 0.0
	crack_ptr = structure["crack_ptr"]
	crack_segments = structure["crack_segments"]
	criterion = "stress" if _stress else "modes"
	site_bonds_count = shapes[6][0] if _stress else 0
	_bond_ptr = arrays[5] if _stress else PoolIntArray()
	_bond_edge = arrays[6] if _stress else PoolIntArray()
	_bond_gain = arrays[7] if _stress else PoolRealArray()
	_bond_strength = arrays[8] if _stress else PoolRealArray()
	sharing_concentration = _number(top["sharing"]["concentration"]) if _sharing else 0.0
	site_fragment = shared
	sites_count = s[0]
	modes = w[0]
	fragments = w[1]
	dim = d
	edges_count = e[0]
	default_threshold = threshold
	impact_radius = radius
	transform_values = []
	for value in transform:
		transform_values.append(_number(value))
	fragment_names = names
	sites = arrays[0]
	_B = arrays[1]
	_W = arrays[2]
	edges = arrays[3]
	edge_areas = arrays[4]
	_incident = []
	if _sharing:
		for _j in range(fragments):
			_incident.append([])
		for m in range(edges_count):  # increasing bond index within each fragment's list
			_incident[edges[2 * m]].append(m)
			_incident[edges[2 * m + 1]].append(m)
	return true


# Section 11: shapes, counts.site_bonds, then site_bonds_ptr (from 0, never decreasing, to nnz), site_bonds
# (edge indices, strictly ascending within a site), finite gains and strengths, strengths >= 0. Appends the
# four arrays to `arrays`; null on failure.
func _check_stress(shapes: Array, counts: Dictionary, table: Dictionary, peer: StreamPeerBuffer, arrays: Array):
	var s: int = shapes[0][0]
	var e: int = shapes[3][0]
	var nnz: int = shapes[6][0]
	if shapes[5][0] != s + 1 or shapes[7][0] != nnz or shapes[7][1] != 3 or shapes[8][0] != e:
		return _fail("stress arrays must be site_bonds_ptr (s + 1), site_bonds (nnz), site_bond_gain (nnz, 3) " +
				"and bond_strength (e)")
	if _integer(counts.get("site_bonds")) != nnz:
		return _fail("header counts.site_bonds does not match the arrays")
	for i in range(5, 9):
		var entry: Dictionary = table[ARRAY_NAMES[i]]
		var values = _read_array(peer, _integer(entry["byte_offset"]), _integer(entry["byte_length"]) / 4,
				i in INT_ARRAYS)
		if values == null:
			return _fail("array '%s' has non-finite values" % ARRAY_NAMES[i])
		arrays.append(values)
	var ptr: PoolIntArray = arrays[5]
	var bonds: PoolIntArray = arrays[6]
	if ptr[0] != 0 or ptr[s] != nnz:
		return _fail("site_bonds_ptr must start at 0, never decrease and end at %d" % nnz)
	for v in range(s):
		if ptr[v + 1] < ptr[v]:
			return _fail("site_bonds_ptr must start at 0, never decrease and end at %d" % nnz)
	for v in range(s):
		for j in range(ptr[v], ptr[v + 1]):
			if bonds[j] < 0 or bonds[j] >= e:
				return _fail("site_bonds must be bond indices in 0..%d" % (e - 1))
			if j > ptr[v] and bonds[j] <= bonds[j - 1]:
				return _fail("site_bonds must be strictly ascending within each site")
	for x in arrays[8]:
		if x < 0.0:
			return _fail("bond_strength must be >= 0")
	return true


# Section 11.1: the sharing object (concentration kappa, a finite number > 0) and site_fragment (s,) of
# fragment indices 0..p-1. The array, or null on failure.
func _check_sharing(top: Dictionary, table: Dictionary, peer: StreamPeerBuffer, size: int, s: int, p: int):
	var sharing = top.get("sharing")
	if not sharing is Dictionary:
		return _fail("runtime file lists feature 'sharing' but has no header object 'sharing'")
	var kappa = _number(sharing.get("concentration"))
	if kappa == null or not _finite(kappa) or not kappa > 0.0:
		return _fail("sharing.concentration must be a finite number > 0")
	if not table.has("site_fragment"):
		return _fail("the feature 'sharing' needs the array site_fragment")
	var shape = _check_array(table.get("site_fragment"), SITE_FRAGMENT, size)
	if shape == null:
		return null
	if shape[0] != s:
		return _fail("array site_fragment has shape %s, expected [%d]" % [str(shape), s])
	var values = _read_entry(peer, table, SITE_FRAGMENT)
	for f in values:
		if f < 0 or f >= p:
			return _fail("site_fragment must be fragment indices in 0..%d" % (p - 1))
	return values


# Section 12.2: anchored (p,) of 0/1 with "anchors"; the damage object (0 < c <= 1, finite r >= 0) with
# "damage"; crack_ptr (e + 1, from 0, never decreasing, to n) and crack_segments (n, 2, 3, finite), both or
# neither, in any version-2 file. A Dictionary of what was read, or null on failure.
func _check_structure(top: Dictionary, table: Dictionary, counts: Dictionary, peer: StreamPeerBuffer, size: int,
		e: int, p: int):
	var out := {"anchored": PoolIntArray(), "damage": null, "crack_ptr": PoolIntArray(),
			"crack_segments": PoolRealArray()}
	if "anchors" in _features:
		var shape = _check_array(table.get("anchored"), ANCHORED, size)
		if shape == null:
			return null
		if shape[0] != p:
			return _fail("array 'anchored' must have %d entries, one per fragment" % p)
		var flags = _read_entry(peer, table, ANCHORED)
		for flag in flags:
			if flag != 0 and flag != 1:
				return _fail("array anchored must hold only 0 and 1")
		out["anchored"] = flags
	if "damage" in _features:
		var damage = top.get("damage")
		if not damage is Dictionary:
			return _fail("runtime file lists feature 'damage' but has no header object 'damage'")
		var c = _number(damage.get("crack_level"))
		var r = _number(damage.get("damage_rate"))
		if c == null or not _finite(c) or not (c > 0.0 and c <= 1.0):
			return _fail("damage.crack_level must be a number in (0, 1]")
		if r == null or not _finite(r) or r < 0.0:
			return _fail("damage.damage_rate must be a finite number >= 0")
		out["damage"] = [c, r]
	if (_features.empty() and not _view) or (not table.has("crack_ptr") and not table.has("crack_segments")):
		return out
	if not table.has("crack_ptr") or not table.has("crack_segments"):
		return _fail("the crack arrays come together: crack_ptr and crack_segments")
	var ptr_shape = _check_array(table.get("crack_ptr"), CRACK_PTR, size)
	var segment_shape = _check_array(table.get("crack_segments"), CRACK_SEGMENTS, size) if ptr_shape != null else null
	if segment_shape == null:
		return null
	var n: int = segment_shape[0]
	if ptr_shape[0] != e + 1 or segment_shape[1] != 2 or segment_shape[2] != 3:
		return _fail("crack arrays must be crack_ptr (e + 1) and crack_segments (n, 2, 3)")
	# Present with the crack arrays, as counts.collision_parts with the game-ready arrays (FORMAT.md 12.1).
	if not counts.has("crack_segments") or _integer(counts.get("crack_segments")) != n:
		return _fail("header counts.crack_segments does not match the arrays")
	var ptr = _read_entry(peer, table, CRACK_PTR)
	if ptr[0] != 0 or ptr[e] != n:
		return _fail("crack_ptr must start at 0, never decrease and end at %d" % n)
	for m in range(e):
		if ptr[m + 1] < ptr[m]:
			return _fail("crack_ptr must start at 0, never decrease and end at %d" % n)
	var segments = _read_entry(peer, table, CRACK_SEGMENTS)
	if segments == null:
		return _fail("array 'crack_segments' has non-finite values")
	out["crack_ptr"] = ptr
	out["crack_segments"] = segments
	return out


# The values of array ARRAY_NAMES[i] (checked by _check_array), or null if a float is not finite.
func _read_entry(peer: StreamPeerBuffer, table: Dictionary, i: int):
	var entry: Dictionary = table[ARRAY_NAMES[i]]
	return _read_array(peer, _integer(entry["byte_offset"]), _integer(entry["byte_length"]) / 4, i in INT_ARRAYS)


func _read_array(peer: StreamPeerBuffer, offset: int, count: int, integers: bool):
	var values = PoolIntArray() if integers else PoolRealArray()
	values.resize(count)
	peer.seek(offset)
	for i in range(count):
		var bits := peer.get_u32()
		if integers:
			values[i] = bits - 0x100000000 if bits >= 0x80000000 else bits
		elif bits & 0x7F800000 == 0x7F800000:
			return null
		else:
			peer.seek(offset + 4 * i)
			values[i] = peer.get_float()
	return values


func _crc32(data: PoolByteArray) -> int:
	var table := []  # an Array: PoolIntArray holds 32-bit signed values
	table.resize(256)
	for i in range(256):
		var c := i
		for _k in range(8):
			c = (0xEDB88320 ^ (c >> 1)) if c & 1 else c >> 1
		table[i] = c
	var crc := 0xFFFFFFFF
	for x in data:
		crc = table[(crc ^ x) & 0xFF] ^ (crc >> 8)
	return crc ^ 0xFFFFFFFF


# ---------------------------------------------------------------- JSON (strict RFC 8259)

func _space() -> void:
	while _at < _json.size() and _json[_at] in [32, 9, 10, 13]:
		_at += 1


func _eat(c: int) -> bool:
	_space()
	if _at < _json.size() and _json[_at] == c:
		_at += 1
		return true
	return false


# A value, or null on a syntax error (JSON null is the string "__null__", which no key uses).
func _value():
	_space()
	if _at >= _json.size():
		return null
	var c: int = _json[_at]
	if c == 123 or c == 91:  # { [
		_depth += 1
		if _depth > MAX_DEPTH:
			return null
		var container = _object() if c == 123 else _list()
		_depth -= 1
		return container
	if c == 34:
		return _string()
	if c == 45 or (c >= 48 and c <= 57):
		return _number_token()
	for word in ["true", "false", "null"]:
		if _matches(word):
			_at += word.length()
			return true if word == "true" else (false if word == "false" else "__null__")
	return null


func _matches(word: String) -> bool:
	if _at + word.length() > _json.size():
		return false
	for i in range(word.length()):
		if _json[_at + i] != word.ord_at(i):
			return false
	return true


func _object():
	var result := {}
	_at += 1
	if _eat(125):
		return result
	while true:
		_space()
		if _at >= _json.size() or _json[_at] != 34:
			return null
		var key = _string()
		if key == null or not _eat(58):
			return null
		var value = _value()
		if value == null:
			return null
		result[key] = value
		if _eat(44):
			continue
		return result if _eat(125) else null


func _list():
	var result := []
	_at += 1
	if _eat(93):
		return result
	while true:
		var value = _value()
		if value == null:
			return null
		result.append(value)
		if _eat(44):
			continue
		return result if _eat(93) else null


func _string():
	var out := PoolByteArray()
	_at += 1
	while _at < _json.size():
		var c: int = _json[_at]
		_at += 1
		if c == 34:
			return out.get_string_from_utf8()
		if c < 32:
			return null
		if c >= 128:
			var n := _utf8_length(_at - 1)
			if n == 0:
				return null
			for i in range(n):
				out.append(_json[_at - 1 + i])
			_at += n - 1
		elif c != 92:
			out.append(c)
		else:
			var decoded = _escape()  # returned, not appended: pool arrays are passed by value
			if decoded == null:
				return null
			out.append_array(decoded)
	return null


# The UTF-8 bytes of the escape after a backslash, or null.
func _escape():
	if _at >= _json.size():
		return null
	var e: int = _json[_at]
	_at += 1
	var simple := {34: 34, 92: 92, 47: 47, 98: 8, 102: 12, 110: 10, 114: 13, 116: 9}
	if simple.has(e):
		return PoolByteArray([simple[e]])
	if e != 117:
		return null
	var cp := _hex4()
	if cp < 0 or (cp >= 0xDC00 and cp <= 0xDFFF):
		return null
	if cp >= 0xD800 and cp <= 0xDBFF:
		if _at + 1 >= _json.size() or _json[_at] != 92 or _json[_at + 1] != 117:
			return null
		_at += 2
		var low := _hex4()
		if low < 0xDC00 or low > 0xDFFF:
			return null
		cp = 0x10000 + ((cp - 0xD800) << 10) + (low - 0xDC00)
	if cp < 0x80:
		return PoolByteArray([cp])
	if cp < 0x800:
		return PoolByteArray([0xC0 | (cp >> 6), 0x80 | (cp & 0x3F)])
	if cp < 0x10000:
		return PoolByteArray([0xE0 | (cp >> 12), 0x80 | ((cp >> 6) & 0x3F), 0x80 | (cp & 0x3F)])
	return PoolByteArray([0xF0 | (cp >> 18), 0x80 | ((cp >> 12) & 0x3F), 0x80 | ((cp >> 6) & 0x3F),
			0x80 | (cp & 0x3F)])


func _hex4() -> int:
	if _at + 4 > _json.size():
		return -1
	var value := 0
	for _i in range(4):
		var c: int = _json[_at]
		_at += 1
		var digit := -1
		if c >= 48 and c <= 57:
			digit = c - 48
		elif c >= 97 and c <= 102:
			digit = c - 87
		elif c >= 65 and c <= 70:
			digit = c - 55
		if digit < 0:
			return -1
		value = value * 16 + digit
	return value


# Length of the valid UTF-8 sequence starting at byte i (first byte >= 0x80), 0 if invalid.
func _utf8_length(i: int) -> int:
	var c: int = _json[i]
	var n := 0
	var cp := 0
	var low := 0
	if c >= 0xC2 and c <= 0xDF:
		n = 2
		cp = c & 0x1F
		low = 0x80
	elif c >= 0xE0 and c <= 0xEF:
		n = 3
		cp = c & 0x0F
		low = 0x800
	elif c >= 0xF0 and c <= 0xF4:
		n = 4
		cp = c & 0x07
		low = 0x10000
	else:
		return 0
	if i + n > _json.size():
		return 0
	for k in range(1, n):
		if _json[i + k] & 0xC0 != 0x80:
			return 0
		cp = (cp << 6) | (_json[i + k] & 0x3F)
	if cp < low or cp > 0x10FFFF or (cp >= 0xD800 and cp <= 0xDFFF):
		return 0
	return n


func _number_token():
	var begin := _at
	var integer := true
	if _json[_at] == 45:
		_at += 1
	if _at < _json.size() and _json[_at] == 48:
		_at += 1
	elif not _digits():
		return null
	if _at < _json.size() and _json[_at] == 46:
		integer = false
		_at += 1
		if not _digits():
			return null
	if _at < _json.size() and _json[_at] in [101, 69]:
		integer = false
		_at += 1
		if _at < _json.size() and _json[_at] in [43, 45]:
			_at += 1
		if not _digits():
			return null
	var text := _json.subarray(begin, _at - 1).get_string_from_ascii()
	if integer:
		# Up to 18 digits fit a 64-bit int exactly; longer integers are out of any valid range.
		return {"int": int(text)} if text.trim_prefix("-").length() <= 18 else {"int": -1 << 62}
	return _decimal(text)


# The double of a JSON number with a fraction or an exponent. Godot 3's String.to_float() and float()
# round to 32 bits, so: an integer mantissa below 2^53 scaled by a power of ten up to 1e22 (both exact in
# double) is one correctly rounded operation (Clinger's fast path; it covers what writers emit, "0.6",
# "1e-05"); any other spelling goes through str2var(), which computes in double (within an ulp).
func _decimal(text: String) -> float:
	var negative := text.begins_with("-")
	var mantissa := 0
	var digits := 0
	var scale := 0
	var fraction := false
	var at := 1 if negative else 0
	while at < text.length() and not text[at] in ["e", "E"]:
		var c := text.ord_at(at)
		at += 1
		if c == 46:  # .
			fraction = true
			continue
		if fraction:
			scale -= 1
		if mantissa == 0 and c == 48:
			continue
		if digits == 18:
			return str2var(text.to_lower()) * 1.0
		mantissa = mantissa * 10 + (c - 48)
		digits += 1
	if at < text.length():
		var exponent := text.substr(at + 1, text.length() - at - 1).trim_prefix("+")
		if exponent.trim_prefix("-").length() > 4:
			return str2var(text.to_lower()) * 1.0
		scale += int(exponent)
	if mantissa == 0:
		return -0.0 if negative else 0.0
	if mantissa > (1 << 53) or scale < -22 or scale > 22:
		return str2var(text.to_lower()) * 1.0
	var power := 1.0
	for _k in range(-scale if scale < 0 else scale):
		power *= 10.0
	var value: float = mantissa * power if scale >= 0 else mantissa / power
	return -value if negative else value


func _digits() -> bool:
	var begin := _at
	while _at < _json.size() and _json[_at] >= 48 and _json[_at] <= 57:
		_at += 1
	return _at > begin


# ---------------------------------------------------------------- nearest site (k-d tree)

func _build_kd_tree() -> void:
	_kd_index.resize(sites_count)
	for i in range(sites_count):
		_kd_index[i] = i
	_kd_nodes = []
	_kd_build(0, sites_count)
	_kd_points = []
	for i in range(sites_count):
		for c in range(3):
			_kd_points.append(float(sites[3 * _kd_index[i] + c]))


func _kd_build(begin: int, end: int) -> int:
	var node := [begin, end, -1, -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
	var id := _kd_nodes.size()
	_kd_nodes.append(node)
	var axis := 0
	for c in range(3):
		var lo: float = sites[3 * _kd_index[begin] + c]
		var hi := lo
		for i in range(begin + 1, end):
			var v: float = sites[3 * _kd_index[i] + c]
			if v < lo:  # not min()/max(): those round to 32-bit floats in Godot 3
				lo = v
			if v > hi:
				hi = v
		node[4 + c] = lo
		node[7 + c] = hi
		if hi - lo > node[7 + axis] - node[4 + axis]:
			axis = c
	if end - begin <= KD_LEAF:
		return id
	var mid := begin + (end - begin) / 2
	_select(begin, end - 1, mid, axis)
	node[2] = _kd_build(begin, mid)
	node[3] = _kd_build(mid, end)
	return id


# Quickselect on _kd_index[lo..hi] by coordinate `axis` (any split is correct: boxes are exact).
func _select(lo: int, hi: int, nth: int, axis: int) -> void:
	while hi > lo:
		var pivot: float = sites[3 * _kd_index[lo + (hi - lo) / 2] + axis]
		var i := lo
		var j := hi
		while i <= j:
			while sites[3 * _kd_index[i] + axis] < pivot:
				i += 1
			while sites[3 * _kd_index[j] + axis] > pivot:
				j -= 1
			if i <= j:
				var t := _kd_index[i]
				_kd_index[i] = _kd_index[j]
				_kd_index[j] = t
				i += 1
				j -= 1
		if nth <= j:
			hi = j
		elif nth >= i:
			lo = i
		else:
			break


func _box_distance2(node: Array, x: float, y: float, z: float) -> float:
	var dx := 0.0
	var dy := 0.0
	var dz := 0.0
	if x < node[4]:
		dx = node[4] - x
	elif x > node[7]:
		dx = x - node[7]
	if y < node[5]:
		dy = node[5] - y
	elif y > node[8]:
		dy = y - node[8]
	if z < node[6]:
		dz = node[6] - z
	elif z > node[9]:
		dz = z - node[9]
	return dx * dx + dy * dy + dz * dz


# Nearest contact site, the smallest index on exact ties (a box is skipped only when strictly farther).
func nearest_site(x: float, y: float, z: float) -> int:
	var best := INF
	var best_index := 1 << 62
	var stack := [[0, _box_distance2(_kd_nodes[0], x, y, z)]]
	while not stack.empty():
		var top = stack.pop_back()
		if top[1] > best:
			continue
		var node: Array = _kd_nodes[top[0]]
		if node[2] < 0:
			for i in range(node[0], node[1]):
				var dx: float = _kd_points[3 * i] - x
				var dy: float = _kd_points[3 * i + 1] - y
				var dz: float = _kd_points[3 * i + 2] - z
				var d2 := dx * dx + dy * dy + dz * dz
				if d2 < best or (d2 == best and _kd_index[i] < best_index):
					best = d2
					best_index = _kd_index[i]
			continue
		var a := _box_distance2(_kd_nodes[node[2]], x, y, z)
		var b := _box_distance2(_kd_nodes[node[3]], x, y, z)
		if a <= b:
			stack.append([node[3], b])
			stack.append([node[2], a])
		else:
			stack.append([node[2], a])
			stack.append([node[3], b])
	return best_index


# ---------------------------------------------------------------- projection

func _root(parent: Array, a: int) -> int:
	while parent[a] != a:
		a = parent[a]
	return a


# Groups of the graph without the `broken` edges: the smallest fragment index of each group.
func components(broken: Array) -> PoolIntArray:
	var parent := []  # an Array, not a PoolIntArray: pool arrays are copied when passed to _root()
	parent.resize(fragments)
	for v in range(fragments):
		parent[v] = v
	for m in range(edges_count):
		if not broken[m]:
			var a := _root(parent, edges[2 * m])
			var b := _root(parent, edges[2 * m + 1])
			if a < b:
				parent[b] = a
			elif b < a:
				parent[a] = b
	for v in range(fragments):
		parent[v] = parent[parent[v]]  # parent[v] <= v, so one increasing pass resolves every root
	return PoolIntArray(parent)


func _whole_graph() -> void:
	_identity = []
	for j in range(fragments):
		_identity.append(j)
	_no_edges = []
	_zero_edges = []
	for m in range(edges_count):
		_no_edges.append(false)
		_zero_edges.append(0.0)
	_zero_modes = []
	for i in range(modes):
		_zero_modes.append(0.0)
	_no_anchors = []
	for j in range(fragments):
		_no_anchors.append(0)
	_whole = components(_no_edges)
	_whole_groups = 0
	for j in range(fragments):
		if _whole[j] == j:
			_whole_groups += 1


# The largest over edges of c with |jump'| <= |alpha'| * c for the computed jump (Cauchy-Schwarz on
# W[:, P] - W[:, Q], plus slack for the rounding of both displacements): project() skips the
# displacements and the edge pass when |alpha'| * c <= t.
func _edge_bounds() -> void:
	var count := fragments * dim
	_max_bound = 0.0
	for m in range(edges_count):
		var P: int = edges[2 * m] * dim
		var Q: int = edges[2 * m + 1] * dim
		var diff2 := 0.0
		var wp2 := 0.0
		var wq2 := 0.0
		for i in range(modes):
			for c in range(dim):
				var wp: float = _W[i * count + P + c]
				var wq: float = _W[i * count + Q + c]
				diff2 += (wp - wq) * (wp - wq)
				wp2 += wp * wp
				wq2 += wq * wq
		var bound := (sqrt(diff2) + BOUND_SLACK * (sqrt(wp2) + sqrt(wq2))) * (1.0 + BOUND_SLACK)
		if bound > _max_bound:
			_max_bound = bound


func _finite(x: float) -> bool:
	return not is_nan(x) and not is_inf(x)


# Why a hit's inputs are invalid (section 4), or "".
func _input_error(px: float, py: float, pz: float, nx: float, ny: float, nz: float, threshold: float) -> String:
	if not (_finite(px) and _finite(py) and _finite(pz) and _finite(nx) and _finite(ny) and _finite(nz)):
		return "point and impulse must be finite"
	if is_nan(threshold) or threshold < 0:
		return "threshold must not be NaN or negative"
	return ""


# Project a hit (docs/FORMAT.md section 4). Point in model space, impulse in model axes (any unit),
# threshold in the impulse's unit (INF: unbreakable). Returns a Dictionary: ok (bool), error (String),
# site, groups (PoolIntArray), num_groups, broken (Array of bool), cracked (Array of bool, all false
# without "damage"), anchored (Array of 0/1 per fragment: 1 when its group holds a fragment bonded to the
# world; all 0 without "anchors"), alpha (Array), displacement (Array, p*d; empty when with_displacement
# is false, which skips the displacements when nothing can break). On a file with feature "damage" this
# is hit() on a fresh state that is then thrown away (section 12.4), so bonds may also crack.
func project(px: float, py: float, pz: float, nx: float, ny: float, nz: float, threshold: float,
		with_displacement := true) -> Dictionary:
	if has_damage:
		return _respond(new_state(), px, py, pz, nx, ny, nz, threshold, with_displacement)
	var problem := _input_error(px, py, pz, nx, ny, nz, threshold)
	if problem != "":
		return {"ok": false, "error": problem}
	var site := nearest_site(px, py, pz)
	# Not max(): Godot 3's max() and min() compute in 32-bit floats (1e155 would become INF).
	var m: float = abs(nx)
	if abs(ny) > m:
		m = abs(ny)
	if abs(nz) > m:
		m = abs(nz)
	var alpha: Array = _zero_modes.duplicate()
	var broken: Array = _no_edges.duplicate()
	var groups := _whole
	var disp := []
	var breaks := false
	if m > 0.0:
		var n0 := nx / m
		var n1 := ny / m
		var n2 := nz / m
		var B := _B
		var base := site * modes * dim
		var norm2 := 0.0
		if dim == 1:
			var length := sqrt(n0 * n0 + n1 * n1 + n2 * n2)
			for i in range(modes):
				alpha[i] = B[base + i] * length
				norm2 += alpha[i] * alpha[i]
		else:
			for i in range(modes):
				alpha[i] = B[base + 3 * i] * n0 + B[base + 3 * i + 1] * n1 + B[base + 3 * i + 2] * n2
				norm2 += alpha[i] * alpha[i]
		var t := threshold / m  # overflow: INF, nothing breaks; underflow: 0, any nonzero jump breaks
		if _stress:
			breaks = _stress_break(site, n0, n1, n2, t, broken)
			if with_displacement:
				disp = _displacements(alpha)
			if breaks:
				groups = components(broken)
		else:
			breaks = not (sqrt(norm2) * (1.0 + BOUND_SLACK) * _max_bound <= t)
			if breaks or with_displacement:
				disp = _displacements(alpha)
			if breaks:
				groups = _break(disp, t, broken)
	elif with_displacement:
		disp.resize(fragments * dim)
		for j in range(fragments * dim):
			disp[j] = 0.0
	var num_groups := _whole_groups
	if breaks:
		num_groups = 0
		for j in range(fragments):
			if groups[j] == j:
				num_groups += 1
	for i in range(modes):
		alpha[i] *= m
	if with_displacement:
		for j in range(disp.size()):
			disp[j] *= m
	return {"ok": true, "site": site, "groups": groups, "num_groups": num_groups, "broken": broken,
			"cracked": _no_edges.duplicate(), "anchored": _anchored_of(groups), "alpha": alpha, "displacement": disp}


# ---------------------------------------------------------------- damage states (section 12)

# A fresh damage state (section 12.3): an Array of e floats (doubles), every bond at health 1.0.
func new_state() -> Array:
	var state := []
	state.resize(edges_count)
	for m in range(edges_count):
		state[m] = 1.0
	return state


# Why `state` is not a damage state of this file, or "": an Array (not a PoolRealArray, whose values are
# 32-bit) of e numbers, each finite and in [0, 1].
func check_state(state) -> String:
	if typeof(state) != TYPE_ARRAY or state.size() != edges_count:
		return "a damage state must be an Array of %d bond healths" % edges_count
	for h in state:
		if not typeof(h) in [TYPE_REAL, TYPE_INT] or not (h >= 0 and h <= 1):  # NaN fails both comparisons
			return "a damage state holds numbers in [0, 1]; this one has %s" % str(h)
	return ""


# One hit on `state` (docs/FORMAT.md section 12.4), updated in place. Answers like project() for the state
# after the hit: broken is every broken bond (this hit's and earlier ones'), cracked the bonds that hold
# but were loaded above the crack level now or weakened earlier; groups and anchored follow from the bonds
# that hold (world bonds never break). An invalid state or input: {"ok": false, "error": ...} and the state
# is unchanged. Works on any file: without "damage" the state only remembers which bonds broke.
func hit(state, px: float, py: float, pz: float, nx: float, ny: float, nz: float, threshold: float,
		with_displacement := true) -> Dictionary:
	var problem := check_state(state)
	if problem != "":
		return {"ok": false, "error": problem}
	return _respond(state, px, py, pz, nx, ny, nz, threshold, with_displacement)


# The state as the bytes a game saves: e little-endian doubles (the same in every reader).
func state_to_bytes(state: Array) -> PoolByteArray:
	var peer := StreamPeerBuffer.new()  # little-endian unless told otherwise
	for h in state:
		peer.put_double(h)
	return peer.data_array


# A state saved by state_to_bytes() (or by another reader), checked; null when invalid (error_message says why).
func state_from_bytes(bytes: PoolByteArray):
	if bytes.size() != 8 * edges_count:
		return _fail("a saved damage state of this file has %d bytes, got %d" % [8 * edges_count, bytes.size()])
	var peer := StreamPeerBuffer.new()
	peer.data_array = bytes
	var state := []
	for _m in range(edges_count):
		state.append(peer.get_double())
	var problem := check_state(state)
	return _fail(problem) if problem != "" else state


# Bond `bond`'s crack segments (where its fault meets the surface), two Vector3 per segment, model space
# (exact: the file's values are 32-bit); empty when the file has no crack arrays.
func crack_segments_of(bond: int) -> Array:
	var out := []
	if crack_ptr.empty():
		return out
	for i in range(crack_ptr[bond], crack_ptr[bond + 1]):
		out.append(Vector3(crack_segments[6 * i], crack_segments[6 * i + 1], crack_segments[6 * i + 2]))
		out.append(Vector3(crack_segments[6 * i + 3], crack_segments[6 * i + 4], crack_segments[6 * i + 5]))
	return out


# Section 12.4 on a checked `state`: steps 1-3 update it, step 4 answers.
func _respond(state: Array, px: float, py: float, pz: float, nx: float, ny: float, nz: float, threshold: float,
		with_displacement: bool) -> Dictionary:
	var problem := _input_error(px, py, pz, nx, ny, nz, threshold)
	if problem != "":
		return {"ok": false, "error": problem}
	var site := nearest_site(px, py, pz)
	var m: float = abs(nx)  # not max(): 32-bit in Godot 3
	if abs(ny) > m:
		m = abs(ny)
	if abs(nz) > m:
		m = abs(nz)
	var alpha: Array = _zero_modes.duplicate()
	var now_cracked: Array = _no_edges.duplicate()
	var disp := []
	if m > 0.0:  # a zero impulse changes nothing
		var n0 := nx / m
		var n1 := ny / m
		var n2 := nz / m
		var base := site * modes * dim
		var norm2 := 0.0
		if dim == 1:
			var length := sqrt(n0 * n0 + n1 * n1 + n2 * n2)
			for i in range(modes):
				alpha[i] = _B[base + i] * length
				norm2 += alpha[i] * alpha[i]
		else:
			for i in range(modes):
				alpha[i] = _B[base + 3 * i] * n0 + _B[base + 3 * i + 1] * n1 + _B[base + 3 * i + 2] * n2
				norm2 += alpha[i] * alpha[i]
		var t := threshold / m  # overflow: INF, nothing breaks; underflow: 0, any nonzero measure breaks
		if _stress:
			_stress_damage(state, site, n0, n1, n2, t, now_cracked)
			if with_displacement:
				disp = _displacements(alpha)
		else:
			# No bond cracks when every jump's bound is at most c t (the crack test is a > c * b with b = t).
			var crackable := not (sqrt(norm2) * (1.0 + BOUND_SLACK) * _max_bound <= crack_level * t)
			if crackable or with_displacement:
				disp = _displacements(alpha)
			if crackable:
				_modes_damage(state, disp, t, now_cracked)
	elif with_displacement:
		disp.resize(fragments * dim)
		for j in range(fragments * dim):
			disp[j] = 0.0
	var broken: Array = _no_edges.duplicate()
	var cracked: Array = _no_edges.duplicate()
	for r in range(edges_count):
		broken[r] = state[r] <= 0.0
		cracked[r] = not broken[r] and (now_cracked[r] or state[r] < 1.0)
	var groups := components(broken)
	var num_groups := 0
	for j in range(fragments):
		if groups[j] == j:
			num_groups += 1
	for i in range(modes):
		alpha[i] *= m
	for j in range(disp.size()):
		disp[j] *= m
	return {"ok": true, "site": site, "groups": groups, "num_groups": num_groups, "broken": broken,
			"cracked": cracked, "anchored": _anchored_of(groups), "alpha": alpha, "displacement": disp}


# Step 3 for criterion "modes": measure a = |jump'| (d = 3: sqrt(j0 j0 + j1 j1 + j2 j2)), limit t. A bond
# that does not crack (a <= c t) cannot break either (c <= 1), so only cracked bonds change.
func _modes_damage(state: Array, disp: Array, t: float, now_cracked: Array) -> void:
	var c := crack_level
	var q := _damage_factor
	var limit := c * t  # one product
	var E := edges
	for r in range(edges_count):
		var P: int = E[2 * r]
		var Q: int = E[2 * r + 1]
		var a: float
		if dim == 1:
			a = abs(disp[P] - disp[Q])
		else:
			var j0: float = disp[3 * P] - disp[3 * Q]
			var j1: float = disp[3 * P + 1] - disp[3 * Q + 1]
			var j2: float = disp[3 * P + 2] - disp[3 * Q + 2]
			a = sqrt(j0 * j0 + j1 * j1 + j2 * j2)
		if a > limit:
			now_cracked[r] = true
			var h: float = state[r]
			if h > 0.0:
				h = 0.0 if a > t else h - q * (a / t - c)  # a / b: one division
				state[r] = h if h > 0.0 else 0.0


# Step 3 for criterion "stress": the site's listed bonds, measure g = (G0 n'0 + G1 n'1) + G2 n'2 against
# the limit b = t * S[e]; every other bond has measure 0 and neither cracks nor breaks.
# With "sharing" the measure is section 11.1's (every bond: those off the site's list and the struck fragment's
# have measure 0, which neither cracks nor breaks), with the bonds broken earlier (health <= 0) in the set X.
func _stress_damage(state: Array, site: int, n0: float, n1: float, n2: float, t: float, now_cracked: Array) -> void:
	var c := crack_level
	var q := _damage_factor
	if _sharing:
		var measure := _shared_measure(site, n0, n1, n2, t, state)
		for edge in range(edges_count):
			var a: float = measure[edge]
			var b: float = t * _bond_strength[edge]
			if a > c * b:  # one product
				now_cracked[edge] = true
				var h: float = state[edge]
				if h > 0.0:
					h = 0.0 if a > b else h - q * (a / b - c)  # a / b: one division
					state[edge] = h if h > 0.0 else 0.0
		return
	var G := _bond_gain
	for j in range(_bond_ptr[site], _bond_ptr[site + 1]):
		var g: float = G[3 * j] * n0 + G[3 * j + 1] * n1 + G[3 * j + 2] * n2
		var edge: int = _bond_edge[j]
		var b: float = t * _bond_strength[edge]
		if g > c * b:
			now_cracked[edge] = true
			var h: float = state[edge]
			if h > 0.0:
				h = 0.0 if g > b else h - q * (g / b - c)
				state[edge] = h if h > 0.0 else 0.0


# Per fragment: 1 when its group holds a fragment with anchored = 1 (all 0 without feature "anchors").
func _anchored_of(groups: PoolIntArray) -> Array:
	if anchored.empty():
		return _no_anchors.duplicate()
	var held := {}
	for j in range(anchored.size()):
		if anchored[j] == 1:
			held[groups[j]] = true
	var out := []
	out.resize(fragments)
	for j in range(fragments):
		out[j] = 1 if held.has(groups[j]) else 0
	return out




# Criterion "stress" (docs/FORMAT.md section 11): bond e of the site's list breaks when
# g = (G0 n'0 + G1 n'1) + G2 n'2 > t * S[e] (in this order, strictly); every other bond holds.
# Marks `broken`; returns whether any bond broke.
# With "sharing", the test is on section 11.1's measure, after the struck fragment's bonds shared the load.
func _stress_break(site: int, n0: float, n1: float, n2: float, t: float, broken: Array) -> bool:
	var G := _bond_gain
	var S := _bond_strength
	var E := _bond_edge
	var hit_any := false
	if _sharing:
		var measure := _shared_measure(site, n0, n1, n2, t, [])
		for edge in range(edges_count):
			if measure[edge] > t * S[edge]:
				broken[edge] = true
				hit_any = true
		return hit_any
	for j in range(_bond_ptr[site], _bond_ptr[site + 1]):
		var g: float = G[3 * j] * n0 + G[3 * j + 1] * n1 + G[3 * j + 2] * n2
		var edge: int = E[j]
		var limit: float = t * S[edge]
		if g > limit:
			broken[edge] = true
			hit_any = true
	return hit_any


# Section 11.1 (feature "sharing"): the measure a of every bond, doubles. a0 is section 11's g for the site's
# listed bonds (0 for the others), b = t * S; the bonds F of the struck fragment f = site_fragment[site] (by
# increasing index) run passes: X starts as the bonds of F with a0 > b (and, with a damage `state` (not []),
# those whose health is <= 0); each pass spreads L = sum of max(a0, 0) over F in X on A = sum of the areas of
# F not in X, q = (kappa * L) / A, gives every bond of F not in X a = a0 + q * area and adds those with a > b
# to X after the pass; it stops when L or A is 0 or no bond joins X. Sums in increasing bond order, literally
# as the spec says (so every reader's measures are the same doubles).
func _shared_measure(site: int, n0: float, n1: float, n2: float, t: float, state: Array) -> Array:
	var a: Array = _zero_edges.duplicate()
	var G := _bond_gain
	for j in range(_bond_ptr[site], _bond_ptr[site + 1]):
		a[_bond_edge[j]] = G[3 * j] * n0 + G[3 * j + 1] * n1 + G[3 * j + 2] * n2
	var F: Array = _incident[site_fragment[site]]
	var count := F.size()
	var with_state := not state.empty()
	var a0 := []
	var b := []
	var area := []
	var out := []
	for i in range(count):
		var e: int = F[i]
		var x: float = a[e]
		var y: float = t * _bond_strength[e]
		a0.append(x)
		b.append(y)
		area.append(edge_areas[e])  # float32, exact as a double
		out.append(x > y or (with_state and state[e] <= 0.0))
	var kappa := sharing_concentration
	while true:
		var L := 0.0
		for i in range(count):
			if out[i] and a0[i] > 0.0:  # max(a0, 0) (not max(): 32-bit in Godot 3); adding 0 changes nothing
				L = L + a0[i]
		var A := 0.0
		for i in range(count):
			if not out[i]:
				A = A + area[i]
		if L == 0.0 or A == 0.0:
			break
		var q: float = (kappa * L) / A
		var marked := []
		for i in range(count):
			if not out[i]:
				var x: float = a0[i] + q * area[i]  # one product, one sum (inf * 0 is NaN, which holds)
				a[F[i]] = x
				if x > b[i]:
					marked.append(i)
		if marked.empty():
			break
		for i in marked:
			out[i] = true
	return a


# disp'[j, c] = sum over i of alpha'[i] W[i, j, c], each sum in mode order.
func _displacements(alpha: Array) -> Array:
	var count := fragments * dim
	var W := _W
	var disp := []
	disp.resize(count)
	var a: float = alpha[0]
	for j in range(count):
		disp[j] = 0.0 + a * W[j]  # 0.0 + : the same first sum as a zero start (turns -0.0 into 0.0)
	for i in range(1, modes):
		a = alpha[i]
		var row := i * count
		for j in range(count):
			disp[j] += a * W[row + j]
	return disp


# Steps 5-6: test every edge, union-find (inline: calls are slow in GDScript) over those that hold.
func _break(disp: Array, t: float, broken: Array) -> PoolIntArray:
	var parent: Array = _identity.duplicate()
	var E := edges
	for r in range(edges_count):
		var P: int = E[2 * r]
		var Q: int = E[2 * r + 1]
		var jump: float
		if dim == 1:
			jump = abs(disp[P] - disp[Q])
		else:
			var j0: float = disp[3 * P] - disp[3 * Q]
			var j1: float = disp[3 * P + 1] - disp[3 * Q + 1]
			var j2: float = disp[3 * P + 2] - disp[3 * Q + 2]
			jump = sqrt(j0 * j0 + j1 * j1 + j2 * j2)
		if jump > t:
			broken[r] = true
			continue
		while parent[P] != P:
			P = parent[P]
		while parent[Q] != Q:
			Q = parent[Q]
		if P < Q:  # the smaller root wins: roots are their component's smallest fragment
			parent[Q] = P
		elif Q < P:
			parent[P] = Q
	for j in range(fragments):
		parent[j] = parent[parent[j]]  # parent[j] <= j, so one increasing pass resolves every root
	return PoolIntArray(parent)


# ---------------------------------------------------------------- levels (docs/FORMAT.md section 14)
#
# A body is a set of fragments (its children) with its own impact data: body 0 is this runtime (the p
# level-1 fragments), body b >= 1 breaks fragment body_fragment(b) into fragments body_first(b) ..
# body_first(b + 1) - 1 (global indices over every level). body(b) is body b's view, a FractureRuntime of
# its own (loaded and checked as a file), on which project() and hit() run in local indices. An object
# state is one Array of every body's bond healths; hit_piece() hits the piece holding a shown fragment
# (section 14.5) and object_pieces() lists the rigid bodies a game shows (section 14.4).
#
#   var state: Array = runtime.new_object_state()
#   var res = runtime.hit_piece(state, struck, x, y, z, nx, ny, nz)   # struck: the fragment whose collider was hit
#   # res.split: struck broke into its children; res.pieces: [{"body", "fragments", "anchored"}, ...]

const LEVEL_ARRAYS := ["parent", "body_fragment", "body_child_ptr", "body_site_ptr", "body_sites", "body_B", "body_W",
		"body_edge_ptr", "body_edges", "body_edge_areas", "body_site_bonds_ptr", "body_site_bonds",
		"body_site_bond_gain", "body_bond_strength", "body_crack_ptr", "body_crack_segments", "body_site_fragment"]
const LEVEL_RANKS := [1, 1, 1, 1, 2, 3, 3, 1, 2, 1, 1, 1, 2, 1, 1, 3, 1]
const LEVEL_INTS := [0, 1, 2, 3, 7, 8, 10, 11, 14, 16]

var level_count := 1  # the deepest level
var child_names := []  # the names of fragments p .. p_all - 1
var _lv_parent := []
var _lv_owner := []      # body_fragment
var _lv_child_ptr := []
var _lv_state := []      # where each body's healths start in an object state (nb + 1 entries)
var _lv_body_of := []
var _lv_holding := []
var _lv_views := []      # views[0] is null: body 0 is this runtime


# One levels array entry (dtype, rank, length, inside the file); its shape, or null.
func _check_level_array(entry, i: int, size: int):
	return _check_entry(entry, LEVEL_ARRAYS[i], i in LEVEL_INTS, LEVEL_RANKS[i], size)


func _ptr_ok(ptr, first: int, end: int) -> bool:
	if ptr[0] != first or ptr[ptr.size() - 1] != end:
		return false
	for i in range(1, ptr.size()):
		if ptr[i] < ptr[i - 1]:
			return false
	return true


func _int(value) -> Dictionary:
	return {"int": value}


func _read_levels(top: Dictionary, binary: PoolByteArray):
	var table: Dictionary = top["arrays"]
	var counts: Dictionary = top["counts"]
	var cracks: bool = table.has("body_crack_ptr") or table.has("body_crack_segments")
	var shapes := {}
	var a := {}
	var peer := StreamPeerBuffer.new()
	peer.data_array = binary
	for i in range(LEVEL_ARRAYS.size()):
		if (i >= 10 and i < 14 and not _stress) or (i >= 14 and i < 16 and not cracks) or (i == 16 and not _sharing):
			continue
		var name: String = LEVEL_ARRAYS[i]
		var shape = _check_level_array(table.get(name), i, binary.size())
		if shape == null:
			return null
		var entry: Dictionary = table[name]
		var values = _read_array(peer, _integer(entry["byte_offset"]), _integer(entry["byte_length"]) / 4, i in LEVEL_INTS)
		if values == null:
			return _fail("array '%s' has non-finite values" % name)
		shapes[name] = shape
		a[name] = values
	var p := fragments
	var d := dim
	var parent: PoolIntArray = a["parent"]
	var owner: PoolIntArray = a["body_fragment"]
	var child: PoolIntArray = a["body_child_ptr"]
	var site_ptr: PoolIntArray = a["body_site_ptr"]
	var edge_ptr: PoolIntArray = a["body_edge_ptr"]
	var p_all := parent.size()
	var nb := owner.size()
	var S: int = shapes["body_sites"][0]
	var K: int = shapes["body_B"][1]
	var E: int = shapes["body_edges"][0]
	var C := p_all - p
	if _integer(counts.get("bodies")) != nb or _integer(counts.get("all_fragments")) != p_all \
			or _integer(counts.get("body_sites")) != S or _integer(counts.get("body_modes")) != K \
			or _integer(counts.get("body_edges")) != E:
		return _fail("header counts of the levels arrays do not match the arrays")
	if p_all <= p or nb < 2:
		return _fail("a file with levels has more fragments than level 1 and at least two bodies")
	var info = top.get("levels")
	if not info is Dictionary:
		return _fail("the feature 'levels' needs a header object 'levels'")
	var names = top.get("child_names")
	if not names is Array or names.size() != C:
		return _fail("child_names must be %d strings" % C)
	for name in names:
		if not name is String:
			return _fail("child_names must be %d strings" % C)
	if shapes["body_child_ptr"] != [nb + 1] or shapes["body_site_ptr"] != [nb + 1] or shapes["body_edge_ptr"] != [nb + 1] \
			or shapes["body_sites"] != [S, 3] or K < 1 or shapes["body_B"] != [S, K, d] or shapes["body_W"] != [K, C, d] \
			or shapes["body_edges"] != [E, 2] or shapes["body_edge_areas"] != [E]:
		return _fail("levels array shapes do not agree with each other")
	var N: int = shapes["body_site_bonds"][0] if _stress else 0
	if _stress and (shapes["body_site_bonds_ptr"] != [S + 1] or shapes["body_site_bond_gain"] != [N, 3] \
			or shapes["body_bond_strength"] != [E] or _integer(counts.get("body_site_bonds")) != N):
		return _fail("levels stress arrays do not agree with each other or counts")
	if _sharing and shapes["body_site_fragment"] != [S]:  # its values: each body's view checks them (0 .. c_b - 1)
		return _fail("array body_site_fragment must have %d entries, one per row of body_sites" % S)
	var n: int = shapes["body_crack_segments"][0] if cracks else 0
	if cracks and (shapes["body_crack_ptr"] != [E + 1] or shapes["body_crack_segments"] != [n, 2, 3] \
			or _integer(counts.get("body_crack_segments")) != n):
		return _fail("levels crack arrays do not agree with each other or counts")
	var level := []
	level.resize(p_all)
	var deepest := 1
	for g in range(p_all):
		if (parent[g] != -1) if g < p else not (parent[g] >= 0 and parent[g] < g):
			return _fail("parent must be -1 for the level-1 fragments and a smaller fragment index for every other")
		level[g] = 1 if parent[g] < 0 else level[parent[g]] + 1
		deepest = int(max(deepest, level[g]))
	var ok: bool = owner[0] == -1 and owner[1] >= 0 and owner[nb - 1] < p_all
	for b in range(2, nb):
		ok = ok and owner[b] > owner[b - 1]
	if not ok:
		return _fail("body_fragment must be -1 for body 0, then fragment indices strictly increasing")
	if not _ptr_ok(child, 0, p_all) or child[1] != p:
		return _fail("body_child_ptr must start at 0, then %d, and end at %d" % [p, p_all])
	for b in range(nb):
		if child[b + 1] - child[b] < 2:
			return _fail("every body must have at least 2 children (body %d)" % b)
	for b in range(1, nb):
		for g in range(child[b], child[b + 1]):
			if parent[g] != owner[b]:
				return _fail("parent of every child must be the fragment of the body that holds it")
	if not _ptr_ok(site_ptr, 0, S) or not _ptr_ok(edge_ptr, 0, E) or site_ptr[1] != 0 or edge_ptr[1] != 0:
		return _fail("body_site_ptr and body_edge_ptr must start at 0 (body 0 has no rows) and end at their arrays' lengths")
	for b in range(1, nb):
		if site_ptr[b + 1] <= site_ptr[b]:
			return _fail("body %d has no sites" % b)
	if _stress and not _ptr_ok(a["body_site_bonds_ptr"], 0, N):
		return _fail("body_site_bonds_ptr must start at 0, never decrease and end at N")
	if cracks and not _ptr_ok(a["body_crack_ptr"], 0, n):
		return _fail("body_crack_ptr must start at 0, never decrease and end at n")
	for b in range(1, nb):
		if not anchored.empty() and owner[b] < p and anchored[owner[b]] == 1:
			return _fail("an anchored fragment cannot be broken further (it has a body)")
	if _integer(info.get("count")) != deepest:
		return _fail("levels.count must be the deepest level, %d" % deepest)
	var thresholds = info.get("thresholds")
	if not thresholds is Array or thresholds.size() != deepest:
		return _fail("levels.thresholds must list %d finite numbers >= 0, one per level" % deepest)
	for i in range(deepest):
		var t = _number(thresholds[i])
		if t == null or not _finite(t) or t < 0.0:
			return _fail("levels.thresholds must list %d finite numbers >= 0, one per level" % deepest)
	if _number(thresholds[0]) != default_threshold:
		return _fail("levels.thresholds[0] must be default_threshold")
	var radii = info.get("impact_radii", [])
	level_count = deepest
	child_names = names
	_lv_parent = Array(parent)
	_lv_owner = Array(owner)
	_lv_child_ptr = Array(child)
	_lv_body_of = []
	_lv_holding = []
	for _g in range(p_all):
		_lv_body_of.append(-1)
		_lv_holding.append(0)
	_lv_state = [0]
	for b in range(1, nb):
		_lv_body_of[owner[b]] = b
		for g in range(child[b], child[b + 1]):
			_lv_holding[g] = b
		_lv_state.append(edges_count + edge_ptr[b])
	_lv_state.append(edges_count + E)
	_lv_views = [null]
	for b in range(1, nb):
		var body_level: int = level[owner[b]] + 1
		var radius = _number(radii[body_level - 1]) if radii is Array and radii.size() >= body_level else null
		var view = _make_view(b, a, K, C, cracks, _number(thresholds[body_level - 1]),
				radius if radius != null else impact_radius, top)
		if view == null:
			return null
		_lv_views.append(view)
	return true


func _slice(values, start: int, count: int) -> Array:
	var out := []
	for i in range(start, start + count):
		out.append(values[i])
	return out


# Body b's view (section 14.3): a header Dictionary (as the JSON parser makes them) and binary, loaded by a new
# FractureRuntime as a file of its own.
func _make_view(b: int, a: Dictionary, K: int, C: int, cracks: bool, threshold: float, radius: float, top: Dictionary):
	var p := fragments
	var d := dim
	var s0: int = a["body_site_ptr"][b]
	var s1: int = a["body_site_ptr"][b + 1]
	var g0: int = a["body_child_ptr"][b] - p
	var g1: int = a["body_child_ptr"][b + 1] - p
	var e0: int = a["body_edge_ptr"][b]
	var e1: int = a["body_edge_ptr"][b + 1]
	var sb := s1 - s0
	var cb := g1 - g0
	var eb := e1 - e0
	var W := []
	for k in range(K):
		W += _slice(a["body_W"], (k * C + g0) * d, cb * d)
	var arrays := [["sites", false, [sb, 3], _slice(a["body_sites"], 3 * s0, 3 * sb)],
			["B", false, [sb, K, d], _slice(a["body_B"], s0 * K * d, sb * K * d)], ["W", false, [K, cb, d], W],
			["edges", true, [eb, 2], _slice(a["body_edges"], 2 * e0, 2 * eb)],
			["edge_areas", false, [eb], _slice(a["body_edge_areas"], e0, eb)]]
	var counts := {"sites": _int(sb), "modes": _int(K), "fragments": _int(cb), "edges": _int(eb)}
	var features := []
	if _stress:
		var n0: int = a["body_site_bonds_ptr"][s0]
		var n1: int = a["body_site_bonds_ptr"][s1]
		var ptr := _slice(a["body_site_bonds_ptr"], s0, sb + 1)
		for i in range(ptr.size()):
			ptr[i] -= n0
		arrays += [["site_bonds_ptr", true, [sb + 1], ptr],
				["site_bonds", true, [n1 - n0], _slice(a["body_site_bonds"], n0, n1 - n0)],
				["site_bond_gain", false, [n1 - n0, 3], _slice(a["body_site_bond_gain"], 3 * n0, 3 * (n1 - n0))],
				["bond_strength", false, [eb], _slice(a["body_bond_strength"], e0, eb)]]
		counts["site_bonds"] = _int(n1 - n0)
		if _sharing:
			arrays.append(["site_fragment", true, [sb], _slice(a["body_site_fragment"], s0, sb)])
			features.append("sharing")
		features.append("stress")
	if has_damage:
		features.append("damage")
	if cracks:
		var c0: int = a["body_crack_ptr"][e0]
		var c1: int = a["body_crack_ptr"][e1]
		var ptr := _slice(a["body_crack_ptr"], e0, eb + 1)
		for i in range(ptr.size()):
			ptr[i] -= c0
		arrays += [["crack_ptr", true, [eb + 1], ptr],
				["crack_segments", false, [c1 - c0, 2, 3], _slice(a["body_crack_segments"], 6 * c0, 6 * (c1 - c0))]]
		counts["crack_segments"] = _int(c1 - c0)
	var peer := StreamPeerBuffer.new()  # little-endian
	var entries := {}
	for array in arrays:
		var at := peer.get_size()
		for x in array[3]:
			if array[1]:
				peer.put_32(x)
			else:
				peer.put_float(x)
		var length := peer.get_size() - at
		while peer.get_size() % 16 != 0:
			peer.put_u8(0)
		var shape := []
		for v in array[2]:
			shape.append(_int(v))
		entries[array[0]] = {"dtype": "int32" if array[1] else "float32", "shape": shape, "byte_offset": _int(at),
				"byte_length": _int(length)}
	var view_top := {"format": "fracture-modes-runtime", "version": _int(2), "features": features, "criterion": criterion,
			"dim": _int(d), "counts": counts, "fragment_names": child_names.slice(g0, g1 - 1) if cb > 0 else [],
			"transform": top["transform"], "default_threshold": threshold, "impact_radius": radius,
			"buffer": {"uri": "view.fracture.bin", "byte_length": _int(peer.get_size())}, "arrays": entries}
	if has_damage:
		view_top["damage"] = top["damage"]
	if _sharing:
		view_top["sharing"] = top["sharing"]  # the file's kappa applies to every body
	var view = get_script().new()
	view._view = true
	if view._check_features(view_top, 2) == null or view._load_parsed(view_top, peer.data_array, false) != OK:
		return _fail("body %d: %s" % [b, view.error_message])
	return view


func body_count() -> int:
	return _lv_views.size() if not _lv_views.empty() else 1


func all_fragments() -> int:
	return _lv_parent.size() if not _lv_parent.empty() else fragments


# Body b's view (body 0: this runtime).
func body(b: int):
	return self if b == 0 else _lv_views[b]


func body_fragment(b: int) -> int:
	return -1 if b == 0 else _lv_owner[b]


func body_first(b: int) -> int:
	if _lv_child_ptr.empty():
		return 0 if b == 0 else fragments
	return _lv_child_ptr[b]


# The body breaking fragment g into its children, -1 for a leaf.
func body_of(g: int) -> int:
	return -1 if _lv_body_of.empty() else _lv_body_of[g]


# The body whose child fragment g is (0 at level 1).
func body_holding(g: int) -> int:
	return 0 if _lv_holding.empty() else _lv_holding[g]


func parent_of(g: int) -> int:
	return -1 if _lv_parent.empty() else _lv_parent[g]


# The GLB node name of fragment g (any level).
func any_fragment_name(g: int) -> String:
	return fragment_names[g] if g < fragments else child_names[g - fragments]


func _state_offset(b: int) -> int:
	if _lv_state.empty():
		return 0 if b == 0 else edges_count
	return _lv_state[b]


# A fresh object state (section 14.4): every body's bond healths, all 1.0.
func new_object_state() -> Array:
	var state := []
	for _i in range(_state_offset(body_count())):
		state.append(1.0)
	return state


# Why `state` is not an object state of this file, or "".
func check_object_state(state) -> String:
	var size := _state_offset(body_count())
	if typeof(state) != TYPE_ARRAY or state.size() != size:
		return "an object state must be an Array of %d bond healths (every body's)" % size
	for h in state:
		if not typeof(h) in [TYPE_REAL, TYPE_INT] or not (h >= 0 and h <= 1):
			return "an object state holds numbers in [0, 1]; this one has %s" % str(h)
	return ""


# Groups (smallest local index) of body b's children over bonds with health > 0 between two kept children.
func _body_groups(state: Array, b: int, keep) -> Array:
	var view = body(b)
	var offset := _state_offset(b)
	var parent := []
	for j in range(view.fragments):
		parent.append(j)
	for m in range(view.edges_count):
		var P: int = view.edges[2 * m]
		var Q: int = view.edges[2 * m + 1]
		if state[offset + m] > 0 and (keep == null or (keep[P] and keep[Q])):
			var x := _root(parent, P)
			var y := _root(parent, Q)
			if x < y:
				parent[y] = x
			elif y < x:
				parent[x] = y
	for j in range(parent.size()):
		parent[j] = parent[parent[j]]
	return parent


func _roots(groups: Array) -> int:
	var count := 0
	for j in range(groups.size()):
		if groups[j] == j:
			count += 1
	return count


# Whether fragment g broke into its children (its body's unbroken bonds leave two or more groups).
func is_split(state: Array, g: int) -> bool:
	var b := body_of(g)
	return b >= 0 and _roots(_body_groups(state, b, null)) >= 2


func _opened(state: Array, g: int) -> bool:
	var up := parent_of(g)
	while up >= 0:
		if not is_split(state, up):
			return false
		up = parent_of(up)
	return true


# Whether fragment g is shown: not split, every ancestor split.
func is_shown(state: Array, g: int) -> bool:
	return g >= 0 and g < all_fragments() and not is_split(state, g) and _opened(state, g)


func _shown_children(state: Array, b: int) -> Array:
	var first := body_first(b)
	var keep := []
	for j in range(body(b).fragments):
		keep.append(not is_split(state, first + j))
	return keep


# The pieces of body b's kept children: {"body", "fragments" (global, ascending), "anchored"}, by first fragment.
func _pieces_of(state: Array, b: int, keep: Array) -> Array:
	var groups := _body_groups(state, b, keep)
	var first := body_first(b)
	var pieces := []
	var by_root := {}
	for j in range(groups.size()):
		if not keep[j]:
			continue
		if not by_root.has(groups[j]):
			by_root[groups[j]] = pieces.size()
			pieces.append({"body": b, "fragments": [], "anchored": false})
		var piece: Dictionary = pieces[by_root[groups[j]]]
		piece["fragments"].append(first + j)
		if b == 0 and not anchored.empty() and anchored[j] == 1:
			piece["anchored"] = true
	return pieces


# Every piece of the object (section 14.4): body by body, each by its first fragment.
func object_pieces(state: Array) -> Array:
	var out := []
	for b in range(body_count()):
		if b == 0 or (is_split(state, body_fragment(b)) and _opened(state, body_fragment(b))):
			out += _pieces_of(state, b, _shown_children(state, b))
	return out


# Hit the piece holding the shown fragment `struck` (docs/FORMAT.md section 14.5): point and impulse in the
# asset's model space (undo the piece's rigid transform), threshold null for each body's default. `state` is
# updated in place, unchanged when the hit is refused ({"ok": false, "error": ...}). Answers {"ok", "body",
# "result" (body's answer after the hit, local indices), "child_body" (-1: none), "child_result", "split",
# "pieces" (what struck's piece became)}.
func hit_piece(state, struck: int, px: float, py: float, pz: float, nx: float, ny: float, nz: float,
		threshold = null) -> Dictionary:
	var problem := check_object_state(state)
	if problem != "":
		return {"ok": false, "error": problem}
	if not is_shown(state, struck):
		return {"ok": false, "error": "fragment %d is not shown (split, or inside an unbroken parent)" % struck}
	var b := body_holding(struck)
	var view = body(b)
	var first := body_first(b)
	var offset := _state_offset(b)
	var keep := _shown_children(state, b)
	var before := _body_groups(state, b, keep)
	var inside := []
	for j in range(keep.size()):
		inside.append(keep[j] and before[j] == before[struck - first])
	var trial: Array = state.slice(offset, offset + view.edges_count - 1) if view.edges_count > 0 else []
	var result: Dictionary = view.hit(trial, px, py, pz, nx, ny, nz,
			view.default_threshold if threshold == null else threshold)
	if not result["ok"]:
		return result
	var broken := []
	var cracked := []
	for m in range(view.edges_count):
		var within: bool = inside[view.edges[2 * m]] and inside[view.edges[2 * m + 1]]
		if within:
			state[offset + m] = trial[m]
		broken.append(state[offset + m] <= 0)
		cracked.append(not broken[m] and ((result["cracked"][m] and within) or state[offset + m] < 1))
	var groups := _body_groups(state, b, null)
	result["broken"] = broken
	result["cracked"] = cracked
	result["groups"] = PoolIntArray(groups)
	result["num_groups"] = _roots(groups)
	result["anchored"] = view._anchored_of(PoolIntArray(groups))
	var child_body := body_of(struck)
	var child_result = null
	var split := false
	if child_body >= 0:
		var child_view = body(child_body)
		var child_offset := _state_offset(child_body)
		var health: Array = state.slice(child_offset, child_offset + child_view.edges_count - 1) \
				if child_view.edges_count > 0 else []
		child_result = child_view.hit(health, px, py, pz, nx, ny, nz,
				child_view.default_threshold if threshold == null else threshold)
		for m in range(health.size()):
			state[child_offset + m] = health[m]
		split = child_result["num_groups"] >= 2
	if split:
		inside[struck - first] = false
	var pieces := _pieces_of(state, b, inside)
	if split:
		pieces += _pieces_of(state, child_body, _shown_children(state, child_body))
	return {"ok": true, "struck": struck, "body": b, "result": result, "child_body": child_body,
			"child_result": child_result, "split": split, "pieces": pieces}
