"""A normal (non-editable) install works: the wheel ships every module and the built-in recipes, and bakes.

The wheel is built into build/wheel and installed into build/wheel-venv, a fresh
virtualenv. pip resolves the wheel's declared requirements (so a dependency missing
from pyproject.toml fails here) with the committed lock as constraints, which puts it
in hash-checking mode: every dependency comes at the lock's version and with one of
its hashes, never a newer release. They are installed once (from pip's cache), again
only when the wheel's declared requirements or the lock change; the package itself is
reinstalled whenever the wheel's bytes change.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import subprocess
import sys
import tomllib
import zipfile

import pytest

from conftest import REPO, SAMPLE_ASSETS

BUILD = os.path.join(REPO, "build")
VENV = os.path.join(BUILD, "wheel-venv")
LOCK = os.path.join(REPO, "requirements.lock")


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


def _outside_env() -> dict[str, str]:
    """The environment without what points at the checkout (PYTHONPATH) or its recipes."""
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "FRACTURE_RECIPES")}


def _installed(wheel: str) -> str:
    """The venv's python, with the wheel installed (dependencies at the lock's versions, from pip's cache)."""
    python = os.path.join(VENV, "bin", "python")
    stamp_deps = os.path.join(VENV, ".requirements-sha256")
    stamp_wheel = os.path.join(VENV, ".wheel-sha256")
    with open(wheel, "rb") as fh:
        digest = _digest(fh.read())
    with open(LOCK, "rb") as fh:
        deps = _digest(_requirements(wheel).encode() + fh.read())
    if not (os.path.exists(python) and _stamped(stamp_deps, deps)):
        _run([sys.executable, "-m", "venv", "--clear", VENV])
        # In hash-checking mode (the lock's hashes) every top-level requirement needs a hash too: the wheel's.
        requirement = os.path.join(BUILD, "wheel", "requirement.txt")
        with open(requirement, "w") as fh:
            fh.write(f"fracture-cli @ file://{wheel} --hash=sha256:{digest}\n")
        # The running pip (the lock's, under make test), not the fresh venv's bundled one, does the install.
        # Without PYTHONPATH: the checkout on it holds the build's fracture_cli.egg-info, which pip would take for
        # an installed fracture-cli and skip the wheel.
        _run([sys.executable, "-m", "pip", "--python", python, "install", "-q", "-c", LOCK, "-r", requirement],
             env=_outside_env())
        with open(stamp_deps, "w") as fh:
            fh.write(deps)
        with open(stamp_wheel, "w") as fh:
            fh.write(digest)
    if not _stamped(stamp_wheel, digest):
        _run([python, "-m", "pip", "install", "-q", "--no-deps", "--force-reinstall", wheel], env=_outside_env())
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
    spec = importlib.util.spec_from_file_location("venv_lock", os.path.join(REPO, "scripts", "venv_lock.py"))
    assert spec is not None and spec.loader is not None
    venv_lock = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(venv_lock)
    # Only what the wheel needs (the test and batch extras stay out), each at the lock's version; the fresh
    # venv's own pip (bundled with Python, not installed from anything) is left out.
    installed = venv_lock.freeze_pins(python)
    installed.pop("pip", None)
    assert "pytest" not in installed and "numpy" in installed
    assert not [line for line in venv_lock.differences(venv_lock.lock_pins(LOCK), installed)
                if not line.startswith("missing")]
    fracture = os.path.join(VENV, "bin", "fracture")
    # Run outside the checkout, so neither the source tree nor ./recipes can stand in for the installed package.
    env = _outside_env()
    where = _run([python, "-c", "import fracture_cli; print(fracture_cli.__file__)"], cwd=tmp_path, env=env)
    assert where.stdout.strip().startswith(VENV)
    listed = _run([fracture, "recipes"], cwd=tmp_path, env=env).stdout
    assert all(name in listed for name in ("default", "wood", "stone", "glass", "ceramic"))
    out = tmp_path / "out"
    _run([fracture, "-q", "bake", os.path.join(SAMPLE_ASSETS, "pillar.glb"), "-o", str(out), "--recipe", "stone",
          "--set", "cage.target_faces=300", "--set", "modes.num_modes=2"], cwd=tmp_path, env=env)
    for name in ("pillar.glb", "pillar.fracture.json", "pillar.fracture.bin", "pillar.report.json"):
        assert (out / name).stat().st_size > 0, name
