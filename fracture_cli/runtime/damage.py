"""Damage that adds up: the per-object state a game keeps between hits (docs/FORMAT.md section 12).

::

    state = new_state(data)                 # (e,) float64, every bond at health 1
    result = hit(data, state, point, impulse)   # updates state in place
    result.broken, result.cracked, result.groups, result.anchored

A bond is broken when its health is 0; a hit that loads it above the file's
crack level ``c`` (but not above its strength) cracks it and takes
``r * (load - c) / (1 - c)`` of its health, so about ``1 / r`` hits just under
the strength break it. Health never comes back. The state is a flat array of
doubles: save it with ``state.tobytes()`` and load it with :func:`state_from_bytes`.

Depends on numpy only.
"""

from __future__ import annotations

import numpy as np

from fracture_cli.errors import ImpactArgumentError
from fracture_cli.runtime.format import RuntimeData
from fracture_cli.runtime.impact import ImpactResult, apply_hit
from fracture_cli.runtime.levels import body_view

STATE_DTYPE = np.dtype("<f8")


def new_state(data: RuntimeData) -> np.ndarray:
    """A fresh state for ``data``: ``(e,)`` float64, all ``1.0`` (no bond damaged)."""
    return np.ones(data.num_edges, dtype=np.float64)


def check_state(data: RuntimeData, state: np.ndarray) -> None:
    """Refuse a state that does not belong to ``data`` (docs/FORMAT.md section 12.3).

    Raises
    ------
    ImpactArgumentError
        (a :class:`ValueError`) when ``state`` is not ``(e,)`` float64 with finite values in ``[0, 1]``.
    """
    if not isinstance(state, np.ndarray) or state.dtype != np.float64 or state.shape != (data.num_edges,):
        shape = getattr(state, "shape", None)
        dtype = getattr(state, "dtype", type(state).__name__)
        raise ImpactArgumentError(f"a damage state must be a float64 array of {data.num_edges} bond healths, "
                                  f"got shape {shape} of {dtype}")
    if not state.flags.writeable:
        raise ImpactArgumentError("the damage state is read-only; hit() updates it in place (pass a copy)")
    if not np.all((state >= 0.0) & (state <= 1.0)):  # NaN fails both comparisons
        raise ImpactArgumentError("a damage state holds healths in [0, 1]; this one has other values (NaN?)")


def hit(data: RuntimeData, state: np.ndarray, point, impulse, threshold: float | None = None,
        body: int = 0) -> ImpactResult:
    """Apply one hit to ``state`` (in place) and say what it does.

    Parameters
    ----------
    data : RuntimeData
    state : (e,) float64
        From :func:`new_state` or a saved state; updated in place (unchanged when the hit is refused). With
        ``body``: that body's state (``e_b`` bonds; :func:`new_state` of ``body_view(data, body)``).
    point, impulse, threshold, body
        As :func:`fracture_cli.runtime.impact.project_impact`.

    Returns
    -------
    ImpactResult
        ``broken`` lists every broken bond (this hit's and earlier ones'), ``cracked`` the bonds that
        hold but are cracked, ``groups`` the fragments that move together, ``anchored`` the fragments
        whose group is held by the world.

    Raises
    ------
    ImpactArgumentError
        For an invalid state or invalid hit inputs.
    """
    view = body_view(data, body)
    check_state(view, state)
    return apply_hit(view, state, point, impulse, threshold)


def state_from_bytes(data: RuntimeData, raw: bytes) -> np.ndarray:
    """A state saved with ``state.astype('<f8').tobytes()`` (little-endian doubles), checked."""
    if len(raw) != 8 * data.num_edges:
        raise ImpactArgumentError(f"a saved damage state of this file has {8 * data.num_edges} bytes "
                                  f"({data.num_edges} bonds), got {len(raw)}")
    state = np.frombuffer(raw, dtype=STATE_DTYPE).astype(np.float64)
    check_state(data, state)
    return state


def state_to_bytes(state: np.ndarray) -> bytes:
    """The bytes of ``state`` as a game saves it: ``e`` little-endian doubles."""
    return np.ascontiguousarray(state, dtype=STATE_DTYPE).tobytes()
