"""A 2-level bake of every sample asset (issue 34, done-when 1): every fragment check at both levels, the leaf cap.

Each sample asset is baked once with the recipe its manifest names and ``levels.count = 2``, under a leaf
cap set below what the rule alone would refine, so the cap binds. Checked, level by level:

* the report: level 1's checks as without levels, the children's (the pipeline's own checks of every
  refined fragment's children: closed, one body, no pinched, misoriented or degenerate faces, the nesting
  in their parent), and leaves within the cap with candidates left whole because of it;
* the GLB as written, with the independent checker of :mod:`invariants`: every fragment of either level
  closed, oriented, one body; level 1 summing to the input's volume, every parent's children to the parent's,
  everything inside the input's bounding box;
* the runtime file: the fragments the GLB names, the parent of every child, the leaves.

The wall time against a 1-level bake is a bench figure (bench/bench_levels.py), not a test.
"""

from __future__ import annotations

import json
import os
import tomllib

import numpy as np
import pytest
from click.testing import CliRunner
from invariants import check_fragment, input_box, read_glb_fragments

from fracture_cli.cli import cli
from fracture_cli.runtime import levels as lv
from fracture_cli.runtime.format import load_runtime

from conftest import SAMPLE_ASSETS

pytestmark = pytest.mark.slow

with open(os.path.join(SAMPLE_ASSETS, "manifest.toml"), "rb") as _fh:
    RECIPES = tomllib.load(_fh)["assets"]

# A cap that binds: the level-1 fragments plus room for a few parents' children (the rule alone would refine
# every fragment above 2 % of the volume: the pillar's 10 into 45 leaves, the chair's 12 of 16 into 42).
CAPS = {"pillar.glb": 20, "chair.glb": 26, "vase.obj": 100}
# The report's counts of broken faces, summed over the children (all must be 0), and the worst of the rest.
ZERO = ("open_edges", "pinched_edges", "misoriented_edges", "degenerate_faces")


@pytest.fixture(scope="module", params=sorted(CAPS))
def baked(request, tmp_path_factory):
    """(asset, report, output folder) of the asset's 2-level bake."""
    asset = request.param
    out = str(tmp_path_factory.mktemp(os.path.splitext(asset)[0]))
    result = CliRunner().invoke(cli, ["bake", os.path.join(SAMPLE_ASSETS, asset), "-o", out, "-r", RECIPES[asset],
                                      "--set", "levels.count=2", "--set", f"levels.max_leaves={CAPS[asset]}",
                                      "--json"])
    assert result.exit_code == 0, result.output[-2000:]
    report = json.loads(result.stdout[result.stdout.index("{"):])
    return asset, report, out


def test_report_checks_at_both_levels_and_the_leaf_cap(baked):
    asset, report, _ = baked
    level1, block = report["checks"], report["levels"]
    assert level1["watertight"] and level1["connected"] and level1["fragment_bodies_max"] == 1
    assert all(level1[key] == 0 for key in ZERO)
    checks = block["checks"]
    assert block["refined"], "a parent is broken again"
    assert checks["watertight"] and checks["connected"] and checks["fragment_bodies_max"] == 1
    assert all(checks[key] == 0 for key in ZERO), checks
    assert checks["volume_error_max"] <= 1e-6 and checks["parent_area_error_max"] <= 1e-6
    assert checks["parent_distance_max"] <= 1e-9
    assert block["max_leaves"] == CAPS[asset]
    assert block["leaves"] == level1["fragments"] + sum(n - 1 for n in block["children"]) <= CAPS[asset]
    assert any("max_leaves" in why for why in block["stay_whole"].values()), "the cap binds"


def test_glb_fragments_at_both_levels(baked):
    asset, report, out = baked
    stem = os.path.splitext(asset)[0]
    data = load_runtime(os.path.join(out, f"{stem}.fracture.json"))
    written = {f.name: f for f in read_glb_fragments(os.path.join(out, f"{stem}.glb"))}
    names = [lv.fragment_name(data, g) for g in range(lv.num_fragments(data))]
    checks = {name: check_fragment(written[name]) for name in names}
    bad = {name: c.problems for name, c in checks.items() if not c.ok}
    assert not bad
    level1 = names[: data.p]
    total = sum(checks[n].volume for n in level1)
    assert abs(total - report["checks"]["input_volume"]) <= 1e-5 * report["checks"]["input_volume"]
    parents = np.asarray(data.levels["parent"])
    assert len(names) - data.p == sum(report["levels"]["children"])
    for j in np.unique(parents[data.p:]):
        mine = [names[g] for g in range(data.p, len(names)) if parents[g] == j]
        assert abs(sum(checks[n].volume for n in mine) - checks[names[j]].volume) <= 1e-5 * checks[names[j]].volume
    box = input_box(os.path.join(SAMPLE_ASSETS, asset))
    diagonal = float(np.linalg.norm(box[1] - box[0]))
    low = np.min([c.bbox_min for c in checks.values()], axis=0)
    high = np.max([c.bbox_max for c in checks.values()], axis=0)
    assert max(np.max(box[0] - low), np.max(high - box[1])) <= 1e-6 * diagonal
    leaves = len(names) - len(np.unique(parents[data.p:]))
    assert leaves == report["levels"]["leaves"] <= CAPS[asset]
