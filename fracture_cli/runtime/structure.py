"""Structures, damage and cracks in the runtime file (format version 2; docs/FORMAT.md section 12).

Feature ``"anchors"``: an ``anchored (p,)`` int32 array (1: the fragment is bonded to
the world). Feature ``"damage"``: a header object ``damage`` with the crack level
``c`` (``0 < c <= 1``) and the damage rate ``r`` (``r >= 0``) that say how a hit
below a bond's strength cracks it and lowers its health (:mod:`fracture_cli.runtime.damage`).
Optional drawing arrays ``crack_ptr (e+1,)`` int32 and ``crack_segments (n, 2, 3)``
float32: where each bond's fault meets the outer surface.

Depends on numpy only.
"""

from __future__ import annotations

import math

import numpy as np

# name -> (dtype, number of dimensions), in file order (after the stress arrays).
ANCHOR_LAYOUT: dict[str, tuple[str, int]] = {"anchored": ("int32", 1)}
CRACK_LAYOUT: dict[str, tuple[str, int]] = {"crack_ptr": ("int32", 1), "crack_segments": ("float32", 3)}
DAMAGE_KEYS: tuple[str, ...] = ("crack_level", "damage_rate")


def check_anchored(anchored: np.ndarray, p: int) -> str | None:
    """Why ``anchored`` is not a valid ``(p,)`` array of 0/1 flags, or None."""
    anchored = np.asarray(anchored)
    if anchored.shape != (p,):
        return f"array anchored has shape {list(anchored.shape)}, expected [{p}]"
    if not np.all((anchored == 0) | (anchored == 1)):
        return "array anchored must hold only 0 and 1"
    return None


def check_damage(damage: dict) -> str | None:
    """Why the header's ``damage`` object is invalid (``0 < crack_level <= 1``, finite rate ``>= 0``), or None."""
    if not isinstance(damage, dict):
        return "runtime header 'damage' must be an object"
    values = []
    for key in DAMAGE_KEYS:
        value = damage.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return f"damage.{key} must be a finite number, got {value!r}"
        values.append(float(value))
    c, r = values
    if not 0 < c <= 1:
        return f"damage.crack_level must be in (0, 1], got {c!r}"
    if r < 0:
        return f"damage.damage_rate must be >= 0, got {r!r}"
    return None


def check_cracks(cracks: dict[str, np.ndarray], e: int) -> str | None:
    """Why the crack arrays do not fit ``e`` bonds, or None (both present or both absent)."""
    if not cracks:
        return None
    missing = [name for name in CRACK_LAYOUT if name not in cracks]
    if missing:
        return f"the crack arrays come together: {', '.join(missing)} missing"
    ptr = np.asarray(cracks["crack_ptr"], dtype=np.int64)
    segments = np.asarray(cracks["crack_segments"])
    n = segments.shape[0] if segments.ndim == 3 else -1
    if segments.ndim != 3 or segments.shape[1:] != (2, 3):
        return f"array crack_segments has shape {list(segments.shape)}, expected [n, 2, 3]"
    if ptr.shape != (e + 1,) or ptr[0] != 0 or ptr[-1] != n or np.any(np.diff(ptr) < 0):
        return f"crack_ptr must have {e + 1} entries, start at 0, never decrease and end at {n}"
    if not np.all(np.isfinite(segments)):
        return "array crack_segments must be finite"
    return None


def damage_factor(damage: dict) -> tuple[float, float]:
    """``(c, q)``: the crack level and ``q = r / (1 - c)`` in double (``q = 0`` when ``c == 1``), once per file."""
    c = float(damage["crack_level"])
    r = float(damage["damage_rate"])
    return c, (0.0 if c == 1.0 else r / (1.0 - c))


def crack_segments_of(cracks: dict[str, np.ndarray], bond: int) -> np.ndarray:
    """The segments ``(m, 2, 3)`` float32 where ``bond``'s fault meets the outer surface (empty without cracks)."""
    if not cracks:
        return np.zeros((0, 2, 3), np.float32)
    ptr = cracks["crack_ptr"]
    return np.asarray(cracks["crack_segments"][int(ptr[bond]): int(ptr[bond + 1])])
