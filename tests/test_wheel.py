"""A normal (non-editable) install works: the wheel ships every module and the built-in recipes, and bakes.

The wheel is built into build/wheel and installed into build/wheel-venv, a fresh
virtualenv whose dependencies come from pip's cache (installed once, again only
when the wheel's declared requirements change); the package itself is
reinstalled whenever the wheel's bytes change.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tomllib
import zipfile

import pytest

from conftest import REPO, SAMPLE_ASSETS

BUILD = os.path.join(REPO, "build")
VENV = os.path.join(BUILD, "wheel-venv")


def _packages_in_tree() -> set[str]:
    found = set()
    for folder, _, files in os.walk(os.path.join(REPO, "fracture_cli")):
        if "__init__.py" in files:
            found.add(os.path.relpath(folder, REPO).replace(os.sep, "."))
    return found


def test_pyproject_lists_every_package():
    with open(os.path.join(REPO, "pyproject.toml"), "rb") as fh:
        listed = set(tomllib.load(fh)["tool"]["setuptools"]["packages"])
    missing = _packages_in_tree() - listed
    assert not missing, f"add {sorted(missing)} to [tool.setuptools] packages in pyproject.toml"
    assert listed - _packages_in_tree() == {"fracture_cli.recipes"}


def _run(args: list[str], **kwargs) -> subprocess.CompletedProcess:
    result = subprocess.run(args, capture_output=True, text=True, **kwargs)
    assert result.returncode == 0, f"{' '.join(args)}\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result


def _build_wheel() -> str:
    out = os.path.join(BUILD, "wheel")
    os.makedirs(out, exist_ok=True)
    for name in os.listdir(out):
        os.remove(os.path.join(out, name))
    # No build isolation: setuptools comes from the test extra, so no download is needed.
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", ".", "-w", out], cwd=REPO)
    (wheel,) = [os.path.join(out, n) for n in os.listdir(out) if n.endswith(".whl")]
    return wheel


def _requirements(wheel: str) -> str:
    with zipfile.ZipFile(wheel) as zf:
        meta = next(n for n in zf.namelist() if n.endswith(".dist-info/METADATA"))
        lines = zf.read(meta).decode().splitlines()
    return "\n".join(sorted(line for line in lines if line.startswith("Requires-Dist:") and "extra ==" not in line))


def _digest(text: bytes) -> str:
    return hashlib.sha256(text).hexdigest()


def _stamped(path: str, value: str) -> bool:
    if not os.path.exists(path):
        return False
    with open(path) as fh:
        return fh.read() == value


def _installed(wheel: str) -> str:
    """The venv's python, with the wheel installed (dependencies from pip's cache)."""
    python = os.path.join(VENV, "bin", "python")
    stamp_deps = os.path.join(VENV, ".requirements-sha256")
    stamp_wheel = os.path.join(VENV, ".wheel-sha256")
    deps = _digest(_requirements(wheel).encode())
    if not (os.path.exists(python) and _stamped(stamp_deps, deps)):
        _run([sys.executable, "-m", "venv", "--clear", VENV])
        _run([python, "-m", "pip", "install", "-q", wheel])
        with open(stamp_deps, "w") as fh:
            fh.write(deps)
    with open(wheel, "rb") as fh:
        digest = _digest(fh.read())
    if not _stamped(stamp_wheel, digest):
        _run([python, "-m", "pip", "install", "-q", "--no-deps", "--force-reinstall", wheel])
        with open(stamp_wheel, "w") as fh:
            fh.write(digest)
    return python


@pytest.mark.slow
def test_wheel_installs_and_bakes(tmp_path):
    wheel = _build_wheel()
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
    assert {f"fracture_cli/recipes/{r}.toml" for r in ("default", "wood", "stone", "glass", "ceramic")} <= names
    python = _installed(wheel)
    fracture = os.path.join(VENV, "bin", "fracture")
    # Run outside the checkout, so neither the source tree nor ./recipes can stand in for the installed package.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "FRACTURE_RECIPES")}
    where = _run([python, "-c", "import fracture_cli; print(fracture_cli.__file__)"], cwd=tmp_path, env=env)
    assert where.stdout.strip().startswith(VENV)
    listed = _run([fracture, "recipes"], cwd=tmp_path, env=env).stdout
    assert all(name in listed for name in ("default", "wood", "stone", "glass", "ceramic"))
    out = tmp_path / "out"
    _run([fracture, "-q", "bake", os.path.join(SAMPLE_ASSETS, "pillar.glb"), "-o", str(out), "--recipe", "stone",
          "--set", "cage.target_faces=300", "--set", "modes.num_modes=2"], cwd=tmp_path, env=env)
    for name in ("pillar.glb", "pillar.fracture.json", "pillar.fracture.bin", "pillar.report.json"):
        assert (out / name).stat().st_size > 0, name
