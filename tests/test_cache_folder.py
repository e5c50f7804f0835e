"""A ``--cache`` folder that cannot be used only costs time: one warning line, never a failed bake (issue 38).

A read-only cache gave ``internal error (PermissionError ...)`` at the cage
stage, and a cache folder that could not be made failed the bake before its
first stage. What a build tool user expects of a cache: the bake carries on
without it (reading what it can, storing nothing) and says so once. Tests that
need a folder this user cannot write are skipped as root (chmod does not
restrict root); the same failures are also simulated with monkeypatch.
"""

from __future__ import annotations

import errno
import logging
import os
import shutil
import stat
from types import SimpleNamespace

import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli
from fracture_cli.io.outputs import verify_output_set
from fracture_cli.pipeline import cache as cache_module
from fracture_cli.pipeline.cache import StageCache

HERE = os.path.dirname(os.path.abspath(__file__))
BOX = os.path.join(HERE, "data", "bad", "uv_seams.obj")
SMALL = ["--set", "cage.target_faces=500", "--set", "modes.num_modes=3"]
as_root = pytest.mark.skipif(os.geteuid() == 0 if hasattr(os, "geteuid") else False,
                             reason="root writes into read-only folders anyway (chmod does not restrict root)")


def warnings(records) -> list[str]:
    return [r.getMessage() for r in records if r.levelno >= logging.WARNING]


def refuse_writes(monkeypatch) -> None:
    """Every cache store fails as in a read-only folder."""
    def read_only(path):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(cache_module, "atomic_path", read_only)


def test_a_cache_that_takes_no_file_is_warned_about_once(tmp_path, monkeypatch, caplog):
    refuse_writes(monkeypatch)
    cache = StageCache(str(tmp_path / "cache"))
    with caplog.at_level(logging.WARNING, logger="fracture_cli"):
        cache._store("cage", "k" * 64, {"a": cache_module.np.zeros(3)})
        cache._store("tetra", "j" * 64, {"a": cache_module.np.zeros(3)})  # no second line
    [line] = warnings(caplog.records)
    assert line == f"{tmp_path / 'cache'}: cannot store in the cache folder (Permission denied); this bake's " \
                   "results are not cached"


def test_a_cache_folder_that_cannot_be_made(tmp_path, caplog):
    (tmp_path / "a file").write_text("x")
    with caplog.at_level(logging.WARNING, logger="fracture_cli"):
        cache = StageCache(str(tmp_path / "a file" / "cache"))
        assert cache._load("cage", "k" * 64) is None
        cache._store("cage", "k" * 64, {"a": cache_module.np.zeros(3)})
    [line] = warnings(caplog.records)
    assert "cannot use the cache folder (Not a directory); baking without the cache" in line


def test_bake_with_a_read_only_cache_carries_on(tmp_path, monkeypatch):
    """The simulated read-only folder: exit 0, a complete set, one warning line, no internal error."""
    refuse_writes(monkeypatch)
    out = tmp_path / "out"
    result = CliRunner().invoke(cli, ["bake", BOX, "-o", str(out), "--cache", str(tmp_path / "cache"), *SMALL])
    assert result.exit_code == 0, result.stderr
    assert "internal error" not in result.stderr and "Traceback" not in result.stderr
    assert [line for line in result.stderr.splitlines() if line.startswith("warning:")] == [
        f"warning: {tmp_path / 'cache'}: cannot store in the cache folder (Permission denied); this bake's results "
        "are not cached"]
    assert verify_output_set(str(out), "uv_seams") is None


@as_root
def test_a_chmod_read_only_cache_is_read_but_not_written(tmp_path, caplog):
    folder = tmp_path / "cache"
    warm = StageCache(str(folder))
    warm._store("cage", "k" * 64, {"a": cache_module.np.arange(3)})
    os.chmod(folder, stat.S_IRUSR | stat.S_IXUSR)
    try:
        cache = StageCache(str(folder))
        with caplog.at_level(logging.WARNING, logger="fracture_cli"):
            assert list(cache._load("cage", "k" * 64)["a"]) == [0, 1, 2]  # what is there is still used
            cache._store("tetra", "j" * 64, {"a": cache_module.np.zeros(3)})
        [line] = warnings(caplog.records)
        assert "cannot store in the cache folder (Permission denied)" in line
    finally:
        os.chmod(folder, stat.S_IRWXU)


def test_damaged_and_odd_entries_are_recomputed(tmp_path, caplog):
    cache = StageCache(str(tmp_path))
    key = "k" * 64
    with open(cache._path("cage", key), "wb") as fh:
        fh.write(b"PK\x03\x04 not a zip")
    os.mkfifo(cache._path("tetra", key))  # would block a reader forever
    cache._store("modes", key, {"U": cache_module.np.zeros(3)})  # the right key, not the arrays modes needs
    with caplog.at_level(logging.WARNING, logger="fracture_cli"):
        assert cache._load("cage", key) is None
        assert cache._load("tetra", key) is None
        state = SimpleNamespace(need=lambda *a: SimpleNamespace(normalization=None))
        assert cache.get("modes", key, state) is None  # type: ignore[arg-type]
    lines = warnings(caplog.records)
    assert len(lines) == 3 and all(line.startswith("cache: ignoring") for line in lines), lines
    assert cache.events == {"cage": "miss", "tetra": "miss", "modes": "miss"}


@as_root
def test_an_entry_this_user_cannot_read_is_recomputed(tmp_path, caplog):
    cache = StageCache(str(tmp_path))
    cache._store("cage", "k" * 64, {"a": cache_module.np.zeros(3)})
    os.chmod(cache._path("cage", "k" * 64), 0)
    with caplog.at_level(logging.WARNING, logger="fracture_cli"):
        assert cache._load("cage", "k" * 64) is None
    assert "ignoring unreadable entry" in warnings(caplog.records)[0]
    shutil.rmtree(tmp_path, ignore_errors=True)
