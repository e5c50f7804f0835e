"""``run_atlas``: load a runtime file, sweep hits, summarize, gate, draw."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import numpy as np

from fracture_cli.atlas.criterion import criterion_named
from fracture_cli.atlas.hits import analyse_hit
from fracture_cli.atlas.layout import fragment_layout
from fracture_cli.atlas.leaves import StruckHit
from fracture_cli.atlas.summary import (
    SUMMARY_FORMAT,
    SUMMARY_VERSION,
    failed_requirements,
    figures_dict,
    parse_requirement,
    rounded,
    summary_json,
)
from fracture_cli.atlas.sweep import (
    DEFAULT_SITES,
    atlas_figures,
    example_hits,
    farthest_point_sites,
    inward_direction,
    sweep_hits,
)
from fracture_cli.errors import UsageError
from fracture_cli.runtime.format import JSON_SUFFIX, RuntimeData, load_runtime

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AtlasResult:
    """What :func:`run_atlas` found.

    Attributes
    ----------
    summary : dict
        The JSON summary (:func:`fracture_cli.atlas.summary.summary_json` prints it).
    failures : tuple of str
        The requirements that do not hold, one line each (empty: the gate passes).
    hits : tuple of StruckHit
        The sweep's hits, in site order (with the struck fragment's children's answer where the file has levels).
    png_path : str or None
        The PNG written, if any.
    """

    summary: dict
    failures: tuple[str, ...]
    hits: tuple[StruckHit, ...]
    png_path: str | None = None

    @property
    def passed(self) -> bool:
        """Whether every requirement holds."""
        return not self.failures

    def json(self) -> str:
        """The summary as deterministic JSON text."""
        return summary_json(self.summary)


def glb_beside(json_path: str | os.PathLike) -> str:
    """The fragments GLB of a runtime file: ``<stem>.glb`` next to ``<stem>.fracture.json``."""
    path = os.fspath(json_path)
    stem = path[: -len(JSON_SUFFIX)] if path.endswith(JSON_SUFFIX) else os.path.splitext(path)[0]
    return stem + ".glb"


def site_first_detachments(data: RuntimeData, center: np.ndarray, criterion_name: str = "modes") -> np.ndarray:
    """``d1`` (s,) of an inward hit at every contact site (the PNG's map); ``+inf`` where nothing detaches."""
    criterion = criterion_named(criterion_name)
    points = np.asarray(data.sites, dtype=np.float64)
    return np.array([analyse_hit(data, points[v], inward_direction(points[v], center), criterion).d1
                     for v in range(data.num_sites)])


def run_atlas(runtime_json_path: str | os.PathLike, *, sites: int = DEFAULT_SITES, require=(),
              png_path: str | os.PathLike | None = None, criterion: str = "modes") -> AtlasResult:
    """The break atlas of one baked asset.

    Parameters
    ----------
    runtime_json_path : path
        ``<stem>.fracture.json``; ``<stem>.glb`` beside it is used for fragment
        positions (only if the file has no game-ready arrays) and for the PNG.
    sites : int, optional (default 200)
        How many contact sites to hit (farthest-point sampling; every site if
        the file has fewer), >= 1.
    require : iterable of str, optional
        Requirements such as ``"hit_detached>=0.95"`` (:mod:`fracture_cli.atlas.summary`).
    png_path : path, optional (default None)
        Where to write the PNG (:mod:`fracture_cli.atlas.render`); none if None.
    criterion : str, optional (default "modes")
        Break criterion (:data:`fracture_cli.atlas.criterion.CRITERIA`).

    Returns
    -------
    AtlasResult
        Its ``summary`` holds, in this order: ``format`` (``"fracture-atlas"``), ``version``, ``runtime``
        (the file name), ``criterion``, ``threshold`` (``T``), ``counts``, ``hits`` (sampling), ``layout``
        (where fragment positions came from), ``figures`` (:mod:`fracture_cli.atlas.sweep`),
        ``examples`` (the lowest, median and highest ``d1`` hits: site, and ``b0``, ``d1``,
        ``everything`` divided by ``T``) and ``requirements`` (checked, failed).

    Raises
    ------
    RuntimeFileError
        The runtime file is missing, damaged or of an unknown version.
    UsageError
        ``sites`` < 1, a malformed requirement or an unknown key or criterion.
    """
    requirements = tuple(parse_requirement(text) for text in require)  # fail on a bad gate before any work
    if isinstance(sites, bool) or not isinstance(sites, (int, np.integer)) or sites < 1:
        raise UsageError(f"atlas: the number of sites must be a whole number >= 1, got {sites!r}")
    breaking = criterion_named(criterion)
    data = load_runtime(runtime_json_path)
    glb_path = glb_beside(runtime_json_path)
    layout = fragment_layout(data, glb_path)
    chosen = farthest_point_sites(data.sites, int(sites))
    hits = sweep_hits(data, layout, chosen, breaking)
    figures = figures_dict(atlas_figures(data, layout, hits))
    failures = failed_requirements(figures, requirements)
    threshold = float(data.default_threshold)
    examples = example_hits(hits)

    def relative(value: float) -> float | None:
        return rounded(value / threshold) if threshold > 0.0 else None

    summary = {
        "format": SUMMARY_FORMAT,
        "version": SUMMARY_VERSION,
        "runtime": os.path.basename(os.fspath(runtime_json_path)),
        "criterion": criterion,
        "threshold": rounded(threshold),
        "counts": {"sites": data.num_sites, "fragments": data.p, "edges": data.num_edges},
        "hits": {"sampling": "every site" if len(chosen) == data.num_sites else "farthest-point from site 0",
                 "requested": int(sites), "used": len(hits)},
        "layout": layout.source,
        "figures": figures,
        "examples": [{"site": h.hit.site, "b0": relative(h.b0), "d1": relative(h.d1),
                      "everything": relative(h.everything)} for h in examples],
        "requirements": {"checked": [str(r) for r in requirements], "failed": list(failures)},
    }
    written = None
    if png_path is not None:
        # on first use: the atlas loads the renderer only for a PNG
        from fracture_cli.atlas.render import render_atlas

        site_d1 = site_first_detachments(data, layout.asset_center(data), criterion)
        stem = os.path.basename(glb_path)[: -len(".glb")]
        title = (f"{stem}  |  break atlas, criterion {criterion}  |  {data.p} fragments, {data.num_edges} bonds, "
                 f"threshold T = {threshold:g}  |  bottom: what comes off at 2 x b0")
        render_atlas(data, layout, site_d1, tuple(h.hit for h in examples), png_path, glb_path=glb_path, title=title)
        written = os.fspath(png_path)
    for line in failures:
        log.info("atlas: requirement failed: %s", line)
    return AtlasResult(summary=summary, failures=failures, hits=hits, png_path=written)
