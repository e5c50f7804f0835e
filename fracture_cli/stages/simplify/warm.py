"""Compile the simplify stage's numba kernels ahead of the first bake (``make install``)."""

from __future__ import annotations

import numpy as np

from fracture_cli.stages.simplify.decimate import SurfaceComplex


def warm_kernels() -> int:
    """Compile (and cache) the simplify stage's numba kernels by simplifying a small curved fault patch.

    ``make install`` calls this once, so that the first bake does not pay the compilation (some seconds; the
    collapse loop and replay of :mod:`.collapse_loop` and :mod:`.collapse_replay` half a minute);
    a real complex, not hand-made arguments, so every kernel is compiled for the types the stage passes.
    Returns the collapses done (the patch is fine enough that some are).
    """
    n = 6
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n), indexing="ij")
    V = np.column_stack([x.ravel(), y.ravel(), 0.01 * x.ravel() * (1.0 - x.ravel()) * y.ravel()])
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    faces = np.concatenate([np.column_stack([a, a + n, a + n + 1]), np.column_stack([a, a + n + 1, a + 1])])
    border = {int(v) for v in range(n * n) if v // n in (0, n - 1) or v % n in (0, n - 1)}
    complex_ = SurfaceComplex(V, faces, np.full(len(faces), -1), [(0, 1)] * len(faces),
                              np.ones(len(faces), dtype=bool), border)
    again = complex_.copy()
    done = complex_.decimate(0.05)
    again.replay(complex_.done, 0.05, complex_.final_refusals())  # (the compiled replay of a retry)
    return done
