"""The runtime file's optional game-ready arrays: their layout and consistency (docs/FORMAT.md section 8)."""

from __future__ import annotations

import numpy as np

# Optional game-ready arrays (docs/FORMAT.md section 8), after the required ones; a file has all or none.
GAMEREADY_LAYOUT: dict[str, tuple[str, int]] = {
    "fragment_volume": ("float32", 1),
    "fragment_center_of_mass": ("float32", 2),
    "fragment_inertia": ("float32", 2),
    "collision_vertices": ("float32", 2),
    "collision_part_offsets": ("int32", 1),
    "collision_fragment_offsets": ("int32", 1),
}


def check_gameready(arrays: dict[str, np.ndarray], p: int) -> str | None:
    """Why the optional game-ready arrays are inconsistent (FORMAT.md section 8), or None."""
    missing = [name for name in GAMEREADY_LAYOUT if name not in arrays]
    if missing:
        return f"game-ready arrays come all or none; missing {', '.join(missing)}"
    n = len(arrays["collision_vertices"])
    parts = np.asarray(arrays["collision_part_offsets"], dtype=np.int64)
    owners = np.asarray(arrays["collision_fragment_offsets"], dtype=np.int64)
    shapes = {"fragment_volume": (p,), "fragment_center_of_mass": (p, 3), "fragment_inertia": (p, 6),
              "collision_vertices": (n, 3), "collision_fragment_offsets": (p + 1,)}
    for name, shape in shapes.items():
        if np.asarray(arrays[name]).shape != shape:
            return f"array {name} has shape {list(np.asarray(arrays[name]).shape)}, expected {list(shape)}"
    for name, offsets, end in (("collision_part_offsets", parts, n), ("collision_fragment_offsets", owners,
                                                                       len(parts) - 1)):
        if offsets.ndim != 1 or len(offsets) < 1 or offsets[0] != 0 or offsets[-1] != end or np.any(
                np.diff(offsets) < 0):
            return f"{name} must start at 0, never decrease and end at {end}"
    for name in ("fragment_volume", "fragment_center_of_mass", "fragment_inertia", "collision_vertices"):
        if not np.all(np.isfinite(arrays[name])):
            return f"array {name} has non-finite values"
    return None
