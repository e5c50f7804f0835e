# hex_bits.gd - doubles to and from 16 hex digits of their IEEE-754 bits (the test drivers' protocol).
#
# Exact both ways, unlike Godot 3's decimal parsing (which rounds some values and drops subnormals).
#
# MIT licence, Copyright (c) fracture developers.
extends Reference


static func from_bits(hex: String) -> float:
	var peer := StreamPeerBuffer.new()
	peer.put_32(_hex32(hex.substr(8, 8)))
	peer.put_32(_hex32(hex.substr(0, 8)))
	peer.seek(0)
	return peer.get_double()


static func to_bits(value: float) -> String:
	var peer := StreamPeerBuffer.new()
	peer.put_double(value)
	peer.seek(0)
	var low := peer.get_u32()
	var high := peer.get_u32()
	return "%08x%08x" % [high, low]


# 8 hex digits; String.hex_to_int() clamps to 31 bits in Godot 3.
static func _hex32(text: String) -> int:
	var value := 0
	for i in range(text.length()):
		value = value * 16 + "0123456789abcdef".find(text[i].to_lower())
	return value
