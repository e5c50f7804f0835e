"""Conformance files and vectors for docs/FORMAT.md section 14 (feature ``"levels"``).

Three synthetic runtime files with levels (see README.md here) and the sample pillar baked with two:

* ``levels_dyadic``: d = 1, four level-1 fragments in a row, three bodies below them (one at level 3),
  dyadic values so every decision is exact; designed hits on each body and object sequences;
* ``levels_stress``: criterion ``"stress"`` with damage and an anchor, a body with its own site lists;
* ``levels_random``: d = 3, many bodies, the game-ready arrays of every child and crack segments;
* ``pillar_levels``: the sample pillar baked with ``levels.count = 2`` (fast settings).

Each vector file has the stateless ``impacts`` of body 0 (as every file), ``bodies``: the stateless
impacts of every other body on its own view (section 14.3, local indices), and ``level_sequences``: hits
on pieces applied one after another to one object state (section 14.5).
"""

from __future__ import annotations

import dataclasses
import json
import math
import struct

import numpy as np
import reference
import reference_levels

from fracture_cli.runtime.format import RuntimeData

# The game-ready arrays of section 9 and their children's counterparts (section 14.2).
CHILD_GAMEREADY = {"fragment_volume": "child_volume", "fragment_center_of_mass": "child_center_of_mass",
                   "fragment_inertia": "child_inertia", "collision_vertices": "child_collision_vertices",
                   "collision_part_offsets": "child_collision_part_offsets",
                   "collision_fragment_offsets": "child_collision_fragment_offsets"}
BODY_IMPACTS = 6  # random hits per body (synthetic files); the sample bake: fewer bodies get some
SEQUENCE_HITS = 8


def _names(p: int, prefix: str = "fragment_") -> tuple[str, ...]:
    return tuple(f"{prefix}{j:03d}" for j in range(p))


def _child_names(parent: list[int], p: int) -> tuple[str, ...]:
    """``fragment_001_c00`` ...: the parent's name and the index among its siblings (the bake's scheme)."""
    names: dict[int, str] = {j: f"fragment_{j:03d}" for j in range(p)}
    count: dict[int, int] = {}
    for g in range(p, len(parent)):
        k = count.get(parent[g], 0)
        count[parent[g]] = k + 1
        names[g] = f"{names[parent[g]]}_c{k:02d}"
    return tuple(names[g] for g in range(p, len(parent)))


def _levels(parent: list[int], bodies: list[dict], K: int, d: int, thresholds: list[float]) -> tuple[dict, tuple, dict]:
    """The ``levels`` arrays, child names and header object of bodies given one by one.

    Each body: ``fragment``, ``sites`` (s, 3), ``B`` (s, K, d), ``W`` (K, c, d), ``edges`` (e, 2) local,
    ``areas`` (e,), optionally ``stress`` = (ptr (s+1), bonds, gains (n, 3), strength (e,)).
    """
    p = next(i for i, g in enumerate(parent) if g >= 0)
    child_ptr, site_ptr, edge_ptr = [0, p], [0, 0], [0, 0]
    for body in bodies:
        child_ptr.append(child_ptr[-1] + np.asarray(body["W"]).shape[1])
        site_ptr.append(site_ptr[-1] + len(body["sites"]))
        edge_ptr.append(edge_ptr[-1] + len(body["edges"]))
    arrays = {
        "parent": np.array(parent, np.int32),
        "body_fragment": np.array([-1] + [b["fragment"] for b in bodies], np.int32),
        "body_child_ptr": np.array(child_ptr, np.int32),
        "body_site_ptr": np.array(site_ptr, np.int32),
        "body_sites": np.concatenate([np.asarray(b["sites"], np.float32).reshape(-1, 3) for b in bodies]),
        "body_B": np.concatenate([np.asarray(b["B"], np.float32).reshape(-1, K, d) for b in bodies]),
        "body_W": np.concatenate([np.asarray(b["W"], np.float32).reshape(K, -1, d) for b in bodies], axis=1),
        "body_edge_ptr": np.array(edge_ptr, np.int32),
        "body_edges": np.concatenate([np.asarray(b["edges"], np.int32).reshape(-1, 2) for b in bodies]),
        "body_edge_areas": np.concatenate([np.asarray(b["areas"], np.float32).reshape(-1) for b in bodies]),
    }
    if "stress" in bodies[0]:
        ptrs, start = [0], 0
        for b in bodies:
            ptrs += [start + int(x) for x in b["stress"][0][1:]]
            start = ptrs[-1]
        arrays["body_site_bonds_ptr"] = np.array(ptrs, np.int32)
        arrays["body_site_bonds"] = np.concatenate([np.asarray(b["stress"][1], np.int32) for b in bodies])
        arrays["body_site_bond_gain"] = np.concatenate([np.asarray(b["stress"][2], np.float32).reshape(-1, 3)
                                                        for b in bodies])
        arrays["body_bond_strength"] = np.concatenate([np.asarray(b["stress"][3], np.float32) for b in bodies])
    info = {"count": len(thresholds), "thresholds": thresholds}
    return arrays, _child_names(parent, p), info


def levels_dyadic() -> RuntimeData:
    """Four fragments in a row (d = 1, two modes); fragments 1 and 3 break again, and child 5 once more.

    Body 1 (fragment 1): children 4, 5, 6 in a triangle of bonds; body 2 (fragment 3): children 7, 8;
    body 3 (fragment 5, level 3): children 9, 10. Thresholds 1, 0.5, 0.25 per level; dyadic values, so
    a hit at a site with a unit impulse along an axis gives exact jumps (ties on purpose below).
    """
    parent = [-1, -1, -1, -1, 1, 1, 1, 3, 3, 5, 5]
    bodies = [
        {"fragment": 1, "sites": [[1, 0, 0], [1, 1, 0], [1.5, 0.5, 0]],
         "B": [[[1.0], [0.5]], [[0.5], [-1.0]], [[0.25], [0.25]]],
         "W": [[[0.5], [-0.25], [0.0]], [[0.0], [0.5], [-0.5]]],
         "edges": [[0, 1], [0, 2], [1, 2]], "areas": [0.5, 0.25, 0.5]},
        {"fragment": 3, "sites": [[3, 0, 0], [3.5, 0, 0]],
         "B": [[[1.0], [0.0]], [[-0.5], [1.0]]],
         "W": [[[0.5], [-0.5]], [[0.25], [0.0]]],
         "edges": [[0, 1]], "areas": [1.0]},
        {"fragment": 5, "sites": [[1, 1, 0.5]],
         "B": [[[0.5], [1.0]]],
         "W": [[[0.25], [-0.25]], [[0.125], [0.0]]],
         "edges": [[0, 1]], "areas": [0.125]},
    ]
    arrays, child_names, info = _levels(parent, bodies, K=2, d=1, thresholds=[1.0, 0.5, 0.25])
    return RuntimeData(
        sites=np.array([[0, 0, 0], [2, 0, 0], [4, 0, 0]], np.float32),
        B=np.array([[[1.0], [0.5]], [[0.5], [1.0]], [[-0.5], [0.25]]], np.float32),
        W=np.array([[[0.25], [0.125], [0.125], [0.875]], [[-0.5], [0.625], [0.375], [-1.0]]], np.float32),
        edges=np.array([[0, 1], [1, 2], [2, 3]], np.int32), edge_areas=np.array([1.0, 1.0, 1.0], np.float32),
        fragment_names=_names(4), default_threshold=1.0, radius=0.05,
        levels=arrays, child_names=child_names, levels_info=info,
    )


def levels_stress() -> RuntimeData:
    """Criterion ``"stress"`` with damage (``c = 0.5``, ``r = 0.5``) and fragment 0 anchored (never refined).

    Level 1: fragments 0-1-2 in a row; fragment 2 breaks into children 3, 4, 5 (a chain) with its own
    site lists; dyadic gains and strengths.
    """
    parent = [-1, -1, -1, 2, 2, 2]
    bodies = [
        {"fragment": 2, "sites": [[2, 0, 0], [2.5, 0, 0]],
         "B": [[[1.0]], [[0.5]]], "W": [[[0.5], [0.0], [-0.5]]],
         "edges": [[0, 1], [1, 2]], "areas": [0.5, 0.5],
         "stress": ([0, 2, 3], [0, 1, 1], [[1.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.0, -1.0, 2.0]], [0.5, 1.0])},
    ]
    arrays, child_names, info = _levels(parent, bodies, K=1, d=1, thresholds=[2.0, 1.0])
    return RuntimeData(
        sites=np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], np.float32),
        B=np.array([[[1.0]], [[0.5]], [[-0.25]]], np.float32),
        W=np.array([[[1.0], [0.5], [-0.5]]], np.float32),
        edges=np.array([[0, 1], [1, 2]], np.int32), edge_areas=np.array([1.0, 0.5], np.float32),
        fragment_names=_names(3), default_threshold=2.0, radius=0.05, criterion="stress",
        stress={"site_bonds_ptr": np.array([0, 1, 3, 4], np.int32),
                "site_bonds": np.array([0, 0, 1, 1], np.int32),
                "site_bond_gain": np.array([[1.0, 0, 0], [0.5, 0.25, 0], [-0.5, 0, 1.0], [0, 2.0, 0]], np.float32),
                "bond_strength": np.array([0.5, 0.25], np.float32)},
        stress_info={"note": "synthetic"}, anchored=np.array([1, 0, 0], np.int32),
        damage={"crack_level": 0.5, "damage_rate": 0.5}, anchors_info={"ground": True, "up": "y", "tolerance": 0.01},
        levels=arrays, child_names=child_names, levels_info=info,
    )


def _random_gameready(rng, centres: np.ndarray, size: float) -> dict[str, np.ndarray]:
    """One or two convex parts (4-6 corners) around each centre, and made-up mass properties."""
    n = len(centres)
    parts_per = rng.integers(1, 3, n)
    corners = [rng.integers(4, 7) for _ in range(int(parts_per.sum()))]
    owner = np.repeat(np.arange(n), parts_per)
    vertices = np.concatenate([centres[o] + rng.uniform(-size, size, (c, 3)) for o, c in zip(owner, corners)])
    return {"fragment_volume": rng.uniform(0.1, 1.0, n).astype(np.float32),
            "fragment_center_of_mass": centres.astype(np.float32),
            "fragment_inertia": rng.uniform(0.01, 0.1, (n, 6)).astype(np.float32),
            "collision_vertices": vertices.astype(np.float32),
            "collision_part_offsets": np.concatenate([[0], np.cumsum(corners)]).astype(np.int32),
            "collision_fragment_offsets": np.concatenate([[0], np.cumsum(parts_per)]).astype(np.int32)}


def levels_random(base: RuntimeData, seed: int) -> RuntimeData:
    """``base`` (d = 3, 40 fragments) with 10 of them broken into 2-6 children each, game-ready and cracks."""
    rng = np.random.default_rng(seed)
    p, d, K = base.p, base.dim, 5
    refined = sorted(rng.choice(p, 10, replace=False).tolist())
    centres = np.asarray(base.sites[rng.integers(0, base.num_sites, p)], np.float64)
    parent = [-1] * p
    bodies = []
    for fragment in refined:
        c = int(rng.integers(2, 7))
        parent += [fragment] * c
        pairs = {(j, j + 1) for j in range(c - 1)}
        for _ in range(int(rng.integers(0, c))):
            a, b = sorted(rng.integers(0, c, 2).tolist())
            if a != b:
                pairs.add((a, b))
        s = int(rng.integers(5, 20))
        sites = centres[fragment] + rng.normal(scale=0.3, size=(s, 3))
        bodies.append({"fragment": fragment, "sites": sites, "B": rng.normal(size=(s, K, d)),
                       "W": rng.normal(size=(K, c, d)), "edges": sorted(pairs),
                       "areas": rng.uniform(0.1, 1, len(pairs))})
    arrays, child_names, info = _levels(parent, bodies, K=K, d=d, thresholds=[2.0, 1.5])
    child_centres = np.array([centres[parent[g]] + rng.normal(scale=0.1, size=3) for g in range(p, len(parent))])
    gameready = _random_gameready(rng, centres, 0.2)
    for name, value in _random_gameready(rng, child_centres, 0.1).items():
        arrays[CHILD_GAMEREADY[name]] = value
    E = len(arrays["body_edges"])
    counts = rng.integers(0, 3, E)
    arrays["body_crack_ptr"] = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    arrays["body_crack_segments"] = rng.uniform(-2, 2, size=(int(counts.sum()), 2, 3)).astype(np.float32)
    return dataclasses.replace(base, gameready=gameready, levels=arrays, child_names=child_names, levels_info=info)


# ---------------------------------------------------------------- vectors


def _hex(x: float) -> str:
    return struct.pack(">d", x).hex()


def body_impacts(rt: reference.Runtime, seed: int, count: int, designed: list | None = None) -> list[dict]:
    """Designed hits plus random ones near the body's sites, scaled so that from none to all bonds break."""
    rng = np.random.default_rng(seed)
    impacts = list(designed or [])
    sites = np.array(rt.sites)
    spread = float(np.ptp(sites, axis=0).max()) * 0.02 or 0.01
    impacts.append({"name": "zero impulse", "point": list(rt.sites[0]), "impulse": [0.0, 0.0, 0.0],
                    "threshold": None})
    impacts.append({"name": "invalid: NaN threshold", "point": list(rt.sites[0]), "impulse": [1.0, 0.0, 0.0],
                    "threshold": math.nan})
    tries = 0
    while len(impacts) < len(designed or []) + 2 + count and tries < 50 * count:
        tries += 1
        point = (sites[rng.integers(len(sites))] + rng.normal(scale=spread, size=3)).tolist()
        v = rng.normal(size=3)
        direction = (v / np.linalg.norm(v)).tolist()
        jump = reference_levels.typical_load(rt, point, direction)
        impulse = [c * rt.default_threshold / jump * float(rng.choice([0.7, 1.3, 2.5, 6.0])) for c in direction]
        threshold = None if len(impacts) % 3 else float(np.float32(rt.default_threshold * rng.uniform(0.5, 2)))
        if reference_levels.safe_stateless(rt, point, impulse, threshold):
            impacts.append({"name": f"random hit {len(impacts)}", "point": point, "impulse": impulse,
                            "threshold": threshold})
    return impacts


def _number(x: float):
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return float(x)


def _inputs(hit: dict) -> dict:
    """The name, inputs and their bits of a hit, as every vector file writes them."""
    point, impulse, threshold = hit["point"], hit["impulse"], hit["threshold"]
    return {"name": hit["name"], "struck": hit["struck"], "point": [_number(c) for c in point],
            "impulse": [_number(c) for c in impulse], "threshold": None if threshold is None else _number(threshold),
            "bits": {"point": [_hex(c) for c in point], "impulse": [_hex(c) for c in impulse],
                     "threshold": None if threshold is None else _hex(threshold)}}


def sequence_entry(lf: reference_levels.LevelFile, hit: dict, health: list) -> dict | None:
    """One hit of a level sequence with its expected outcome (``_health``: the state after), or None near a tie."""
    entry = _inputs(hit)
    try:
        out = reference_levels.hit_piece(lf, health, hit["struck"], hit["point"], hit["impulse"], hit["threshold"])
    except reference.InvalidImpact as exc:
        entry.update(expect="error", error=exc.what)
        entry["_health"] = list(health)
        return entry
    if not hit.get("exact", False) and (not out["_safe"] or out["_tied"]):
        return None
    entry.update(expect="ok", **{key: value for key, value in out.items() if not key.startswith("_")})
    entry["_health"] = out["_health"]
    return entry


def run_level_sequence(lf: reference_levels.LevelFile, name: str, start: list | None, hits: list[dict]) -> dict | None:
    """A sequence as written (every hit on the state the previous one left), or None when a hit is near a tie."""
    health = [1.0] * (lf.e0 + lf.edge_ptr[-1]) if start is None else list(start)
    out = []
    for hit in hits:
        entry = sequence_entry(lf, hit, health)
        if entry is None:
            return None
        health = entry.pop("_health")
        entry["health"] = [_hex(x) for x in health]
        out.append(entry)
    return {"name": name, "start": None if start is None else [_hex(x) for x in start], "hits": out}


def _aimed_hit(lf: reference_levels.LevelFile, health: list, rng, name: str, load: float) -> dict:
    """A hit on a random shown fragment near one of its body's sites (else its holder's), scaled to ``load``."""
    shown = [g for g in range(len(lf.parent)) if reference_levels.shown(lf, health, g)]
    struck = int(shown[int(rng.integers(len(shown)))])
    b = lf.body_of(struck)
    view = lf.view(b if b >= 0 else lf.holder(struck))
    spread = float(np.ptp(np.array(view.sites), axis=0).max()) * 0.02 or 0.01
    point = (np.array(view.sites[int(rng.integers(len(view.sites)))]) + rng.normal(scale=spread, size=3)).tolist()
    v = rng.normal(size=3)
    direction = (v / np.linalg.norm(v)).tolist()
    scale = view.default_threshold / reference_levels.typical_load(view, point, direction) * load
    return {"name": name, "struck": struck, "point": point, "impulse": [c * scale for c in direction],
            "threshold": None}


def random_level_sequences(lf: reference_levels.LevelFile, seed: int, count: int = 3) -> list[dict]:
    """Random hits on random shown fragments, each sequence from a new state; refused hits among them."""
    rng = np.random.default_rng(seed)
    found: list[dict] = []
    for _ in range(40 * count):
        if len(found) == count:
            break
        health = [1.0] * (lf.e0 + lf.edge_ptr[-1])
        hits = []
        for i in range(SEQUENCE_HITS):
            hit = _aimed_hit(lf, health, rng, f"random {i}", float(rng.choice([0.3, 0.8, 1.5, 3.0])))
            entry = sequence_entry(lf, hit, health)
            if entry is None:
                break
            health = entry["_health"]
            hits.append(hit)
        if len(hits) < SEQUENCE_HITS:
            continue
        hits.insert(2, dict(hits[1], name="refused: NaN in the impulse (state unchanged)",
                            impulse=[math.nan, 0.0, 0.0]))
        seq = run_level_sequence(lf, "random hits on shown fragments", None, hits)
        if seq is not None:
            found.append(seq)
    return found


DYADIC_SEQUENCE = [
    {"name": "intact asset, fragment 1 struck at site 1, impulse 4 (t = 0.25): bonds 0 and 2 break, bond 1 holds "
             "at exactly t; body 1 (t = 0.125) breaks bonds (0, 2), (1, 2): fragment 1 splits", "struck": 1,
     "point": [2.0, 0.0, 0.0], "impulse": [4.0, 0.0, 0.0], "threshold": None, "exact": True},
    {"name": "refused: fragment 1 is split, not shown", "struck": 1, "point": [1.0, 0.0, 0.0],
     "impulse": [1.0, 0.0, 0.0], "threshold": None},
    {"name": "piece (4, 5) struck on child 5: bond (0, 1) of body 1 breaks; body 3 (level 3) splits fragment 5",
     "struck": 5, "point": [1.0, 1.0, 0.5], "impulse": [0.0, 0.0, 1.0], "threshold": None, "exact": True},
    {"name": "fragment 3 alone, zero impulse: nothing changes", "struck": 3, "point": [4.0, 0.0, 0.0],
     "impulse": [0.0, 0.0, 0.0], "threshold": None, "exact": True},
    {"name": "fragment 3 struck halfway between body 0's sites 1 and 2 (site 1), its body 2 splits it", "struck": 3,
     "point": [3.0, 0.0, 0.0], "impulse": [4.0, 0.0, 0.0], "threshold": None, "exact": True},
    {"name": "refused: NaN threshold", "struck": 0, "point": [0.0, 0.0, 0.0], "impulse": [1.0, 0.0, 0.0],
     "threshold": math.nan},
]


def level_sequences(lf: reference_levels.LevelFile, name: str, seed: int) -> list[dict]:
    """The designed sequence of ``levels_dyadic`` (exact), then random ones."""
    seqs = []
    if name == "levels_dyadic":
        seq = run_level_sequence(lf, "levels: a split, a refused hit, a level-3 split, a piece hit again", None,
                                 DYADIC_SEQUENCE)
        if seq is None:
            raise ValueError("the designed levels sequence is not exact")
        seqs.append(seq)
    return seqs + random_level_sequences(lf, seed)


def write_level_vectors(path: str, runtime_name: str, data: RuntimeData, seed: int, impacts: list[dict],
                        vector_entry) -> None:
    """``<name>.vectors.json`` of a file with levels (docs/FORMAT.md section 14.7), one impact or hit per line."""
    lf = reference_levels.LevelFile.from_data(data)
    rt = lf.view(0)
    head = {"format": "fracture-runtime-conformance", "version": 1, "runtime": runtime_name, "dim": rt.d,
            "counts": {"sites": len(rt.sites), "modes": rt.k, "fragments": rt.p, "edges": len(rt.edges)},
            "default_threshold": rt.default_threshold, "features": list(data.features), "criterion": data.criterion}
    lines = [json.dumps(vector_entry(rt, impact), allow_nan=False) for impact in impacts]
    text = (json.dumps(head, indent=2, allow_nan=False)[:-2] + ',\n  "impacts": [\n    ' + ",\n    ".join(lines)
            + "\n  ]")
    blocks = []
    for b in range(1, lf.bodies):
        view = lf.view(b)
        meta = {"body": b, "fragment": lf.body_fragment[b], "level": lf.body_level(b), "first": lf.child_ptr[b],
                "counts": {"sites": len(view.sites), "modes": view.k, "fragments": view.p, "edges": len(view.edges)},
                "default_threshold": view.default_threshold}
        count = BODY_IMPACTS if lf.bodies < 20 else 2
        entries = [vector_entry(view, impact) for impact in body_impacts(view, seed * 1000 + b, count)]
        blocks.append(json.dumps(meta, allow_nan=False)[:-1] + ', "impacts": [\n        '
                      + ",\n        ".join(json.dumps(e, allow_nan=False) for e in entries) + "\n    ]}")
    text += ',\n  "bodies": [\n    ' + ",\n    ".join(blocks) + "\n  ]"
    seqs = []
    for seq in level_sequences(lf, runtime_name.split(".")[0], seed):
        hits = ",\n        ".join(json.dumps(h, allow_nan=False) for h in seq["hits"])
        meta = json.dumps({"name": seq["name"], "start": seq["start"]}, allow_nan=False)[:-1]
        seqs.append(meta + ', "hits": [\n        ' + hits + "\n    ]}")
    text += ',\n  "level_sequences": [\n    ' + ",\n    ".join(seqs) + "\n  ]\n}\n"
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write(text)
