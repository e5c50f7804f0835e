"""Properties of the fracture-modes stage (ALGORITHM.md section 2) on tiny meshes built in code."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from fracture_cli.errors import StageError
from fracture_cli.stages.modes import ModesOptions, modes
from fracture_cli.stages.modes.iccm import mode_pieces
from fracture_cli.stages.modes.solver import (
    ConicSubproblemSolver,
    CutSubproblemSolver,
    discontinuity_energy,
    face_weights,
)
from fracture_cli.system.parallel import using
from fracture_cli.testing import grid_tetmesh, two_boxes_with_neck


def adjusted_rand_index(a: np.ndarray, b: np.ndarray) -> float:
    """Adjusted Rand index of two labellings (1 = same partition)."""
    _, a = np.unique(a, return_inverse=True)
    _, b = np.unique(b, return_inverse=True)
    table = np.zeros((a.max() + 1, b.max() + 1))
    np.add.at(table, (a, b), 1)
    pairs = lambda x: float(np.sum(x * (x - 1) / 2))  # noqa: E731
    index, rows, cols, total = pairs(table), pairs(table.sum(1)), pairs(table.sum(0)), pairs(np.array([len(a)]))
    expected = rows * cols / total
    maximum = (rows + cols) / 2
    return 1.0 if maximum == expected else (index - expected) / (maximum - expected)


def asymmetric_mesh():
    """A voxel solid without symmetries (so optimal cuts are unique)."""
    mask = np.ones((6, 4, 3), dtype=bool)
    mask[3:, 2:, :] = False
    mask[5, :, 2] = False
    mask[0, 0, 0] = False
    mask[2, 3, 1:] = False
    return grid_tetmesh(mask.shape, mask=mask, spacing=0.2)


def asymmetric_subproblem():
    """One subproblem on :func:`asymmetric_mesh`: ``(face_tets, weights, volumes, c, fixed)``, ``fixed`` holding
    the mesh's y coordinate made orthogonal to translations."""
    mesh = asymmetric_mesh()
    ft, w, vol = mesh.interior_face_tets, face_weights(mesh), mesh.tet_volumes
    x, y, z = (mesh.tet_centroids[:, i] for i in range(3))
    return ft, w, vol, x + 0.5 * y**2 - 0.3 * z, [y - float(np.dot(vol, y)) / vol.sum()]


@pytest.fixture(scope="module")
def neck():
    mesh = two_boxes_with_neck(3)
    return mesh, modes(mesh, ModesOptions(num_modes=5))


def test_neck_breaks_first(neck):
    mesh, result = neck
    n = 3
    x = mesh.tet_centroids[:, 0]
    left, right = x < n / (2 * n + 1), x > (n + 1) / (2 * n + 1)
    assert result.piece_counts[0] == 2
    labels = result.labels[0]
    assert len(np.unique(labels[left])) == 1 and len(np.unique(labels[right])) == 1
    assert labels[left][0] != labels[right][0]
    # Every cut face lies in the neck.
    cut_x = mesh.tet_centroids[mesh.interior_face_tets[result.cut[0]]][..., 0]
    assert np.all((cut_x > (n - 1) / (2 * n + 1)) & (cut_x < (n + 2) / (2 * n + 1)))
    assert np.all(np.diff(result.energies[:2]) > 0)


def test_orthonormal_and_zero_mean(neck):
    mesh, result = neck
    vol = mesh.tet_volumes
    U = result.U.reshape(result.num_modes, -1)
    gram = np.einsum("it,t,jt->ij", result.U[..., 0], vol, result.U[..., 0])
    assert np.abs(gram - np.eye(result.num_modes)).max() < 1e-6
    assert np.abs(np.einsum("ktd,t->kd", result.U, vol)).max() < 1e-9 * np.abs(U).max()
    assert result.U.shape == (5, mesh.num_tets, 1)
    assert result.labels.dtype == np.int32 and result.cut.shape == (5, len(mesh.interior_faces))
    # Exactly piecewise constant: the labelling does not depend on sigma.
    for i in range(result.num_modes):
        cut, labels, count = mode_pieces(result.U[i], mesh.interior_face_tets, mesh.num_tets, 1e-9)
        assert count == result.piece_counts[i]


def test_dim3_isotropic_gives_triples():
    # Not the neck mesh: its one-voxel neck can be cut on either side at equal cost (a tie).
    mesh = asymmetric_mesh()
    scalar = modes(mesh, ModesOptions(num_modes=2))
    fast3 = modes(mesh, ModesOptions(num_modes=6, dim=3))
    cone3 = modes(mesh, ModesOptions(num_modes=6, dim=3, solver="clarabel"))
    for i in range(6):
        j = i // 3
        assert np.allclose(fast3.energies[i], scalar.energies[j], rtol=1e-9)
        assert np.allclose(cone3.energies[i], scalar.energies[j], rtol=1e-5)
        assert adjusted_rand_index(cone3.labels[i], scalar.labels[j]) >= 0.99
        assert fast3.piece_counts[i] == scalar.piece_counts[j]
    vol = mesh.tet_volumes
    for result in (fast3, cone3):
        U = result.U.reshape(6, -1)
        gram = U @ (np.repeat(vol, 3)[:, None] * U.T)
        assert np.abs(gram - np.eye(6)).max() < 1e-6
        assert np.abs(np.einsum("ktd,t->kd", result.U, vol)).max() < 1e-7


def test_large_eta_prevents_cuts():
    mesh = two_boxes_with_neck(3)
    n = 3
    ft = mesh.interior_face_tets
    x = mesh.tet_centroids[ft][..., 0]
    neck_faces = np.any((x > n / (2 * n + 1)) & (x < (n + 1) / (2 * n + 1)), axis=1)
    eta = np.ones(len(ft))
    eta[neck_faces] = 1e6
    result = modes(mesh, ModesOptions(num_modes=3), eta=eta)
    assert not np.any(result.cut[:, neck_faces])
    assert np.all(result.piece_counts >= 2)


def _record_subproblems(monkeypatch, mesh, num_modes):
    calls = []
    original = CutSubproblemSolver.solve

    def recording(self, c, fixed=(), **kwargs):
        result = original(self, c, fixed, **kwargs)
        if result.stats["certified"]:  # rounds stopped on a max-flow budget claim no optimality
            calls.append((np.array(c, dtype=np.float64).reshape(-1), [np.array(y).reshape(-1) for y in fixed],
                          result))
        return result

    monkeypatch.setattr(CutSubproblemSolver, "solve", recording)
    modes(mesh, ModesOptions(num_modes=num_modes))
    return calls


def _constraint_residual(u, c, fixed, vol):
    """Largest constraint violation, relative to ||y||_M ||u||_M."""
    rows = [np.ones_like(vol)] + list(fixed) + [c]
    values = np.array([np.dot(vol * y, u) for y in rows])
    values[-1] -= 1.0
    scale = np.array([np.sqrt(np.dot(vol * y, y) * np.dot(vol * u, u)) for y in rows])
    return float(np.max(np.abs(values) / np.maximum(scale, 1e-300)))


def compare_with_baseline(mesh, calls) -> list[float]:
    """Check every recorded fast subproblem against the interior-point baseline; return the Rand indices.

    Both feasible to 1e-8, energies within 1e-4, the fast one certified optimal to 1e-7.
    """
    ft, w, vol = mesh.interior_face_tets, face_weights(mesh), mesh.tet_volumes
    cone = ConicSubproblemSolver(ft, w, np.ones((len(ft), 1)), vol)
    agreement = []
    for c, fixed, fast in calls:
        base = cone.solve(c, fixed)
        u_fast, u_base = fast.u[:, 0], base.u[:, 0]
        assert _constraint_residual(u_fast, c, fixed, vol) < 1e-8
        assert _constraint_residual(u_base, c, fixed, vol) < 1e-8
        e_fast = discontinuity_energy(u_fast, ft, w)
        e_base = discontinuity_energy(u_base, ft, w)
        assert e_fast <= e_base * (1 + 1e-4)
        assert abs(e_fast - e_base) <= 1e-4 * e_base
        assert fast.lower_bound <= e_fast * (1 + 1e-9) and e_fast - fast.lower_bound <= 1e-7 * e_fast
        labels_fast = mode_pieces(u_fast, ft, mesh.num_tets, 1e-3)[1]
        labels_base = mode_pieces(u_base, ft, mesh.num_tets, 1e-3)[1]
        agreement.append(adjusted_rand_index(labels_fast, labels_base))
    return agreement


def test_fast_matches_clarabel_subproblem_by_subproblem(monkeypatch):
    mesh = asymmetric_mesh()
    calls = _record_subproblems(monkeypatch, mesh, 5)
    assert len(calls) >= 5
    assert min(compare_with_baseline(mesh, calls)) >= 0.99


def test_ties_on_a_symmetric_box_are_both_optimal():
    """A cube has several optimal cuts of equal energy: the fast solver returns one vertex, the
    interior-point baseline may return a blend. Both are optimal: same energy, both feasible."""
    mesh = grid_tetmesh((3, 3, 3), spacing=1.0 / 3)
    ft, w, vol = mesh.interior_face_tets, face_weights(mesh), mesh.tet_volumes
    x, y = mesh.tet_centroids[:, 0] - 0.5, mesh.tet_centroids[:, 1] - 0.5
    c = x + y  # symmetric in x and y: cutting across x or across y is a tie
    fast = CutSubproblemSolver(ft, w, vol).solve(c)
    base = ConicSubproblemSolver(ft, w, np.ones((len(ft), 1)), vol).solve(c)
    assert abs(fast.energy - base.energy) <= 1e-6 * base.energy
    assert _constraint_residual(fast.u[:, 0], c, [], vol) < 1e-8
    assert _constraint_residual(base.u[:, 0], c, [], vol) < 1e-8
    assert fast.energy - fast.lower_bound <= 1e-7 * fast.energy


def test_deterministic():
    mesh = asymmetric_mesh()
    a = modes(mesh, ModesOptions(num_modes=4))
    b = modes(mesh, ModesOptions(num_modes=4))
    assert a.U.tobytes() == b.U.tobytes()
    assert a.labels.tobytes() == b.labels.tobytes()
    assert a.cut.tobytes() == b.cut.tobytes()


def test_bad_eta_and_too_many_modes():
    mesh = two_boxes_with_neck(2)
    f = len(mesh.interior_faces)
    with pytest.raises(StageError, match="eta"):
        modes(mesh, ModesOptions(num_modes=2), eta=np.ones(f + 1))
    with pytest.raises(StageError, match="eta"):
        modes(mesh, ModesOptions(num_modes=2), eta=-np.ones(f))
    with pytest.raises(StageError, match="num_modes"):
        modes(grid_tetmesh((1, 1, 1)), ModesOptions(num_modes=50))


def test_max_flow_backends_agree():
    pytest.importorskip("ortools")
    mesh = asymmetric_mesh()
    ft, w, vol = mesh.interior_face_tets, face_weights(mesh), mesh.tet_volumes
    c = mesh.tet_centroids[:, 0] + 0.5 * mesh.tet_centroids[:, 1] ** 2
    fixed = [mesh.tet_centroids[:, 2] - mesh.tet_centroids[:, 2].mean()]
    results = [CutSubproblemSolver(ft, w, vol, max_flow=name).solve(c, fixed)
               for name in ("scipy", "ortools", "kernel")]
    assert abs(results[0].energy - results[1].energy) <= 1e-9 * results[1].energy
    assert adjusted_rand_index(mode_pieces(results[0].u, ft, mesh.num_tets, 1e-3)[1],
                               mode_pieces(results[1].u, ft, mesh.num_tets, 1e-3)[1]) >= 0.99
    # The compiled kernel and OR-Tools cut the same integer capacities: the same sets, the same bits.
    np.testing.assert_array_equal(results[2].u, results[1].u)


def test_dim3_anisotropic_fast_matches_vector_baseline():
    """Per-axis eta: the fast solver's axis-aligned modes have the energies the SOCP baseline reaches."""
    mesh = asymmetric_mesh()
    normals = np.abs(mesh.interior_face_normals)
    eta = np.column_stack([np.ones(len(normals)), 2.0 * np.ones(len(normals)), 1.0 + 3.0 * normals[:, 2]])
    fast = modes(mesh, ModesOptions(num_modes=6, dim=3), eta=eta)
    cone = modes(mesh, ModesOptions(num_modes=6, dim=3, solver="clarabel"), eta=eta)
    assert np.allclose(fast.energies, cone.energies, rtol=1e-5)
    for i in range(6):
        assert adjusted_rand_index(fast.labels[i], cone.labels[i]) >= 0.99


@pytest.mark.parametrize("arpack", ["fails-once", "never-converges"])
def test_start_vectors_when_arpack_does_not_converge(arpack, monkeypatch, caplog):
    from scipy.sparse.linalg import ArpackNoConvergence

    from fracture_cli.stages.modes import start as modes_module

    real = modes_module.eigsh
    calls = []

    def flaky(*args, **kwargs):
        calls.append(kwargs.get("sigma"))
        if arpack == "never-converges" or len(calls) == 1:
            raise ArpackNoConvergence("no convergence (test)", np.zeros(0), np.zeros((0, 0)))
        return real(*args, **kwargs)

    monkeypatch.setattr(modes_module, "eigsh", flaky)
    tm = grid_tetmesh((4, 3, 3))
    with caplog.at_level(logging.INFO, logger="fracture_cli.stages.modes"):
        U = modes_module.scalar_start_vectors(tm, 6, seed=0)
    assert "did not converge" in caplog.text
    assert calls[1] == -1.0  # the retry shifts to just below the O(1) spectrum
    if arpack == "never-converges":
        assert "dense problem" in caplog.text
    assert U.shape == (6, tm.num_tets) and np.all(np.isfinite(U))
    assert np.all(np.ptp(U, axis=1) > 0) and np.linalg.matrix_rank(U) == 6
    # Whatever path found them, they span the same lowest eigenspaces as a clean ARPACK run.
    monkeypatch.setattr(modes_module, "eigsh", real)
    clean = modes_module.scalar_start_vectors(tm, 6, seed=0)
    residual = clean - clean @ np.linalg.pinv(U) @ U
    assert np.abs(residual).max() < 1e-6 * np.abs(clean).max()


def test_parallel_chains_are_byte_identical_to_serial():
    """Vector modes with per-axis weights run one ICCM chain per axis; in worker processes or not, same bytes."""
    mesh = asymmetric_mesh()
    normals = np.abs(mesh.interior_face_normals)
    eta = np.column_stack([np.ones(len(normals)), 2.0 + normals[:, 0], 1.0 + 3.0 * normals[:, 2]])
    with using(1):
        serial = modes(mesh, ModesOptions(num_modes=6, dim=3), eta=eta)
    with using(2):
        parallel = modes(mesh, ModesOptions(num_modes=6, dim=3), eta=eta)
    assert serial.stats["chains"] == 3 and parallel.stats["max_workers"] == 2 and serial.stats["max_workers"] == 1
    for name in ("U", "labels", "cut", "piece_counts", "energies", "iterations"):
        assert getattr(serial, name).tobytes() == getattr(parallel, name).tobytes(), name


def test_merging_cells_keeps_the_optimum(monkeypatch):
    """Merging equal-valued cells (always, here) and undoing a merge after an LP failure leave the optimum as is."""
    from fracture_cli.stages.modes.solver.master import MasterLP

    ft, w, vol, c, fixed = asymmetric_subproblem()
    plain = CutSubproblemSolver(ft, w, vol, merge_cells=10**9).solve(c, fixed)
    merging = CutSubproblemSolver(ft, w, vol, merge_cells=0)
    merged = merging.solve(c, fixed)
    assert merged.stats["merges"] >= 1
    assert abs(merged.energy - plain.energy) <= 1e-9 * plain.energy
    assert merged.energy - merged.lower_bound <= 1e-7 * merged.energy

    real = MasterLP.solve
    calls = []

    def fails_once_after_a_merge(self, cells, *args):
        if merging._before_merge is not None and not calls:
            calls.append("failed")
            raise RuntimeError("master LP failed (test)")
        return real(self, cells, *args)

    # The next ICCM round starts on the merged partition; its first master LP "fails".
    x, _, z = asymmetric_mesh().tet_centroids.T
    c2 = c + 0.7 * x * z
    expected = CutSubproblemSolver(ft, w, vol, merge_cells=10**9).solve(c2, fixed)
    assert merging._before_merge is not None
    monkeypatch.setattr(MasterLP, "solve", fails_once_after_a_merge)
    recovered = merging.solve(c2, fixed)
    assert calls == ["failed"] and recovered.stats["unmerges"] == 1
    assert abs(recovered.energy - expected.energy) <= 1e-9 * expected.energy


def test_round_on_a_max_flow_budget_is_feasible_and_descends():
    """A subproblem stopped on its max-flow budget is feasible, uncertified, and no worse than c itself."""
    ft, w, vol, c, fixed = asymmetric_subproblem()
    exact = CutSubproblemSolver(ft, w, vol).solve(c, fixed)
    assert exact.stats["certified"] and exact.stats["max_flows"] > 2
    short = CutSubproblemSolver(ft, w, vol).solve(c, fixed, max_flows=2)
    assert not short.stats["certified"] and short.stats["max_flows"] == 2 and np.isnan(short.lower_bound)
    u = short.u[:, 0]
    assert _constraint_residual(u, c, fixed, vol) < 1e-8
    # c made feasible (orthogonal to translations and the fixed vector, c^T M v = 1) is in every master.
    basis = np.column_stack([np.ones_like(vol), fixed[0]])
    v = c - basis @ np.linalg.solve(basis.T @ (vol[:, None] * basis), basis.T @ (vol * c))
    v = v / float(np.dot(vol * c, v))
    assert exact.energy - 1e-12 <= short.energy <= discontinuity_energy(v, ft, w) * (1 + 1e-9)


def test_master_with_dependent_fixed_rows_solves_on_their_row_space(monkeypatch):
    """When every LP solver fails on a master whose fixed rows are dependent, it is solved with an
    orthonormal basis of their row space instead: same optimum, certified, multipliers mapped back."""
    from fracture_cli.stages.modes.solver.master import MasterLP

    ft, w, vol, c, (y0,) = asymmetric_subproblem()
    expected = CutSubproblemSolver(ft, w, vol).solve(c, [y0])
    real = MasterLP._solve_any

    def fails_with_all_rows(self, args):
        if args[6].shape[0] == 3:  # two fixed rows (dependent) and c's
            raise RuntimeError("master LP failed (test)")
        return real(self, args)

    monkeypatch.setattr(MasterLP, "_solve_any", fails_with_all_rows)
    got = CutSubproblemSolver(ft, w, vol).solve(c, [y0, 2.0 * y0])
    assert got.stats["lp_retries"] >= 1
    assert abs(got.energy - expected.energy) <= 1e-9 * expected.energy
    assert got.energy - got.lower_bound <= 1e-7 * got.energy
    assert _constraint_residual(got.u[:, 0], c, [y0], vol) < 1e-8


def test_master_without_highspy_solves_with_linprog(monkeypatch):
    """scipy's linprog (imported only for this fallback) reaches the warm-started HiGHS master's optimum."""
    from fracture_cli.stages.modes.solver import master

    ft, w, vol, c, fixed = asymmetric_subproblem()
    warm = CutSubproblemSolver(ft, w, vol).solve(c, fixed)
    monkeypatch.setattr(master, "_highspy", None)
    assert master.lp_backend() == "scipy"
    fallback = CutSubproblemSolver(ft, w, vol).solve(c, fixed)
    assert abs(fallback.energy - warm.energy) <= 1e-7 * warm.energy
    assert fallback.energy - fallback.lower_bound <= 1e-7 * fallback.energy
