"""Repair: the decision record, the warnings a user sees at the default verbosity, and report.json's list."""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from fracture_cli.stages.repair.records import RepairRecord
from fracture_cli.types import Normalization

log = logging.getLogger("fracture_cli.stages.repair")

# Repairs that change what the asset looks like or what it is made of: printed as warnings.
_WARNED = ("snapped_vertices", "removed_duplicate_faces", "removed_double_sided_faces", "flipped_winding",
           "split_nonmanifold_edges", "split_nonmanifold_vertices", "doubled_wall_faces", "removed_internal_faces",
           "detached_fins", "dropped_fins", "dropped_empty_bodies", "kept_bodies_apart")
# Lengths in a record's ``extra`` (normalized units, i.e. fractions of the diagonal).
_LENGTHS = ("thickness", "min_thickness")

SHELL_HINT = "to thicken it as a sheet instead: --set repair.open_surface=shell"
FILL_HINT = "to fill its holes instead: --set repair.open_surface=fill"
ERROR_HINT = "to refuse open inputs: --set repair.open_surface=error"


def describe(records: Sequence[RepairRecord], shell: bool) -> RepairRecord:
    """The ``decision`` record: solid or shell, and a one-line summary of the repairs."""
    done = [r.detail for r in records if r.what in _WARNED or r.what in ("unioned_bodies", "thickened_sheet")]
    filled = [r for r in records if r.what == "filled_hole"]
    if filled:
        done.insert(0, f"filled {len(filled)} hole(s)")
    decision = "shell" if shell else "solid"
    if shell:
        detail = "shell: open sheets thickened inward" + (f" ({'; '.join(done)})" if done else "")
    elif done:
        detail = f"solid after repair ({'; '.join(done)})"
    else:
        detail = "solid: closed as given"
    return RepairRecord("decision", detail, count=len(done), extra={"decision": decision})


def warn_significant(name: str, records: Sequence[RepairRecord]) -> None:
    """Log every repair that changes the asset as a warning (default verbosity), with its per-asset override."""
    planned = any(r.what == "open_surface" for r in records)
    for r in records:
        if r.what == "decision":
            continue
        if r.what in _WARNED:
            log.warning("repair: %s: %s", name, r.detail)
        elif r.what == "open_surface":
            filled = r.extra.get("action") == "fill"
            log.warning("repair: %s: %s (%s)", name, r.detail.replace(": fill:", ": filled:").replace(
                ": thicken:", ": thickened inward as a sheet:"), SHELL_HINT if filled else f"{FILL_HINT}; {ERROR_HINT}")
        elif r.what == "thickened_sheet" and not planned:
            log.warning("repair: %s: %s, %.3g of the diagonal thick (%s; %s)", name, r.detail,
                        r.extra.get("thickness", 0.0), FILL_HINT, ERROR_HINT)
        else:
            log.info("repair: %s: %s", name, r.detail)


def records_for_report(records: Sequence[RepairRecord], normalization: Normalization) -> list[dict]:
    """report.json ``repairs``: one dict per record, areas, positions and lengths in the input's units."""
    scale = normalization.scale
    out = []
    for r in records:
        d = r.to_dict()
        if "area" in d:
            d["area"] = float(f"{r.area * scale * scale:.9g}")
        if "where" in d:
            d["where"] = [float(f"{x:.9g}") for x in normalization.to_world(np.array([r.where], dtype=np.float64))[0]]
        for key in _LENGTHS:
            if key in r.extra:
                d[key] = float(f"{float(r.extra[key]) * scale:.9g}")
        out.append(d)
    return out
