"""Every shell command the README shows (its fenced ``sh`` blocks, and its ``python`` block) runs as shown.

The commands run in README order from the root of a scratch copy of the checkout's
tracked files (what a fresh clone has), with this environment's ``fracture`` first
on ``PATH`` (the README's "activate .venv"), so later commands find what earlier
ones wrote (``build/chair``). Each must exit 0 without an internal error, and write what
:data:`WRITES` says. The sections run in four independent groups (:data:`GROUPS`,
each in its own copy), so ``pytest -n 2`` spreads the dozen or so bakes over its
workers. The commands left out are in :data:`LEFT_OUT`, each with the reason; a
left-out command that the README no longer shows fails the test, so the list cannot
go stale.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys

import pytest

from conftest import REPO

# README section (the start of its `## ` heading) -> the group whose copy runs its blocks, in README order.
GROUPS = {
    "Bake": "bake",
    "Recipes": "bake",
    "Batch": "batch",
    "The command chain": "chain",
    "In a game": "chain",  # reads build/chair/chair.fracture.json, which the chain exports
    "Structures": "structures",  # bakes the pillar as a structure, hits it, and runs the game loop on it
    "Fragments that break again": "levels",  # bakes with two levels, then hits the pillar and a piece that flew
}

# Files a command writes (relative to the copy's root), checked right after it.
WRITES = {
    "fracture bake sample_assets/chair.glb -o build/chair --recipe wood": ["build/chair/chair.glb"],
    "fracture bake sample_assets/pillar.glb sample_assets/vase.obj -o build/props --recipe stone --set "
    "modes.num_modes=8 --json > report.json": ["build/props/vase.glb", "report.json"],
    "fracture bake sample_assets/chair.glb -o build/chair --preview": ["build/chair/chair.preview.png"],
    "fracture bake sample_assets/*.glb -o build/props --keep-going --cache build/cache": ["build/props/chair.glb"],
    "fracture batch sample_assets/manifest.toml -o build/assets": ["build/assets/vase.glb",
                                                                   "build/assets/manifest.batch.json"],
    "fracture batch sample_assets/manifest.toml -o build/assets --impacts 100": [
        "build/assets/manifest.impacts.parquet"],
    "fracture load sample_assets/chair.glb save build/chair_copy.glb": ["build/chair_copy.glb"],
    "fracture impact build/chair/chair.fracture.json --point 0.45 0.85 -0.45 --impulse 0 -5 0 -o build/broken.glb": [
        "build/broken.glb"],
    "fracture preview build/chair/chair.fracture.json -o build/chair.png": ["build/chair.png"],
    "fracture bake sample_assets/pillar.glb -o build/pillar -r stone_structure": ["build/pillar/pillar.fracture.json"],
    "fracture bake sample_assets/chair.glb -o build/chair-floor -r wood --set anchors.ground=true --set "
    "runtime.damage=true": ["build/chair-floor/chair.fracture.json"],
    "fracture bake sample_assets/chair.glb -o build/chair_cut -r wood --set aligned.enabled=true": [
        "build/chair_cut/chair.aligned.json", "build/chair_cut/chair.aligned.bin"],
    "fracture bake sample_assets/pillar.glb -o build/pillar_levels -r stone --set levels.count=2": [
        "build/pillar_levels/pillar.fracture.json", "build/pillar_levels/pillar.glb"],
    "fracture bake sample_assets/chair.glb -o build/chair_levels -r wood --set levels.count=2 --set "
    "levels.ratio=0.25 --set levels.max_leaves=24": ["build/chair_levels/chair.fracture.json"],
}

LEFT_OUT = {
    "make demo": "builds its own .venv (about 7 minutes with the downloads) and bakes the chair: what make demo "
                 "does is what the bake commands below do; a fresh clone's make install + make demo was run by hand",
    "make test": "is this test suite",
    "fracture view build/demo": "serves until Ctrl-C and opens a browser; tests/test_view_cli.py and "
                                "tests/test_view_e2e.py run the server and its page",
    "fracture view build/chair_cut": "serves until Ctrl-C; tests/test_view_aligned.py runs the page's cut mode",
    "fracture batch props/manifest.toml -o /shared/out --scheduler tcp://farm:8786": "needs a Dask cluster "
                                                                                       "(a scheduler at farm:8786)",
    "dask scheduler": "starts a cluster's scheduler, which runs until stopped",
    "dask worker tcp://farm:8786 --nworkers 8 --nthreads 1": "needs a Dask scheduler at farm:8786",
}


def readme_blocks(text: str, languages: tuple[str, ...] = ("sh", "python")) -> list[tuple[str, str, str]]:
    """``(section, language, body)`` of each fenced block of those languages, in order, with the heading of the
    ``## `` section it is in; indented fences (in a list) too."""
    blocks = []
    for match in re.finditer(r"^## ([^\n]*)$|^( *)```(\w+)\n(.*?)^\2```", text, flags=re.S | re.M):
        heading, indent, language, body = match.groups()
        if heading is not None:
            section = heading
        elif language in languages:
            blocks.append((section, language, "".join(line[len(indent):] + "\n" for line in body.splitlines())))
    return blocks


def _group(section: str) -> str | None:
    return next((group for start, group in GROUPS.items() if section.startswith(start)), None)


def shell_commands(body: str) -> list[str]:
    """The commands of an ``sh`` block: continuation lines joined, comment-only lines and trailing comments dropped."""
    commands = []
    for line in body.replace("\\\n", " ").splitlines():
        command = re.sub(r"\s+#.*$", "", line).strip()
        if command and not command.startswith("#"):
            commands.append(re.sub(r"\s+", " ", command))
    return commands


def _readme() -> str:
    with open(os.path.join(REPO, "README.md")) as fh:
        return fh.read()


def _scratch_copy(dest: str) -> None:
    """The tracked files (a fresh clone), or the tree without build outputs where there is no git."""
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True)
    if listed.returncode == 0 and listed.stdout:
        for name in listed.stdout.decode().split("\0"):
            if name and os.path.isfile(os.path.join(REPO, name)):
                os.makedirs(os.path.dirname(os.path.join(dest, name)), exist_ok=True)
                shutil.copy2(os.path.join(REPO, name), os.path.join(dest, name))
    else:
        shutil.copytree(REPO, dest, dirs_exist_ok=True, ignore=shutil.ignore_patterns(
            ".git", ".venv", "build", "__pycache__", ".*_cache", "node_modules", "vendor"))


def _commands(blocks) -> list[str]:
    return [c for _, language, body in blocks if language == "sh" for c in shell_commands(body)]


def test_readme_blocks_are_found():
    blocks = readme_blocks(_readme())
    commands = _commands(blocks)
    assert len(commands) >= 15 and "fracture recipes show wood" in commands
    assert any(c.startswith("dask worker") for c in commands)  # the indented block in the cluster steps
    assert [language for _, language, _ in blocks].count("python") == 4  # In a game, Structures, aligned, levels
    stale = (set(LEFT_OUT) | set(WRITES)) - set(commands)
    assert not stale, f"LEFT_OUT or WRITES name commands the README no longer shows: {sorted(stale)}"
    # A section outside GROUPS has nothing to run (a new block there needs a group, or a reason to be left out).
    ungrouped = [c for c in _commands([b for b in blocks if _group(b[0]) is None]) if c not in LEFT_OUT]
    assert not ungrouped, f"add their sections to GROUPS: {ungrouped}"
    assert not [b for b in blocks if b[1] == "python" and _group(b[0]) is None]


@pytest.mark.slow
@pytest.mark.parametrize("group", sorted(set(GROUPS.values())))
def test_readme_commands_run_as_shown(group, tmp_path):
    root = tmp_path / "clone"
    _scratch_copy(str(root))
    env = {k: v for k, v in os.environ.items() if k not in ("FRACTURE_RECIPES", "MAKEFLAGS")}
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    failures = []
    for section, language, body in readme_blocks(_readme()):
        if _group(section) != group:
            continue
        if language == "python":
            runs = [("python block of " + section, [sys.executable, "-c", body])]
        else:
            runs = [(c, ["bash", "-o", "pipefail", "-c", c]) for c in shell_commands(body) if c not in LEFT_OUT]
        for command, args in runs:
            result = subprocess.run(args, cwd=root, env=env, capture_output=True, text=True, timeout=900)
            missing = [name for name in WRITES.get(command, []) if not (root / name).is_file()]
            # fracture's own uncaught errors say "internal error"; a traceback that Dask's logging prints while a
            # loaded machine shuts the local cluster down (a missed heartbeat) is not the command failing.
            if result.returncode != 0 or "internal error" in result.stderr or missing:
                failures.append(f"{command}\n  exit {result.returncode}, missing {missing}: "
                                f"{result.stderr.strip()[-600:]}")
    assert not failures, "README commands that fail from a clone's root:\n" + "\n".join(failures)
