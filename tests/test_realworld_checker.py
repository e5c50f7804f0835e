"""The independent invariant checker (tests/invariants.py) and the corpus generator, on small GLBs built here."""

from __future__ import annotations

import os
import sys
import tomllib

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "data"))
import make_realworld_corpus as corpus
from invariants import check_glb, input_box, read_glb_fragments, read_triangles

from fracture_cli.io.gltf import Primitive, glb_bytes
from fracture_cli.types import Material

SQUARE = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)


def box(lo=(0.0, 0.0, 0.0)):
    V, F = corpus.prism(SQUARE + np.asarray(lo[:2]), lo[2], lo[2] + 1.0)
    return V, F


def write(tmp_path, nodes, name="out.glb"):
    """A GLB with one node per (name, V, F, origin): positions stored relative to the node's translation."""
    meshes = []
    for node, V, F, origin in nodes:
        prim = Primitive(positions=V - origin, normals=np.zeros_like(V), uvs=None, indices=F, material=0)
        meshes.append((node, [prim], origin))
    path = tmp_path / name
    path.write_bytes(glb_bytes(meshes, (Material("m"),)))
    return str(path)


def test_closed_fragments_pass_with_translation(tmp_path):
    V, F = box()
    path = write(tmp_path, [("a", V, F, np.array([0.5, 0.5, 0.5])), ("b", V + [1, 0, 0], F, np.array([1.5, 0.5, 0.5]))])
    result = check_glb(path, reference_volume=2.0, reference_box=np.array([[0, 0, 0], [2, 1, 1]]))
    assert result.ok, result.problems
    assert [f.name for f in result.fragments] == ["a", "b"]
    assert result.total_volume == pytest.approx(2.0) and result.bbox_excess == pytest.approx(0.0)


def test_pinched_open_and_multi_body_fragments_fail(tmp_path):
    V, F = box()
    W, G = box((1.0, 1.0, 0.0))
    touching = (np.vstack([V, W]), np.vstack([F, G + len(V)]))
    path = write(tmp_path, [("pinched", *touching, np.zeros(3)), ("open", V, F[1:], np.zeros(3))])
    result = check_glb(path)
    pinched, opened = result.fragments
    assert pinched.pinched_edges == 1 and pinched.components == 2 and not pinched.ok
    assert opened.open_edges == 3 and not opened.ok
    assert len(result.problems) == 2 and "pinched" in result.problems[0]


def test_volume_and_box_violations(tmp_path):
    V, F = box()
    path = write(tmp_path, [("a", V, F, np.zeros(3))])
    result = check_glb(path, reference_volume=1.5, reference_box=np.array([[0, 0, 0], [1, 1, 0.9]]))
    assert not result.ok and len(result.problems) == 2
    inverted = check_glb(write(tmp_path, [("a", V, F[:, ::-1], np.zeros(3))], "inv.glb"))
    assert inverted.fragments[0].volume == pytest.approx(-1.0) and not inverted.ok


def test_reader_matches_trimesh_on_corpus_files():
    import trimesh

    for name in ("teapot.glb", "soup.stl"):
        path = os.path.join(corpus.OUT, name)
        ours = read_triangles(path)
        theirs = np.concatenate([g.triangles for g in trimesh.load_scene(path, process=False).dump()])
        assert ours.shape == theirs.shape
        assert np.allclose(np.sort(ours.reshape(-1, 3), axis=0), np.sort(theirs.reshape(-1, 3), axis=0))
    assert input_box(os.path.join(corpus.OUT, "two_prisms.glb")).shape == (2, 3)
    assert len(read_glb_fragments(os.path.join(corpus.OUT, "teapot.glb"))) == 4


def test_corpus_files_are_what_the_generator_writes():
    """The committed corpus is reproducible byte for byte, small, and every file has its expected outcome."""
    corpus.CASES.clear()
    corpus.build()
    with open(os.path.join(corpus.OUT, "expected.toml"), "rb") as fh:
        expected = {c["file"]: c for c in tomllib.load(fh)["case"]}
    total = 0
    for case in corpus.CASES:
        with open(os.path.join(corpus.OUT, case["file"]), "rb") as fh:
            assert fh.read() == case["data"], f"{case['file']} differs: re-run tests/data/make_realworld_corpus.py"
        total += len(case["data"])
        assert expected[case["file"]]["outcome"] in ("solid", "shell")
    with open(os.path.join(corpus.OUT, "expected.toml")) as fh:
        assert fh.read() == corpus.manifest()
    assert set(expected) == {c["file"] for c in corpus.CASES} and total < 2_000_000
