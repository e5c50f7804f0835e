"""Fragments of every sample asset, with and without fault smoothing (issue #5's acceptance on real assets).

Each sample asset goes through its manifest recipe up to the atomic pieces once;
then it is smoothed with lambda = 0 (tet-aligned faults) and with the recipe's
lambda, cut into fragments, and checked with the independent invariant checks
of ``test_fragments.check_invariants`` (trimesh, manifold3d, open3d). With
smoothing on, the faults must look smoother: their mean dihedral angle and
their crease density (:func:`fracture_cli.checks.faultshape.fault_shape`) drop.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib

import pytest
from test_fragments import check_invariants

from fracture_cli.checks.faultshape import fragment_fault_shape
from fracture_cli.pipeline.recipe import load_recipe
from fracture_cli.stages.cage import cage
from fracture_cli.stages.fragments import fragments
from fracture_cli.stages.load import load_surface
from fracture_cli.stages.material import material
from fracture_cli.stages.modes import modes
from fracture_cli.stages.pieces import pieces
from fracture_cli.stages.repair import repair
from fracture_cli.stages.smooth import smooth
from fracture_cli.stages.tetra import tetra

from conftest import SAMPLE_ASSETS

with open(os.path.join(SAMPLE_ASSETS, "manifest.toml"), "rb") as _fh:
    MANIFEST = sorted(tomllib.load(_fh)["assets"].items())


@pytest.mark.slow
@pytest.mark.parametrize("asset, recipe_name", MANIFEST, ids=[a for a, _ in MANIFEST])
def test_smoothing_keeps_invariants_and_smooths_faults(asset, recipe_name):
    recipe = load_recipe(recipe_name)
    surface = repair(load_surface(os.path.join(SAMPLE_ASSETS, asset)), recipe["repair"])
    tm = tetra(cage(surface, recipe["cage"]), recipe["tetra"])
    P = pieces(tm, modes(tm, recipe["modes"], eta=material(tm, surface, recipe["material"])), recipe["pieces"])
    shapes = {}
    for lam in (0.0, recipe["smooth"].smoothing):
        regions = smooth(tm, P, dataclasses.replace(recipe["smooth"], smoothing=lam), surface=surface)
        assert len(regions.meshes) == P.num_pieces  # smoothing never creates or removes a piece
        frags = fragments(surface, regions, recipe["fragments"])
        check_invariants(surface, frags, frags.input_volume)
        shapes[lam] = fragment_fault_shape(frags)
    rough, smooth_ = shapes[0.0], shapes[recipe["smooth"].smoothing]
    print(f"{asset} ({recipe_name}, {recipe['smooth'].method}): mean dihedral {rough['mean_dihedral_degrees']:.1f} -> "
          f"{smooth_['mean_dihedral_degrees']:.1f} deg, creases {rough['crease_density']:.1f} -> "
          f"{smooth_['crease_density']:.1f} per unit area")
    assert smooth_["mean_dihedral_degrees"] < rough["mean_dihedral_degrees"]
    assert smooth_["crease_density"] < rough["crease_density"]
