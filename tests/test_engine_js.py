"""The JavaScript reader's jump-table path (engines/web/fracture_runtime.js with ``jumpTable: true``).

tests/test_view_runtime_js.py checks the reader as the viewer uses it (vectors, damaged
files, the Python reference); here the same driver loads with ``--jump-table``, so every
impact also goes through the table path (the driver compares it with the full projection
and answers "error inconsistent" if they differ). Files with feature "damage" build no
table (each hit updates a state from every bond's measure): their impacts and sequences
run the full path. Skipped when node is missing.
"""

from __future__ import annotations

import subprocess

import pytest
from engine_support import (
    JS_DRIVER,
    NODE,
    READER_FEATURES,
    SAMPLE_ASSETS,
    check_answers,
    load_vectors,
    protocol_input,
    random_impacts,
    requires_node,
    runtime_paths,
    vector_names,
)
from levels_support import body_input, check_bodies, check_children, check_sequences, levels_files, sequence_input
from test_view_runtime_js import VARIANTS, check_structure_answers, structure_input, variant_vectors

DRIVER = JS_DRIVER
pytestmark = requires_node


def _answers(name: str, stdin: str) -> str:
    result = subprocess.run([NODE, DRIVER, "--jump-table", *runtime_paths(name)], input=stdin,
                            capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    return result.stdout


@pytest.mark.parametrize("name", vector_names(READER_FEATURES["js"]))
def test_js_jump_table_passes_the_vectors(name):
    vectors = load_vectors(name)
    assert check_structure_answers(vectors, _answers(name, structure_input(vectors))) == []


@pytest.mark.parametrize(("name", "drop"), VARIANTS)
def test_js_jump_table_on_files_with_one_structure_feature(tmp_path, name, drop):
    """Anchors without damage build the table (d = 1, modes): its groups then give the anchored fragments."""
    header, binary, vectors = variant_vectors(name, drop, tmp_path)
    result = subprocess.run([NODE, DRIVER, "--jump-table", header, binary], input=structure_input(vectors),
                            capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    assert check_structure_answers(vectors, result.stdout) == []


@pytest.mark.parametrize("name", SAMPLE_ASSETS)
def test_js_jump_table_matches_the_reference_on_many_hits(name):
    impacts = random_impacts(name, 400)
    assert check_answers({"runtime": name, "impacts": impacts}, _answers(name, protocol_input(impacts))) == []


@pytest.mark.parametrize("flags", [(), ("--jump-table",)], ids=["full", "table"])
@pytest.mark.parametrize("name", levels_files(READER_FEATURES["js"]))
def test_js_reader_runs_the_levels_vectors(name, flags):
    """Section 14: every body's stateless impacts, the object sequences (hitPiece, objectPieces), child names."""
    vectors = load_vectors(name)
    result = subprocess.run([NODE, DRIVER, "--children", *flags, *runtime_paths(name)],
                            input=body_input(vectors) + sequence_input(vectors), capture_output=True, text=True,
                            timeout=300, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    assert check_bodies(vectors, result.stdout) == []
    assert check_sequences(vectors, result.stdout) == []
    assert check_children(runtime_paths(name)[0], result.stdout) == []
