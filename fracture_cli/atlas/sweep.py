"""The atlas's sweep: hits spread over the surface and the figures that describe them.

Hits. ``N`` contact sites (default 200; every site when the file has at most
``N``), chosen by farthest-point sampling: start at site 0, then repeatedly the
site farthest (squared Euclidean distance) from those chosen so far, ties by the
smallest index; deterministic and evenly spread. The hit point is the site (the
sites lie just outside the surface) and resolves to its nearest site as in the
runtime; the impulse points from the site towards the asset's centre (its centre
of mass, :mod:`fracture_cli.atlas.layout`), i.e. into the surface, or straight
down ``(0, -1, 0)`` when the site is the centre. ``T`` is the file's default
threshold. The per-hit quantities ``b0``, ``d1``, ``everything``, groups,
detached fragments and the hit fragment are defined in
:mod:`fracture_cli.atlas.hits`; on a file with levels (docs/FORMAT.md section 14)
the fragment hit breaks too when it has children, as the runtime's ``hit_piece``
does, and the figures count *leaves* (:mod:`fracture_cli.atlas.leaves`): the
fragment hit is then its child the hit lands on once it has split, and ``b0``,
``d1`` and ``everything`` are over both bodies' bonds.

Figures (keys of the JSON summary; ``None`` when no hit qualifies or the file
has no fragment positions):

* ``hit_detached``: share of the detaching hits (``d1`` finite) whose hit fragment
  (the fragment the hit lands on, :meth:`~fracture_cli.atlas.layout.FragmentLayout.hit_fragment`)
  is detached just above the first detachment, at ``d1 * (1 + 1e-9)``;
* ``hit_on_largest``: share of those hits that land on the largest fragment (by volume), which can
  only count as detached when the rest of the object comes off it as one lighter group
  (docs/notes/breaking-analysis.md); ``hit_detached_others``: ``hit_detached`` over the other hits;
* ``locality_2x``, ``locality_8x``: at ``M = 2 * b0`` (``8 * b0``), per hit that
  detaches something at ``M``: the mean over the detached fragments of
  ``|hit - centroid|`` divided by the mean of ``|hit - centroid|`` over all
  fragments (0: at the hit, 1: as far as fragments are on average, above 1: farther;
  the main group never counts as detached); averaged (mean) over those
  hits, whose number is ``locality_2x_hits`` (``locality_8x_hits``);
  ``locality_2x_median`` and ``locality_8x_median`` are the medians over the same hits;
* ``first_break_splits``: share of the hits that break a bond (``b0`` finite)
  whose first broken bond detaches something (``d1 == b0``);
* ``graded_median``, ``graded_p10``: median and 10th percentile of
  ``everything / d1`` over the detaching hits (how much more impulse breaks
  everything than detaches the first piece; ``+inf`` when a bond never breaks);
* ``b0_median``, ``d1_median``: medians of ``b0 / T`` and ``d1 / T`` over the
  hits that break a bond and the detaching hits (``None`` when ``T = 0``);
* ``hits``, ``breaking_hits``, ``detaching_hits``: how many hits there are, break
  a bond, detach something.

Percentiles use numpy's default (linear) definition: for sorted values ``a`` of
length ``n`` the ``q``-quantile is ``a[i] + f * (a[i + 1] - a[i])`` with
``i + f = q * (n - 1)``. Only ``+ - * /`` and ``sqrt`` reach the figures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fracture_cli.atlas.criterion import BreakingImpulses, modes_breaking_impulses
from fracture_cli.atlas.hits import analyse_hit, rest_groups
from fracture_cli.atlas.layout import FragmentLayout
from fracture_cli.atlas.leaves import StruckHit, leaves_at, struck_hit
from fracture_cli.runtime.format import RuntimeData

DEFAULT_SITES = 200
DOWN = np.array([0.0, -1.0, 0.0])
JUST_ABOVE = 1.0 + 1e-9  # "just above d1": the first detachment has happened, nothing else has
LOCALITY_FACTORS = (2.0, 8.0)


@dataclass(frozen=True)
class AtlasFigures:
    """The sweep's figures (module docstring); None where undefined."""

    hits: int
    breaking_hits: int
    detaching_hits: int
    hit_detached: float | None
    hit_on_largest: float | None
    hit_detached_others: float | None
    locality_2x: float | None
    locality_2x_median: float | None
    locality_2x_hits: int
    locality_8x: float | None
    locality_8x_median: float | None
    locality_8x_hits: int
    first_break_splits: float | None
    graded_median: float | None
    graded_p10: float | None
    b0_median: float | None
    d1_median: float | None


def farthest_point_sites(sites: np.ndarray, count: int) -> np.ndarray:
    """``count`` evenly spread site indices (ascending) by farthest-point sampling from site 0.

    Parameters
    ----------
    sites : (s, 3) float
    count : int
        How many; every site when ``count >= s``.

    Returns
    -------
    (min(count, s),) int64
    """
    points = np.asarray(sites, dtype=np.float64)
    s = len(points)
    if count >= s:
        return np.arange(s, dtype=np.int64)
    chosen = [0]
    nearest = np.full(s, np.inf)
    for _ in range(count - 1):
        delta = points - points[chosen[-1]]
        d2 = (delta[:, 0] * delta[:, 0] + delta[:, 1] * delta[:, 1]) + delta[:, 2] * delta[:, 2]
        np.minimum(nearest, d2, out=nearest)
        nearest[chosen[-1]] = -1.0  # never chosen twice, even among identical sites
        chosen.append(int(nearest.argmax()))  # first maximum: ties by the smallest index
    return np.sort(np.asarray(chosen, dtype=np.int64))


def inward_direction(point: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Unit vector (3,) from ``point`` towards ``center``; straight down if they coincide."""
    delta = np.asarray(center, dtype=np.float64) - point
    length = float(np.sqrt((delta[0] * delta[0] + delta[1] * delta[1]) + delta[2] * delta[2]))
    return delta / length if length > 0.0 else DOWN.copy()


def sweep_hits(data: RuntimeData, layout: FragmentLayout, sites: np.ndarray,
               criterion: BreakingImpulses = modes_breaking_impulses) -> tuple[StruckHit, ...]:
    """Analyse one inward hit at each of ``sites`` (indices), with the struck fragment's children where the file
    has levels (:mod:`fracture_cli.atlas.leaves`); see the module docstring."""
    center = layout.asset_center(data)
    points = np.asarray(data.sites, dtype=np.float64)
    child_layouts: dict[int, FragmentLayout] = {}
    return tuple(struck_hit(data, layout, analyse_hit(data, points[v], inward_direction(points[v], center),
                                                      criterion), criterion, child_layouts)
                 for v in np.asarray(sites).tolist())


def just_above(magnitude: float) -> float:
    """A magnitude just above ``magnitude`` (relative ``1e-9``; the smallest positive double above 0)."""
    return magnitude * JUST_ABOVE if magnitude > 0.0 else 5e-324


def quantile(values, q: float) -> float | None:
    """The ``q``-quantile by linear interpolation (module docstring); None for no values; inf-safe."""
    a = np.sort(np.asarray(values, dtype=np.float64))
    if len(a) == 0:
        return None
    position = q * (len(a) - 1)
    low = int(position)
    fraction = position - low
    if fraction == 0.0 or a[low] == a[min(low + 1, len(a) - 1)]:
        return float(a[low])
    return float(a[low] + fraction * (a[low + 1] - a[low]))


def locality(data: RuntimeData, layout: FragmentLayout, hit: StruckHit, magnitude: float,
             rest: np.ndarray) -> float | None:
    """Mean distance from the hit to the detached leaves over the mean to all leaves shown; None if none detach."""
    leaves = leaves_at(data, layout, hit, magnitude, rest)
    if leaves.centroids is None or not leaves.detached.any():
        return None
    delta = leaves.centroids - hit.hit.point
    distance = np.sqrt((delta[:, 0] * delta[:, 0] + delta[:, 1] * delta[:, 1]) + delta[:, 2] * delta[:, 2])
    overall = float(distance.mean())
    return float(distance[leaves.detached].mean()) / overall if overall > 0.0 else None


def _share(flags: list[bool]) -> float | None:
    return sum(flags) / len(flags) if flags else None


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def atlas_figures(data: RuntimeData, layout: FragmentLayout, hits: tuple[StruckHit, ...]) -> AtlasFigures:
    """The figures of a sweep (module docstring)."""
    rest = rest_groups(data)
    threshold = float(data.default_threshold)
    breaking = [h for h in hits if np.isfinite(h.b0)]
    detaching = [h for h in hits if np.isfinite(h.d1)]
    hit_flags, on_largest = [], []
    largest = int(np.argmax(layout.volumes))
    for h in detaching:
        leaves = leaves_at(data, layout, h, just_above(h.d1), rest)
        if h.struck is not None and leaves.struck is not None:
            hit_flags.append(bool(leaves.detached[leaves.struck]))
            on_largest.append(h.struck == largest)
    localities: dict[float, list[float]] = {}
    for factor in LOCALITY_FACTORS:
        values = [locality(data, layout, h, factor * h.b0, rest) for h in breaking]
        localities[factor] = [v for v in values if v is not None]
    graded = [h.everything / h.d1 for h in detaching if h.d1 > 0.0]
    per_threshold = threshold > 0.0
    return AtlasFigures(
        hits=len(hits), breaking_hits=len(breaking), detaching_hits=len(detaching),
        hit_detached=_share(hit_flags), hit_on_largest=_share(on_largest),
        hit_detached_others=_share([flag for flag, big in zip(hit_flags, on_largest) if not big]),
        locality_2x=_mean(localities[2.0]), locality_2x_median=quantile(localities[2.0], 0.5),
        locality_2x_hits=len(localities[2.0]),
        locality_8x=_mean(localities[8.0]), locality_8x_median=quantile(localities[8.0], 0.5),
        locality_8x_hits=len(localities[8.0]),
        first_break_splits=_share([h.d1 == h.b0 for h in breaking]),
        graded_median=quantile(graded, 0.5), graded_p10=quantile(graded, 0.1),
        b0_median=quantile([h.b0 / threshold for h in breaking], 0.5) if per_threshold else None,
        d1_median=quantile([h.d1 / threshold for h in detaching], 0.5) if per_threshold else None,
    )


def example_hits(hits: tuple[StruckHit, ...]) -> tuple[StruckHit, ...]:
    """Up to three detaching hits: the lowest, the median and the highest ``d1`` (ties by site, then order)."""
    detaching = sorted((h for h in hits if np.isfinite(h.d1)), key=lambda h: (h.d1, h.hit.site))
    if not detaching:
        return ()
    picks = sorted({0, (len(detaching) - 1) // 2, len(detaching) - 1})
    return tuple(detaching[i] for i in picks)
