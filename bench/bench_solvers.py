"""The field smoothing's linear solve: which solver, measured on the chair's refined system.

    python bench/bench_solvers.py

The field method (``smooth.method = "field"``, the ``wood`` recipe) solves
``(M + lambda K) Z = M Z0`` on the 1:8-refined tet mesh, one right-hand side
per piece. The system is the chair's through the ``wood`` recipe (54k
unknowns, 24 pieces). CPU seconds (``time.process_time``, BLAS limited to one
thread as in a bake), best of three for the direct solvers. Optional solvers
(cholespy: CHOLMOD, BSD wrapper of LGPL code; pyamg) are measured when
installed and skipped otherwise; neither is a dependency.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)


def chair_system():
    """The chair's field system: matrix (n, n) CSC, right-hand sides (n, p), unknowns, pieces."""
    import scipy.sparse as sp

    from fracture_cli.geometry import tolerances as tol
    from fracture_cli.pipeline import PipelineState
    from fracture_cli.pipeline.recipe import load_recipe
    from fracture_cli.pipeline.runner import Runner
    from fracture_cli.stages.smooth.field import refined

    recipe = load_recipe("wood")
    runner = Runner("bench")
    state = PipelineState(source=os.path.join(REPO, "sample_assets", "chair.glb"))
    for name in ("load", "repair", "cage", "tetra", "material", "modes", "pieces"):
        state = runner.run(name, state, recipe[name])
    options = recipe["smooth"]
    tm, tet_piece = refined(state.tet_mesh, np.asarray(state.pieces.tet_piece), options.refine,
                            options.max_refined_tets)
    n, p = tm.num_vertices, state.pieces.num_pieces
    vol = np.abs(tm.tet_volumes)
    vol = np.maximum(vol, tol.ROUNDOFF * vol.mean())
    quarter = np.repeat(vol / 4.0, 4)
    rhs = sp.coo_matrix((quarter, (tm.tets.reshape(-1), np.repeat(tet_piece, 4))), shape=(n, p)).toarray()
    mass = np.bincount(tm.tets.reshape(-1), weights=quarter, minlength=n)
    return (sp.diags(mass) + options.smoothing * tm.stiffness).tocsc(), rhs


def _best(function, repeat: int = 3):
    times, result = [], None
    for _ in range(repeat):
        c0 = time.process_time()
        result = function()
        times.append(time.process_time() - c0)
    return min(times), result


def _pcg(A, B, apply_preconditioner, tol: float = 1e-10, max_iter: int = 5000):
    """Conjugate gradients on every column of ``B`` at once (one sparse product per iteration)."""
    X = np.zeros_like(B)
    R = B.copy()
    Zp = apply_preconditioner(R)
    P = Zp.copy()
    rz = np.einsum("ij,ij->j", R, Zp)
    norm_b = np.maximum(np.linalg.norm(B, axis=0), 1e-300)
    for it in range(1, max_iter + 1):
        AP = A @ P
        alpha = rz / np.einsum("ij,ij->j", P, AP)
        X += alpha * P
        R -= alpha * AP
        if (np.linalg.norm(R, axis=0) / norm_b).max() < tol:
            return X, it
        Zp = apply_preconditioner(R)
        rz_new = np.einsum("ij,ij->j", R, Zp)
        P = Zp + (rz_new / rz) * P
        rz = rz_new
    return X, max_iter


def run(quick: bool = False) -> str:
    import scipy.sparse.linalg as spla

    from fracture_cli.stages.smooth.field import _spd_factor
    from fracture_cli.system.parallel import blas_threads

    A, B = chair_system()
    n, p = B.shape
    rows = []
    with blas_threads(1):
        def loop():
            solve = spla.factorized(A)
            return np.column_stack([solve(B[:, j]) for j in range(p)])

        t, reference = _best(loop)
        rows.append(("SuperLU, COLAMD + partial pivoting, one solve per piece (before)", t, 0.0, ""))
        t, Z = _best(lambda: spla.splu(A).solve(B))
        rows.append(("SuperLU, COLAMD + partial pivoting, one multi-RHS solve", t, np.abs(Z - reference).max(), ""))
        t, Z = _best(lambda: _spd_factor(A).solve(B))
        rows.append(("SuperLU, symmetric mode (MMD on A+A^T, no pivoting), one multi-RHS solve (used)", t,
                     np.abs(Z - reference).max(), f"nnz(L) {_spd_factor(A).L.nnz:,} vs {spla.splu(A).L.nnz:,}"))
        rows += _optional_rows(A, B, reference, used=rows[-1][1])
        if not quick:
            d = A.diagonal()
            c0 = time.process_time()
            Z, iterations = _pcg(A.tocsr(), B, lambda R: R / d[:, None])
            rows.append(("block conjugate gradients, Jacobi preconditioner, rel. residual 1e-10",
                         time.process_time() - c0, np.abs(Z - reference).max(), f"{iterations} iterations"))
    lines = [
        "## Field smoothing solvers",
        "",
        f"The chair's field-smoothing system through the `wood` recipe: {n:,} unknowns, {A.nnz:,} non-zeros, "
        f"{p} right-hand sides (pieces). CPU seconds (one BLAS thread; best of 3 for direct solvers); "
        "max |Z - Z_before| is the largest change of the smoothed field. The system is badly conditioned "
        "(the 1:8-refined tets include slivers), so iterative solvers need hundreds of iterations.",
        "",
        "| solver | CPU s | max abs change | note |",
        "|---|---|---|---|",
    ]
    lines += [f"| {name} | {t:.2f} | {err:.1e} | {note} |" for name, t, err, note in rows]
    return "\n".join(lines) + "\n"


def _optional_rows(A, B, reference, used: float) -> list[tuple[str, float, float, str]]:
    rows = []
    try:
        from cholespy import CholeskySolverD, MatrixType
    except ImportError:
        rows.append(("CHOLMOD via cholespy (not installed)", float("nan"), float("nan"), "skipped"))
    else:
        def cholmod():
            solver = CholeskySolverD(A.shape[0], A.indptr.astype(np.int32), A.indices.astype(np.int32), A.data,
                                     MatrixType.CSC)
            Z = np.zeros_like(B)
            solver.solve(np.ascontiguousarray(B), Z)
            return Z

        t, Z = _best(cholmod)
        rows.append(("CHOLMOD sparse Cholesky via cholespy", t, np.abs(Z - reference).max(),
                     f"{used / t:.1f}x faster than the row used; a binary dependency bundling LGPL code"))
    try:
        import pyamg
    except ImportError:
        rows.append(("AMG-preconditioned CG via pyamg (not installed)", float("nan"), float("nan"), "skipped"))
    else:
        c0 = time.process_time()
        ml = pyamg.smoothed_aggregation_solver(A.tocsr(), symmetry="symmetric")
        columns = min(4, B.shape[1])
        Z = np.column_stack([ml.solve(B[:, j], tol=1e-10, accel="cg") for j in range(columns)])
        per_column = (time.process_time() - c0) / columns
        rows.append(("smoothed-aggregation AMG + CG via pyamg, rel. residual 1e-10", per_column * B.shape[1],
                     np.abs(Z - reference[:, :columns]).max(), f"timed on {columns} pieces, scaled to all"))
    return rows


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
