"""The runtime file's levels: every refined fragment's body in the concatenated arrays of docs/FORMAT.md 14.2."""

from __future__ import annotations

import dataclasses

import numpy as np

from fracture_cli.errors import StageError
from fracture_cli.io.names import child_name
from fracture_cli.io.physics import runtime_arrays
from fracture_cli.runtime.data import RuntimeData, check_runtime
from fracture_cli.stages.levels import Levels
from fracture_cli.stages.levels.options import STAGE

# The game-ready arrays of section 9 and their children's names (section 14.2).
CHILD_GAMEREADY = {"fragment_volume": "child_volume", "fragment_center_of_mass": "child_center_of_mass",
                   "fragment_inertia": "child_inertia", "collision_vertices": "child_collision_vertices",
                   "collision_part_offsets": "child_collision_part_offsets",
                   "collision_fragment_offsets": "child_collision_fragment_offsets"}


def _ptr(sizes: list[int], first: tuple[int, ...] = (0, 0)) -> np.ndarray:
    return np.concatenate([np.asarray(first, dtype=np.int64), first[-1] + np.cumsum(sizes, dtype=np.int64)]
                          ).astype(np.int32)


def with_levels(data: RuntimeData, result: Levels) -> RuntimeData:
    """``data`` (the level-1 runtime data) with feature ``"levels"`` for ``result``'s bodies; unchanged without any.

    Parameters
    ----------
    data : RuntimeData
        Level 1 (body 0), ``p`` fragments.
    result : Levels
        The refinements, by increasing fragment index; body ``b`` breaks ``result.refinements[b - 1].fragment``.

    Returns
    -------
    RuntimeData
        ``levels`` arrays (``parent``, ``body_*``, ``child_*`` when ``data`` has game-ready arrays), ``child_names``
        and ``levels_info`` (``count``, ``thresholds``, ``impact_radii``, and the rule, informational).
    """
    bodies = [r.body for r in result.refinements]
    if not bodies:
        return data
    p = data.p
    sizes = [len(r.children.fragments) for r in result.refinements]
    parent = np.concatenate([np.full(p, -1), np.repeat([r.fragment for r in result.refinements], sizes)])
    K = max(np.asarray(b["B"]).shape[1] for b in bodies)
    d = data.dim

    def padded(array: np.ndarray, axis: int) -> np.ndarray:  # modes beyond a body's own are zero (section 14.2)
        widths = [(0, 0)] * array.ndim
        widths[axis] = (0, K - array.shape[axis])
        return np.pad(np.asarray(array, dtype=np.float32), widths)

    levels = {
        "parent": parent.astype(np.int32),
        "body_fragment": np.array([-1] + [r.fragment for r in result.refinements], np.int32),
        "body_child_ptr": _ptr(sizes, (0, p)),
        "body_site_ptr": _ptr([len(b["sites"]) for b in bodies]),
        "body_sites": np.concatenate([b["sites"] for b in bodies]).astype(np.float32),
        "body_B": np.concatenate([padded(b["B"], 1) for b in bodies]).reshape(-1, K, d),
        "body_W": np.concatenate([padded(b["W"], 0) for b in bodies], axis=1).reshape(K, -1, d),
        "body_edge_ptr": _ptr([len(b["edges"]) for b in bodies]),
        "body_edges": np.concatenate([b["edges"] for b in bodies]).astype(np.int32).reshape(-1, 2),
        "body_edge_areas": np.concatenate([b["edge_areas"] for b in bodies]).astype(np.float32),
    }
    if data.criterion == "stress":
        starts = np.cumsum([0] + [len(b["site_bonds"]) for b in bodies])
        levels["body_site_bonds_ptr"] = np.concatenate(
            [[0]] + [np.asarray(b["site_bonds_ptr"][1:], dtype=np.int64) + s for b, s in zip(bodies, starts)]
        ).astype(np.int32)
        for name in ("site_bonds", "site_bond_gain", "bond_strength"):
            levels["body_" + name] = np.concatenate([b[name] for b in bodies])
    if data.sharing:  # docs/FORMAT.md section 11.1: local fragment indices, one per body site
        levels["body_site_fragment"] = np.concatenate([b["site_fragment"] for b in bodies]).astype(np.int32)
    if data.gameready:
        ready = runtime_arrays([body for r in result.refinements for body in r.physics])
        levels.update({CHILD_GAMEREADY[name]: value for name, value in ready.items()})
    if data.damage:
        counts = [np.diff(b["crack_ptr"]) for b in bodies]
        levels["body_crack_ptr"] = np.concatenate([[0], np.cumsum(np.concatenate(counts))]).astype(np.int32)
        levels["body_crack_segments"] = np.concatenate([b["crack_segments"] for b in bodies]).astype(np.float32)
    names = tuple(child_name(data.fragment_names[r.fragment], j) for r, c in zip(result.refinements, sizes)
                  for j in range(c))
    options = result.options
    info = {"count": 2, "thresholds": [float(data.default_threshold),
                                       float(data.default_threshold) * float(options.threshold_factor)],
            "impact_radii": [float(data.radius), float(data.radius) * float(options.radius_factor)],
            "max_leaves": int(options.max_leaves), "ratio": float(options.ratio),
            "min_volume": float(options.min_volume), "leaves": int(result.leaves)}
    out = dataclasses.replace(data, levels=levels, child_names=names, levels_info=info)
    problem = check_runtime(out)
    if problem:
        raise StageError(f"runtime data with levels is inconsistent: {problem}", stage=STAGE)
    return out
