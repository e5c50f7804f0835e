"""The fast modes solver against the interior-point baseline on the sample assets' tet meshes.

Subproblem by subproblem (same c, same constraints): both feasible to 1e-8, the
fast energy within 1e-4 of the baseline's, the same pieces (adjusted Rand index
>= 0.99). Where the baseline lands on a different optimal cut of the same energy
(a tie), both are checked optimal instead.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from fracture_cli.discontinuity import ConicSubproblemSolver, discontinuity_energy, face_weights
from fracture_cli.io.read import load_surface
from fracture_cli.stages.cage import CageOptions, cage
from fracture_cli.stages.modes import mode_pieces
from fracture_cli.stages.repair import RepairOptions, repair
from fracture_cli.stages.tetra import TetraOptions, tetra

from conftest import SAMPLE_ASSETS
from test_modes import _constraint_residual, _record_subproblems, adjusted_rand_index


@pytest.mark.parametrize("asset", ["chair.glb", "pillar.glb", "vase.obj"])
def test_fast_matches_baseline_on_sample_asset(asset, monkeypatch):
    surface = repair(load_surface(os.path.join(SAMPLE_ASSETS, asset)), RepairOptions())
    mesh = tetra(cage(surface, CageOptions(target_faces=400)), TetraOptions())
    calls = _record_subproblems(monkeypatch, mesh, 3)
    ft, w, vol = mesh.interior_face_tets, face_weights(mesh), mesh.tet_volumes
    cone = ConicSubproblemSolver(ft, w, np.ones((len(ft), 1)), vol)
    assert len(calls) >= 3
    ties = 0
    for c, fixed, fast in calls:
        base = cone.solve(c, fixed)
        u_fast, u_base = fast.u[:, 0], base.u[:, 0]
        assert _constraint_residual(u_fast, c, fixed, vol) < 1e-8
        assert _constraint_residual(u_base, c, fixed, vol) < 1e-8
        e_fast = discontinuity_energy(u_fast, ft, w)
        e_base = discontinuity_energy(u_base, ft, w)
        assert abs(e_fast - e_base) <= 1e-4 * e_base, (asset, e_fast, e_base)
        # The fast solver carries a dual certificate: its energy is optimal to 1e-7.
        assert e_fast - fast.lower_bound <= 1e-7 * e_fast
        ari = adjusted_rand_index(mode_pieces(u_fast, ft, mesh.num_tets, 1e-3)[1],
                                  mode_pieces(u_base, ft, mesh.num_tets, 1e-3)[1])
        if ari < 0.99:
            ties += 1  # same energy (asserted above), another optimal cut: a tie
    print(f"{asset}: {len(calls)} subproblems, {ties} ties (same energy, another optimal cut)")
    assert ties <= len(calls) // 2, f"{asset}: {ties} of {len(calls)} subproblems disagree on pieces"
