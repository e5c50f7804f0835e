"""Levels of fracture in the runtime file (format version 2, feature ``"levels"``; docs/FORMAT.md section 14).

A *body* is a set of fragments (its *children*) with its own impact data. Body 0 is the
whole asset: its children are the level-1 fragments and its data the arrays of
docs/FORMAT.md sections 2, 9, 11 and 12, exactly as in a file without levels. Body
``b >= 1`` breaks one fragment (``body_fragment[b]``) into its children, with its own
sites, coefficients, piece modes and bonds among those children, stored in
concatenated ``body_*`` arrays with offset tables. Fragments are numbered over every
level: ``0 .. p-1`` at level 1, then the children of body 1, of body 2, ... (each body's
children contiguous); ``parent (p_all,)`` says whose child every fragment is.

:func:`body_view` cuts body ``b``'s data out as a plain :class:`~fracture_cli.runtime.data.RuntimeData`,
so a hit on a body is the algorithm of sections 4, 11 and 12 on that body's own arrays,
answering in the body's local indices (fragment ``first + j``).

Depends on numpy only.
"""

from __future__ import annotations

import dataclasses
import math
import weakref
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # data.py imports this module (its checks); the views are made with dataclasses.replace
    from fracture_cli.runtime.data import RuntimeData

# name -> (dtype, number of dimensions), in file order (after the crack arrays of section 12).
LEVELS_LAYOUT: dict[str, tuple[str, int]] = {
    "parent": ("int32", 1),
    "body_fragment": ("int32", 1),
    "body_child_ptr": ("int32", 1),
    "body_site_ptr": ("int32", 1),
    "body_sites": ("float32", 2),
    "body_B": ("float32", 3),
    "body_W": ("float32", 3),
    "body_edge_ptr": ("int32", 1),
    "body_edges": ("int32", 2),
    "body_edge_areas": ("float32", 1),
}
# With criterion "stress": each body's stress arrays, concatenated (site lists over body_sites, bonds local).
LEVEL_STRESS_LAYOUT: dict[str, tuple[str, int]] = {
    "body_site_bonds_ptr": ("int32", 1),
    "body_site_bonds": ("int32", 1),
    "body_site_bond_gain": ("float32", 2),
    "body_bond_strength": ("float32", 1),
}
# With feature "sharing" (section 11.1): the fragment each row of body_sites loads, local to its body.
LEVEL_SHARING_LAYOUT: dict[str, tuple[str, int]] = {"body_site_fragment": ("int32", 1)}
# With the game-ready arrays of section 9: the same per child (fragment p + c is row c).
LEVEL_GAMEREADY_LAYOUT: dict[str, tuple[str, int]] = {
    "child_volume": ("float32", 1),
    "child_center_of_mass": ("float32", 2),
    "child_inertia": ("float32", 2),
    "child_collision_vertices": ("float32", 2),
    "child_collision_part_offsets": ("int32", 1),
    "child_collision_fragment_offsets": ("int32", 1),
}
# Optional drawing data, as section 12's crack arrays, over every body's bonds (body_edges' rows).
LEVEL_CRACK_LAYOUT: dict[str, tuple[str, int]] = {
    "body_crack_ptr": ("int32", 1),
    "body_crack_segments": ("float32", 3),
}
ALL_LEVEL_LAYOUTS: dict[str, tuple[str, int]] = {**LEVELS_LAYOUT, **LEVEL_STRESS_LAYOUT, **LEVEL_SHARING_LAYOUT,
                                                 **LEVEL_GAMEREADY_LAYOUT, **LEVEL_CRACK_LAYOUT}
# The game-ready arrays of section 9 and the children's names for them (same order).
_GAMEREADY_OF_CHILD = {
    "fragment_volume": "child_volume",
    "fragment_center_of_mass": "child_center_of_mass",
    "fragment_inertia": "child_inertia",
    "collision_vertices": "child_collision_vertices",
    "collision_part_offsets": "child_collision_part_offsets",
    "collision_fragment_offsets": "child_collision_fragment_offsets",
}
_STRESS_OF_BODY = {
    "site_bonds_ptr": "body_site_bonds_ptr",
    "site_bonds": "body_site_bonds",
    "site_bond_gain": "body_site_bond_gain",
    "bond_strength": "body_bond_strength",
}
# The header's ``levels`` object: what a reader needs from it (the rest is informational).
LEVELS_INFO_KEYS: tuple[str, ...] = ("count", "thresholds")


def level_counts(data: RuntimeData) -> dict[str, int]:
    """The header's ``counts`` entries of the levels arrays (empty without levels)."""
    lv = data.levels
    if not lv:
        return {}
    counts = {"bodies": int(len(lv["body_fragment"])), "all_fragments": int(len(lv["parent"])),
              "body_sites": int(len(lv["body_sites"])), "body_modes": int(np.asarray(lv["body_B"]).shape[1]),
              "body_edges": int(len(lv["body_edges"]))}
    if "body_site_bonds" in lv:
        counts["body_site_bonds"] = int(len(lv["body_site_bonds"]))
    if "child_collision_part_offsets" in lv:
        counts["child_collision_parts"] = int(len(lv["child_collision_part_offsets"]) - 1)
        counts["child_collision_vertices"] = int(len(lv["child_collision_vertices"]))
    if "body_crack_segments" in lv:
        counts["body_crack_segments"] = int(len(lv["body_crack_segments"]))
    return counts


def fragment_levels(parent: np.ndarray) -> np.ndarray:
    """The level (p_all,) int64 of every fragment: 1 without a parent, else its parent's level + 1.

    ``parent[g] < g`` (checked by :func:`check_level_structure`), so one pass in index order suffices.
    """
    parent = np.asarray(parent, dtype=np.int64)
    level = np.ones(len(parent), dtype=np.int64)
    for g in np.flatnonzero(parent >= 0).tolist():
        level[g] = level[parent[g]] + 1
    return level


def body_level(data: RuntimeData, body: int) -> int:
    """The level of body ``body``'s children (1 for body 0)."""
    if body == 0:
        return 1
    fragment = int(data.levels["body_fragment"][body])
    return int(fragment_levels(data.levels["parent"][: fragment + 1])[fragment]) + 1


def body_threshold(data: RuntimeData, body: int) -> float:
    """Body ``body``'s default threshold: the header's ``levels.thresholds`` entry of its children's level."""
    if body == 0 or not data.levels:
        return float(data.default_threshold)
    return float(data.levels_info["thresholds"][body_level(data, body) - 1])


def num_bodies(data: RuntimeData) -> int:
    """Bodies in the file: 1 without levels (the whole asset)."""
    return int(len(data.levels["body_fragment"])) if data.levels else 1


def num_fragments(data: RuntimeData) -> int:
    """Fragments of every level (``p_all``); ``p`` without levels."""
    return int(len(data.levels["parent"])) if data.levels else data.p


def fragment_name(data: RuntimeData, fragment: int) -> str:
    """The GLB node name of fragment ``fragment`` (any level)."""
    return data.fragment_names[fragment] if fragment < data.p else data.child_names[fragment - data.p]


def children_range(data: RuntimeData, body: int) -> range:
    """The fragments body ``body`` breaks into (global indices)."""
    if body == 0:
        return range(data.p)
    ptr = data.levels["body_child_ptr"]
    return range(int(ptr[body]), int(ptr[body + 1]))


def body_of(data: RuntimeData, fragment: int) -> int:
    """The body that breaks fragment ``fragment`` into its children, or -1 when it has none (a leaf)."""
    if not data.levels:
        return -1
    owners = np.asarray(data.levels["body_fragment"])
    b = int(np.searchsorted(owners[1:], fragment)) + 1  # body_fragment[1:] strictly increases
    return b if b < len(owners) and int(owners[b]) == fragment else -1


def body_holding(data: RuntimeData, fragment: int) -> int:
    """The body whose children include fragment ``fragment`` (0 for a level-1 fragment)."""
    if fragment < data.p or not data.levels:
        return 0
    ptr = np.asarray(data.levels["body_child_ptr"])
    return int(np.searchsorted(ptr, fragment, side="right")) - 1


def body_edge_range(data: RuntimeData, body: int) -> range:
    """Rows of ``body_edges`` holding body ``body``'s bonds (body 0: ``range(e)`` of the top-level ``edges``)."""
    if body == 0:
        return range(data.num_edges)
    ptr = data.levels["body_edge_ptr"]
    return range(int(ptr[body]), int(ptr[body + 1]))


def state_offsets(data: RuntimeData) -> np.ndarray:
    """Where each body's bond healths start in an object state (nb + 1,): body 0 at 0, body b at e + edge_ptr[b]."""
    if not data.levels:
        return np.array([0, data.num_edges], dtype=np.int64)
    ptr = np.asarray(data.levels["body_edge_ptr"], dtype=np.int64)
    out = data.num_edges + ptr
    out[0] = 0
    return out


_VIEWS: weakref.WeakKeyDictionary[RuntimeData, dict[int, RuntimeData]] = weakref.WeakKeyDictionary()


def body_view(data: RuntimeData, body: int) -> RuntimeData:
    """Body ``body``'s impact data as a runtime file of its own (docs/FORMAT.md section 14.3; cached).

    Parameters
    ----------
    data : RuntimeData
        A file with feature ``"levels"`` (any file for body 0).
    body : int
        ``0 <= body < num_bodies(data)``.

    Returns
    -------
    RuntimeData
        Body 0: ``data`` itself. Body ``b >= 1``: its sites ``(s_b, 3)``, ``B (s_b, K, d)``, ``W (K, c_b, d)``
        (columns: its children in order), bonds ``(e_b, 2)`` in local child indices, the children's names,
        its level's default threshold, the stress, game-ready and crack arrays of its children (offsets
        rebased), the file's damage object and criterion; no anchors, no levels.

    Raises
    ------
    IndexError
        For a body the file does not have.
    """
    if body == 0:
        return data
    if not 0 < body < num_bodies(data):
        raise IndexError(f"body {body} does not exist (the file has {num_bodies(data)})")
    cache = _VIEWS.setdefault(data, {})
    view = cache.get(body)
    if view is None:
        view = cache[body] = _make_view(data, body)
    return view


def _make_view(data: RuntimeData, body: int) -> RuntimeData:
    lv, p = data.levels, data.p
    s0, s1 = (int(x) for x in lv["body_site_ptr"][body: body + 2])
    g0, g1 = (int(x) - p for x in lv["body_child_ptr"][body: body + 2])
    e0, e1 = (int(x) for x in lv["body_edge_ptr"][body: body + 2])
    stress: dict[str, np.ndarray] = {}
    if "body_site_bonds_ptr" in lv:
        ptr = np.asarray(lv["body_site_bonds_ptr"][s0: s1 + 1], dtype=np.int64)
        n0, n1 = int(ptr[0]), int(ptr[-1])
        stress = {"site_bonds_ptr": ptr - n0, "site_bonds": lv["body_site_bonds"][n0:n1],
                  "site_bond_gain": lv["body_site_bond_gain"][n0:n1], "bond_strength": lv["body_bond_strength"][e0:e1]}
        if "body_site_fragment" in lv:
            stress["site_fragment"] = lv["body_site_fragment"][s0:s1]
    gameready: dict[str, np.ndarray] = {}
    if "child_collision_fragment_offsets" in lv:
        owners = np.asarray(lv["child_collision_fragment_offsets"][g0: g1 + 1], dtype=np.int64)
        parts = np.asarray(lv["child_collision_part_offsets"][owners[0]: owners[-1] + 1], dtype=np.int64)
        gameready = {"fragment_volume": lv["child_volume"][g0:g1],
                     "fragment_center_of_mass": lv["child_center_of_mass"][g0:g1],
                     "fragment_inertia": lv["child_inertia"][g0:g1],
                     "collision_vertices": lv["child_collision_vertices"][parts[0]: parts[-1]],
                     "collision_part_offsets": parts - parts[0], "collision_fragment_offsets": owners - owners[0]}
    cracks: dict[str, np.ndarray] = {}
    if "body_crack_ptr" in lv:
        ptr = np.asarray(lv["body_crack_ptr"][e0: e1 + 1], dtype=np.int64)
        cracks = {"crack_ptr": ptr - ptr[0], "crack_segments": lv["body_crack_segments"][int(ptr[0]): int(ptr[-1])]}
    radii = data.levels_info.get("impact_radii")
    level = body_level(data, body)
    radius = float(radii[level - 1]) if isinstance(radii, list) and len(radii) >= level else data.radius
    return dataclasses.replace(
        data, sites=lv["body_sites"][s0:s1], B=lv["body_B"][s0:s1], W=lv["body_W"][:, g0:g1],
        edges=lv["body_edges"][e0:e1], edge_areas=lv["body_edge_areas"][e0:e1],
        fragment_names=tuple(data.child_names[g0:g1]), default_threshold=body_threshold(data, body), radius=radius,
        gameready=gameready, stress=stress, anchored=None, cracks=cracks, anchors_info={}, levels={},
        child_names=(), levels_info={})


def _ptr_problem(ptr: np.ndarray, name: str, size: int, end: int, first: int = 0) -> str | None:
    """Why offsets ``ptr`` are not ``size`` entries starting at ``first``, never decreasing and ending at ``end``."""
    if ptr.shape != (size,) or ptr[0] != first or ptr[-1] != end or np.any(np.diff(ptr) < 0):
        return f"{name} must have {size} entries, start at {first}, never decrease and end at {end}"
    return None


def check_level_structure(data: RuntimeData) -> str | None:
    """Why the levels arrays of ``data`` are inconsistent as a whole, or None (docs/FORMAT.md section 14.2).

    Checks everything but the contents of each body's own arrays, which :func:`body_view` cuts out and
    the caller checks as a runtime file of its own: the arrays present with their dtypes and ranks, the
    ``parent`` tree, the offset tables, the names, the header's ``levels`` object (``count`` the deepest
    level, ``thresholds`` one per level, the first equal to ``default_threshold``), no body on an
    anchored fragment.
    """
    lv, p = data.levels, data.p
    wanted = dict(LEVELS_LAYOUT)
    if data.criterion == "stress":
        wanted.update(LEVEL_STRESS_LAYOUT)
    if data.sharing:
        wanted.update(LEVEL_SHARING_LAYOUT)
    if data.gameready:
        wanted.update(LEVEL_GAMEREADY_LAYOUT)
    if any(name in lv for name in LEVEL_CRACK_LAYOUT):
        wanted.update(LEVEL_CRACK_LAYOUT)
    missing = [name for name in wanted if name not in lv]
    if missing:
        return f"feature 'levels' needs the arrays {', '.join(missing)}"
    extra = [name for name in lv if name not in wanted]
    if extra:
        return f"levels arrays {', '.join(extra)} do not belong to this file (criterion, sharing or game-ready data)"
    for name in wanted:
        if np.asarray(lv[name]).ndim != ALL_LEVEL_LAYOUTS[name][1]:
            return f"array {name} has {np.asarray(lv[name]).ndim} dimensions, expected {ALL_LEVEL_LAYOUTS[name][1]}"
    parent = np.asarray(lv["parent"], dtype=np.int64)
    owners = np.asarray(lv["body_fragment"], dtype=np.int64)
    p_all, nb = len(parent), len(owners)
    if p_all <= p or nb < 2:
        return f"a file with levels has more fragments than level 1 ({p_all} for {p}) and at least two bodies ({nb})"
    if len(data.child_names) != p_all - p:
        return f"{len(data.child_names)} child names for {p_all - p} fragments below level 1"
    if np.any(parent[:p] != -1) or np.any(parent[p:] < 0) or np.any(parent[p:] >= np.arange(p, p_all)):
        return "parent must be -1 for the level-1 fragments and a smaller fragment index for every other"
    if owners[0] != -1 or np.any(np.diff(owners[1:]) <= 0) or owners[1] < 0 or owners[-1] >= p_all:
        return "body_fragment must be -1 for body 0, then fragment indices strictly increasing"
    child = np.asarray(lv["body_child_ptr"], dtype=np.int64)
    problem = _ptr_problem(child, "body_child_ptr", nb + 1, p_all)
    if problem is None and (child[1] != p or np.any(np.diff(child) < 2)):
        problem = f"body_child_ptr[1] must be {p} (level 1) and every body must have at least 2 children"
    if problem:
        return problem
    if np.any(parent[p:] != np.repeat(owners[1:], np.diff(child)[1:])):
        return "parent of every child must be the fragment of the body that holds it"
    S, E = len(lv["body_sites"]), len(lv["body_edges"])
    sites = np.asarray(lv["body_site_ptr"], dtype=np.int64)
    edges = np.asarray(lv["body_edge_ptr"], dtype=np.int64)
    problem = _ptr_problem(sites, "body_site_ptr", nb + 1, S) or _ptr_problem(edges, "body_edge_ptr", nb + 1, E)
    if problem:
        return problem
    if sites[1] != 0 or edges[1] != 0 or np.any(np.diff(sites)[1:] < 1):
        return "body 0 has no rows in body_site_ptr and body_edge_ptr, and every other body at least one site"
    B, W = np.asarray(lv["body_B"]), np.asarray(lv["body_W"])
    K = B.shape[1]
    if B.shape != (S, K, data.dim) or K < 1 or W.shape != (K, p_all - p, data.dim):
        return (f"body_B has shape {list(B.shape)} and body_W {list(W.shape)}, expected [{S}, K, {data.dim}] and "
                f"[K, {p_all - p}, {data.dim}] with K >= 1")
    if np.asarray(lv["body_edges"]).shape != (E, 2) or np.asarray(lv["body_edge_areas"]).shape != (E,):
        return f"body_edges must be [{E}, 2] and body_edge_areas [{E}]"
    problem = _offsets_problem(data, S, E, p_all - p)
    if problem:
        return problem
    if data.anchored is not None and np.any(np.asarray(data.anchored)[owners[1:][owners[1:] < p]] == 1):
        return "an anchored fragment cannot be broken further (it has a body)"
    return _info_problem(data, int(fragment_levels(parent).max()))


def _offsets_problem(data: RuntimeData, S: int, E: int, C: int) -> str | None:
    """The concatenated stress, game-ready and crack offsets: whole-file validity (each body's: by its view)."""
    lv = data.levels
    if "body_site_bonds_ptr" in lv:
        N = len(lv["body_site_bonds"])
        problem = _ptr_problem(np.asarray(lv["body_site_bonds_ptr"], dtype=np.int64), "body_site_bonds_ptr", S + 1, N)
        if problem or np.asarray(lv["body_bond_strength"]).shape != (E,):
            return problem or f"body_bond_strength must have {E} entries"
    if "body_site_fragment" in lv and np.asarray(lv["body_site_fragment"]).shape != (S,):
        return f"body_site_fragment must have {S} entries"
    if "child_collision_fragment_offsets" in lv:
        parts = np.asarray(lv["child_collision_part_offsets"], dtype=np.int64)
        problem = (_ptr_problem(np.asarray(lv["child_collision_fragment_offsets"], dtype=np.int64),
                                "child_collision_fragment_offsets", C + 1, len(parts) - 1) if len(parts) else
                   "child_collision_part_offsets must have at least one entry")
        problem = problem or _ptr_problem(parts, "child_collision_part_offsets", len(parts),
                                          len(lv["child_collision_vertices"]))
        if problem:
            return problem
    if "body_crack_ptr" in lv:
        segments = np.asarray(lv["body_crack_segments"])
        if segments.ndim != 3 or segments.shape[1:] != (2, 3):
            return f"array body_crack_segments has shape {list(segments.shape)}, expected [n, 2, 3]"
        return _ptr_problem(np.asarray(lv["body_crack_ptr"], dtype=np.int64), "body_crack_ptr", E + 1, len(segments))
    return None


def _info_problem(data: RuntimeData, deepest: int) -> str | None:
    """Why the header's ``levels`` object does not fit the file (section 14.1), or None."""
    info = data.levels_info
    count = info.get("count")
    if isinstance(count, bool) or not isinstance(count, int) or count != deepest:
        return f"levels.count must be the deepest level, {deepest}; got {count!r}"
    thresholds = info.get("thresholds")
    if not isinstance(thresholds, list) or len(thresholds) != count:
        return f"levels.thresholds must list {count} numbers, one per level"
    for value in thresholds:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            return f"levels.thresholds must be finite numbers >= 0, got {value!r}"
    if float(thresholds[0]) != float(data.default_threshold):
        return f"levels.thresholds[0] must be default_threshold ({data.default_threshold!r}), got {thresholds[0]!r}"
    return None
