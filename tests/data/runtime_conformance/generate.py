"""Generate the runtime conformance vectors in this folder (see README.md here).

    .venv/bin/python tests/data/runtime_conformance/generate.py            # regenerate everything
    .venv/bin/python tests/data/runtime_conformance/generate.py --rebake   # also re-bake the sample assets
    .venv/bin/python tests/data/runtime_conformance/generate.py --out DIR  # write elsewhere (the test does)

Small runtime files (the worked example of docs/FORMAT.md, a dyadic d = 3 file
with exact ties, random d = 1 and d = 3 files, a one-fragment file) are written
by the reference writer; the sample assets' runtime files are baked with the
recipe of sample_assets/manifest.toml only with ``--rebake`` (slow) and are
otherwise read from this folder. Expected answers come from ``reference.py``
(docs/FORMAT.md section 4 to the letter); tests/test_engine_conformance.py
checks they agree with ``fracture_cli.runtime.impact``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(os.path.dirname(HERE)))
sys.path.insert(0, HERE)
sys.path.insert(0, REPO)

# fracture_cli first: it pins the numeric kernels before numpy loads (fracture_cli/system/numeric_env.py).
import fracture_cli  # noqa: E402, F401, I001

import numpy as np  # noqa: E402

import corrupt  # noqa: E402
import levels  # noqa: E402
import reference  # noqa: E402
import reference_damage  # noqa: E402
import reference_levels  # noqa: E402
import sharing  # noqa: E402
import structures  # noqa: E402

from fracture_cli.runtime.format import RuntimeData, load_runtime, write_runtime  # noqa: E402

VECTORS_FORMAT = "fracture-runtime-conformance"
VECTORS_VERSION = 1
SAMPLE_IMPACTS = 24  # random hits per sample asset
SMALL_IMPACTS = 40  # random hits per random synthetic file


# ---------------------------------------------------------------- the runtime files


def _names(p: int) -> tuple[str, ...]:
    return tuple(f"fragment_{j:03d}" for j in range(p))


def _doc_example() -> dict:
    """The JSON block after <!-- example-data --> in docs/FORMAT.md."""
    with open(os.path.join(REPO, "docs", "FORMAT.md"), encoding="utf-8") as fh:
        match = re.search(r"<!-- example-data -->\s*```json\n(.*?)```", fh.read(), re.DOTALL)
    if match is None:
        raise ValueError("docs/FORMAT.md has no <!-- example-data --> block")
    return json.loads(match.group(1))


def example_data() -> RuntimeData:
    """The worked example of docs/FORMAT.md section 6 (d = 1)."""
    ex = _doc_example()
    return RuntimeData(
        sites=np.array(ex["sites"], np.float32),
        B=np.array(ex["B"], np.float32),
        W=np.array(ex["W"], np.float32),
        edges=np.array(ex["edges"], np.int32),
        edge_areas=np.array(ex["edge_areas"], np.float32),
        fragment_names=tuple(ex["fragment_names"]),
        default_threshold=ex["default_threshold"],
        radius=ex["impact_radius"],
    )


def dyadic_d3() -> RuntimeData:
    """Five fragments with a cycle, three vector modes, small dyadic values (every sum exact).

    Sites 2 and 6 are the same point (an identical-site tie); edge (1, 3) has a
    jump of exactly 1.25 for a unit x impulse at site 0 (an exact threshold tie).
    """
    sites = [[0, 0, 0], [4, 0, 0], [0, 4, 0], [0, 0, 4], [4, 4, 0], [-4, 0, 0], [0, 4, 0], [2, 2, 2]]
    B = np.array(
        [
            [[1, 0, 0], [0, 0.5, 0], [0, 0, 0.25]],
            [[-0.5, 0, 0], [0, 1, 0], [0.5, 0, 0]],
            [[0, 1, 0], [0.25, 0, 0], [0, 0, -1]],
            [[0, 0, 1], [0, -0.5, 0], [1, 0, 0]],
            [[0.5, 0.5, 0], [0, 0, 0.5], [-0.25, 0, 0]],
            [[-1, 0, 0], [0, -1, 0], [0, 0, -1]],
            [[0, 0.75, 0], [0, 0, 0.5], [0.5, 0, 0]],
            [[0.25, 0.25, 0.25], [0.5, 0, 0], [0, 0.5, 0]],
        ]
    )
    W = np.array(
        [
            [[1, 0, 0], [0.25, 0, 0], [-0.5, 0, 0], [-1, 0, 0], [0, 0, 0]],
            [[0, 0.5, 0], [0, -0.5, 0], [0, 0, 0], [0, 0.25, 0.5], [0, 0, -1]],
            [[0, 0, 1], [0, 0, 0], [0, 0, -0.5], [0.5, 0, 0], [0, 0.25, 0]],
        ]
    )
    edges = [[0, 1], [0, 2], [1, 2], [1, 3], [2, 4], [3, 4]]
    return RuntimeData(
        sites=np.array(sites, np.float32),
        B=B.astype(np.float32),
        W=W.astype(np.float32),
        edges=np.array(edges, np.int32),
        edge_areas=np.arange(1, 7, dtype=np.float32),
        fragment_names=_names(5),
        default_threshold=1.0,
        radius=0.05,
    )


def single_fragment() -> RuntimeData:
    """One site, one mode, one fragment, no edges: zero-length arrays in the file."""
    return RuntimeData(
        sites=np.array([[1, 2, 3]], np.float32),
        B=np.array([[[2.0]]], np.float32),
        W=np.array([[[1.0]]], np.float32),
        edges=np.zeros((0, 2), np.int32),
        edge_areas=np.zeros(0, np.float32),
        fragment_names=_names(1),
        default_threshold=0.5,
    )


def stress_dyadic() -> RuntimeData:
    """Criterion ``"stress"`` (format version 2): four fragments in a cycle, three sites, dyadic gains.

    Every product and sum of the stress test is exact, so the ties below are ties in any order:
    at site 0 a unit x impulse gives bond 0 ``g = 1`` against ``t * S = 0.5 * T`` (a tie at ``T = 2``),
    bond 2 is compressed, bond 3 is not in site 0's list (never breaks from there).
    """
    gains = [[1.0, 0.0, 0.0], [0.5, 0.25, 0.0], [-0.5, 0.0, 0.25],  # site 0: bonds 0, 1, 2
             [0.0, 2.0, 0.0], [0.0, -1.0, 1.0],  # site 1: bonds 1, 3
             [0.25, 0.25, 0.25], [1.0, -1.0, 0.5], [0.0, 0.0, 4.0], [-2.0, 0.0, 0.0]]  # site 2: bonds 0..3
    return RuntimeData(
        sites=np.array([[0, 0, 0], [4, 0, 0], [0, 4, 2]], np.float32),
        B=np.array([[[1.0]], [[0.5]], [[-0.25]]], np.float32),
        W=np.array([[[1.0], [0.5], [-0.5], [0.0]]], np.float32),
        edges=np.array([[0, 1], [0, 3], [1, 2], [2, 3]], np.int32),
        edge_areas=np.array([1.0, 0.5, 2.0, 0.25], np.float32),
        fragment_names=_names(4),
        default_threshold=2.0,
        radius=0.05,
        criterion="stress",
        stress={
            "site_bonds_ptr": np.array([0, 3, 5, 9], np.int32),
            "site_bonds": np.array([0, 1, 2, 1, 3, 0, 1, 2, 3], np.int32),
            "site_bond_gain": np.array(gains, np.float32),
            "bond_strength": np.array([0.5, 0.25, 1.0, 0.125], np.float32),
        },
        stress_info={"note": "synthetic"},
    )


def random_data(d: int, seed: int, s: int = 400, k: int = 8, p: int = 40, e: int = 100) -> RuntimeData:
    """Random sites on a bumpy sphere and a connected graph with cycles (many cuts per hit)."""
    rng = np.random.default_rng(seed)
    sites = rng.normal(size=(s, 3))
    sites *= rng.uniform(0.8, 1.2, size=(s, 1)) / np.linalg.norm(sites, axis=1, keepdims=True)
    pairs = {(j, j + 1) for j in range(p - 1)}
    while len(pairs) < e:
        a, b = sorted(rng.integers(0, p, 2).tolist())
        if a != b:
            pairs.add((a, b))
    W = rng.normal(size=(k, p, d))
    return RuntimeData(
        sites=(sites * 2.5).astype(np.float32),
        B=rng.normal(size=(s, k, d)).astype(np.float32),
        W=W.astype(np.float32),
        edges=np.array(sorted(pairs), np.int32),
        edge_areas=rng.uniform(0.1, 1, e).astype(np.float32),
        fragment_names=_names(p),
        default_threshold=2.0,
        radius=0.05,
    )


def sample_assets() -> list[tuple[str, str]]:
    """(asset file, recipe) pairs of sample_assets/manifest.toml."""
    with open(os.path.join(REPO, "sample_assets", "manifest.toml"), "rb") as fh:
        return sorted(tomllib.load(fh)["assets"].items())


# Sample assets baked with the stress criterion too: (asset, recipe, name of the runtime file here).
STRESS_BAKES = [("chair.glb", "wood", "chair_stress")]
# ... and with the stress criterion's defaults (blocks, load sharing kappa 2: docs/FORMAT.md section 11.1).
SHARING_BAKES = [("chair.glb", "wood", "chair_sharing")]
# ... and with two levels of fracture (docs/FORMAT.md section 14), fast settings: (asset, recipe, name, --set values).
LEVEL_BAKES = [("pillar.glb", "stone", "pillar_levels", ("levels.count=2", "levels.ratio=0.5"))]


def rebake_sample_assets(dest: str) -> None:
    """Bake every sample asset with its manifest recipe and copy its runtime file to ``dest``."""
    bakes = [(asset, recipe, os.path.splitext(asset)[0], ()) for asset, recipe in sample_assets()]
    # The chair's stress file predates the blocks model (the default since): it stays the tet mesh's response.
    bakes += [(asset, recipe, name, ("--set", "runtime.criterion=stress", "--set", "runtime.stress_model=tets",
                                     "--set", "runtime.load_sharing=0"))
              for asset, recipe, name in STRESS_BAKES]
    bakes += [(asset, recipe, name, ("--set", "runtime.criterion=stress")) for asset, recipe, name in SHARING_BAKES]
    bakes += [(asset, recipe, name, tuple(x for value in sets for x in ("--set", value)))
              for asset, recipe, name, sets in LEVEL_BAKES]
    for asset, recipe, name, extra in bakes:
        stem = os.path.splitext(asset)[0]
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "fracture_cli",
                    "-q",
                    "bake",
                    os.path.join(REPO, "sample_assets", asset),
                    "-o",
                    tmp,
                    "--recipe",
                    recipe,
                    *extra,
                ],
                check=True,
                cwd=REPO,
            )
            if name == stem:
                for suffix in (".fracture.json", ".fracture.bin"):
                    shutil.copyfile(os.path.join(tmp, stem + suffix), os.path.join(dest, name + suffix))
            else:  # renamed: the header names its binary file
                data = load_runtime(os.path.join(tmp, stem + ".fracture.json"))
                write_runtime(data, os.path.join(dest, name + ".fracture.json"))


# ---------------------------------------------------------------- the impacts


def _unit(rng) -> list[float]:
    v = rng.normal(size=3)
    return (v / np.linalg.norm(v)).tolist()


def _midpoint_tie(rt: reference.Runtime, rng):
    """A point exactly halfway between two sites with no site nearer (an exact tie), or None."""
    sites = np.array(rt.sites)
    for a in rng.permutation(len(sites))[:50].tolist():
        d2 = ((sites - sites[a]) ** 2).sum(axis=1)
        d2[a] = np.inf
        b = int(d2.argmin())
        mid = [(sites[a, c] + sites[b, c]) / 2 for c in range(3)]
        if all(2 * mid[c] - sites[a, c] == sites[b, c] for c in range(3)):
            _, tied, _ = reference.nearest(rt, mid)
            if tied == tuple(sorted((a, b))) and not np.array_equal(sites[a], sites[b]):
                return mid
    return None


def designed_impacts(rt: reference.Runtime, rng) -> list[dict]:
    """The hand-picked cases every file gets (ties, extremes, invalid inputs)."""
    site0 = list(rt.sites[0])
    lo = [min(s[c] for s in rt.sites) for c in range(3)]
    u = _unit(rng)
    T = rt.default_threshold
    strong = [c * 2 * T / reference_levels.typical_load(rt, site0, u) for c in u]
    cases = [
        ("zero impulse at a site", site0, [0.0, 0.0, 0.0], None),
        ("zero impulse, threshold 0", site0, [0.0, -0.0, 0.0], 0.0),
        ("point far outside", [lo[0] - 1e6, lo[1] - 3e5, lo[2] + 2e5], strong, None),
        ("point on a site", list(rt.sites[-1]), strong, None),
        ("threshold +inf: unbreakable", site0, strong, math.inf),
        ("threshold 0: every nonzero jump breaks", site0, u, 0.0),
        ("threshold -0.0 acts as 0", site0, u, -0.0),
        ("impulse 1e155 (|n|^2 overflows), threshold scaled alike", site0, [c * 1e155 for c in strong], T * 1e155),
        ("impulse 1e-170 (|n|^2 underflows), threshold 1e-171", site0, [c * 1e-170 for c in u], 1e-171),
        ("subnormal impulse: T/m overflows, nothing breaks", site0, [5e-324, 0.0, 0.0], T),
        ("huge impulse against a tiny threshold", site0, [1e300, -1e300, 1e300], 1e-300),
        ("invalid: NaN in point", [math.nan, 0.0, 0.0], u, None),
        ("invalid: inf in point", [0.0, math.inf, 0.0], u, None),
        ("invalid: -inf in impulse", site0, [0.0, 0.0, -math.inf], None),
        ("invalid: NaN in impulse", site0, [1.0, math.nan, 0.0], None),
        ("invalid: NaN threshold", site0, u, math.nan),
        ("invalid: negative threshold", site0, u, -1.0),
        ("invalid: -inf threshold", site0, u, -math.inf),
    ]
    impacts = [
        {"name": name, "point": point, "impulse": impulse, "threshold": threshold}
        for name, point, impulse, threshold in cases
    ]
    # Exact site ties by construction: every squared distance overflows to +inf (so site 0),
    # and a point exactly halfway between two sites that no other site is nearer to.
    impacts.append(
        {
            "name": "exact tie: point so far that every squared distance overflows (site 0)",
            "point": [1e300, -1e300, 1e300],
            "impulse": strong,
            "threshold": None,
            "site_tie": True,
        }
    )
    mid = _midpoint_tie(rt, rng)
    if mid is not None:
        impacts.append(
            {
                "name": "exact tie: halfway between two sites",
                "point": mid,
                "impulse": strong,
                "threshold": None,
                "site_tie": True,
            }
        )
    return impacts


def random_impacts(rt: reference.Runtime, count: int, seed: int) -> list[dict]:
    """Hits near sites, impulses scaled so that from none to many edges break; ties avoided."""
    rng = np.random.default_rng(seed)
    sites = np.array(rt.sites)
    spread = float(np.ptp(sites, axis=0).max()) * 0.02 or 0.1
    impacts: list[dict] = []
    while len(impacts) < count:
        point = (sites[rng.integers(len(sites))] + rng.normal(scale=spread, size=3)).tolist()
        direction = _unit(rng)
        magnitude = (rt.default_threshold / reference_levels.typical_load(rt, point, direction)
                     * float(rng.choice([0.7, 1.3, 2.5, 6.0])))
        impulse = [c * magnitude for c in direction]
        threshold = None if len(impacts) % 3 else float(np.float32(rt.default_threshold * rng.uniform(0.5, 2)))
        if reference_damage.safe(reference_damage.solve(rt, point, impulse, threshold)):
            impacts.append(
                {"name": f"random hit {len(impacts)}", "point": point, "impulse": impulse, "threshold": threshold}
            )
    return impacts


# Exact ties in the dyadic d = 3 file: all sums exact, so every evaluation order agrees.
DYADIC_TIES: list[dict] = [
    {
        "name": "exact threshold tie: |jump| == T holds",
        "point": [0.5, 0.0, 0.0],
        "impulse": [1.0, 0.0, 0.0],
        "threshold": 1.25,
        "exact": True,
    },
    {
        "name": "exact threshold tie, impulse and threshold x8",
        "point": [0.5, 0.0, 0.0],
        "impulse": [8.0, 0.0, 0.0],
        "threshold": 10.0,
        "exact": True,
    },
    {
        "name": "identical sites 2 and 6: the smaller index",
        "point": [0.0, 4.0, 0.0],
        "impulse": [0.0, -2.0, 0.0],
        "threshold": None,
        "exact": True,
    },
    {
        "name": "equidistant from sites 0 and 5",
        "point": [-2.0, 7.0, -3.0],
        "impulse": [0.0, 0.0, 3.0],
        "threshold": 0.5,
        "exact": True,
    },
]
STRESS_TIES: list[dict] = [
    {
        "name": "exact stress tie: g == t * S holds (site 0, bond 0)",
        "point": [0.5, 0.0, 0.0],
        "impulse": [1.0, 0.0, 0.0],
        "threshold": 2.0,
        "exact": True,
    },
    {
        "name": "exact stress tie x 1024",
        "point": [0.5, 0.0, 0.0],
        "impulse": [1024.0, 0.0, 0.0],
        "threshold": 2048.0,
        "exact": True,
    },
    {
        "name": "just above the tie: bond 0 breaks, bond 2 compressed, bond 3 not listed",
        "point": [0.5, 0.0, 0.0],
        "impulse": [1.0, 0.0, 0.0],
        "threshold": 1.75,
        "exact": True,
    },
    {
        "name": "site 2, every bond listed, mixed signs",
        "point": [0.0, 3.5, 2.0],
        "impulse": [0.5, -1.0, 1.0],
        "threshold": 1.0,
        "exact": True,
    },
]
EXAMPLE_TIES: list[dict] = [
    {
        "name": "worked example case 1 with T = 2.5: |jump| == T holds",
        "point": [0.1, 0.0, 0.0],
        "impulse": [0.0, 0.0, -2.0],
        "threshold": 2.5,
        "exact": True,
    },
]


# ---------------------------------------------------------------- writing


def _number(x):
    """A JSON value for a double: the shortest round-trip decimal, or "nan" / "inf" / "-inf"."""
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return float(x)


def _bits(x: float) -> str:
    return struct.pack(">d", x).hex()


def vector_entry(rt: reference.Runtime, impact: dict, health: list | None = None) -> dict | None:
    """One impact with its expected outcome, as written to ``<name>.vectors.json``.

    With ``health`` (a hit of a sequence, docs/FORMAT.md section 12.5): the hit on that state, the new state
    under the private key ``_health``, and None instead of an error when a decision is within rounding of a tie.
    """
    point, impulse, threshold = impact["point"], impact["impulse"], impact["threshold"]
    entry = {
        "name": impact["name"],
        "point": [_number(c) for c in point],
        "impulse": [_number(c) for c in impulse],
        "threshold": None if threshold is None else _number(threshold),
        "bits": {
            "point": [_bits(c) for c in point],
            "impulse": [_bits(c) for c in impulse],
            "threshold": None if threshold is None else _bits(threshold),
        },
    }
    try:
        if health is None:
            result = reference_damage.solve(rt, point, impulse, threshold)
        else:
            result = reference_damage.hit(rt, health, point, impulse, threshold)
    except reference.InvalidImpact as exc:
        entry.update(expect="error", error=exc.what)
        return entry
    exact = impact.get("exact", False)
    site_tie = exact or impact.get("site_tie", False)
    if health is not None and not exact and not reference_damage.safe(result):
        return None
    if not exact and not (result.crack_margin > reference.SAFE_MARGIN
                          and result.health_margin > reference_damage.HEALTH_MARGIN):
        raise ValueError(f"{impact['name']}: a crack or a health is within rounding of a tie")
    if len(result.tied_sites) > 1 and not site_tie:
        raise ValueError(f"{impact['name']}: unplanned exact tie between sites {result.tied_sites}")
    if len(result.tied_sites) == 1 and result.site_margin <= reference.SAFE_MARGIN:
        raise ValueError(f"{impact['name']}: nearest site within rounding of a tie")
    if not exact and result.edge_margin <= reference.SAFE_MARGIN:
        raise ValueError(f"{impact['name']}: an edge is within rounding of the threshold")
    entry.update(
        expect="ok",
        site=result.site,
        tied_sites=list(result.tied_sites),
        num_groups=sum(1 for j, g in enumerate(result.groups) if g == j),
        groups=result.groups,
        broken=[m for m, cut in enumerate(result.broken) if cut],
        alpha=[_number(a) for a in result.alpha],
        displacement=[[_number(x) for x in row] for row in result.displacement],
    )
    if result.loads is not None:
        entry["loads"] = [_number(x) for x in result.loads]
    if result.cracked is not None:  # section 12: cracked bonds, anchored fragments
        entry["cracked"] = [m for m, cut in enumerate(result.cracked) if cut]
        entry["anchored"] = result.anchored
    if health is not None:
        entry["_health"] = result.health
    return entry


def write_vectors(path: str, runtime_name: str, rt: reference.Runtime, impacts: list[dict],
                  sequences: list[dict] | None = None) -> None:
    """``<name>.vectors.json``: one impact per line so diffs stay readable (one hit per line in sequences)."""
    head = {
        "format": VECTORS_FORMAT,
        "version": VECTORS_VERSION,
        "runtime": runtime_name,
        "dim": rt.d,
        "counts": {"sites": len(rt.sites), "modes": rt.k, "fragments": rt.p, "edges": len(rt.edges)},
        "default_threshold": rt.default_threshold,
    }
    if rt.features:  # version 2: what a reader needs to run these vectors
        head["features"] = rt.features
        head["criterion"] = rt.criterion
    lines = [json.dumps(vector_entry(rt, impact), allow_nan=False) for impact in impacts]
    text = (json.dumps(head, indent=2, allow_nan=False)[:-2] + ',\n  "impacts": [\n    ' + ",\n    ".join(lines)
            + "\n  ]")
    if sequences is not None:
        blocks = []
        for seq in sequences:
            hits = ",\n        ".join(json.dumps(h, allow_nan=False) for h in seq["hits"])
            meta = json.dumps({"name": seq["name"], "start": seq["start"]}, allow_nan=False)[:-1]
            blocks.append(meta + ', "hits": [\n        ' + hits + "\n    ]}")
        text += ',\n  "sequences": [\n    ' + ",\n    ".join(blocks) + "\n  ]"
    text += "\n}\n"
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write(text)


def generate(out: str, rebake: bool = False) -> list[str]:
    """Write every file of the conformance set into ``out``; returns the file names written."""
    os.makedirs(out, exist_ok=True)
    written = []
    small = {
        "example": example_data(),
        "dyadic_d3": dyadic_d3(),
        "single": single_fragment(),
        "random_d1": random_data(1, seed=11),
        "random_d3": random_data(3, seed=13),
    }
    stress_small = {"stress_dyadic": stress_dyadic()}  # version 2: after the others, so their seeds stay
    for name, data in {**small, **stress_small}.items():
        write_runtime(data, os.path.join(out, f"{name}.fracture.json"))
        written += [f"{name}.fracture.json", f"{name}.fracture.bin"]
    if rebake:
        rebake_sample_assets(out)
    stems = [os.path.splitext(asset)[0] for asset, _ in sample_assets()]
    stress_stems = [name for _, _, name in STRESS_BAKES]
    level_stems = [name for _, _, name, _ in LEVEL_BAKES]
    sharing_stems = [name for _, _, name in SHARING_BAKES]
    for stem in stems + stress_stems + level_stems + sharing_stems:
        if os.path.abspath(out) != HERE and not rebake:
            for suffix in (".fracture.json", ".fracture.bin"):
                shutil.copyfile(os.path.join(HERE, stem + suffix), os.path.join(out, stem + suffix))
    structure = _structure_files(out, small, stress_small)
    for seed, name in enumerate([*small, *stems, *stress_small, *stress_stems, *structure]):
        rt = reference.Runtime.from_data(load_runtime(os.path.join(out, f"{name}.fracture.json")))
        rng = np.random.default_rng(100 + seed)
        impacts = designed_impacts(rt, rng)
        if name == "example":
            impacts = _doc_cases() + EXAMPLE_TIES + impacts
        elif name == "dyadic_d3":
            impacts = DYADIC_TIES + impacts
        elif name == "stress_dyadic":
            impacts = STRESS_TIES + impacts
        count = (SMALL_IMPACTS if name.startswith("random") else
                 SAMPLE_IMPACTS if name in stems + stress_stems else 8)
        impacts += random_impacts(rt, count, seed=200 + seed)
        seqs = None
        if name in structure:  # section 12.5: hits applied one after another to one state
            seqs = structures.dyadic_sequences(rt, vector_entry) if name == "structure_dyadic" else []
            seqs += structures.sequences(rt, 300 + seed, vector_entry)
        write_vectors(os.path.join(out, f"{name}.vectors.json"), f"{name}.fracture.json", rt, impacts, seqs)
        written.append(f"{name}.vectors.json")
    written += [f"{name}{suffix}" for name in structure for suffix in (".fracture.json", ".fracture.bin")]
    # Levels (docs/FORMAT.md section 14): after every other file, so the seeds above stay as they were.
    first_seed = len([*small, *stems, *stress_small, *stress_stems, *structure])
    level_names = _levels_files(out, small) + level_stems
    for offset, name in enumerate(level_names):
        seed = first_seed + offset
        data = load_runtime(os.path.join(out, f"{name}.fracture.json"))
        rt = reference_levels.LevelFile.from_data(data).view(0)
        rng = np.random.default_rng(100 + seed)
        impacts = designed_impacts(rt, rng) + random_impacts(rt, SAMPLE_IMPACTS if name in level_stems else 8,
                                                              seed=200 + seed)
        levels.write_level_vectors(os.path.join(out, f"{name}.vectors.json"), f"{name}.fracture.json", data, seed,
                                   impacts, vector_entry)
        written += [f"{name}{suffix}" for suffix in (".fracture.json", ".fracture.bin", ".vectors.json")]
    # Load sharing (docs/FORMAT.md section 11.1): after every other file, so the seeds above stay as they were.
    first_seed += len(level_names)
    written += _sharing_vectors(out, first_seed, sharing_stems)
    written += corrupt.generate(
        os.path.join(out, "corrupt"),
        os.path.join(out, "example.fracture.json"),
        os.path.join(out, "dyadic_d3.fracture.json"),
        os.path.join(out, "structure_dyadic.fracture.json"),
        os.path.join(out, "levels_dyadic.fracture.json"),
        os.path.join(out, "sharing_dyadic.fracture.json"),
        os.path.join(out, "levels_sharing.fracture.json"),
    )
    return written


def _levels_files(out: str, small: dict) -> list[str]:
    """Write the synthetic section-14 runtime files (levels.py) into ``out``; their names, in seed order."""
    files = {
        "levels_dyadic": levels.levels_dyadic(),
        "levels_stress": levels.levels_stress(),
        "levels_random": levels.levels_random(small["random_d3"], seed=19),
    }
    for name, data in files.items():
        write_runtime(data, os.path.join(out, f"{name}.fracture.json"))
    return list(files)


def _sharing_vectors(out: str, first_seed: int, stems: list[str]) -> list[str]:
    """Write the section-11.1 runtime files (sharing.py) and the vectors of those and ``stems``; the names written."""
    base = sharing.sharing_dyadic()
    files = {"sharing_dyadic": base, "damage_sharing": sharing.damage_sharing(base),
             "levels_sharing": sharing.levels_sharing()}
    written = []
    for name, data in files.items():
        write_runtime(data, os.path.join(out, f"{name}.fracture.json"))
        written += [f"{name}.fracture.json", f"{name}.fracture.bin"]
    for offset, name in enumerate([*files, *stems]):
        seed = first_seed + offset
        data = load_runtime(os.path.join(out, f"{name}.fracture.json"))
        count = SAMPLE_IMPACTS if name in stems else 8
        if data.levels:
            rt = reference_levels.LevelFile.from_data(data).view(0)
            impacts = designed_impacts(rt, np.random.default_rng(100 + seed)) + random_impacts(rt, count, 200 + seed)
            levels.write_level_vectors(os.path.join(out, f"{name}.vectors.json"), f"{name}.fracture.json", data,
                                       seed, impacts, vector_entry)
        else:
            rt = reference.Runtime.from_data(data)
            impacts = (sharing.SHARING_TIES if name == "sharing_dyadic" else []) + designed_impacts(
                rt, np.random.default_rng(100 + seed)) + random_impacts(rt, count, 200 + seed)
            seqs = structures.sequences(rt, 300 + seed, vector_entry) if data.damage else None
            write_vectors(os.path.join(out, f"{name}.vectors.json"), f"{name}.fracture.json", rt, impacts, seqs)
        written.append(f"{name}.vectors.json")
    return written


def _structure_files(out: str, small: dict, stress_small: dict) -> list[str]:
    """Write the section-12 runtime files (structures.py) into ``out``; their names, in vector-seed order."""
    files = {
        "structure_dyadic": structures.structure_dyadic(),
        "damage_stress": structures.damage_stress(stress_small["stress_dyadic"]),
        "random_structure": structures.random_structure(small["random_d3"], seed=17),
        "pillar_structure": structures.pillar_structure(load_runtime(os.path.join(out, "pillar.fracture.json"))),
    }
    for name, data in files.items():
        write_runtime(data, os.path.join(out, f"{name}.fracture.json"))
    return list(files)


def _doc_cases() -> list[dict]:
    ex = _doc_example()
    return [
        {
            "name": f"worked example case {i + 1}",
            "point": [float(c) for c in case["point"]],
            "impulse": [float(c) for c in case["impulse"]],
            "threshold": case["threshold"],
            "exact": True,
        }
        for i, case in enumerate(ex["cases"])
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=HERE, help="output folder (default: this folder)")
    parser.add_argument("--rebake", action="store_true", help="re-bake the sample assets' runtime files (slow)")
    args = parser.parse_args()
    names = generate(args.out, rebake=args.rebake)
    print(f"wrote {len(names)} files to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
