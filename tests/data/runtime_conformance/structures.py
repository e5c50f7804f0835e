"""Conformance files and hit sequences for docs/FORMAT.md section 12 (anchors, damage, cracks).

Four runtime files (see README.md here): ``structure_dyadic`` (d = 1, a stacked
column anchored at its foot, dyadic values so every decision and health is exact),
``damage_stress`` (the stress criterion with damage and an anchor), ``random_structure``
(d = 3, many bonds, crack segments) and ``pillar_structure`` (the sample pillar's
runtime file with its base anchored and the stone recipe's damage). Each gets
stateless impacts (like every file) plus **sequences**: hits applied one after
another to one state, with the health expected after each.
"""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
import reference
import reference_damage

from fracture_cli.runtime.format import RuntimeData

SEQUENCE_RANDOM_HITS = 8


def _names(p: int) -> tuple[str, ...]:
    return tuple(f"fragment_{j:03d}" for j in range(p))


def _crack_arrays(rng, e: int, lo, hi) -> dict[str, np.ndarray]:
    """0-3 random segments per bond inside the box ``lo``..``hi`` (drawing data; no answer depends on it)."""
    counts = rng.integers(0, 4, e)
    ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    segments = rng.uniform(lo, hi, size=(int(ptr[-1]), 2, 3)).astype(np.float32)
    return {"crack_ptr": ptr, "crack_segments": segments}


def structure_dyadic() -> RuntimeData:
    """Five fragments stacked along y (0 at the foot, anchored), one cycle, two modes, dyadic values.

    ``c = 0.5``, ``r = 0.5``: ``q = 1``, so a hit loading a bond at ``L`` takes exactly ``L - 0.5``
    of its health; every sum, product and quotient below is exact in double.
    """
    sites = [[0, 0, 0], [0, 1, 0], [0, 2, 0], [0, 3, 0], [0, 4, 0], [1, 2, 0]]
    B = [[[1.0], [0.0]], [[0.5], [0.5]], [[0.25], [1.0]], [[0.0], [1.0]], [[-0.5], [0.5]], [[0.5], [-0.25]]]
    W = [[[0.0], [0.25], [0.5], [0.875], [1.25]],
         [[0.0], [0.0], [0.5], [-0.5], [0.5]]]
    edges = [[0, 1], [1, 2], [1, 3], [2, 3], [3, 4]]
    ptr = np.array([0, 2, 2, 3, 5, 6], np.int32)
    segments = np.array([[[0, 0.5, 0], [1, 0.5, 0]], [[1, 0.5, 0], [1, 0.5, 1]], [[0, 2.5, 0], [1, 2.5, 0]],
                         [[0, 3.5, 0], [1, 3.5, 0]], [[1, 3.5, 0], [1, 3.5, 1]], [[0, 4.5, 0], [1, 4.5, 0]]],
                        np.float32)
    return RuntimeData(
        sites=np.array(sites, np.float32), B=np.array(B, np.float32), W=np.array(W, np.float32),
        edges=np.array(edges, np.int32), edge_areas=np.full(5, 0.5, np.float32), fragment_names=_names(5),
        default_threshold=1.0, radius=0.05,
        anchored=np.array([1, 0, 0, 0, 0], np.int32),
        damage={"crack_level": 0.5, "damage_rate": 0.5},
        cracks={"crack_ptr": ptr, "crack_segments": segments},
        anchors_info={"ground": True, "up": "y", "tolerance": 0.01},
    )


def damage_stress(stress: RuntimeData) -> RuntimeData:
    """The ``stress_dyadic`` file with damage (``c = 0.25``, ``r = 0.75``: ``q = 1``) and fragment 3 anchored."""
    return dataclasses.replace(stress, anchored=np.array([0, 0, 0, 1], np.int32),
                               damage={"crack_level": 0.25, "damage_rate": 0.75})


def random_structure(base: RuntimeData, seed: int) -> RuntimeData:
    """A random d = 3 file with three anchored fragments, ``c = 0.6``, ``r = 0.3`` and crack segments."""
    rng = np.random.default_rng(seed)
    anchored = np.zeros(base.p, np.int32)
    anchored[rng.choice(base.p, 3, replace=False)] = 1
    lo, hi = base.sites.min(axis=0), base.sites.max(axis=0)
    return dataclasses.replace(base, anchored=anchored, damage={"crack_level": 0.6, "damage_rate": 0.3},
                               cracks=_crack_arrays(rng, base.num_edges, lo, hi),
                               anchors_info={"boxes": ["random"]})


def pillar_structure(pillar: RuntimeData) -> RuntimeData:
    """The sample pillar with every fragment whose collision hull reaches its foot (1% of its height) anchored.

    Damage as the stone recipe: ``c = 0.5``, ``r = 0.25`` (about four hits just under the strength).
    """
    vertices = np.asarray(pillar.gameready["collision_vertices"], np.float64)
    offsets = np.asarray(pillar.gameready["collision_part_offsets"])
    fragment_parts = np.asarray(pillar.gameready["collision_fragment_offsets"])
    foot, height = vertices[:, 1].min(), np.ptp(vertices[:, 1])
    anchored = np.zeros(pillar.p, np.int32)
    for j in range(pillar.p):
        rows = vertices[offsets[fragment_parts[j]]: offsets[fragment_parts[j + 1]]]
        anchored[j] = int(len(rows) > 0 and rows[:, 1].min() <= foot + 0.01 * height)
    return dataclasses.replace(pillar, anchored=anchored, damage={"crack_level": 0.5, "damage_rate": 0.25},
                               anchors_info={"ground": True, "up": "y", "tolerance": 0.01})


# ---------------------------------------------------------------- sequences


def _hex(x: float) -> str:
    return struct.pack(">d", x).hex()


def _unit(rng) -> list[float]:
    v = rng.normal(size=3)
    return (v / np.linalg.norm(v)).tolist()


def _scaled(rt: reference.Runtime, point, direction, load: float) -> list[float]:
    """``direction`` scaled so the most loaded bond is at ``load`` (1 = its strength) at the default threshold."""
    peak = reference_damage.peak_load(rt, point, direction, None)
    return [c * load / peak for c in direction] if peak > 0 else list(direction)


def _strongest_site(rt: reference.Runtime, rng) -> tuple[list, list]:
    """A site and direction that load some bond (deterministic draw from ``rng``)."""
    for _ in range(200):
        point = list(rt.sites[int(rng.integers(len(rt.sites)))])
        direction = _unit(rng)
        if reference_damage.peak_load(rt, point, direction, None) > 0:
            return point, direction
    raise ValueError("no hit loads any bond")


def run_sequence(rt: reference.Runtime, name: str, start: list | None, hits: list[dict], exact: bool,
                 vector_entry) -> dict | None:
    """The sequence as written to the vectors file, or None when a hit is within rounding of a tie."""
    health = [1.0] * len(rt.edges) if start is None else list(start)
    out = []
    for h in hits:
        entry = vector_entry(rt, h, health=health)
        if entry is None:
            return None
        if entry["expect"] == "ok":
            health = entry.pop("_health")
        entry["health"] = [_hex(x) for x in health]
        out.append(entry)
    return {"name": name, "start": None if start is None else [_hex(x) for x in start], "hits": out}


def sequences(rt: reference.Runtime, seed: int, vector_entry, designed: list | None = None) -> list[dict]:
    """Repeated hits below the strength until a break, random hits, a saved start state, refused hits between."""
    rng = np.random.default_rng(seed)
    found = []
    if designed:
        found += designed
    # 1. The same hit at 0.8 of the strength, repeated: cracks first, a break after about (1 - c) / (r (0.8 - c)) hits.
    for attempt in range(20):
        point, direction = _strongest_site(rt, rng)
        impulse = _scaled(rt, point, direction, 0.8 if attempt < 10 else 0.9)
        hits = [{"name": f"repeat {i}", "point": point, "impulse": impulse, "threshold": None} for i in range(12)]
        seq = run_sequence(rt, "the same hit below the strength, repeated", None, hits, False, vector_entry)
        if seq is not None:
            found.append(seq)
            break
    # 2. Random hits from 0.3 to 1.5 x the strength, with a refused hit and a zero impulse among them.
    for _ in range(50):
        hits = []
        for i in range(SEQUENCE_RANDOM_HITS):
            point, direction = _strongest_site(rt, rng)
            impulse = _scaled(rt, point, direction, float(rng.choice([0.3, 0.7, 0.9, 1.5])))
            hits.append({"name": f"random {i}", "point": point, "impulse": impulse, "threshold": None})
        hits.insert(3, {"name": "refused: NaN impulse (state unchanged)", "point": hits[0]["point"],
                        "impulse": [math.nan, 0.0, 0.0], "threshold": None})
        hits.insert(6, {"name": "zero impulse: earlier damage stays", "point": hits[0]["point"],
                        "impulse": [0.0, 0.0, 0.0], "threshold": None})
        seq = run_sequence(rt, "random hits", None, hits, False, vector_entry)
        if seq is not None:
            found.append(seq)
            break
    # 3. From a saved state: some bonds broken, some weakened (values exact in double).
    for _ in range(50):
        start = [float(rng.choice([0.0, 0.25, 0.5, 0.875, 1.0])) for _ in rt.edges]
        hits = []
        for i in range(4):
            point, direction = _strongest_site(rt, rng)
            hits.append({"name": f"after load {i}", "point": point,
                         "impulse": _scaled(rt, point, direction, float(rng.choice([0.6, 0.95]))), "threshold": None})
        seq = run_sequence(rt, "from a saved state", start, hits, False, vector_entry)
        if seq is not None:
            found.append(seq)
            break
    return found


def dyadic_sequences(rt: reference.Runtime, vector_entry) -> list[dict]:
    """Exact sequences on ``structure_dyadic`` (every jump exact; ``t`` and ``a / b`` correctly rounded).

    Site 0, unit +x impulse, ``T = 0.78125``: bond 2 (1, 3) is at load 0.8 and loses 0.3 per hit
    (1 -> 0.7 -> 0.4 -> 0.1 -> broken), the others are below c. Site 4, unit +y, ``T = 1.125``: bond 2
    is exactly at the crack level (``a == c * b``: not cracked), bond 3 cracks; then ``T = 2`` with an
    impulse of 8 breaks bonds 2, 3 and 4 (bonds 0 and 1 exactly at the crack level): the top two
    fragments come off, the foot's group stays anchored.
    """
    repeat = [{"name": f"site 0, +x, bond 2 at load 0.8 (hit {i + 1})", "point": [0.0, 0.0, 0.0],
               "impulse": [1.0, 0.0, 0.0], "threshold": 0.78125, "exact": True} for i in range(5)]
    top = [{"name": "site 4: bond 2 exactly at the crack level, bond 3 cracks", "point": [0.0, 4.0, 0.0],
            "impulse": [0.0, 1.0, 0.0], "threshold": 1.125, "exact": True},
           {"name": "site 4, impulse 8: the top breaks off", "point": [0.0, 4.0, 0.0], "impulse": [0.0, 8.0, 0.0],
            "threshold": 2.0, "exact": True}]
    seqs = [run_sequence(rt, "four hits at 0.8 break bond 2, the fifth finds it broken", None, repeat, True,
                         vector_entry),
            run_sequence(rt, "the top breaks off, the foot stays anchored", None, top, True, vector_entry)]
    return [s for s in seqs if s is not None]
