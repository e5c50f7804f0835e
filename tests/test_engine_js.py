"""The JavaScript reader's jump-table path (engines/web/fracture_runtime.js with ``jumpTable: true``).

tests/test_view_runtime_js.py checks the reader as the viewer uses it (vectors, damaged
files, the Python reference); here the same driver loads with ``--jump-table``, so every
impact also goes through the table path (the driver compares it with the full projection
and answers "error inconsistent" if they differ). Skipped when node is missing.
"""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest
from engine_support import (
    REPO,
    SAMPLE_ASSETS,
    check_answers,
    load_vectors,
    protocol_input,
    random_impacts,
    runtime_paths,
    vector_names,
)

DRIVER = os.path.join(REPO, "engines", "web", "fracture_check.mjs")
NODE = shutil.which("node")

pytestmark = pytest.mark.skipif(NODE is None, reason="node (Node.js) is not installed; the JavaScript reader "
                                "runs under it (apt-get install nodejs)")


def _answers(name: str, impacts: list[dict]) -> str:
    result = subprocess.run([NODE, DRIVER, "--jump-table", *runtime_paths(name)], input=protocol_input(impacts),
                            capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    return result.stdout


@pytest.mark.parametrize("name", vector_names())
def test_js_jump_table_passes_the_vectors(name):
    vectors = load_vectors(name)
    assert check_answers(vectors, _answers(name, vectors["impacts"])) == []


@pytest.mark.parametrize("name", SAMPLE_ASSETS)
def test_js_jump_table_matches_the_reference_on_many_hits(name):
    impacts = random_impacts(name, 400)
    assert check_answers({"runtime": name, "impacts": impacts}, _answers(name, impacts)) == []
