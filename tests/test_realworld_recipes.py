"""Issue 39: every built-in recipe bakes every procedural failure class into valid fragments.

The corpus entries marked ``recipes = "all"`` in tests/data/realworld/expected.toml
(a closed teapot of touching parts, an open pot, a bust with a non-planar hole,
thin gear teeth, a truck of touching bodies, overlapping boxes touching along
edges, fins on a solid, a wall with a window far from the origin, a soup of
rocks, a GLB with an unpadded chunk) are baked with each built-in recipe at
reduced settings (a 500-face cage, 4 modes, one field refinement, no
collision parts: the failure classes do not depend on them) and checked by
tests/invariants.py, which shares no geometry code with the library: every
fragment closed, edge-manifold, one body, no vertex
where it touches itself; the volumes summing to the solid the report says was
cut and, where the recipe leaves the repair policy to the mesh, to the solid
the input describes; everything inside the input's bounding box.
"""

from __future__ import annotations

import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from invariants import check_glb, input_box
from test_realworld import CASES, CORPUS, SMALL, _shared_dir, bake_once, read_report

from fracture_cli.pipeline.recipe import load_recipe

RECIPES = ("default", "glass", "wood", "stone", "ceramic", "glass_pane", "brick_wall")
# Cheap settings: a 500-face cage and 4 modes (test_realworld's), one level of field refinement (wood, brick_wall)
# and no collision parts (the fragments are what is checked here); 70 bakes of about 3 s each.
CHEAP = (*SMALL, "smooth.refine=1", "collision.glb=none")
ISSUE39 = sorted(name for name, case in CASES.items() if case.get("recipes") == "all")


def test_the_issue39_cases_are_in_the_corpus():
    assert len(ISSUE39) == 10


def _auto_repair(recipe: str) -> bool:
    """Whether the recipe leaves open surfaces to the mesh's own policy (``repair.open_surface = "auto"``)."""
    return load_recipe(recipe)["repair"].open_surface == "auto"


@pytest.mark.slow
@pytest.mark.parametrize("recipe", RECIPES)
@pytest.mark.parametrize("name", ISSUE39)
def test_every_recipe_bakes_every_case(name, recipe, tmp_path_factory):
    case = CASES[name]
    path = os.path.join(CORPUS, name)
    exit_code, output, out = bake_once(_shared_dir(tmp_path_factory), path, recipe, CHEAP, "cheap")
    assert exit_code == 0, f"{name} with {recipe}: {output.strip().splitlines()[-1:]}"
    stem = os.path.splitext(name)[0]
    report = read_report(out, path)
    cut_volume = report["checks"]["input_volume"]
    check = check_glb(os.path.join(out, f"{stem}.glb"), reference_volume=cut_volume, volume_tolerance=1e-4,
                      reference_box=input_box(path))
    problems = list(check.problems)
    problems += [f"{f.name}: touches itself at {f.pinched_vertices} vertices" for f in check.fragments
                 if f.pinched_vertices]
    decision = next(r for r in report["repairs"] if r["what"] == "decision")["decision"]
    if _auto_repair(recipe):
        if decision != case["outcome"]:
            problems.append(f"repair decided {decision!r}, expected {case['outcome']!r}")
        if case.get("volume") is not None:
            against_input = check_glb(os.path.join(out, f"{stem}.glb"), reference_volume=case["volume"],
                                      volume_tolerance=case["volume_tolerance"])
            problems += [p for p in against_input.problems if "volumes sum" in p]
    assert report["checks"]["watertight"] and report["checks"]["connected"]
    assert not problems, f"{name} with {recipe}: " + "; ".join(problems[:6])


@pytest.mark.slow
@pytest.mark.parametrize("name", ["open_pot.glb", "bust_hole.glb", "fins_on_solid.glb", "unpadded_chunk.glb"])
def test_each_choice_is_listed_with_its_override(name, tmp_path_factory):
    """What repair decided for the artist (a thin wall, a non-planar patch, fins cut off) and what the reader
    tolerated is in report.json ``repairs`` or printed as a warning, with the setting that changes it."""
    path = os.path.join(CORPUS, name)
    exit_code, output, out = bake_once(_shared_dir(tmp_path_factory), path, "default", CHEAP, "cheap")
    assert exit_code == 0, output
    repairs = read_report(out, path)["repairs"]
    details = " ".join(r["detail"] for r in repairs)
    if name == "open_pot.glb":
        assert "open container" in details and "--set repair.open_surface=fill" in output
    elif name == "bust_hole.glb":
        assert any(r.get("patch") == "least_area" for r in repairs if r["what"] == "filled_hole")
        assert "--set repair.open_surface=shell" in output
    elif name == "fins_on_solid.glb":
        assert "detached_fins" in {r["what"] for r in repairs} and "--set repair.fins=drop" in output
    else:
        assert "not padded to a multiple of 4" in output
