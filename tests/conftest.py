"""Shared fixtures and the --update-goldens flag."""

from __future__ import annotations

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
