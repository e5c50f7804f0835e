"""The anchors stage and the rest of a structure's bake (docs/FORMAT.md section 12): damage, crack lines, ``impact``.

Tiny fragments built in code: unit cubes with their shared faces in the interior material.
The pillar baked as a structure, in a physics engine, is tests/test_structure_physics.py.
"""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.errors import RecipeError
from fracture_cli.pipeline.recipe import list_recipes, load_recipe
from fracture_cli.runtime.format import RuntimeData, decode, encode, write_runtime
from fracture_cli.stages.anchors import AnchorOptions, anchors, parse_boxes
from fracture_cli.stages.anchors.rules import in_box, on_ground, painted
from fracture_cli.stages.fragments.cracks import crack_segments
from fracture_cli.stages.runtime import RuntimeOptions, with_structure
from fracture_cli.types import Anchors, Fragment, Fragments, Material, Normalization, SurfaceMesh

OUTER, INTERIOR = 0, 1


def _fragments(boxes: list[tuple[tuple[float, float, float], tuple[float, float, float]]],
               scale: float = 1.0) -> Fragments:
    """One fragment per box (lo, hi); a face lying on another box's surface is a fault (interior material)."""
    meshes = [trimesh.creation.box(bounds=np.array(b, dtype=np.float64)) for b in boxes]
    frags = []
    for j, mesh in enumerate(meshes):
        centroids = mesh.triangles_center
        fault = np.zeros(len(mesh.faces), dtype=bool)
        for k, other in enumerate(meshes):
            if k != j:  # on the other box's boundary: within its bounds and on one of its planes
                lo, hi = other.bounds
                inside = np.all((centroids >= lo - 1e-12) & (centroids <= hi + 1e-12), axis=1)
                on_plane = np.any(np.isclose(centroids, lo) | np.isclose(centroids, hi), axis=1)
                fault |= inside & on_plane
        frags.append(Fragment(vertices=np.asarray(mesh.vertices, dtype=np.float64),
                              faces=np.asarray(mesh.faces, dtype=np.int64), uvs=None,
                              normals=np.asarray(mesh.vertex_normals, dtype=np.float64),
                              material_ids=np.where(fault, INTERIOR, OUTER).astype(np.int32), piece=j))
    volume = float(sum(m.volume for m in meshes))
    return Fragments(fragments=tuple(frags), materials=(Material("stone"), Material("interior")),
                     normalization=Normalization(center=np.zeros(3), scale=scale), input_volume=volume)


STACK = [((0, 0, 0), (1, 1, 1)), ((0, 1, 0), (1, 2, 1))]  # two cubes, one on the other (+Y up)
# Two cubes side by side under a 2 x 1 x 1 block: some of each fault's rim lies inside the asset.
ARCH = [((0, 0, 0), (1, 1, 1)), ((1, 0, 0), (2, 1, 1)), ((0, 1, 0), (2, 2, 1))]


def test_ground_picks_the_fragments_with_an_outer_face_on_the_lowest_plane():
    frags = _fragments(STACK)
    assert on_ground(frags, "+y", 0.01).tolist() == [True, False]
    assert on_ground(frags, "-y", 0.01).tolist() == [False, True]  # hung from the top
    assert on_ground(frags, "+x", 0.01).tolist() == [True, True]  # both have a face on x = 0
    # The upper cube's side faces have corners at y = 1, but they reach up to 2: a face counts with all three
    # corners within the tolerance (its bottom, at y = 1, is a fault, not outer surface).
    assert on_ground(frags, "+y", 1.5).tolist() == [True, False]
    assert on_ground(frags, "+y", 2.0).tolist() == [True, True]


def test_a_box_anchors_the_fragments_it_shares_volume_with():
    frags = _fragments(STACK, scale=2.0)  # boxes are in input units: twice the normalized coordinates
    assert in_box(frags, np.array([-1.0, -1.0, -1.0]), np.array([1.0, 0.5, 1.0])).tolist() == [True, False]
    # Strictly inside the upper cube, holding none of its vertices: the exact intersection decides.
    assert in_box(frags, np.array([0.8, 2.8, 0.8]), np.array([1.2, 3.2, 1.2])).tolist() == [False, True]
    # Touching the top face only, or far away: no shared volume.
    assert in_box(frags, np.array([0.0, 4.0, 0.0]), np.array([2.0, 5.0, 2.0])).tolist() == [False, False]
    assert in_box(frags, np.array([10.0, 10.0, 10.0]), np.array([11.0, 11.0, 11.0])).tolist() == [False, False]
    # A box across the fault, between vertices: both.
    assert in_box(frags, np.array([0.5, 1.5, 0.5]), np.array([1.5, 2.5, 1.5])).tolist() == [True, True]


def _painted_column() -> SurfaceMesh:
    """The 1 x 2 x 1 column the STACK was cut from, red growing from 0 at its foot to 1 at its top."""
    box = trimesh.creation.box(bounds=np.array([[0, 0, 0], [1, 2, 1]], dtype=np.float64))
    colors = np.ones((len(box.vertices), 4))
    colors[:, 0] = box.vertices[:, 1] / 2.0
    colors[:, 1] = 1.0 - box.vertices[:, 1] / 2.0
    return SurfaceMesh(vertices=np.asarray(box.vertices), faces=np.asarray(box.faces), uvs=None, normals=None,
                       colors=colors, material_ids=np.zeros(len(box.faces), np.int32), materials=(Material("stone"),),
                       normalization=Normalization(np.zeros(3), 1.0), name="column")


def test_painted_channel_anchors_the_fragments_whose_outer_surface_carries_it():
    frags, column = _fragments(STACK), _painted_column()
    # Outer-face centroids of the lower cube lie at y <= 1 (red <= 0.5 exactly on its top rim: not above), of the
    # upper cube at y > 1.
    assert painted(frags, column, 0).tolist() == [False, True]
    assert painted(frags, column, 1).tolist() == [True, False]
    assert painted(frags, column, 3).tolist() == [True, True]  # alpha 1 everywhere


def test_anchors_combine_the_rules_and_say_how(caplog):
    frags, column = _fragments(STACK), _painted_column()
    none = anchors(frags, column)
    assert none.anchored.tolist() == [0, 0] and none.info == {} and not none.any
    ground = anchors(frags, column, AnchorOptions(ground=True))
    assert ground.anchored.tolist() == [1, 0] and ground.anchored.dtype == np.int32
    assert ground.info == {"ground": True, "up": "+y", "tolerance": 0.01}
    both = anchors(frags, column, AnchorOptions(boxes=[{"name": "lintel", "min": [0.2, 1.8, 0.2],
                                                        "max": [0.8, 2.2, 0.8]}], color="g"))
    assert both.anchored.tolist() == [1, 1]
    assert both.info == {"boxes": ["lintel"], "color": "g"}
    assert {k: v.tolist() for k, v in both.rules.items()} == {"box lintel": [False, True], "color": [True, False]}
    with caplog.at_level(logging.WARNING, logger="fracture_cli"):
        nothing = anchors(frags, column, AnchorOptions(boxes=[{"min": [5, 5, 5], "max": [6, 6, 6]}]))
    assert not nothing.any and nothing.info == {} and "no fragment is anchored" in caplog.text
    plain = SurfaceMesh(**{**column.__dict__, "colors": None})
    with pytest.raises(RecipeError, match="no vertex colours"):
        anchors(frags, plain, AnchorOptions(color="r"))


@pytest.mark.parametrize("value, words", [
    ('[{name = "a", min = [0, 0, 0], max = [1, 0, 1]}]', ["anchors.boxes[0]", "min must be < max"]),
    ('[{name = "a", min = [0, 0], max = [1, 1, 1]}]', ["anchors.boxes[0]", "min = [x, y, z]"]),
    ('[{name = "a", min = [0, 0, 0], max = [1, 1, 1], strength = 2}]', ["unknown key", "strength"]),
    ('[3]', ["anchors.boxes[0] must be a table"]),
])
def test_bad_boxes_are_refused_when_the_recipe_is_read(value, words):
    with pytest.raises(RecipeError) as info:
        load_recipe("default", [f"anchors.boxes={value}"])
    for word in words:
        assert word in str(info.value)
    assert [b.name for b in parse_boxes([{"min": [0, 0, 0], "max": [1, 1, 1]}])] == ["box_0"]


def test_crack_lines_are_the_fault_rims_on_the_outer_surface():
    frags = _fragments(STACK, scale=2.0)
    ptr, segments = crack_segments(frags, np.array([[0, 1]]))
    assert ptr.tolist() == [0, 4] and ptr.dtype == np.int32 and segments.dtype == np.float32
    # Model space (twice the normalized coordinates): the square rim of the fault at y = 1 (world 2), no diagonal.
    assert np.allclose(segments[:, :, 1], 2.0)
    assert np.isclose(np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1).sum(), 8.0)
    arch = _fragments(ARCH)
    ptr, segments = crack_segments(arch, np.array([[0, 1], [0, 2], [1, 2]]))
    # Each fault has one edge of its square inside the asset (where three fragments meet): three on the surface.
    assert ptr.tolist() == [0, 3, 6, 9]
    lengths = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
    assert np.allclose(lengths, 1.0)
    inside = (np.isclose(segments[:, :, 0], 1.0) & np.isclose(segments[:, :, 1], 1.0)).all(axis=1)
    assert not inside.any()


def _stack_runtime() -> RuntimeData:
    sites = np.array([[0.5, 0.0, 0.5], [0.5, 2.0, 0.5]], np.float32)
    return RuntimeData(sites=sites, B=np.ones((2, 1, 1), np.float32), W=np.array([[[1.0], [-1.0]]], np.float32),
                       edges=np.array([[0, 1]], np.int32), edge_areas=np.ones(1, np.float32),
                       fragment_names=("f0", "f1"), default_threshold=1.0)


def test_with_structure_writes_only_what_the_recipe_asks_for():
    frags, data = _fragments(STACK), _stack_runtime()
    plain = with_structure(data, Anchors(anchored=np.zeros(2, np.int32)), frags, RuntimeOptions())
    assert plain.version == 1 and encode(plain, "x.bin") == encode(data, "x.bin")
    held = Anchors(anchored=np.array([1, 0], np.int32), info={"ground": True, "up": "+y", "tolerance": 0.01})
    full = with_structure(data, held, frags, RuntimeOptions(damage=True, crack_level=0.5, damage_rate=0.25))
    header, binary = encode(full, "x.bin")
    parsed = json.loads(header)
    assert parsed["version"] == 2 and parsed["features"] == ["anchors", "damage"]
    assert parsed["damage"] == {"crack_level": 0.5, "damage_rate": 0.25}
    assert parsed["anchors"] == {"ground": True, "tolerance": 0.01, "up": "+y"}
    assert parsed["counts"]["crack_segments"] == 4
    back = decode(header, binary)
    assert back.anchored.tolist() == [1, 0] and back.cracks["crack_ptr"].tolist() == [0, 4]


def test_builtin_recipes_keep_hits_stateless_unless_they_are_structures():
    for name in list_recipes():
        recipe = load_recipe(name)
        runtime, anchor = recipe["runtime"], recipe["anchors"]
        assert 0 < runtime.crack_level <= 1 and runtime.damage_rate >= 0
        structure = name == "stone_structure"
        assert runtime.damage == structure and anchor.active == structure, name
    assert load_recipe("glass")["runtime"].crack_level == 1.0  # any crack is a break
    stone = load_recipe("stone")["runtime"]
    assert (stone.crack_level, stone.damage_rate) == (0.5, 0.25)
    structure = load_recipe("stone_structure")
    assert structure["anchors"].ground and structure["anchors"].up == "+y"
    assert structure["runtime"].crack_level == 0.5
    assert load_recipe("wood", ["anchors.up=-z"])["anchors"].up == "-z"


def _row(folder, damage=True):
    """Three fragments in a row, the first held by the world; one bond each side of the middle one."""
    data = RuntimeData(sites=np.array([[0.0, 0.6, 0.0], [2.0, 0.6, 0.0], [4.0, 0.6, 0.0]], np.float32),
                       B=np.ones((3, 1, 1), np.float32), W=np.array([[[1.0], [0.0], [-1.0]]], np.float32),
                       edges=np.array([[0, 1], [1, 2]], np.int32), edge_areas=np.ones(2, np.float32),
                       fragment_names=("f0", "f1", "f2"), default_threshold=0.5,
                       anchored=np.array([1, 0, 0], np.int32),
                       damage={"crack_level": 0.5, "damage_rate": 0.5} if damage else {})
    path = folder / "row.fracture.json"
    write_runtime(data, path)
    return str(path)


def test_impact_shows_cracks_adding_up_until_the_fourth_hit_breaks(tmp_path):
    runtime = _row(tmp_path)
    # Every bond at 0.8 of its strength: a hit takes 0.5 (0.8 - 0.5) / 0.5 = 0.3 of its health.
    result = CliRunner().invoke(cli, ["impact", runtime, "--point", "2", "0.6", "0", "--impulse", "0.4", "0", "0",
                                      "--repeat", "4"])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[:4] == ["hit 1: 1 group(s), 0 of 2 bonds broken, 2 cracked (lowest health 0.7)",
                         "hit 2: 1 group(s), 0 of 2 bonds broken, 2 cracked (lowest health 0.4)",
                         "hit 3: 1 group(s), 0 of 2 bonds broken, 2 cracked (lowest health 0.1)",
                         "hit 4: 3 group(s), 2 of 2 bonds broken, 0 cracked"]
    assert lines[4:] == ["group_000: f0 (anchored)", "group_001: f1", "group_002: f2"]
    same = CliRunner().invoke(cli, ["impact", runtime, "--hit", "2", "0.6", "0", "0.4", "0", "0", "--repeat", "4"])
    assert same.stdout == result.stdout
    body = json.loads(CliRunner().invoke(cli, ["impact", runtime, "--point", "2", "0.6", "0", "--impulse", "0.4", "0",
                                               "0", "--repeat", "3", "--json"]).stdout)
    assert body["anchored_groups"] == ["group_000"] and body["broken_bonds"] == 0
    assert [c["fragments"] for c in body["cracked_bonds"]] == [["f0", "f1"], ["f1", "f2"]]
    assert [h["cracked_bonds"] for h in body["hits"]] == [[0, 1]] * 3
    assert body["health"] == pytest.approx([0.1, 0.1])
    one = CliRunner().invoke(cli, ["impact", runtime, "--point", "2", "0.6", "0", "--impulse", "0.4", "0", "0"])
    assert one.stdout.splitlines() == ["1 group(s), 0 of 2 bonds broken, 2 cracked (lowest health 0.7)",
                                       "group_000: f0 f1 f2 (anchored)",
                                       "cracked: f0 - f1 (health 0.7)", "cracked: f1 - f2 (health 0.7)"]


def test_impact_sequences_on_a_file_without_damage_remember_what_broke(tmp_path):
    runtime = _row(tmp_path, damage=False)
    result = CliRunner().invoke(cli, ["impact", runtime, "--point", "2", "0.6", "0", "--impulse", "0.6", "0", "0",
                                      "--hit", "2", "0.6", "0", "0.1", "0", "0"])
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[:2] == ["hit 1: 3 group(s), 2 of 2 bonds broken",
                                              "hit 2: 3 group(s), 2 of 2 bonds broken"]


@pytest.mark.parametrize("args, words", [
    (["--point", "0", "0", "0"], "--point and --impulse come together"),
    ([], "give a hit"),
    (["--point", "0", "0", "0", "--impulse", "1", "0", "0", "--repeat", "2", "--png", "x.png"], "--png pictures one"),
])
def test_impact_refuses_incomplete_hits(tmp_path, args, words):
    result = CliRunner().invoke(cli, ["impact", _row(tmp_path), *args])
    assert result.exit_code == 2 and words in result.stderr
