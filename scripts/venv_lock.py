"""Compare a virtualenv with the committed dependency lock, or make it match.

    .venv/bin/python scripts/venv_lock.py check requirements.lock
    .venv/bin/python scripts/venv_lock.py sync requirements.lock

Run with the virtualenv's own interpreter (the Makefile's ``$(PY)``): it reads
that interpreter's ``pip freeze --all``. ``check`` prints every difference
(missing, extra, other version) and exits 1 if there is any; ``sync``
first uninstalls what the lock does not list (left by an older lock or by
hand: ``pip install --no-deps -r`` never removes anything), runs
``pip check`` (every installed requirement satisfied, so the lock is complete
for pyproject.toml's ranges), then checks. The project itself is left out of
the comparison: it is installed from the checkout (editable), and its version
is the tool's, not a dependency's.
"""

from __future__ import annotations

import re
import subprocess
import sys

PROJECT = "fracture-cli"


def normalize(name: str) -> str:
    """A distribution name as PEP 503 compares them (``Jinja2`` == ``jinja2``, ``fast_simplification``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def lock_pins(path: str) -> dict[str, str]:
    """``{name: version}`` of every ``name==version`` line of a requirements lock (hash lines skipped)."""
    pins = {}
    with open(path) as fh:
        for line in fh:
            match = re.match(r"^([A-Za-z0-9][A-Za-z0-9._-]*)(?:\[[^\]]*\])?==([^\s;\\]+)", line)
            if match:
                pins[normalize(match.group(1))] = match.group(2)
    return pins


def freeze_pins(python: str = sys.executable) -> dict[str, str]:
    """``{name: version}`` of what ``python -m pip freeze --all`` lists, without the project (editable or not)."""
    out = subprocess.run([python, "-m", "pip", "freeze", "--all", "--exclude-editable"], check=True,
                         capture_output=True, text=True).stdout
    pins = {}
    for line in out.splitlines():
        if "==" in line and not line.startswith(("#", "-e")):
            name, version = line.split("==", 1)
            pins[normalize(name)] = version.strip()
    pins.pop(PROJECT, None)
    return pins


def differences(locked: dict[str, str], installed: dict[str, str]) -> list[str]:
    """One line per distribution that is missing, extra or at another version than the lock says."""
    lines = [f"missing: {name}=={version}" for name, version in sorted(locked.items()) if name not in installed]
    lines += [f"not in the lock: {name}=={version}" for name, version in sorted(installed.items())
              if name not in locked]
    lines += [f"other version: {name}=={installed[name]} (lock: {version})" for name, version in sorted(locked.items())
              if name in installed and installed[name] != version]
    return lines


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] not in ("check", "sync"):
        print(__doc__, file=sys.stderr)
        return 2
    command, lock = argv
    locked = lock_pins(lock)
    if command == "sync":
        extra = sorted(set(freeze_pins()) - set(locked))
        if extra:
            print(f"uninstalling what {lock} does not list: {' '.join(extra)}")
            subprocess.run([sys.executable, "-m", "pip", "uninstall", "-y", "-q", *extra], check=True)
        broken = subprocess.run([sys.executable, "-m", "pip", "check"], capture_output=True, text=True)
        if broken.returncode:
            print(f"pip check in {sys.prefix}:\n{broken.stdout}{broken.stderr}", file=sys.stderr)
            return 1
    lines = differences(locked, freeze_pins())
    for line in lines:
        print(f"{sys.prefix} vs {lock}: {line}", file=sys.stderr)
    return 1 if lines else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
