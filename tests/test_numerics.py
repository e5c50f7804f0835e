"""The same bytes on every CPU: pinned kernels, no libm on the way to an output, and bakes under forced kernels.

A machine that is not this one cannot be borrowed in a test, but every numeric
choice a CPU makes can be forced here: OpenBLAS's kernel set
(``OPENBLAS_CORETYPE``), numpy's SIMD level (``NPY_DISABLE_CPU_FEATURES``),
numba's target (``NUMBA_CPU_NAME``) and glibc's libm variants without FMA
(``GLIBC_TUNABLES``). A sample bake under each must give the golden bytes.
"""

from __future__ import annotations

import ast
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
from test_golden import GOLDEN_DIR, MANIFEST, output_hashes

from fracture_cli.pipeline.cache import cache_key
from fracture_cli.system import detmath, numeric_env

from conftest import REPO, SAMPLE_ASSETS

PACKAGE = pathlib.Path(REPO) / "fracture_cli"

# libm functions (numpy's, math's): their last bit depends on the CPU (FMA or not) and the glibc version.
LIBM = {"exp", "exp2", "expm1", "log", "log2", "log10", "log1p", "sin", "cos", "tan", "arcsin", "arccos", "arctan",
        "arctan2", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "arcsinh", "arccosh", "arctanh", "pow",
        "power", "float_power", "cbrt", "hypot", "degrees_to_radians", "logaddexp", "erf", "gamma", "lgamma"}
# `**` whose operands are ints (exact integer arithmetic), by file and expression.
INT_POWERS = {"system/detmath.py": {"(-1) ** i"}, "geometry/boxlevels.py": {"_RATIO ** int(k)"},
              "stages/simplify/fit.py": {"2 ** BUDGET_ROUNDS"}}

# Kernel choices any x86-64 machine with AVX2 can force (and, with the pin, must not change a byte).
FORCED = {
    "openblas-haswell": {"OPENBLAS_CORETYPE": "Haswell"},
    "openblas-sandybridge": {"OPENBLAS_CORETYPE": "Sandybridge"},
    "prescott-no-avx2": {"OPENBLAS_CORETYPE": "Prescott", "NPY_DISABLE_CPU_FEATURES": "X86_V3"},
    "libm-without-fma": {"GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA,-FMA4,-AVX512F"},
}
# numba compiling for a generic x86-64 adds ~40 s of compilation once: one asset shows it.
NUMBA_GENERIC = {"numba-generic": {"NUMBA_CPU_NAME": "generic"}}


def _libm_uses(path: pathlib.Path) -> list[str]:
    """Calls of libm functions and ``**`` on anything but ints in one module, as "file:line: code"."""
    relative = path.relative_to(PACKAGE).as_posix()
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Call):
            name = ast.unparse(node.func).split(".")
            if len(name) >= 2 and name[0] in ("np", "numpy", "math") and name[-1] in LIBM:
                found.append(f"{relative}:{node.lineno}: {ast.unparse(node.func)}")
        elif isinstance(node, ast.ImportFrom) and node.module == "math":
            found += [f"{relative}:{node.lineno}: from math import {a.name}" for a in node.names if a.name in LIBM]
        elif isinstance(node, (ast.BinOp, ast.AugAssign)) and isinstance(node.op, ast.Pow):
            text = ast.unparse(node)
            ints = (isinstance(node, ast.BinOp) and isinstance(node.left, ast.Constant) and type(node.left.value) is int
                    and isinstance(node.right, ast.Constant) and type(node.right.value) is int)
            if not ints and text not in INT_POWERS.get(relative, ()):
                found.append(f"{relative}:{node.lineno}: {text}")
    return found


def test_the_library_calls_no_libm_function():
    """No transcendental call and no power of floats anywhere in the package (detmath is made of products)."""
    found = [use for path in sorted(PACKAGE.rglob("*.py")) for use in _libm_uses(path)]
    assert not found, ("libm calls round by the CPU (fracture_cli/system/numeric_env.py); use "
                       "fracture_cli.system.detmath or products instead:\n" + "\n".join(found))


def test_this_process_runs_pinned():
    """conftest imports fracture_cli before numpy: the tests bake with the kernels a user's bake has."""
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    from threadpoolctl import threadpool_info

    assert numeric_env.pinned(), numeric_env.unpinned_because()
    assert os.environ["OPENBLAS_CORETYPE"] == numeric_env.BLAS_CORE
    assert not [f for f in __cpu_dispatch__ if __cpu_features__.get(f)], "numpy dispatches above its baseline"
    blas = {info.get("architecture") for info in threadpool_info() if info.get("internal_api") == "openblas"}
    assert len(blas) == 1, f"numpy and scipy run different OpenBLAS kernels: {blas}"


def test_report_and_cache_key_name_the_numeric_versions(monkeypatch):
    env = numeric_env.environment()
    assert env["pinned"] is True and env["blas_core"] == numeric_env.BLAS_CORE
    assert set(numeric_env.NUMERIC_DISTRIBUTIONS) <= set(env["versions"])
    assert env["versions"]["numpy"] == np.__version__
    before = cache_key("cage", "input")
    changed = dict(numeric_env.versions(), scipy="0.0.0")
    monkeypatch.setattr(numeric_env, "versions", lambda: changed)
    assert cache_key("cage", "input") != before, "a cache entry of other numeric versions would be reused"


# ---------------------------------------------------------------------------
# detmath: accurate, exact where exact, and made of IEEE operations only (so the same bits everywhere).

def _ulps(got, want) -> float:
    got, want = np.asarray(got), np.asarray(want)
    return float(np.max(np.abs(got - want) / np.spacing(np.maximum(np.abs(want), 1e-300))))


@pytest.mark.parametrize("name, args, reference, bound", [
    ("exp", lambda r: (r.uniform(-700, 700, 20000),), np.exp, 2),
    ("log", lambda r: (np.exp(r.uniform(-700, 700, 20000)),), np.log, 3),
    ("atan2", lambda r: (r.uniform(-1, 1, 20000), r.uniform(-1, 1, 20000)), np.arctan2, 6),
    ("acos", lambda r: (r.uniform(-1, 1, 20000),), np.arccos, 6),
    ("cbrt", lambda r: (np.exp(r.uniform(-60, 60, 20000)),), np.cbrt, 4),
])
def test_detmath_is_accurate(name, args, reference, bound):
    values = args(np.random.default_rng(7))
    assert _ulps(getattr(detmath, name)(*values), reference(*values)) <= bound


def test_detmath_sin_cos_and_exact_cases():
    angle = np.random.default_rng(3).uniform(-50, 50, 20000)
    s, c = detmath.sin_cos(angle)
    assert np.max(np.abs(s - np.sin(angle))) < 4e-16 and np.max(np.abs(c - np.cos(angle))) < 4e-16
    assert detmath.sin_cos(0.0) == (0.0, 1.0) and detmath.exp(0.0) == 1.0 and detmath.log(1.0) == 0.0
    assert detmath.cbrt(27.0) == 3.0 and detmath.cbrt(0.0) == 0.0 and detmath.acos(1.0) == 0.0
    assert detmath.atan2(0.0, -1.0) == np.pi and detmath.atan2(-0.0, -1.0) == -np.pi
    assert detmath.power(2.0, 10.0) == pytest.approx(1024.0, rel=1e-15)
    assert detmath.exact_log_ceil(17.0, 4.0) == 3 and detmath.exact_log_ceil(16.0, 4.0) == 2


def test_pseudo_angle_orders_as_the_angle():
    rng = np.random.default_rng(5)
    y, x = rng.standard_normal(5000), rng.standard_normal(5000)
    angle = np.mod(np.arctan2(y, x), 2 * np.pi)
    assert np.array_equal(np.argsort(detmath.pseudo_angle(y, x), kind="stable"), np.argsort(angle, kind="stable"))
    assert detmath.pseudo_angle(0.0, 0.0) == 0.0 and detmath.pseudo_angle(0.0, 1.0) == 0.0


def test_uniform_directions_are_unit_and_seeded():
    a = detmath.uniform_directions(np.random.default_rng(1), 500)
    b = detmath.uniform_directions(np.random.default_rng(1), 500)
    assert a.shape == (500, 3) and np.array_equal(a, b)
    assert np.allclose(np.linalg.norm(a, axis=1), 1.0) and np.all(np.abs(a.mean(axis=0)) < 0.1)


# ---------------------------------------------------------------------------
# Sample bakes under forced kernels: the golden bytes, every time.

def _cases():
    cases = [(label, env, asset, recipe) for label, env in FORCED.items() for asset, recipe in MANIFEST]
    cases += [(label, env, asset, recipe) for label, env in NUMBA_GENERIC.items()
              for asset, recipe in MANIFEST if asset == "chair.glb"]
    return cases


@pytest.mark.slow
@pytest.mark.parametrize("label, env, asset, recipe", _cases(), ids=[f"{c[0]}-{c[2]}" for c in _cases()])
def test_forced_kernels_give_the_golden_bytes(label, env, asset, recipe, tmp_path):
    stem = os.path.splitext(asset)[0]
    with open(os.path.join(GOLDEN_DIR, f"{stem}.{recipe}.json")) as fh:
        expected = json.load(fh)["sha256"]
    result = subprocess.run([sys.executable, "-m", "fracture_cli", "-q", "bake", os.path.join(SAMPLE_ASSETS, asset),
                             "-o", str(tmp_path), "--recipe", recipe, "-j", "1"],
                            env={**os.environ, **env}, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert output_hashes(str(tmp_path), stem) == expected, f"{asset} baked under {env} gives other bytes"
    with open(tmp_path / f"{stem}.report.json") as fh:
        assert json.load(fh)["numerics"]["pinned"] is True
