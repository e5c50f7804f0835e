"""GLB files whose JSON chunk is not padded to 4 bytes: the probe and the reader agree and read them (issue 39)."""

from __future__ import annotations

import json
import logging
import struct

import numpy as np
import pytest

from fracture_cli.errors import InputError
from fracture_cli.io.gltf import Primitive, glb_bytes, read_glb_chunks
from fracture_cli.io.probe import probe_triangles
from fracture_cli.stages.load import LoadOptions, load_surface
from fracture_cli.types import Material

V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int64)


def _tetra_glb() -> bytes:
    prim = Primitive(positions=V, normals=np.zeros_like(V), uvs=None, indices=F, material=0)
    return glb_bytes([("tetra", [prim])], (Material("m"),))


def _repacked(data: bytes, *, pad_uncounted: bool = False, cut: int = 0) -> bytes:
    """``data`` with a JSON chunk whose length is not a multiple of 4; the binary chunk right after it, or after
    padding the chunk's length does not count (``pad_uncounted``); ``cut`` bytes removed from the end."""
    length, _ = struct.unpack_from("<II", data, 12)
    doc = json.loads(data[20:20 + length])
    rest = data[20 + length:]
    text = json.dumps(doc, separators=(",", ":")).encode()
    if len(text) % 4 == 0:
        text += b" "
    pad = b" " * (-len(text) % 4) if pad_uncounted else b""
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + pad + rest
    out = struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body
    return out[:len(out) - cut] if cut else out


@pytest.mark.parametrize("pad_uncounted", [False, True])
def test_unpadded_json_chunk_is_probed_and_read_with_a_warning(tmp_path, caplog, pad_uncounted):
    path = tmp_path / "tetra.glb"
    path.write_bytes(_repacked(_tetra_glb(), pad_uncounted=pad_uncounted))
    assert probe_triangles(str(path), "glb") == 4
    with caplog.at_level(logging.WARNING):
        doc, binary = read_glb_chunks(str(path))
    assert binary is not None and len(binary) >= doc["buffers"][0]["byteLength"]
    assert any("not padded to a multiple of 4" in r.getMessage() for r in caplog.records)
    surface = load_surface(str(path), LoadOptions())
    assert len(surface.faces) == 4


def test_padded_glb_reads_without_warning(tmp_path, caplog):
    path = tmp_path / "tetra.glb"
    path.write_bytes(_tetra_glb())
    with caplog.at_level(logging.WARNING):
        read_glb_chunks(str(path))
    assert not caplog.records
    assert probe_triangles(str(path), "glb") == 4


def test_truly_truncated_binary_is_still_refused_by_the_probe(tmp_path):
    data = _repacked(_tetra_glb())
    # The binary chunk loses its last 8 bytes and the header's total length follows, so only the chunk is short.
    short = data[:-8]
    short = short[:8] + struct.pack("<I", len(short)) + short[12:]
    path = tmp_path / "short.glb"
    path.write_bytes(short)
    with pytest.raises(InputError, match="truncated"):
        probe_triangles(str(path), "glb")
