"""The committed lock (requirements.lock) is what `make install` installs, and it fits pyproject.toml.

`make install` installs exactly the lock's versions (hash-checked) and removes
anything else; the comparison of this venv's ``pip freeze --all`` with the lock
runs only from the checkout's own ``.venv`` (the Makefile's), because any other
environment (a developer's, a wheel venv) may legitimately hold other versions.
The project itself is left out of the comparison: it is installed editable from
the checkout, and its version is the tool's own. pip and setuptools are not left
out: the lock pins them too (setuptools is the test extra's wheel builder, pip
the installer).
"""

from __future__ import annotations

import importlib.util
import os
import re
import sys
import tomllib

import pytest
from packaging.markers import default_environment
from packaging.requirements import Requirement

from conftest import REPO

LOCK = os.path.join(REPO, "requirements.lock")
EXTRAS = ("test", "batch")  # what `make install` installs (`--extra` in `make lock`)


def _venv_lock():
    spec = importlib.util.spec_from_file_location("venv_lock", os.path.join(REPO, "scripts", "venv_lock.py"))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _in_makefile_venv() -> bool:
    return os.path.realpath(sys.prefix) == os.path.realpath(os.path.join(REPO, ".venv"))


@pytest.mark.skipif(not _in_makefile_venv(), reason=f"not run from this checkout's .venv (make test) but from "
                    f"{sys.prefix}, whose versions need not be the lock's")
def test_venv_is_exactly_the_lock():
    venv_lock = _venv_lock()
    diff = venv_lock.differences(venv_lock.lock_pins(LOCK), venv_lock.freeze_pins(sys.executable))
    assert not diff, "the venv differs from requirements.lock (run make install):\n" + "\n".join(diff)


def _pyproject_requirements() -> list[Requirement]:
    with open(os.path.join(REPO, "pyproject.toml"), "rb") as fh:
        project = tomllib.load(fh)["project"]
    found = [Requirement(r) for r in project["dependencies"]]
    for extra in EXTRAS:
        found += [Requirement(r) for r in project["optional-dependencies"][extra]]
    return found


def test_lock_pins_every_requirement_within_its_range():
    """Every requirement of pyproject.toml (and of the extras `make install` uses) is locked at a version in its
    range, for the platform the lock is made for: edit a range, then run `make lock`."""
    venv_lock = _venv_lock()
    pins = venv_lock.lock_pins(LOCK)
    environment = {**default_environment(), "sys_platform": "linux", "platform_machine": "x86_64",
                   "python_version": "3.11"}
    problems = []
    for req in _pyproject_requirements():
        if req.marker is not None and not req.marker.evaluate(environment):
            continue
        name = venv_lock.normalize(req.name)
        if name not in pins:
            problems.append(f"{req} is not in the lock")
        elif not req.specifier.contains(pins[name], prereleases=True):
            problems.append(f"{req}: the lock has {pins[name]}")
    assert not problems, "run make lock:\n" + "\n".join(problems)


def test_every_locked_version_has_hashes():
    hashes: dict[str, int] = {}
    current = None
    with open(LOCK) as fh:
        for line in fh:
            if re.match(r"^[A-Za-z0-9]", line):
                current = line.split("==", 1)[0]
                hashes[current] = 0
            elif current is not None and line.strip().startswith("--hash=sha256:"):
                hashes[current] += 1
    assert len(hashes) == len(_venv_lock().lock_pins(LOCK)) > 50
    unhashed = [name for name, count in hashes.items() if count == 0]
    assert not unhashed, f"no hash for {unhashed}"
