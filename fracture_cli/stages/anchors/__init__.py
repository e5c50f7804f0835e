"""The ``anchors`` stage: which fragments the world holds (a structure's base; docs/FORMAT.md section 12).

A structure in a level stands on something: a pillar on the floor, a bridge on its
piers, a lamp on the ceiling. A fragment bonded to the world (NVIDIA Blast's world
bond) never moves, and neither does any group of fragments that still holds one.
Three rules pick them, each off unless the recipe turns it on; a fragment is
anchored when any rule picks it:

* ``ground``: the fragment has a face of the input's surface (not a fault) lying on
  the asset's lowest plane along ``up``, within ``tolerance``;
* ``boxes``: the fragment's solid shares volume with a named box (input units);
* ``color``: the fragment's outer surface carries the input's vertex-colour channel
  above 0.5 somewhere.

The rules themselves are in :mod:`fracture_cli.stages.anchors.rules`. With every rule
off (the default) no fragment is anchored and the runtime file is as before.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fracture_cli.errors import RecipeError
from fracture_cli.options import option
from fracture_cli.types import Anchors, Fragments, SurfaceMesh

log = logging.getLogger(__name__)
STAGE = "anchors"

UP_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")
CHANNELS = ("none", "r", "g", "b", "a")
_BOX_KEYS = ("name", "min", "max")


@dataclass(frozen=True)
class AnchorBox:
    """One named box of ``anchors.boxes``, checked: ``lo < hi`` on every axis, input units."""

    name: str
    lo: np.ndarray
    hi: np.ndarray


def parse_boxes(boxes: Sequence[object]) -> list[AnchorBox]:
    """The boxes of ``anchors.boxes``, or a :class:`RecipeError` naming the first bad one.

    Parameters
    ----------
    boxes : sequence of dict
        ``{name = "...", min = [x, y, z], max = [x, y, z]}`` in the input's units (``name`` optional:
        ``box_<i>``).
    """
    out = []
    for i, box in enumerate(boxes):
        if not isinstance(box, dict):
            raise RecipeError(f"anchors.boxes[{i}] must be a table {{name, min = [x, y, z], max = [x, y, z]}}")
        unknown = set(box) - set(_BOX_KEYS)
        if unknown:
            raise RecipeError(f"anchors.boxes[{i}] has unknown key(s) {', '.join(sorted(unknown))}; "
                              f"valid: {', '.join(_BOX_KEYS)}")
        try:
            lo = np.asarray(box["min"], dtype=np.float64).reshape(3)
            hi = np.asarray(box["max"], dtype=np.float64).reshape(3)
        except (KeyError, ValueError, TypeError) as exc:
            raise RecipeError(f"anchors.boxes[{i}] needs min = [x, y, z] and max = [x, y, z] ({exc})") from None
        # A box without volume (min == max on an axis) shares volume with nothing: say so rather than anchor nothing.
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo < hi)):
            raise RecipeError(f"anchors.boxes[{i}]: min must be < max on every axis, both finite")
        name = box.get("name", f"box_{i}")
        if not isinstance(name, str):
            raise RecipeError(f"anchors.boxes[{i}].name must be a string, got {name!r}")
        out.append(AnchorBox(name, lo, hi))
    return out


@dataclass(frozen=True)
class AnchorOptions:
    """Options of the ``anchors`` stage (recipe section ``[anchors]``): which fragments the world holds.

    Attributes
    ----------
    ground : bool, optional (default False)
        Anchor the fragments with an outer face on the asset's lowest plane along ``up``.
    up : str, optional (default "+y")
        The asset's up axis (glTF assets: ``+y``; ``-y`` anchors at the top, e.g. a lamp on a ceiling).
    tolerance : float, optional (default 0.01)
        How far above the lowest plane every corner of such a face may lie, fraction of the bounding-box
        diagonal.
    boxes : list of dict, optional (default none)
        Named boxes ``{name, min, max}`` in input units; a fragment whose solid shares volume with one is
        anchored.
    color : str, optional (default "none")
        Vertex-colour channel; a fragment whose outer surface carries it above 0.5 is anchored.
    """

    ground: bool = option(False, "anchor the fragments that have an outer face on the asset's lowest plane "
                                 "along 'up' (the ground a structure stands on)")
    up: str = option("+y", "the asset's up axis for 'ground' (glTF: +y; -y anchors the top, e.g. a lamp on a "
                           "ceiling)", choices=UP_AXES)
    tolerance: float = option(0.01, "ground: how far above the lowest plane all three corners of an outer face may "
                                    "lie, fraction of the bounding-box diagonal", min=0.0, max=1.0)
    boxes: list = option([], "named boxes {name, min = [x, y, z], max = [x, y, z]} in input units: a fragment "
                             "whose solid shares volume with one is anchored")
    color: str = option("none", "vertex-colour channel: a fragment whose outer surface carries it above 0.5 is "
                                "anchored", choices=CHANNELS)

    def __post_init__(self) -> None:
        # Checked when the recipe is resolved, so a bad box stops the bake before any work.
        parse_boxes(self.boxes)

    @property
    def active(self) -> bool:
        """Whether any rule is on."""
        return self.ground or bool(self.boxes) or self.color != "none"


def anchors(fragments: Fragments, surface: SurfaceMesh | None, options: AnchorOptions = AnchorOptions()) -> Anchors:
    """The fragments held by the world, and how they were chosen.

    Parameters
    ----------
    fragments : Fragments
        The baked fragments (normalized coordinates); outer faces are those not of the interior material.
    surface : SurfaceMesh or None
        The solid the fragments were cut from, with its vertex colours (needed for ``color`` only).
    options : AnchorOptions

    Returns
    -------
    Anchors
        ``anchored (p,)`` int32 flags in the fragments' order, the header's ``info`` and each rule's picks.

    Raises
    ------
    RecipeError
        ``color`` is set but the input has no vertex colours.
    """
    # on first use: the rules load the geometry stack (manifold3d) only when a rule is on
    from fracture_cli.stages.anchors import rules

    p = len(fragments.fragments)
    picked: dict[str, np.ndarray] = {}
    info: dict = {}
    if options.ground:
        picked["ground"] = rules.on_ground(fragments, options.up, options.tolerance)
        info.update(ground=True, up=options.up, tolerance=float(options.tolerance))
    boxes = parse_boxes(options.boxes)
    for box in boxes:
        picked[f"box {box.name}"] = rules.in_box(fragments, box.lo, box.hi)
    if boxes:
        info["boxes"] = [box.name for box in boxes]
    if options.color != "none":
        if surface is None or surface.colors is None:
            name = surface.name if surface is not None else "the input"
            raise RecipeError(f"anchors.color = '{options.color}' but {name} has no vertex colours; paint the "
                              "anchored part or set anchors.color = 'none'", stage=STAGE)
        picked["color"] = rules.painted(fragments, surface, CHANNELS.index(options.color) - 1)
        info["color"] = options.color
    flags = np.zeros(p, dtype=bool)
    for which in picked.values():
        flags |= which
    anchored = flags.astype(np.int32)
    if options.active:
        count = int(flags.sum())
        log.info("%s: %d of %d fragments anchored (%s)", STAGE, count, p,
                 ", ".join(f"{rule}: {int(which.sum())}" for rule, which in picked.items()))
        if count == 0:
            log.warning("%s: no fragment is anchored (%s): the runtime file gets no anchors; widen "
                        "anchors.tolerance or the boxes", STAGE, ", ".join(picked))
        elif count == p:
            log.warning("%s: every fragment is anchored: nothing can ever fall", STAGE)
    return Anchors(anchored=anchored, info=info if flags.any() else {}, rules=picked)
