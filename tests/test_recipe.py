"""Recipes (destructible materials): loading, inheritance, validation, overrides."""

from __future__ import annotations

import logging

import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.errors import RecipeError
from fracture_cli.pipeline.recipe import SECTIONS, list_recipes, load_recipe


def test_builtin_recipes_exist_and_resolve():
    names = list_recipes()
    for required in ("default", "glass", "stone", "ceramic", "wood"):
        assert required in names
    for name in names:
        recipe = load_recipe(name)
        assert recipe.description and "\n" not in recipe.description
        assert set(recipe.options) == set(SECTIONS)


def test_extends_and_override_order():
    glass = load_recipe("glass")
    default = load_recipe("default")
    assert glass.chain == ("glass", "default")
    assert glass["modes"].num_modes > default["modes"].num_modes
    assert glass["cage"].target_faces == default["cage"].target_faces  # inherited
    over = load_recipe("glass", ["modes.num_modes=7", "smooth.smoothing=0"])
    assert over["modes"].num_modes == 7 and over["smooth"].smoothing == 0.0


def test_wood_is_anisotropic_and_stone_is_smoother():
    wood, stone, glass = load_recipe("wood"), load_recipe("stone"), load_recipe("glass")
    assert wood["material"].grain_axis != "none" and wood["material"].grain_strength > 1
    assert stone["smooth"].smoothing > glass["smooth"].smoothing
    assert stone["modes"].num_modes < glass["modes"].num_modes


def _recipe(tmp_path, text, name="mine.toml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize(
    "text, words",
    [
        ('description = "x"\n[modes]\nnum_modes = -3\n', ["modes.num_modes", "-3", "range"]),
        ('description = "x"\n[modes]\nnum_modes = "many"\n', ["modes.num_modes", "'many'", "number"]),
        ('description = "x"\n[modes]\nnum_modes = 2.5\n', ["modes.num_modes", "2.5", "whole number"]),
        ('description = "x"\n[modes]\nbogus = 1\n', ["modes.bogus: unknown option", "num_modes"]),
        ('description = "x"\n[nonsense]\na = 1\n', ["unknown key", "nonsense"]),
        ('description = "x"\n[material]\ngrain_axis = "w"\n', ["material.grain_axis", "'w'", "'x'"]),
        ('description = "x"\nextends = "no_such_recipe"\n', ["unknown recipe 'no_such_recipe'", "default"]),
        ('description = "x\n', ["not valid TOML"]),
    ],
)
def test_invalid_recipes_name_key_value_and_range(tmp_path, text, words):
    path = _recipe(tmp_path, text)
    with pytest.raises(RecipeError) as info:
        load_recipe(path)
    message = str(info.value)
    for word in words:
        assert word in message, message


def test_extends_cycle_is_reported(tmp_path):
    a = _recipe(tmp_path, f'description = "a"\nextends = "{tmp_path}/b.toml"\n', "a.toml")
    _recipe(tmp_path, f'description = "b"\nextends = "{tmp_path}/a.toml"\n', "b.toml")
    with pytest.raises(RecipeError, match="cycle"):
        load_recipe(a)


@pytest.mark.parametrize(
    "override, words",
    [
        ("modes.num_modes=0", ["modes.num_modes", "0", "range"]),
        ("modes.num_modes", ["section.key=value"]),
        ("nosection.x=1", ["unknown section 'nosection'"]),
        ("smooth.smoothing=-1", ["smooth.smoothing", "-1", "range"]),
    ],
)
def test_set_overrides_are_validated(override, words):
    with pytest.raises(RecipeError) as info:
        load_recipe("default", [override])
    for word in words:
        assert word in str(info.value)


def test_cli_recipes_list_and_show():
    runner = CliRunner()
    result = runner.invoke(cli, ["recipes"])
    assert result.exit_code == 0
    assert "glass" in result.output and "wood" in result.output
    result = runner.invoke(cli, ["recipes", "show", "wood"])
    assert result.exit_code == 0
    assert "[material]" in result.output and 'grain_axis = "y"' in result.output
    result = runner.invoke(cli, ["recipes", "show", "nope"])
    assert result.exit_code == 1 and "unknown recipe 'nope'" in result.output


def test_cli_bake_rejects_bad_set_before_work(tmp_path):
    result = CliRunner().invoke(cli, ["bake", "sample_assets/chair.glb", "-o", str(tmp_path / "out"),
                                      "--set", "modes.num_modes=-1"])
    assert result.exit_code == 1
    assert "modes.num_modes = -1" in result.output
    assert not (tmp_path / "out").exists()


def test_interior_colour_is_a_validated_vector():
    recipe = load_recipe("default", ["fragments.interior_color=[0.2, 0.1, 0.1, 1.0]"])
    assert recipe["fragments"].interior_color == [0.2, 0.1, 0.1, 1.0]
    with pytest.raises(RecipeError, match="4 numbers"):
        load_recipe("default", ["fragments.interior_color=[0.2, 0.1]"])
    with pytest.raises(RecipeError, match="out of range"):
        load_recipe("default", ["fragments.interior_color=[2, 0, 0, 1]"])


def test_keys_of_older_recipes_still_load(tmp_path, caplog):
    """A retired key is ignored and a renamed one read under its new name, each with a warning saying why."""
    old = tmp_path / "old.toml"
    old.write_text('extends = "default"\n[repair]\nmax_fill_ratio = 0.02\n[pieces]\nmin_volume_fraction = 0.004\n')
    with caplog.at_level(logging.WARNING, logger="fracture_cli.pipeline.recipe"):
        recipe = load_recipe(str(old))
    assert recipe["pieces"].min_fragment_fraction == 0.004
    messages = " ".join(r.message for r in caplog.records)
    assert "repair.max_fill_ratio is no longer used" in messages and "max_fill_share" in messages
    assert "pieces.min_volume_fraction is now pieces.min_fragment_fraction" in messages
    with pytest.raises(RecipeError, match="no longer used.*max_fill_share"):
        load_recipe("default", ["repair.max_fill_ratio=0.1"])
