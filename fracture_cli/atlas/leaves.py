"""A hit on a file with levels: the struck fragment's own children answer it too (docs/FORMAT.md 14.5).

A hit on the intact object is a hit on the piece holding every level-1 fragment. Body 0
answers it (:func:`~fracture_cli.atlas.hits.analyse_hit` on the file), and when the
fragment hit (the *struck* fragment, :meth:`~fracture_cli.atlas.layout.FragmentLayout.hit_fragment`)
has children, its body answers the same point and direction on its own view, with its own
default threshold (``levels.thresholds``), exactly as the runtime's ``hit_piece``. Every bond of
either body breaks at its own breaking impulse, so at any magnitude ``M``:

* the struck fragment is *split* when its children fall into two or more groups (``M`` above the
  child body's ``d1``); it then leaves its level-1 group and its children's groups are pieces;
* the *leaves* shown are the level-1 fragments, with the struck one replaced by its children
  when it is split; each leaf is in one piece: a group of the other level-1 fragments over their
  unbroken bonds (without the split fragment, which may have held them together), or a group of
  its children;
* a leaf is *detached* when it is outside the heaviest piece of its rest component (the
  component of the intact level-1 graph: a split fragment's children belong to its component),
  ties by the smallest piece id (level-1 groups before children's groups);
* the *struck leaf* is the struck fragment, or, when it is split, its child the hit lands on
  (the child layout's ``hit_fragment``).

A file without levels (or a struck fragment without children) gives the level-1 figures
unchanged. The first break ``b0``, first detachment ``d1`` and ``everything`` of the hit are
the smallest, smallest and largest over the two bodies.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fracture_cli.atlas.criterion import BreakingImpulses
from fracture_cli.atlas.hits import HitAnalysis, analyse_hit, detached, groups_at
from fracture_cli.atlas.layout import FragmentLayout, fragment_layout
from fracture_cli.runtime.format import RuntimeData
from fracture_cli.runtime.impact import components
from fracture_cli.runtime.levels import body_of, body_view


@dataclass(frozen=True, eq=False)
class StruckHit:
    """One hit on the intact object and, where the fragment hit has children, their answer.

    Attributes
    ----------
    hit : HitAnalysis
        Body 0's answer (level-1 fragments).
    struck : int or None
        The level-1 fragment hit; None without fragment positions.
    child : HitAnalysis or None
        The struck fragment's body's answer (its children, local indices), or None.
    child_view : RuntimeData or None
        The struck fragment's body as a runtime file of its own (docs/FORMAT.md 14.3), or None.
    child_layout : FragmentLayout or None
        The children's volumes and centroids (the body's view), or None.
    """

    hit: HitAnalysis
    struck: int | None
    child: HitAnalysis | None = None
    child_view: RuntimeData | None = None
    child_layout: FragmentLayout | None = None

    @property
    def b0(self) -> float:
        """First bond broken in either body."""
        return min(self.hit.b0, self.child.b0) if self.child is not None else self.hit.b0

    @property
    def d1(self) -> float:
        """First detachment: level-1 fragments part, or the struck fragment splits."""
        return min(self.hit.d1, self.child.d1) if self.child is not None else self.hit.d1

    @property
    def everything(self) -> float:
        """Every bond of both bodies broken."""
        return max(self.hit.everything, self.child.everything) if self.child is not None else self.hit.everything

    def split(self, magnitude: float) -> bool:
        """Whether the struck fragment is split at ``magnitude``."""
        return self.child is not None and magnitude > self.child.d1


@dataclass(frozen=True, eq=False)
class Leaves:
    """The leaves shown after a hit of one magnitude (module docstring).

    Attributes
    ----------
    volumes : (n,) float64
    centroids : (n, 3) float64 or None
    detached : (n,) bool
    struck : int or None
        Index (into these arrays) of the struck leaf; None without positions.
    """

    volumes: np.ndarray
    centroids: np.ndarray | None
    detached: np.ndarray
    struck: int | None


def struck_hit(data: RuntimeData, layout: FragmentLayout, hit: HitAnalysis, criterion: BreakingImpulses,
               child_layouts: dict[int, FragmentLayout]) -> StruckHit:
    """``hit`` with the struck fragment's children's answer (module docstring).

    ``child_layouts`` caches each body's layout (filled here on first use).
    """
    struck = layout.hit_fragment(hit.point)
    if struck is None or not data.levels:
        return StruckHit(hit=hit, struck=struck)
    body = body_of(data, struck)
    if body < 1:
        return StruckHit(hit=hit, struck=struck)
    view = body_view(data, body)
    if body not in child_layouts:
        child_layouts[body] = fragment_layout(view)
    child = analyse_hit(view, hit.point, hit.direction, criterion)
    return StruckHit(hit=hit, struck=struck, child=child, child_view=view, child_layout=child_layouts[body])


def leaves_at(data: RuntimeData, layout: FragmentLayout, sh: StruckHit, magnitude: float,
              rest: np.ndarray) -> Leaves:
    """The leaves shown after ``sh`` at ``magnitude``, which are detached, and the struck one.

    Parameters
    ----------
    data : RuntimeData
    layout : FragmentLayout
        The level-1 fragments' volumes and centroids.
    sh : StruckHit
    magnitude : float
    rest : (p,) int
        Level-1 groups with every bond intact (:func:`fracture_cli.atlas.hits.rest_groups`).
    """
    volumes = np.asarray(layout.volumes, dtype=np.float64)
    if not sh.split(magnitude) or sh.struck is None or sh.child_view is None or sh.child is None \
            or sh.child_layout is None:
        return Leaves(volumes=volumes, centroids=layout.centroids,
                      detached=detached(groups_at(data, sh.hit, magnitude), rest, volumes), struck=sh.struck)
    keep = np.arange(data.p) != sh.struck
    child_groups = groups_at(sh.child_view, sh.child, magnitude) + data.p  # after every level-1 group id
    groups = np.concatenate([_groups_without(data, sh.hit, magnitude, sh.struck)[keep], child_groups])
    volumes = np.concatenate([volumes[keep], np.asarray(sh.child_layout.volumes, dtype=np.float64)])
    centroids = None
    if layout.centroids is not None and sh.child_layout.centroids is not None:
        centroids = np.concatenate([layout.centroids[keep], sh.child_layout.centroids])
    components = np.concatenate([rest[keep], np.full(len(child_groups), rest[sh.struck])])
    local = sh.child_layout.hit_fragment(sh.hit.point)
    struck = None if local is None else int(np.count_nonzero(keep)) + local
    return Leaves(volumes=volumes, centroids=centroids, detached=detached(groups, components, volumes),
                  struck=struck)


def _groups_without(data: RuntimeData, hit: HitAnalysis, magnitude: float, gone: int) -> np.ndarray:
    """Level-1 groups (p,) at ``magnitude`` over the unbroken bonds that do not touch fragment ``gone``.

    A split fragment leaves its group, which may fall apart without it (it held the others together), so the
    spanning forest of the whole graph does not answer this; the bonds do.
    """
    edges = np.asarray(data.edges, dtype=np.int64)
    kept = (hit.magnitudes >= magnitude) & (edges[:, 0] != gone) & (edges[:, 1] != gone)
    return components(data.p, edges[kept, 0], edges[kept, 1])
