"""Shared fixtures and the --update-goldens flag."""

from __future__ import annotations

import logging
import os
import signal

import pytest

# Before any test module imports numpy: the pinned numeric kernels every bake runs with (numeric_env.py).
import fracture_cli  # noqa: F401, I001

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLE_ASSETS = os.path.join(REPO, "sample_assets")
SAMPLE_FILES = ("pillar.glb", "chair.glb", "vase.obj")


def pytest_configure(config):
    # A run started in the background (nohup, `&` in a script) inherits SIGINT ignored, and so would every process
    # the Ctrl-C tests start (a Python started with SIGINT ignored keeps ignoring it): give this process, and so its
    # children, the disposition a terminal's run has.
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    # Before any test touches manifold3d: its TBB pool without worker threads, so the tests' forked workers
    # (fracture_cli.system.parallel) never inherit a TBB lock (what a bake's parallel.using() does first).
    from fracture_cli.system import parallel

    parallel.single_threaded_tbb()


def pytest_addoption(parser):
    parser.addoption("--update-goldens", action="store_true", default=False,
                     help="rewrite tests/golden/*.json from the current output instead of comparing")
    parser.addoption("--full-matrix", action="store_true", default=False,
                     help="bake the whole pattern matrix (tests/test_pattern_matrix.py), not only its half")


@pytest.fixture
def update_goldens(request) -> bool:
    return bool(request.config.getoption("--update-goldens"))


@pytest.fixture(params=SAMPLE_FILES)
def sample_asset(request) -> str:
    return os.path.join(SAMPLE_ASSETS, request.param)


@pytest.fixture(autouse=True)
def _pristine_fracture_logger():
    """CLI tests route the 'fracture_cli' logger to stderr and stop its propagation (configure_output).

    Every test starts with the logger as a library user gets it (no handlers, level unset, records
    propagating to the root, where caplog listens), whatever ran before in this worker: a module-scoped
    fixture that ran a CLI command changes it before any function-scoped fixture could save it.
    """
    logger = logging.getLogger("fracture_cli")
    logger.handlers[:], logger.level, logger.propagate = [], logging.NOTSET, True
    yield
    logger.handlers[:], logger.level, logger.propagate = [], logging.NOTSET, True


@pytest.fixture
def outside_make(monkeypatch):
    """The test runs as outside make (the suite itself may run under `make -j2 test`, whose MAKEFLAGS would
    change the default jobs), with no jobserver client kept from another test."""
    from fracture_cli.system import jobserver

    monkeypatch.delenv("MAKEFLAGS", raising=False)
    jobserver.forget()
    yield
    jobserver.forget()
