"""Damaged and unusual-but-valid runtime files for the conformance set (``corrupt/``).

Every case is a header + binary pair built from a valid file by one edit. When
the edit is in the binary data (a NaN, an edge out of range), the header's
crc32 is recomputed, so the case tests that check and not the checksum.
``corrupt/index.json`` lists each case with ``"expect": "rejected"`` or ``"ok"``.
"""

from __future__ import annotations

import json
import os
import struct
import zlib

INDEX_FORMAT = "fracture-runtime-conformance-files"


def _header(header: dict) -> bytes:
    return (json.dumps(header, sort_keys=True, indent=2) + "\n").encode("ascii")


def _set_crc(header: dict, binary: bytes) -> dict:
    if "crc32" in header["buffer"]:
        header["buffer"]["crc32"] = zlib.crc32(binary)
    header["buffer"]["byte_length"] = len(binary)
    return header


def _poke(header: dict, binary: bytes, array: str, index: int, fmt: str, value) -> tuple[dict, bytes]:
    """Overwrite element ``index`` of ``array`` and fix the checksum."""
    raw = bytearray(binary)
    struct.pack_into("<" + fmt, raw, header["arrays"][array]["byte_offset"] + 4 * index, value)
    return _set_crc(header, bytes(raw)), bytes(raw)


def _edit(path: list, value):
    """A header edit: set (or with value ``...`` delete) the entry at ``path``."""

    def apply(header, binary):
        node = header
        for key in path[:-1]:
            node = node[key]
        if value is ...:
            del node[path[-1]]
        else:
            node[path[-1]] = value
        return header, binary

    return apply


def _text(transform):
    """A case that edits the header's bytes (for JSON that cannot be produced by json.dumps)."""

    def apply(header, binary):
        return transform(_header(header)), binary

    return apply


def _relayout(order: list[str], align: int, gap_byte: int = 0):
    """Rewrite the binary with the arrays in ``order``, each at a multiple of ``align``."""

    def apply(header, binary):
        out = bytearray()
        arrays = header["arrays"]
        chunks = {name: binary[e["byte_offset"] : e["byte_offset"] + e["byte_length"]] for name, e in arrays.items()}
        for name in order:
            out += bytes([gap_byte]) * (-len(out) % align)
            arrays[name]["byte_offset"] = len(out)
            out += chunks[name]
        out += bytes([gap_byte]) * (-len(out) % align)
        return _set_crc(header, bytes(out)), bytes(out)

    return apply


def _binary(transform):
    def apply(header, binary):
        return header, transform(binary)

    return apply


def _empty_array(name: str, axis: int):
    """Make one count zero: the array ``name`` gets ``shape[axis] = 0`` and no bytes."""

    def apply(header, binary):
        entry = header["arrays"][name]
        entry["shape"][axis] = 0
        entry["byte_length"] = 0
        return header, binary

    return apply


def _flip_padding(header, binary):
    # A byte in the gap after `sites` (24 bytes, padded to 32): only the checksum notices.
    raw = bytearray(binary)
    raw[28] ^= 0x40
    return header, bytes(raw)


# Cases the numpy reference (fracture_cli/runtime/format.py) does not handle as the spec says yet.
PYTHON_REFERENCE_BUGS: dict[str, str] = {}  # none left: the reference bounds the JSON depth

UNICODE_NAMES = ["fr\u00e4gment_000", '\U0001f4a5 shard "1" \\ /', "tab\there\nnewline \u20ac"]

# (name, base file, edit, expect, what the reader must notice). Bases: "example" (d = 1,
# s = 2, k = 2, p = 3, e = 2) and "dyadic" (d = 3, s = 8, k = 3, p = 5, e = 6).
CASES = [
    ("header_empty", "example", _text(lambda t: b""), "rejected", "empty header"),
    ("header_truncated_half", "example", _text(lambda t: t[: len(t) // 2]), "rejected", "truncated JSON"),
    ("header_truncated_end", "example", _text(lambda t: t[:-3]), "rejected", "missing closing brace"),
    ("header_not_json", "example", _text(lambda t: b"\x00\x01\x02 not json"), "rejected", "not JSON"),
    ("header_not_object", "example", _text(lambda t: b"[1, 2, 3]\n"), "rejected", "JSON but not an object"),
    ("header_trailing_garbage", "example", _text(lambda t: t + b"x"), "rejected", "text after the JSON value"),
    (
        "header_invalid_utf8",
        "example",
        _text(lambda t: t.replace(b"sites are", b"sites \xff\xfe")),
        "rejected",
        "invalid UTF-8",
    ),
    (
        "header_nan_token",
        "example",
        _text(lambda t: t.replace(b'"default_threshold": 1.5', b'"default_threshold": NaN')),
        "rejected",
        "NaN is not JSON (and not a valid threshold)",
    ),
    (
        "header_deep_nesting",
        "example",
        _text(lambda t: t[:-2] + b',\n  "zzz": ' + b"[" * 5000 + b"]" * 5000 + b"\n}\n"),
        "rejected",
        "an unknown key nested 5000 deep: readers limit the depth instead of recursing without bound",
    ),
    ("format_wrong", "example", _edit(["format"], "fracture-modes-runtime-x"), "rejected", "other format"),
    ("format_missing", "example", _edit(["format"], ...), "rejected", "no format key"),
    ("version_2", "example", _edit(["version"], 2), "rejected", "unknown version"),
    ("version_0", "example", _edit(["version"], 0), "rejected", "unknown version"),
    ("version_string", "example", _edit(["version"], "1"), "rejected", "version is not an integer"),
    ("version_fraction", "example", _edit(["version"], 1.5), "rejected", "version is not an integer"),
    ("dim_2", "example", _edit(["dim"], 2), "rejected", "d must be 1 or 3"),
    ("dim_disagrees", "example", _edit(["dim"], 3), "rejected", "dim disagrees with the arrays' shapes"),
    ("counts_sites", "example", _edit(["counts", "sites"], 3), "rejected", "counts disagree with shapes"),
    ("counts_edges_missing", "example", _edit(["counts", "edges"], ...), "rejected", "counts incomplete"),
    (
        "names_too_few",
        "example",
        _edit(["fragment_names"], ["fragment_000", "fragment_001"]),
        "rejected",
        "fewer names than fragments",
    ),
    ("threshold_negative", "example", _edit(["default_threshold"], -1.0), "rejected", "default threshold < 0"),
    (
        "threshold_overflow",
        "example",
        _text(lambda t: t.replace(b'"default_threshold": 1.5', b'"default_threshold": 1e999')),
        "rejected",
        "default threshold is not finite",
    ),
    ("buffer_missing", "example", _edit(["buffer"], ...), "rejected", "no buffer entry"),
    ("byte_length_wrong", "example", _edit(["buffer", "byte_length"], 128), "rejected", "binary size differs"),
    (
        "uri_directory",
        "example",
        _edit(["buffer", "uri"], "sub/example.fracture.bin"),
        "rejected",
        "uri is not a plain file name",
    ),
    (
        "uri_parent",
        "example",
        _edit(["buffer", "uri"], "../example.fracture.bin"),
        "rejected",
        "uri is not a plain file name",
    ),
    (
        "uri_backslash",
        "example",
        _edit(["buffer", "uri"], "sub\\example.fracture.bin"),
        "rejected",
        "uri is not a plain file name",
    ),
    ("uri_empty", "example", _edit(["buffer", "uri"], ""), "rejected", "uri is empty"),
    ("arrays_missing", "example", _edit(["arrays"], ...), "rejected", "no arrays table"),
    ("array_W_missing", "example", _edit(["arrays", "W"], ...), "rejected", "array W missing"),
    ("dtype_float64", "example", _edit(["arrays", "sites", "dtype"], "float64"), "rejected", "wrong dtype"),
    ("dtype_edges_float", "example", _edit(["arrays", "edges", "dtype"], "float32"), "rejected", "wrong dtype"),
    ("shape_rank", "example", _edit(["arrays", "sites", "shape"], [6]), "rejected", "sites must be (s, 3)"),
    ("shape_negative", "example", _edit(["arrays", "B", "shape"], [-2, -2, 1]), "rejected", "negative size"),
    (
        "shape_vs_length",
        "example",
        _edit(["arrays", "W", "byte_length"], 20),
        "rejected",
        "byte_length != 4 * product(shape)",
    ),
    (
        "shape_overflow",
        "example",
        _edit(["arrays", "B", "shape"], [1 << 31, 1 << 31, 1 << 2]),
        "rejected",
        "product of the shape overflows 64 bits",
    ),
    (
        "offset_outside",
        "example",
        _edit(["arrays", "edge_areas", "byte_offset"], 112),
        "rejected",
        "array past the end of the binary",
    ),
    ("offset_negative", "example", _edit(["arrays", "sites", "byte_offset"], -16), "rejected", "negative offset"),
    (
        "offset_huge",
        "example",
        _edit(["arrays", "sites", "byte_offset"], 1 << 62),
        "rejected",
        "offset + length overflows",
    ),
    (
        "offset_unaligned_4",
        "example",
        _edit(["arrays", "B", "byte_offset"], 34),
        "rejected",
        "offset not a multiple of 16",
    ),
    (
        "offset_unaligned_16",
        "example",
        _relayout(["sites", "B", "W", "edges", "edge_areas"], 4),
        "rejected",
        "arrays packed at 4-byte alignment (offsets must be multiples of 16)",
    ),
    ("bin_truncated", "example", _binary(lambda b: b[:-1]), "rejected", "binary shorter than byte_length"),
    ("bin_empty", "example", _binary(lambda b: b""), "rejected", "empty binary"),
    ("bin_extra_byte", "example", _binary(lambda b: b + b"\0"), "rejected", "binary longer than byte_length"),
    ("crc_mismatch", "example", _flip_padding, "rejected", "crc32 differs (only the checksum can tell)"),
    ("edge_out_of_range", "example", lambda h, b: _poke(h, b, "edges", 3, "i", 3), "rejected", "Q >= p"),
    ("edge_negative", "example", lambda h, b: _poke(h, b, "edges", 0, "i", -1), "rejected", "P < 0"),
    ("edge_self", "example", lambda h, b: _poke(h, b, "edges", 1, "i", 0), "rejected", "P == Q"),
    (
        "edge_reversed",
        "example",
        lambda h, b: _poke(*_poke(h, b, "edges", 2, "i", 2), "edges", 3, "i", 1),
        "rejected",
        "P > Q",
    ),
    ("site_nan", "example", lambda h, b: _poke(h, b, "sites", 4, "f", float("nan")), "rejected", "NaN in sites"),
    ("B_inf", "example", lambda h, b: _poke(h, b, "B", 1, "f", float("inf")), "rejected", "inf in B"),
    ("W_nan", "example", lambda h, b: _poke(h, b, "W", 5, "f", float("nan")), "rejected", "NaN in W"),
    (
        "edge_area_inf",
        "example",
        lambda h, b: _poke(h, b, "edge_areas", 0, "f", float("-inf")),
        "rejected",
        "inf in edge_areas",
    ),
    ("no_sites", "example", _empty_array("sites", 0), "rejected", "s = 0 (and B disagrees)"),
    ("d3_B_with_d1", "dyadic", _edit(["arrays", "B", "shape"], [8, 9, 1]), "rejected", "B's d differs from W's"),
    ("d3_W_nan", "dyadic", lambda h, b: _poke(h, b, "W", 7, "f", float("nan")), "rejected", "NaN in W"),
    ("d3_edge_out_of_range", "dyadic", lambda h, b: _poke(h, b, "edges", 11, "i", 5), "rejected", "Q >= p"),
    # Valid files a reader must accept.
    (
        "ok_minified",
        "example",
        _text(lambda t: json.dumps(json.loads(t), separators=(",", ":")).encode()),
        "ok",
        "no whitespace",
    ),
    (
        "ok_reordered_keys",
        "example",
        _text(lambda t: json.dumps(dict(reversed(list(json.loads(t).items()))), indent=4).encode()),
        "ok",
        "keys in another order, other indent",
    ),
    (
        "ok_unknown_keys",
        "example",
        lambda h, b: (
            {
                **h,
                "zzz_future": {"nested": [1, 2.5e-3, None, True, "x"]},
                "buffer": {**h["buffer"], "mime": "application/octet-stream"},
                "counts": {**h["counts"], "groups": 7},
                "arrays": {
                    **h["arrays"],
                    "extra": {"dtype": "uint8", "shape": [3], "byte_offset": 0, "byte_length": 3},
                },
            },
            b,
        ),
        "ok",
        "keys a reader does not know are ignored",
    ),
    ("ok_no_crc", "example", _edit(["buffer", "crc32"], ...), "ok", "crc32 is optional"),
    (
        "ok_unicode_names",
        "example",
        _edit(["fragment_names"], UNICODE_NAMES),
        "ok",
        "\\u escapes (incl. a surrogate pair) and other escapes in names",
    ),
    (
        "ok_arrays_reordered",
        "example",
        _relayout(["edges", "W", "edge_areas", "B", "sites"], 16, 0),
        "ok",
        "arrays in another order: use the header's offsets",
    ),
    (
        "ok_gaps_nonzero",
        "example",
        _relayout(["sites", "B", "W", "edges", "edge_areas"], 32, 0xAB),
        "ok",
        "wider, non-zero gaps between arrays",
    ),
    ("ok_dyadic", "dyadic", lambda h, b: (h, b), "ok", "the d = 3 base file itself"),
    # docs/FORMAT.md section 12 (base: structure_dyadic, features "anchors" and "damage").
    ("anchored_value_2", "structure", lambda h, b: _poke(h, b, "anchored", 1, "i", 2), "rejected",
     "anchored holds a value other than 0 and 1"),
    ("anchored_short", "structure", _edit(["arrays", "anchored", "shape"], [4]), "rejected",
     "anchored has p - 1 entries (and a byte length that disagrees)"),
    ("anchors_without_array", "structure", _edit(["arrays", "anchored"], ...), "rejected",
     "feature 'anchors' without the anchored array"),
    ("damage_missing", "structure", _edit(["damage"], ...), "rejected", "feature 'damage' without the damage object"),
    ("damage_crack_level_0", "structure", _edit(["damage", "crack_level"], 0.0), "rejected", "crack_level 0"),
    ("damage_crack_level_above_1", "structure", _edit(["damage", "crack_level"], 1.5), "rejected",
     "crack_level above 1"),
    ("damage_rate_negative", "structure", _edit(["damage", "damage_rate"], -0.25), "rejected", "damage_rate < 0"),
    ("damage_rate_string", "structure", _edit(["damage", "damage_rate"], "0.5"), "rejected",
     "damage_rate is a string"),
    ("crack_ptr_decreasing", "structure", lambda h, b: _poke(h, b, "crack_ptr", 2, "i", 1), "rejected",
     "crack_ptr decreases"),
    ("crack_ptr_without_segments", "structure", _edit(["arrays", "crack_segments"], ...), "rejected",
     "crack_ptr without crack_segments"),
    ("crack_segment_nan", "structure", lambda h, b: _poke(h, b, "crack_segments", 7, "f", float("nan")), "rejected",
     "NaN in crack_segments"),
    ("crack_count_missing", "structure", _edit(["counts", "crack_segments"], ...), "rejected",
     "crack arrays without counts.crack_segments"),
    ("crack_count_wrong", "structure", _edit(["counts", "crack_segments"], 5), "rejected",
     "counts.crack_segments differs from crack_segments' rows"),
    ("feature_unknown", "structure", _edit(["features"], ["anchors", "damage", "levels"]), "rejected",
     "feature 'levels' on a structure file without the levels object "
     "(a reader without levels refuses the feature by name)"),
    ("ok_structure_without_cracks", "structure",
     lambda h, b: _edit(["arrays", "crack_ptr"], ...)(*_edit(["arrays", "crack_segments"], ...)(h, b)),
     "ok", "the crack arrays are optional (drawing only)"),
    ("ok_structure", "structure", lambda h, b: (h, b), "ok", "the anchors + damage base file itself"),
    ("feature_unknown_name", "structure", _edit(["features"], ["anchors", "damage", "teleport"]), "rejected",
     "a feature no reader implements ('teleport')"),
    # docs/FORMAT.md section 14 (base: levels_dyadic, feature "levels": p = 4, 4 bodies, p_all = 11, S = 6, E = 5).
    ("levels_header_missing", "levels", _edit(["levels"], ...), "rejected",
     "feature 'levels' without the levels object"),
    ("levels_child_names_short", "levels", _edit(["child_names"], ["a", "b"]), "rejected",
     "child_names has fewer names than p_all - p"),
    ("levels_count_wrong", "levels", _edit(["levels", "count"], 2), "rejected",
     "levels.count is not the deepest level (3)"),
    ("levels_thresholds_short", "levels", _edit(["levels", "thresholds"], [1.0, 0.5]), "rejected",
     "levels.thresholds has fewer entries than levels.count"),
    ("levels_threshold0_differs", "levels", _edit(["levels", "thresholds"], [2.0, 0.5, 0.25]), "rejected",
     "levels.thresholds[0] differs from default_threshold"),
    ("levels_threshold_negative", "levels", _edit(["levels", "thresholds"], [1.0, -0.5, 0.25]), "rejected",
     "a negative level threshold"),
    ("levels_array_missing", "levels", _edit(["arrays", "body_W"], ...), "rejected", "body_W missing"),
    ("levels_counts_bodies", "levels", _edit(["counts", "bodies"], 3), "rejected", "counts.bodies disagrees"),
    ("levels_parent_wrong", "levels", lambda h, b: _poke(h, b, "parent", 6, "i", 3), "rejected",
     "a child's parent is not its body's fragment"),
    ("levels_parent_level1", "levels", lambda h, b: _poke(h, b, "parent", 0, "i", 2), "rejected",
     "a level-1 fragment has a parent"),
    ("levels_body_fragment_order", "levels", lambda h, b: _poke(h, b, "body_fragment", 2, "i", 0), "rejected",
     "body_fragment not strictly increasing over bodies >= 1"),
    ("levels_child_ptr_one_child", "levels", lambda h, b: _poke(h, b, "body_child_ptr", 2, "i", 8), "rejected",
     "body 2 has one child"),
    ("levels_site_ptr_body0", "levels", lambda h, b: _poke(h, b, "body_site_ptr", 1, "i", 1), "rejected",
     "body 0 has rows in body_site_ptr"),
    ("levels_edge_out_of_range", "levels", lambda h, b: _poke(h, b, "body_edges", 7, "i", 3), "rejected",
     "a bond of body 2 names local child 3 (it has 2)"),
    ("levels_edge_reversed", "levels", lambda h, b: _poke(h, b, "body_edges", 0, "i", 1), "rejected",
     "a bond (P, Q) with P >= Q"),
    ("levels_W_nan", "levels", lambda h, b: _poke(h, b, "body_W", 3, "f", float("nan")), "rejected",
     "NaN in body_W"),
    ("levels_sites_inf", "levels", lambda h, b: _poke(h, b, "body_sites", 4, "f", float("inf")), "rejected",
     "inf in body_sites"),
    ("ok_levels_reordered", "levels", _relayout(["body_W", "parent", "sites", "body_edges", "B", "body_B", "W",
                                                 "body_fragment", "edges", "body_sites", "body_child_ptr",
                                                 "body_edge_areas", "edge_areas", "body_site_ptr",
                                                 "body_edge_ptr"], 16, 0x5A),
     "ok", "levels arrays in another order, non-zero gaps"),
    ("ok_levels", "levels", lambda h, b: (h, b), "ok", "the levels base file itself"),
    # docs/FORMAT.md section 11.1 (base: sharing_dyadic, features "sharing" and "stress": s = 3, p = 5).
    ("sharing_object_missing", "sharing", _edit(["sharing"], ...), "rejected",
     "feature 'sharing' without the sharing object"),
    ("sharing_concentration_zero", "sharing", _edit(["sharing", "concentration"], 0.0), "rejected",
     "sharing.concentration 0"),
    ("sharing_concentration_negative", "sharing", _edit(["sharing", "concentration"], -2.0), "rejected",
     "sharing.concentration < 0"),
    ("sharing_concentration_string", "sharing", _edit(["sharing", "concentration"], "2"), "rejected",
     "sharing.concentration is a string"),
    ("sharing_concentration_huge", "sharing", _text(lambda t: t.replace(b'"concentration": 2.0',
                                                                         b'"concentration": 1e400')),
     "rejected", "sharing.concentration overflows a double (not finite)"),
    ("sharing_array_missing", "sharing", _edit(["arrays", "site_fragment"], ...), "rejected",
     "feature 'sharing' without site_fragment"),
    ("sharing_fragment_out_of_range", "sharing", lambda h, b: _poke(h, b, "site_fragment", 1, "i", 5), "rejected",
     "site_fragment names fragment 5 (the file has 5)"),
    ("sharing_fragment_negative", "sharing", lambda h, b: _poke(h, b, "site_fragment", 2, "i", -1), "rejected",
     "site_fragment -1"),
    ("sharing_without_stress", "sharing",
     lambda h, b: _edit(["criterion"], "modes")(*_edit(["features"], ["sharing"])(h, b)), "rejected",
     "feature 'sharing' with criterion 'modes'"),
    ("ok_sharing", "sharing", lambda h, b: (h, b), "ok", "the sharing base file itself"),
    # ... with levels (base: levels_sharing: body 1 has 3 children and 2 sites)
    ("levels_sharing_array_missing", "levels_sharing", _edit(["arrays", "body_site_fragment"], ...), "rejected",
     "feature 'sharing' with levels but without body_site_fragment"),
    ("levels_sharing_fragment_out_of_range", "levels_sharing",
     lambda h, b: _poke(h, b, "body_site_fragment", 1, "i", 3), "rejected",
     "body_site_fragment names local child 3 (body 1 has 3)"),
    ("ok_levels_sharing", "levels_sharing", lambda h, b: (h, b), "ok", "the levels + sharing base file itself"),
]


def generate(out: str, example_json: str, dyadic_json: str, structure_json: str, levels_json: str,
             sharing_json: str, levels_sharing_json: str) -> list[str]:
    """Write every case and ``index.json`` into ``out``; returns the paths written (relative to its parent)."""
    os.makedirs(out, exist_ok=True)
    bases = {}
    for key, path in (("example", example_json), ("dyadic", dyadic_json), ("structure", structure_json),
                      ("levels", levels_json), ("sharing", sharing_json), ("levels_sharing", levels_sharing_json)):
        with open(path, encoding="utf-8") as fh:
            header = json.load(fh)
        with open(os.path.join(os.path.dirname(path), header["buffer"]["uri"]), "rb") as fh:
            binary = fh.read()
        bases[key] = (header, binary, os.path.basename(path).replace(".fracture.json", ".vectors.json"))
    entries, written = [], []
    for name, base, edit, expect, why in CASES:
        header, binary, vectors = bases[base]
        header = json.loads(json.dumps(header))  # a private copy to edit
        if isinstance(header.get("buffer"), dict) and "uri" in header["buffer"] and not name.startswith("uri_"):
            header["buffer"]["uri"] = f"{name}.fracture.bin"
        header_out, binary_out = edit(header, binary)
        if isinstance(header_out, dict):
            header_out = _header(header_out)
        with open(os.path.join(out, f"{name}.fracture.json"), "wb") as fh:
            fh.write(header_out)
        with open(os.path.join(out, f"{name}.fracture.bin"), "wb") as fh:
            fh.write(binary_out)
        entry: dict[str, object] = {
            "name": name,
            "header": f"{name}.fracture.json",
            "binary": f"{name}.fracture.bin",
            "expect": expect,
            "why": why,
        }
        if expect == "ok":
            entry["vectors"] = vectors
            entry["fragment_names"] = UNICODE_NAMES if name == "ok_unicode_names" else header["fragment_names"]
        if base in ("structure", "levels", "sharing", "levels_sharing"):  # a reader without these features refuses
            entry["features"] = list(bases[base][0]["features"])
        if name == "crc_mismatch":
            entry["only_crc"] = True
        if name in PYTHON_REFERENCE_BUGS:
            entry["python_reference_bug"] = PYTHON_REFERENCE_BUGS[name]
        entries.append(entry)
        written += [f"corrupt/{name}.fracture.json", f"corrupt/{name}.fracture.bin"]
    index = {"format": INDEX_FORMAT, "version": 1, "cases": entries}
    with open(os.path.join(out, "index.json"), "w", encoding="ascii", newline="\n") as fh:
        fh.write(json.dumps(index, indent=1) + "\n")
    return written + ["corrupt/index.json"]
