"""Triangle budgets of the fault simplification (issue 20, "lean meshes").

Two limits, both optional: ``max_triangles`` per fragment (a recipe's cap),
and the whole asset's budget, twice the input's triangles plus
:data:`BUDGET_PER_FRAGMENT` per fragment (what a default bake promises and
the report checks). The simplification first runs at the recipe's tolerance;
while a limit is exceeded, the fragments above their limit get their tolerance
doubled and are simplified again (:func:`fracture_cli.stages.simplify.faults.simplify_faults`).
This module only decides which fragments those are.

For the asset's budget every fragment gets a share in proportion to what the
budget allows it: :data:`BUDGET_PER_FRAGMENT`, plus twice the input triangles
its outer surface covers (by area). Fragments that cannot go further (at the
largest tolerance, or kept as cut) keep what they have, and the others share
what is left, so a few stubborn fragments do not make the asset miss its
budget when the rest can make up for them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The triangle budget the issue sets for a default bake: twice the input's triangles plus this many per fragment.
BUDGET_PER_FRAGMENT = 64


def triangle_budget(input_triangles: int, fragments: int) -> int:
    """The issue's budget for a bake's output: twice the input's triangles plus 64 per fragment."""
    return 2 * input_triangles + BUDGET_PER_FRAGMENT * fragments


def shares(input_triangles: int, outer_area: np.ndarray) -> np.ndarray:
    """Each fragment's share of :func:`triangle_budget` (they sum to it).

    Parameters
    ----------
    input_triangles : int
        Triangles of the input the fragments were cut from.
    outer_area : (n,) float
        Area of each fragment's outer surface (the part on the input).

    Returns
    -------
    (n,) float
    """
    area = np.asarray(outer_area, dtype=float)
    total = float(area.sum())
    part = area / total if total > 0 else np.full(len(area), 1.0 / max(len(area), 1))
    return BUDGET_PER_FRAGMENT + 2.0 * input_triangles * part


@dataclass(frozen=True)
class Limits:
    """The triangle limits of one simplification.

    Attributes
    ----------
    max_triangles : int
        Per-fragment limit; 0 = none.
    budget : int
        Limit on the asset's triangles (:func:`triangle_budget`); 0 = none.
    share : (n,) float or None
        Each fragment's :func:`shares` of ``budget`` (required with it).
    """

    max_triangles: int = 0
    budget: int = 0
    share: np.ndarray | None = None

    @property
    def active(self) -> bool:
        """Whether there is any limit."""
        return self.max_triangles > 0 or (self.budget > 0 and self.share is not None)

    def over(self, sizes: np.ndarray, stuck: np.ndarray) -> np.ndarray:
        """The fragments to simplify further: above ``max_triangles``, or above their part of ``budget``.

        While the asset is above ``budget``, each fragment that can still go further is held to its share
        of what the ``stuck`` ones leave.

        Parameters
        ----------
        sizes : (n,) int
            Triangles of each fragment as it would be written.
        stuck : (n,) bool
            Fragments that cannot be simplified further (never returned).

        Returns
        -------
        (k,) int
            Fragment indices, ascending.
        """
        sizes = np.asarray(sizes)
        free = ~np.asarray(stuck, dtype=bool)
        above = np.zeros(len(sizes), dtype=bool)
        if self.max_triangles > 0:
            above |= sizes > self.max_triangles
        if self.budget > 0 and self.share is not None and int(sizes.sum()) > self.budget and free.any():
            share = np.asarray(self.share, dtype=float)
            room = self.budget - int(sizes[~free].sum())
            above |= sizes > share * room / float(share[free].sum())
        return np.flatnonzero(above & free)
