"""The fast modes solver against the interior-point baseline on the sample assets' tet meshes.

Subproblem by subproblem (same c, same constraints): both feasible to 1e-8, the
fast energy within 1e-4 of the baseline's, the same pieces (adjusted Rand index
>= 0.99). Where the baseline lands on a different optimal cut of the same energy
(a tie), both are checked optimal instead.
"""

from __future__ import annotations

import os

import pytest
from test_modes import _record_subproblems, compare_with_baseline

from fracture_cli.stages.cage import CageOptions, cage
from fracture_cli.stages.load import load_surface
from fracture_cli.stages.repair import RepairOptions, repair
from fracture_cli.stages.tetra import TetraOptions, tetra

from conftest import SAMPLE_ASSETS


@pytest.mark.parametrize("asset", ["chair.glb", "pillar.glb", "vase.obj"])
def test_fast_matches_baseline_on_sample_asset(asset, monkeypatch):
    surface = repair(load_surface(os.path.join(SAMPLE_ASSETS, asset)), RepairOptions())
    mesh = tetra(cage(surface, CageOptions(target_faces=400)), TetraOptions())
    calls = _record_subproblems(monkeypatch, mesh, 3)
    assert len(calls) >= 3
    agreement = compare_with_baseline(mesh, calls)
    # A subproblem where the pieces differ at equal energy (asserted in the helper) is a tie: another
    # optimal cut. Report them; most must agree.
    ties = sum(a < 0.99 for a in agreement)
    print(f"{asset}: {len(calls)} subproblems, {ties} ties (same energy, another optimal cut)")
    assert ties <= len(calls) // 2, f"{asset}: {ties} of {len(calls)} subproblems disagree on pieces"
