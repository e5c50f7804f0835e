"""The numeric environment of a bake: the same bits on every x86-64 CPU.

A bake's outputs are byte-identical for the same input, recipe and tool version
on any machine. Three things in the numeric stack would otherwise change the
last bits of a result with the CPU, and discrete decisions (a tet's piece, a
collapse, a bond) then turn those bits into other meshes:

* **OpenBLAS** (inside numpy and scipy) picks kernels for the CPU it finds
  (``SkylakeX``, ``Haswell``, ``Zen`` ...), which sum in other orders and with or
  without fused multiply-adds. :func:`pin_environment` fixes the kernel set to
  ``Prescott`` (SSE3, which every x86-64 CPU in use has) through
  ``OPENBLAS_CORETYPE``, read when the library loads. It costs nothing
  measurable here: the bake's dense products are small (bench/RESULTS.md).
* **numpy's SIMD dispatch** picks loops (sorts, transcendental functions) for the
  CPU; ``NPY_ENABLE_CPU_FEATURES`` limits it to the baseline every numpy wheel
  requires (``X86_V2``), also read at import.
* **glibc's libm** picks FMA or plain variants of ``exp``, ``log``, ``pow``,
  ``sin``, ``atan2`` ... by the CPU, in every process, and no variable a
  program can set after it started changes that. The library therefore calls
  no transcendental function where a result reaches an output: squares are
  products, and :mod:`fracture_cli.system.detmath` has the few functions needed, made
  of IEEE operations only; tests/test_numerics.py fails on a new call.

Both variables only act before numpy is first imported, so :mod:`fracture_cli`
sets them when it is imported (the ``fracture`` command imports it first; a
program that imported numpy before it gets a warning in the bake's log and
``"pinned": false`` in the report's ``numerics``). A user's own
``OPENBLAS_CORETYPE`` or ``NPY_*_CPU_FEATURES`` is replaced: they would change
the bytes. ``FRACTURE_NUMERICS=host`` keeps the machine's own choices (faster
nowhere measurable, and the bytes may then differ between machines).
"""

from __future__ import annotations

import functools
import os
import platform
import sys

# What the variables are set to on x86-64 (elsewhere there is no kernel set shared by every CPU to pin).
BLAS_CORE = "Prescott"
NUMPY_FEATURES = "X86_V2"
HOST_ENV = "FRACTURE_NUMERICS"

# The distributions whose arithmetic reaches an output, named in the report and in every cache key.
NUMERIC_DISTRIBUTIONS = ("numpy", "scipy", "manifold3d", "trimesh", "open3d", "numba", "llvmlite", "highspy",
                         "ortools", "tetgen", "fast-simplification", "scikit-image")

_PINNED: bool | None = None  # whether pin_environment() acted before numpy was loaded
_UNPINNED_BECAUSE = ""  # why not, for the bake's warning


def pin_environment() -> bool:
    """Fix OpenBLAS's kernel set and numpy's SIMD level for this process and its children.

    Returns
    -------
    bool
        True when the pin is in effect (numpy not imported before, an x86-64 machine, no
        ``FRACTURE_NUMERICS=host``).
    """
    global _PINNED, _UNPINNED_BECAUSE
    if _PINNED is not None:
        return _PINNED
    if os.environ.get(HOST_ENV) == "host":
        _PINNED, _UNPINNED_BECAUSE = False, f"{HOST_ENV}=host"
    elif platform.machine().lower() not in ("x86_64", "amd64"):
        _PINNED, _UNPINNED_BECAUSE = False, f"no kernel set to pin on {platform.machine()}"
    elif "numpy" in sys.modules:
        _PINNED = _already_pinned()
        _UNPINNED_BECAUSE = "" if _PINNED else "numpy was imported before fracture_cli"
    else:
        os.environ["OPENBLAS_CORETYPE"] = BLAS_CORE
        # numpy refuses both variables at once; the enable list is the stronger statement.
        os.environ.pop("NPY_DISABLE_CPU_FEATURES", None)
        os.environ["NPY_ENABLE_CPU_FEATURES"] = NUMPY_FEATURES
        _PINNED = True
    return _PINNED


def _already_pinned() -> bool:
    """Whether a process that loaded numpy before :mod:`fracture_cli` still has the pinned environment."""
    return (os.environ.get("OPENBLAS_CORETYPE") == BLAS_CORE
            and os.environ.get("NPY_ENABLE_CPU_FEATURES") == NUMPY_FEATURES
            and "NPY_DISABLE_CPU_FEATURES" not in os.environ)


def pinned() -> bool:
    """Whether this process runs with the pinned kernels (see :func:`pin_environment`)."""
    return bool(_PINNED)


def unpinned_because() -> str:
    """Why the kernels are not pinned ("" when they are)."""
    return _UNPINNED_BECAUSE


@functools.lru_cache(maxsize=1)
def versions() -> dict[str, str]:
    """Installed versions of :data:`NUMERIC_DISTRIBUTIONS` (``"-"`` where one is missing), without importing them."""
    from importlib import metadata  # here, not at the top: 40 ms of every start-up, before Ctrl-C is handled

    found = {}
    for name in NUMERIC_DISTRIBUTIONS:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "-"
    return found


def environment() -> dict[str, object]:
    """What the report's ``numerics`` says: whether the kernels are pinned, which, and the versions."""
    return {"pinned": pinned(),
            "blas_core": BLAS_CORE if pinned() else os.environ.get("OPENBLAS_CORETYPE", "host"),
            "numpy_simd": NUMPY_FEATURES if pinned() else "host",
            "versions": dict(versions())}
