"""A broken object with levels: which pieces fly, and what a hit on one of them does (docs/FORMAT.md 14.4-14.5).

::

    state = new_object_state(data)                  # (e + E,) float64: every body's bond healths
    for piece in shown_pieces(data, state): ...     # the rigid bodies a game shows
    outcome = hit_piece(data, state, struck, point, impulse)   # updates state in place
    outcome.pieces                                  # what the struck fragment's piece became

A *piece* is a set of sibling fragments (children of one body) held together by unbroken
bonds: the intact asset is one piece of body 0. A hit on a piece names the fragment the
game struck (its collider) and the contact point and impulse in the asset's model space
(the piece's rigid transform undone). The body that holds the piece answers it, changing
only the bonds inside that piece (section 12.4 on that body's data); then, if the struck
fragment has children, its own body answers the same hit, and when that splits it into
two or more groups the fragment is *split*: it leaves its piece and its children fly as
the pieces of its body. Everything is decided by the runtime file and the state, so every
reader answers alike.

Depends on numpy only.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import ImpactArgumentError
from fracture_cli.runtime.data import RuntimeData
from fracture_cli.runtime.impact import ImpactResult, apply_hit, components
from fracture_cli.runtime.levels import (
    body_holding,
    body_of,
    body_view,
    children_range,
    num_bodies,
    num_fragments,
    state_offsets,
)


@dataclass(frozen=True)
class Piece:
    """Sibling fragments that move together.

    Attributes
    ----------
    body : int
        The body whose children they are (0: level-1 fragments).
    fragments : tuple of int
        Global fragment indices, ascending.
    anchored : bool
        Whether the piece holds a fragment bonded to the world (level 1 only; a game keeps it static).
    """

    body: int
    fragments: tuple[int, ...]
    anchored: bool = False


@dataclass(frozen=True, eq=False)
class PieceHit:
    """What one hit on a piece did (docs/FORMAT.md section 14.5).

    Attributes
    ----------
    struck : int
        The fragment hit.
    body : int
        The body holding the struck fragment's piece; ``result`` is its answer, in its local indices, over
        the state after the hit (``groups`` over all its children, as section 12.4 step 4 computes them).
    result : ImpactResult
    child_body : int
        The struck fragment's own body, -1 when it has no children.
    child_result : ImpactResult or None
        That body's answer (local indices), or None.
    split : bool
        Whether the struck fragment broke into its children (``child_result`` has two or more groups).
    pieces : tuple of Piece
        The pieces the hit piece became: its fragments regrouped (without the struck one if it split),
        then its children's pieces; in increasing order of their first fragment within each body.
    """

    struck: int
    body: int
    result: ImpactResult
    child_body: int
    child_result: ImpactResult | None
    split: bool
    pieces: tuple[Piece, ...]


def new_object_state(data: RuntimeData) -> np.ndarray:
    """A fresh object state: ``(e + E,)`` float64 of ones (body 0's bonds, then body 1's, ...)."""
    return np.ones(int(state_offsets(data)[-1]), dtype=np.float64)


def check_object_state(data: RuntimeData, state: np.ndarray) -> None:
    """Refuse a state that is not ``(e + E,)`` float64, writeable, with values in ``[0, 1]``."""
    size = int(state_offsets(data)[-1])
    if not isinstance(state, np.ndarray) or state.dtype != np.float64 or state.shape != (size,):
        raise ImpactArgumentError(f"an object state must be a float64 array of {size} bond healths (every body's), "
                                  f"got shape {getattr(state, 'shape', None)} of {getattr(state, 'dtype', None)}")
    if not state.flags.writeable:
        raise ImpactArgumentError("the object state is read-only; hit_piece() updates it in place (pass a copy)")
    if not np.all((state >= 0.0) & (state <= 1.0)):
        raise ImpactArgumentError("an object state holds healths in [0, 1]; this one has other values (NaN?)")


def body_state(data: RuntimeData, state: np.ndarray, body: int) -> np.ndarray:
    """Body ``body``'s bond healths, a writeable view into the object ``state``."""
    offsets = state_offsets(data)
    return state[int(offsets[body]): int(offsets[body + 1])]


def body_groups(data: RuntimeData, state: np.ndarray, body: int, keep: np.ndarray | None = None) -> np.ndarray:
    """Group (c_b,) int64 of every child of ``body``: the smallest local index over unbroken bonds.

    ``keep`` (c_b,) bool: only bonds between two kept children count (the others' children stay alone).
    """
    view = body_view(data, body)
    edges = np.asarray(view.edges, dtype=np.int64)
    holds = body_state(data, state, body) > 0.0
    if keep is not None:
        holds &= keep[edges[:, 0]] & keep[edges[:, 1]]
    return components(view.p, edges[holds, 0], edges[holds, 1])


def is_split(data: RuntimeData, state: np.ndarray, fragment: int) -> bool:
    """Whether ``fragment`` broke into its children: its body's unbroken bonds leave two or more groups."""
    body = body_of(data, fragment)
    if body < 0:
        return False
    groups = body_groups(data, state, body)
    return int(np.count_nonzero(groups == np.arange(len(groups)))) >= 2


def _split_flags(data: RuntimeData, state: np.ndarray) -> np.ndarray:
    """``split (p_all,)`` bool of every fragment."""
    split = np.zeros(num_fragments(data), dtype=bool)
    for body in range(1, num_bodies(data)):
        split[int(data.levels["body_fragment"][body])] = is_split(data, state, int(data.levels["body_fragment"][body]))
    return split


def shown_fragments(data: RuntimeData, state: np.ndarray) -> np.ndarray:
    """``shown (p_all,)`` bool: not split, and every ancestor split (level-1 fragments have none)."""
    split = _split_flags(data, state)
    opened = np.ones(len(split), dtype=bool)  # every ancestor split
    if data.levels:
        parent = np.asarray(data.levels["parent"], dtype=np.int64)
        for g in range(data.p, len(split)):  # parent[g] < g: ancestors first
            opened[g] = opened[parent[g]] and split[parent[g]]
    return opened & ~split


def shown_pieces(data: RuntimeData, state: np.ndarray) -> list[Piece]:
    """Every piece the object is in (docs/FORMAT.md section 14.4), body by body, by first fragment.

    The pieces of a body whose fragment is split (or of body 0) are the components of its shown children
    over the bonds that hold between two shown children.
    """
    check_object_state(data, state)
    shown = shown_fragments(data, state)
    out = []
    for body in range(num_bodies(data)):
        out += _pieces_of(data, state, body, shown, None)
    return out


def piece_of(data: RuntimeData, state: np.ndarray, fragment: int) -> Piece:
    """The piece holding the shown fragment ``fragment``; ImpactArgumentError when it is not shown."""
    shown = shown_fragments(data, state)
    if not 0 <= fragment < len(shown) or not shown[fragment]:
        raise ImpactArgumentError(f"fragment {fragment} is not shown (split into its children, or inside an "
                                  "unbroken parent): hit the fragment the game shows")
    body = body_holding(data, fragment)
    return next(piece for piece in _pieces_of(data, state, body, shown, None) if fragment in piece.fragments)


def _pieces_of(data: RuntimeData, state: np.ndarray, body: int, shown: np.ndarray,
               members: set[int] | None) -> list[Piece]:
    """The pieces of ``body``'s shown children (only ``members`` when given)."""
    first = children_range(data, body).start
    keep = shown[children_range(data, body)].copy()
    if members is not None:
        keep &= np.isin(np.arange(len(keep)) + first, sorted(members))
    if not keep.any():
        return []
    groups = body_groups(data, state, body, keep)
    anchored = np.zeros(len(keep), dtype=bool)
    if body == 0 and data.anchored is not None:
        anchored = np.asarray(data.anchored) == 1
    out = []
    for root in np.flatnonzero(keep & (groups == np.arange(len(groups)))).tolist():
        local = np.flatnonzero(keep & (groups == root))
        out.append(Piece(body, tuple(int(j) + first for j in local), bool(anchored[local].any())))
    return out


def hit_piece(data: RuntimeData, state: np.ndarray, struck: int, point, impulse,
              threshold: float | None = None) -> PieceHit:
    """Hit the piece holding fragment ``struck`` (docs/FORMAT.md section 14.5); ``state`` is updated in place.

    Parameters
    ----------
    data : RuntimeData
    state : (e + E,) float64
        From :func:`new_object_state` (or saved); unchanged when the hit is refused.
    struck : int
        The shown fragment the game hit (the fragment of the collider it touched).
    point, impulse : (3,) float
        Contact point and impulse in the asset's model space (undo the piece's rigid transform).
    threshold : float, optional (default: each body's level threshold)
        Used for both bodies that answer.

    Returns
    -------
    PieceHit

    Raises
    ------
    ImpactArgumentError
        Invalid inputs (as :func:`~fracture_cli.runtime.impact.project_impact`), a state of the wrong size
        or values, or a fragment that is not shown.
    """
    check_object_state(data, state)
    piece = piece_of(data, state, struck)
    body = piece.body
    view = body_view(data, body)
    health = body_state(data, state, body)
    trial = health.copy()
    hit = apply_hit(view, trial, point, impulse, threshold)  # validates every input before anything changes
    first = children_range(data, body).start
    inside = np.zeros(view.p, dtype=bool)
    inside[np.asarray(piece.fragments) - first] = True
    edges = np.asarray(view.edges, dtype=np.int64)
    within = inside[edges[:, 0]] & inside[edges[:, 1]]
    health[within] = trial[within]
    broken = health <= 0.0
    cracked = ~broken & ((hit.cracked & within) | (health < 1.0))
    groups = body_groups(data, state, body)
    anchored = np.zeros(view.p, dtype=bool)
    if body == 0 and data.anchored is not None:
        held = np.zeros(view.p, dtype=bool)
        held[groups[np.asarray(data.anchored) == 1]] = True
        anchored = held[groups]
    result = dataclasses.replace(hit, groups=groups.astype(np.int32), broken=broken, cracked=cracked,
                                 anchored=anchored)
    child_body, child_result, split = body_of(data, struck), None, False
    if child_body >= 0:
        child_result = apply_hit(body_view(data, child_body), body_state(data, state, child_body), point, impulse,
                                 threshold)
        split = child_result.num_groups >= 2
    shown = shown_fragments(data, state)
    pieces = _pieces_of(data, state, body, shown, set(piece.fragments))
    if split:
        pieces += _pieces_of(data, state, child_body, shown, None)
    return PieceHit(struck=struck, body=body, result=result, child_body=child_body, child_result=child_result,
                    split=split, pieces=tuple(pieces))


def nearest_fragment(data: RuntimeData, fragments, point) -> int:
    """Of ``fragments`` (global indices), the one with a collision-part corner nearest to ``point`` (model space).

    An approximation for tools without a physics engine (a game knows which collider it hit): distances
    to the corners of each fragment's convex parts, or to its centre of mass when it has no parts; ties:
    the first of ``fragments``. Needs the game-ready arrays (docs/FORMAT.md section 9).

    Raises
    ------
    ValueError
        When the file has no game-ready arrays or ``fragments`` is empty.
    """
    if not data.gameready:
        raise ValueError("the runtime file has no collision parts (game-ready arrays) to locate fragments by")
    x = np.asarray(point, dtype=np.float64).reshape(3)
    best, best_d2 = -1, np.inf
    for g in fragments:
        body = body_holding(data, int(g))
        view = body_view(data, body)
        j = int(g) - children_range(data, body).start
        ready = view.gameready
        owners, parts = ready["collision_fragment_offsets"], ready["collision_part_offsets"]
        corners = np.asarray(ready["collision_vertices"][int(parts[int(owners[j])]): int(parts[int(owners[j + 1])])],
                             dtype=np.float64)
        if len(corners) == 0:
            corners = np.asarray(ready["fragment_center_of_mass"][j], dtype=np.float64).reshape(1, 3)
        offsets = corners - x
        d2 = float(np.min(np.sum(offsets * offsets, axis=1)))
        if d2 < best_d2:
            best, best_d2 = int(g), d2
    if best < 0:
        raise ValueError("no fragments to choose from")
    return best
