"""The aligned-fracture readers (C, JavaScript, the Python reference) on the shared conformance vectors.

tests/data/aligned_conformance/ holds three files (two synthetic box pairs, the chair from a fast bake)
and hits with the reference's fragments; every reader must give the same fragments within 1e-9 (in
practice the same bits: all three follow docs/FORMAT.md sections 13.3-13.4's arithmetic to the letter).
"""

from __future__ import annotations

import filecmp
import json
import os
import subprocess
import sys

import pytest
from aligned_support import (
    ALIGNED_CONFORMANCE,
    JS_DRIVER,
    NODE,
    compare,
    compile_c_driver,
    data_scales,
    run_driver,
    summarize,
)

from fracture_cli.errors import UsageError
from fracture_cli.runtime.aligned import aligned_fracture
from fracture_cli.runtime.aligned_data import load_aligned

NAMES = ("boxes", "boxes_unbounded", "chair")
SANITIZE = ["-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer"]


def vectors(name: str) -> tuple[dict, list]:
    with open(os.path.join(ALIGNED_CONFORMANCE, f"{name}.vectors.json"), encoding="utf-8") as fh:
        doc = json.load(fh)
    hits = [(h["pattern"], [float(x) for x in h["point"]], [float(x) for x in h["direction"]], float(h["scale"]))
            for h in doc["hits"]]
    return doc, hits


def check(name: str, answers: list) -> list[str]:
    doc, _ = vectors(name)
    data = load_aligned(os.path.join(ALIGNED_CONFORMANCE, doc["file"]))
    volume, size = data_scales(data)
    assert len(answers) == len(doc["hits"])
    return [p for i, (h, a) in enumerate(zip(doc["hits"], answers)) for p in compare(h["expect"], a, volume, size,
                                                                                   f"{name} hit {i}")]


@pytest.fixture(scope="module")
def c_driver(tmp_path_factory) -> str:
    try:
        return compile_c_driver(str(tmp_path_factory.mktemp("aligned_c") / "fracture_aligned_check"))
    except FileNotFoundError:
        pytest.skip("no C compiler")


@pytest.mark.parametrize("name", NAMES)
def test_c_reader_passes_the_vectors(c_driver, name):
    _, hits = vectors(name)
    assert check(name, run_driver([c_driver], os.path.join(ALIGNED_CONFORMANCE, f"{name}.aligned.json"), hits)) == []


@pytest.mark.skipif(NODE is None, reason="node (Node.js) is not installed")
@pytest.mark.parametrize("name", NAMES)
def test_js_reader_passes_the_vectors(name):
    _, hits = vectors(name)
    answers = run_driver([NODE, JS_DRIVER], os.path.join(ALIGNED_CONFORMANCE, f"{name}.aligned.json"), hits)
    assert check(name, answers) == []


@pytest.mark.parametrize("name", ("boxes", "boxes_unbounded"))
def test_reference_passes_the_vectors(name):
    doc, hits = vectors(name)
    data = load_aligned(os.path.join(ALIGNED_CONFORMANCE, doc["file"]))
    answers = []
    for q, p, d, s in hits:
        try:
            answers.append(summarize(data, aligned_fracture(data, p, d, s, q)))
        except UsageError:
            answers.append({"status": "error"})
    assert check(name, answers) == []


def test_c_reader_under_sanitizers(tmp_path):
    probe = subprocess.run(["cc", "-fsanitize=address,undefined", "-x", "c", "-", "-o", os.devnull],
                           input="int main(void){return 0;}", capture_output=True, text=True, check=False)
    if probe.returncode != 0:
        pytest.skip("the C compiler cannot build with AddressSanitizer + UBSan")
    driver = compile_c_driver(str(tmp_path / "fracture_aligned_check"), SANITIZE)
    for name in ("boxes", "boxes_unbounded"):
        _, hits = vectors(name)
        assert check(name, run_driver([driver], os.path.join(ALIGNED_CONFORMANCE, f"{name}.aligned.json"), hits)) == []


def test_damaged_files_are_refused(c_driver, tmp_path):
    """Truncated binaries, a wrong CRC, a wrong format name: an error line from both readers, never a crash."""
    src = os.path.join(ALIGNED_CONFORMANCE, "boxes.aligned")
    header, binary = open(src + ".json", "rb").read(), open(src + ".bin", "rb").read()
    cases = {"truncated": (header, binary[:-16]), "flipped": (header, binary[:100] + bytes([binary[100] ^ 1]) +
                                                            binary[101:]),
             "format": (header.replace(b"fracture-aligned", b"fracture-aligner"), binary),
             "json": (header[:-3], binary)}
    for case, (h, b) in cases.items():
        (tmp_path / f"{case}.aligned.json").write_bytes(h)
        (tmp_path / f"{case}.aligned.bin").write_bytes(b)
        path = str(tmp_path / f"{case}.aligned.json")
        for command in ([c_driver], [NODE, JS_DRIVER]) if NODE else ([c_driver],):
            result = subprocess.run([*command, path, path[:-5] + ".bin"], input="", capture_output=True, text=True,
                                    check=False)
            assert result.returncode == 1 and '"status": "error"' in result.stdout.replace('":"', '": "'), \
                (case, command[-1], result.stdout, result.stderr[-500:])


def test_the_generator_reproduces_this_folder(tmp_path):
    """The vectors and the synthetic files are what generate.py makes now (the chair is copied, not re-baked)."""
    subprocess.run([sys.executable, os.path.join(ALIGNED_CONFORMANCE, "generate.py"), "--out", str(tmp_path)],
                   check=True)
    for name in sorted(os.listdir(tmp_path)):
        assert filecmp.cmp(tmp_path / name, os.path.join(ALIGNED_CONFORMANCE, name), shallow=False), name
