"""Shared fixtures and the --update-goldens flag."""

from __future__ import annotations

import logging
import os

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLE_ASSETS = os.path.join(REPO, "sample_assets")
SAMPLE_FILES = ("pillar.glb", "chair.glb", "vase.obj")


def pytest_addoption(parser):
    parser.addoption("--update-goldens", action="store_true", default=False,
                     help="rewrite tests/golden/*.json from the current output instead of comparing")


@pytest.fixture
def update_goldens(request) -> bool:
    return bool(request.config.getoption("--update-goldens"))


@pytest.fixture(params=SAMPLE_FILES)
def sample_asset(request) -> str:
    return os.path.join(SAMPLE_ASSETS, request.param)


@pytest.fixture(autouse=True)
def _restore_fracture_logger():
    """CLI tests route the 'fracture_cli' logger to stderr and stop its propagation (configure_output); put
    it back afterwards, so a later test in the same worker still sees its records through caplog."""
    logger = logging.getLogger("fracture_cli")
    saved = (list(logger.handlers), logger.level, logger.propagate)
    yield
    logger.handlers[:], logger.level, logger.propagate = saved[0], saved[1], saved[2]
