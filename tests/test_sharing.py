"""Load sharing (feature "sharing", docs/FORMAT.md section 11.1): the struck fragment's bonds share the load of
its broken ones, in passes in the same hit; the atlas's event sweep of the passes; the bake's site fragments."""

from __future__ import annotations

import os

import numpy as np
import pytest

from fracture_cli.atlas.criterion import shared_breaking_impulses, stress_breaking_impulses
from fracture_cli.atlas.layout import fragment_layout
from fracture_cli.atlas.sweep import farthest_point_sites, inward_direction
from fracture_cli.runtime.format import load_runtime
from fracture_cli.runtime.impact import project_impact
from fracture_cli.runtime.stress import Sharing

from conftest import REPO

CONFORMANCE = os.path.join(REPO, "tests", "data", "runtime_conformance")


def _hub() -> Sharing:
    """Fragment 0 bonded to 1, 2, 3 (bonds 0, 1, 2; areas 0.5, 0.25, 0.25), kappa 2; sites 0 and 1 on fragment 0."""
    edges = np.array([[0, 1], [0, 2], [0, 3], [1, 2]])
    return Sharing(np.array([0, 0]), edges, np.array([0.5, 0.25, 0.25, 1.0]), 2.0)


def test_a_broken_bond_passes_its_load_to_the_struck_fragments_other_bonds_by_area():
    a0 = np.array([1.0, 0.25, 0.125, -0.5])
    # bond 0 breaks alone; L = 1 over A = 0.5: q = 4, bonds 1 and 2 carry 1.25 and 1.125; bond 3 is not fragment 0's
    shared = _hub().share(0, a0, np.array([0.75, 6.0, 1.125, 1.5]), None)
    assert shared.tolist() == [1.0, 1.25, 1.125, -0.5]  # bond 2 exactly at its limit: holds
    # a weaker bond 2 breaks in the first pass; then q = 2 * 1.125 / 0.25 = 9 and bond 1 carries 2.5
    assert _hub().share(0, a0, np.array([0.75, 6.0, 1.0, 1.5]), None).tolist() == [1.0, 2.5, 1.125, -0.5]


def test_bonds_broken_by_an_earlier_hit_start_the_passes():
    a0 = np.array([0.5, 0.25, 0.125, 0.0])
    limits = np.array([4.0, 4.0, 4.0, 4.0])
    assert _hub().share(0, a0, limits, None).tolist() == a0.tolist()  # nothing breaks, nothing shared
    before = np.array([True, False, False, False])
    assert _hub().share(0, a0, limits, before).tolist() == [0.5, 0.75, 0.625, 0.0]  # q = 2 * 0.5 / 0.5


def test_the_atlas_sweep_of_the_passes_gives_the_runtimes_broken_bonds_at_every_magnitude():
    """On the sample chair (stress, kappa 2): just below and above every breaking impulse of the first ones the
    atlas finds, the Python reader breaks exactly the bonds the atlas says."""
    data = load_runtime(os.path.join(CONFORMANCE, "chair_sharing.fracture.json"))
    assert data.sharing == {"concentration": 2.0}
    center = fragment_layout(data).asset_center(data)
    threshold = float(data.default_threshold)
    checked = 0
    for site in farthest_point_sites(data.sites, 40).tolist():
        point = np.asarray(data.sites[site], dtype=np.float64)
        u = inward_direction(point, center)
        magnitudes = stress_breaking_impulses(data, site, u)
        for level in sorted(set(magnitudes[np.isfinite(magnitudes)].tolist()))[:4]:
            for factor in (1.0 - 1e-7, 1.0 + 1e-7):
                result = project_impact(data, point, level * factor * u, threshold)
                assert np.array_equal(result.broken, magnitudes < level * factor), (site, level, factor)
                checked += 1
    assert checked > 100


def test_the_struck_fragment_comes_off_on_its_first_break_more_often_with_sharing():
    data = load_runtime(os.path.join(CONFORMANCE, "chair_sharing.fracture.json"))
    center = fragment_layout(data).asset_center(data)
    splits = 0
    sites = farthest_point_sites(data.sites, 60).tolist()
    for site in sites:
        u = inward_direction(np.asarray(data.sites[site], dtype=np.float64), center)
        magnitudes = stress_breaking_impulses(data, site, u)
        struck = int(data.stress["site_fragment"][site])
        own = np.flatnonzero((np.asarray(data.edges) == struck).any(axis=1))
        first = magnitudes.min()
        splits += bool(np.isfinite(first) and np.all(magnitudes[own] == first))
    assert splits >= 0.4 * len(sites)


def test_shared_breaking_impulses_of_a_fibre_bundle():
    """Two equal bonds, one pulled twice as hard: it breaks at T S / 2; its load (2, times kappa 1) then goes to the
    other, which carries 1 + 2 = 3 per unit impulse and breaks at T S / 3 < T S / 2: both at the first break."""
    out = shared_breaking_impulses(np.array([2.0, 1.0]), np.array([1.0, 1.0]), np.array([1.0, 1.0]), 1.0)
    assert out.tolist() == [0.5, 0.5]
    # a strong second bond holds until its own magnitude with the shared load, 4 / 3
    out = shared_breaking_impulses(np.array([2.0, 1.0]), np.array([1.0, 4.0]), np.array([1.0, 1.0]), 1.0)
    assert out.tolist() == [0.5, 4.0 / 3.0]


@pytest.mark.slow
def test_a_stress_bake_writes_the_site_fragments_and_load_sharing_0_writes_none(tmp_path):
    from fracture_cli.geometry.parts import gameready_parts, nearest_parts, part_planes
    from fracture_cli.pipeline.bake import bake
    from fracture_cli.pipeline.recipe import load_recipe

    fast = ("runtime.criterion=stress", "cage.target_faces=600", "modes.num_modes=4")
    bake(os.path.join(REPO, "sample_assets", "chair.glb"), str(tmp_path / "on"), load_recipe("wood", fast))
    data = load_runtime(tmp_path / "on" / "chair.fracture.json")
    assert data.features == ("sharing", "stress") and data.sharing == {"concentration": 2.0}
    planes = part_planes(gameready_parts(data.gameready, data.p))
    assert planes is not None
    expected = nearest_parts(planes, np.asarray(data.sites, dtype=np.float64))
    assert np.array_equal(data.stress["site_fragment"], expected)  # the fragment a game's collider reports
    bake(os.path.join(REPO, "sample_assets", "chair.glb"), str(tmp_path / "off"),
         load_recipe("wood", (*fast, "runtime.load_sharing=0")))
    off = load_runtime(tmp_path / "off" / "chair.fracture.json")
    assert off.features == ("stress",) and "site_fragment" not in off.stress
    for name in ("site_bonds", "site_bond_gain", "bond_strength"):  # the same gains either way
        assert np.array_equal(off.stress[name], data.stress[name])
