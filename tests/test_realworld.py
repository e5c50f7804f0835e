"""The real-world corpus (tests/data/realworld/) baked end to end, checked independently.

Each file of ``expected.toml`` is baked once (reduced cage and mode count, so
each bake takes seconds; the classes of failure do not depend on them) and
the written GLB is checked by tests/invariants.py, which shares no geometry
code with the library: every fragment closed, edge-manifold, consistently
oriented, one body, positive volume; volumes summing to the solid the input
describes; everything inside the input's bounding box; and the report's
``watertight`` agreeing with that check. Classes the tool does not handle yet
are strict expected failures whose reason names the root cause
(docs/notes/realworld-diagnosis.md); fixing one makes its test pass and the
xfail must then be removed.
"""

from __future__ import annotations

import fcntl
import json
import os
import sys
import tomllib

import pytest
from click.testing import CliRunner

from fracture_cli.cli import cli

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from invariants import check_glb, input_box, read_glb_fragments

HERE = os.path.dirname(os.path.abspath(__file__))
CORPUS = os.path.join(HERE, "data", "realworld")
with open(os.path.join(CORPUS, "expected.toml"), "rb") as _fh:
    CASES = {c["file"]: c for c in tomllib.load(_fh)["case"]}
SMALL = ("cage.target_faces=500", "modes.num_modes=4")

# Root causes (see docs/notes/realworld-diagnosis.md); each entry is a strict xfail of test_corpus_bake.
_FILL_LIMIT = (
    "repair.auto shells an open body whose holes exceed max_fill_ratio=2% of the area "
    "(repair.py:repair step 4), so a closed shape with holes becomes an eggshell 1% of the diagonal thick"
)
_EDGE_UNION = (
    "repair.py:_split_nonmanifold + _union_bodies: bodies touching along an edge are united by manifold3d, "
    "which keeps the edge as two coincident edges; fragments cut from that solid have 4-face (pinched) "
    "edges, and checks.py:_closed_by_position counts a balanced 4-face edge as watertight"
)
_REFUSED = (
    "repair.py:_split_nonmanifold pairs only closed patches or open patches with identical boundaries; "
    "coincident faces triangulated differently leave 4-face edges it cannot pair, and the bake is refused"
)
_SOUP = (
    "repair.py:_unique_faces drops a duplicated face together with its reversed copy ('back-to-back'), so a "
    "soup's duplicate of opposite winding becomes a hole; the soup is then shelled (over 2%), outward where the "
    "load-time shading normals (from the random winding) point in, and the shell's rims pinch"
)
KNOWN_FAILURES = {
    "head_open_eyes.glb": _FILL_LIMIT + " (the eyes' rims are 2.35% of the area)",
    "scan_holes_037.glb": _FILL_LIMIT,
    "scan_holes_06.glb": _FILL_LIMIT,
    "scan_holes_10.glb": _FILL_LIMIT,
    "gear_edge_contact.glb": _EDGE_UNION,
    "vertex_contact.glb": _EDGE_UNION,
    "gear_coplanar.glb": _REFUSED,
    "touching_fragments.glb": _REFUSED,
    "soup.stl": _SOUP,
    "teapot.glb": _FILL_LIMIT + " (22.9%): four thin shells, the pot's inside empty; and the shelled union has a "
    "cavity, for which repair.py:_reversed passes manifold3d a read-only vert_properties view: TypeError, "
    "an internal error",
    "awning_sheet.glb": (
        "repair.py:_shell offsets along the area-weighted vertex normal with no bound: at the rim the "
        "normal tilts, and the back side leaves the input's bounding box (by ~0.1% of the diagonal)"
    ),
}


def _shared_dir(tmp_path_factory) -> str:
    """A folder shared by all pytest-xdist workers of this run (bakes are cached there)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    path = os.path.join(str(root), "realworld-bakes")
    os.makedirs(path, exist_ok=True)
    return path


def bake_once(shared: str, path: str, recipe: str = "default", overrides=SMALL) -> tuple[int, str, str]:
    """Bake ``path`` once per run (a lock keeps xdist workers from baking it twice): exit code, output, folder."""
    stem = os.path.splitext(os.path.basename(path))[0]
    out = os.path.join(shared, f"{stem}-{recipe}" + ("-small" if overrides == SMALL else "-full"))
    with open(out + ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        done = out + ".result.json"
        if not os.path.exists(done):
            args = ["bake", path, "-o", out, "-r", recipe]
            for o in overrides:
                args += ["--set", o]
            result = CliRunner().invoke(cli, args)
            with open(done, "w") as fh:
                json.dump({"exit": result.exit_code, "output": result.output}, fh)
        with open(done) as fh:
            record = json.load(fh)
    return record["exit"], record["output"], out


def check_bake(case: dict, path: str, exit_code: int, output: str, out: str) -> list[str]:
    """Everything wrong with one bake of a corpus file, as lines (empty when it meets its expected outcome)."""
    if exit_code != 0:
        return [f"exit code {exit_code}: {output.strip().splitlines()[-1] if output.strip() else ''}"]
    stem = os.path.splitext(os.path.basename(path))[0]
    glb = os.path.join(out, f"{stem}.glb")
    check = check_glb(
        glb,
        reference_volume=case.get("volume"),
        volume_tolerance=case["volume_tolerance"],
        reference_box=input_box(path),
    )
    problems = list(check.problems)
    with open(os.path.join(out, f"{stem}.report.json")) as fh:
        report = json.load(fh)
    claimed = report["checks"]["watertight"]
    really = not any(f.problems for f in check.fragments)
    if claimed != really:
        problems.append(f"report says watertight={claimed}, the independent check says {really}")
    return problems


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CASES))
def test_corpus_bake(name, tmp_path_factory, request):
    """Bake one corpus file and check its expected outcome on the written GLB."""
    if name in KNOWN_FAILURES:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN_FAILURES[name]))
    case = CASES[name]
    path = os.path.join(CORPUS, name)
    exit_code, output, out = bake_once(_shared_dir(tmp_path_factory), path)
    problems = check_bake(case, path, exit_code, output, out)
    assert not problems, f"{name} ({case['kind']}): " + "; ".join(problems[:8])


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True, reason="report.json has no 'repairs' list yet (bake.py); round two adds it from the meshfix records"
)
@pytest.mark.parametrize("name", ["scan_holes_037.glb", "gear_edge_contact.glb", "soup.stl"])
def test_corpus_repairs_are_reported(name, tmp_path_factory):
    """What repair did (filled holes and their area, split edges, re-wound faces) is listed in report.json."""
    path = os.path.join(CORPUS, name)
    exit_code, output, out = bake_once(_shared_dir(tmp_path_factory), path)
    assert exit_code == 0, output
    with open(os.path.join(out, f"{os.path.splitext(name)[0]}.report.json")) as fh:
        report = json.load(fh)
    repairs = report.get("repairs")
    assert isinstance(repairs, list) and repairs, "no repairs listed"
    assert all({"what", "detail"} <= set(r) for r in repairs)


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="the output GLB stores each fragment in float32 about its own pivot, so "
    "neighbours' shared faces no longer coincide (off by ~1e-8); repair.py:_union_bodies unites them "
    "into a solid with hairline gaps and pinched edges; its fragments have vertices 1e-9 apart that "
    "merge when written in float32 (degenerate faces, pinched edges, several bodies), while "
    "checks.py:fragment_invariants checks the float64 meshes and reports watertight",
)
def test_rebaking_an_output_glb(tmp_path_factory):
    """Bake a sample asset, then bake its output GLB: one solid of the same volume, every fragment closed."""
    from conftest import SAMPLE_ASSETS

    shared = _shared_dir(tmp_path_factory)
    source = os.path.join(SAMPLE_ASSETS, "pillar.glb")
    exit_code, output, first = bake_once(shared, source)
    assert exit_code == 0, output
    first_glb = os.path.join(first, "pillar.glb")
    volume = sum(check.volume for check in check_glb(first_glb).fragments)
    assert len(read_glb_fragments(first_glb)) > 1
    rebake_input = os.path.join(shared, "pillar_fragments.glb")
    if not os.path.exists(rebake_input):
        with open(first_glb, "rb") as src, open(rebake_input, "wb") as dst:
            dst.write(src.read())
    exit_code, output, out = bake_once(shared, rebake_input)
    case = {"volume": volume, "volume_tolerance": 1e-3, "kind": "re-baked output GLB"}
    problems = check_bake(case, rebake_input, exit_code, output, out)
    assert not problems, "; ".join(problems[:8])


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [
        "two_prisms.glb",
        pytest.param(
            "scan_holes_01.glb",
            marks=pytest.mark.xfail(
                strict=True,
                reason=(
                    "pieces.py: the atomic pieces are the common refinement of all 12 modes' partitions; on a round, "
                    "nearly symmetric body the modes cut along unrelated surfaces, so the refinement has 520 "
                    "atomic pieces (a cube: 40), and min_volume_fraction=0.002, measured on cage volume, merges only "
                    "down to 197"
                ),
            ),
        ),
    ],
)
def test_fragment_count_follows_the_recipe(name, tmp_path_factory):
    """With the default recipe (full settings), a compact asset gives tens of fragments, not gravel."""
    case = CASES[name]
    exit_code, output, out = bake_once(_shared_dir(tmp_path_factory), os.path.join(CORPUS, name), overrides=())
    assert exit_code == 0, output
    with open(os.path.join(out, f"{os.path.splitext(name)[0]}.report.json")) as fh:
        count = json.load(fh)["counts"]["fragments"]
    assert count <= case["max_fragments"], f"{count} fragments (at most {case['max_fragments']} expected)"
