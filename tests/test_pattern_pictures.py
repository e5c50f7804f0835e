"""The README's picture of each pattern kind is the Makefile's bake, quoted as the Makefile runs it, and committed.

`make docs-pattern-images` bakes each kind (``PATTERN_BAKE_<kind>``) and renders docs/pattern_<kind>.png with
``fracture preview --panels fragments``; here, without baking: the README quotes that very command in the kind's
section and shows that picture, the picture is tracked by git, and it is the preview's PNG (its title names the
kind, read back from the PNG's Title text).
"""

from __future__ import annotations

import os
import re
import subprocess

import pytest
from PIL import Image

from fracture_cli.stages.pattern import KINDS

from conftest import REPO


def _makefile_bakes() -> dict[str, str]:
    """``PATTERN_BAKE_<kind>``'s value for each kind, continuation lines joined."""
    with open(os.path.join(REPO, "Makefile")) as fh:
        text = fh.read().replace("\\\n", " ")
    return {kind: re.sub(r"\s+", " ", value).strip()
            for kind, value in re.findall(r"^PATTERN_BAKE_(\w+)\s*:=\s*(.*)$", text, flags=re.M)}


def _readme_section(kind: str) -> str:
    with open(os.path.join(REPO, "README.md")) as fh:
        text = fh.read()
    part = text.split("## Authored patterns: a picture of each kind", 1)[1].split("\n## ", 1)[0]
    return part.split(f"### {kind}\n", 1)[1].split("\n### ", 1)[0]


AUTHORED = sorted(set(KINDS) - {"modes"})


def test_every_authored_kind_has_a_picture_target():
    assert sorted(_makefile_bakes()) == AUTHORED


@pytest.mark.parametrize("kind", AUTHORED)
def test_the_readme_quotes_the_bake_of_the_picture(kind):
    section = _readme_section(kind)
    assert f"`fracture bake {_makefile_bakes()[kind]} -o build/patterns/{kind}`" in section
    assert f"](docs/pattern_{kind}.png)" in section
    picture = os.path.join(REPO, "docs", f"pattern_{kind}.png")
    tracked = subprocess.run(["git", "ls-files", "--error-unmatch", picture], cwd=REPO, capture_output=True)
    if tracked.returncode == 128:  # not a git checkout (a source archive): the file is there or not
        assert os.path.isfile(picture), f"no docs/pattern_{kind}.png: make docs-pattern-images"
    else:
        assert tracked.returncode == 0, f"docs/pattern_{kind}.png is not committed: make docs-pattern-images"
    with Image.open(picture) as image:
        assert image.size == (720, 280)
        assert f"pattern: {kind}" in image.info.get("Title", "")
