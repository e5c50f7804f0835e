"""The batch report: per asset status, seconds, fragment count and check results.

Written as ``<manifest stem>.batch.json`` and ``<manifest stem>.batch.md`` in
the output folder, and summarised as a plain-text table for the terminal.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

from fracture_cli import __version__
from fracture_cli.batch.jobs import BAKED, FAILED, STATUSES, UP_TO_DATE, TaskResult
from fracture_cli.batch.manifest import Asset
from fracture_cli.io.atomic import write_bytes_atomic


@dataclass(frozen=True)
class AssetOutcome:
    """One row of the report."""

    name: str
    recipe: str
    status: str
    out_dir: str
    seconds: float = 0.0
    fragments: int | None = None
    checks: dict = field(default_factory=dict)
    error: str | None = None
    detail: str = ""
    warnings: tuple[str, ...] = ()
    worker: str = ""


@dataclass(frozen=True)
class BatchReport:
    """The whole batch.

    Attributes
    ----------
    manifest, out_dir : str
    cluster : str
        ``local, N workers`` or the scheduler address.
    assets : tuple of AssetOutcome
        In batch order.
    seconds : float
        Wall-clock seconds of the whole batch.
    dataset : str or None
        The impacts file, when ``--impacts`` was given.
    dataset_rows : int
    interrupted : bool
        True when the batch was stopped before every asset finished.
    """

    manifest: str
    out_dir: str
    cluster: str
    assets: tuple[AssetOutcome, ...]
    seconds: float
    dataset: str | None = None
    dataset_rows: int = 0
    interrupted: bool = False

    def count(self, status: str) -> int:
        """Number of assets with ``status``."""
        return sum(a.status == status for a in self.assets)

    @property
    def failed(self) -> tuple[AssetOutcome, ...]:
        return tuple(a for a in self.assets if a.status == FAILED)


def asset_outcome(asset: Asset, result: TaskResult | None) -> AssetOutcome:
    """Merge an asset and its task result (None: never ran, the batch was interrupted)."""
    if result is None:
        return AssetOutcome(name=asset.name, recipe=asset.recipe.name, status=FAILED, out_dir=asset.out_dir,
                            error=f"{asset.path}: not run (the batch was interrupted)")
    report = result.report or {}
    return AssetOutcome(name=asset.name, recipe=asset.recipe.name, status=result.status, out_dir=asset.out_dir,
                        seconds=result.seconds, fragments=(report.get("counts") or {}).get("fragments"),
                        checks=dict(report.get("checks") or {}), error=result.error, detail=result.detail,
                        warnings=result.warnings,
                        worker=result.worker)


def checks_summary(checks: dict) -> str:
    """One short cell: failed boolean checks first, then the volume error."""
    if not checks:
        return ""
    failed = [k for k, v in sorted(checks.items()) if v is False]
    parts = [f"FAILED {', '.join(failed)}"] if failed else ["ok"]
    volume_error = checks.get("volume_error")
    if isinstance(volume_error, (int, float)) and math.isfinite(volume_error):
        parts.append(f"volume error {volume_error:.1e}")
    return "; ".join(parts)


def to_json(report: BatchReport) -> dict:
    """The report as plain data (what ``--json`` prints)."""
    return {
        "tool": "fracture", "version": __version__, "manifest": report.manifest, "out_dir": report.out_dir,
        "cluster": report.cluster, "seconds": round(report.seconds, 3), "interrupted": report.interrupted,
        "counts": {status: report.count(status) for status in STATUSES},
        "dataset": {"path": report.dataset, "rows": report.dataset_rows} if report.dataset else None,
        "assets": [{"name": a.name, "recipe": a.recipe, "status": a.status, "out_dir": a.out_dir,
                    "seconds": a.seconds, "fragments": a.fragments, "checks": a.checks, "error": a.error,
                    **({"detail": a.detail} if a.detail else {}), "warnings": list(a.warnings),
                    "worker": a.worker} for a in report.assets],
    }


def _cell(text: object) -> str:
    return str(text if text is not None else "").replace("|", "\\|").replace("\n", " ")


def _totals(report: BatchReport) -> str:
    baked = report.count(BAKED)
    rate = f", {baked / report.seconds * 60:.1f} baked per minute" if baked and report.seconds > 0 else ""
    stopped = " (interrupted)" if report.interrupted else ""
    return (f"{len(report.assets)} asset(s): {baked} baked, {report.count(UP_TO_DATE)} up to date, "
            f"{report.count(FAILED)} failed in {report.seconds:.1f} s{rate}{stopped}")


def to_markdown(report: BatchReport) -> str:
    """The report as a Markdown table."""
    lines = [f"# Batch {report.manifest}", "", f"- fracture {__version__}, {report.cluster}",
             f"- {_totals(report)}", f"- outputs: {report.out_dir}"]
    if report.dataset:
        lines.append(f"- impacts dataset: {report.dataset} ({report.dataset_rows} rows)")
    lines += ["", "| asset | recipe | status | seconds | fragments | checks | error |", "|---|---|---|---|---|---|---|"]
    for a in report.assets:
        lines.append(f"| {_cell(a.name)} | {_cell(a.recipe)} | {a.status} | {a.seconds:.1f} | {_cell(a.fragments)} "
                     f"| {_cell(checks_summary(a.checks))} | {_cell(a.error)} |")
    return "\n".join(lines) + "\n"


def summary_text(report: BatchReport) -> str:
    """The terminal summary: an aligned table, then every failure's one-line error."""
    rows = [("status", "asset", "recipe", "seconds", "fragments", "checks")]
    rows += [(a.status, a.name, a.recipe, f"{a.seconds:.1f}", str(a.fragments if a.fragments is not None else "-"),
              checks_summary(a.checks)) for a in report.assets]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in rows]
    lines += [f"failed: {a.name}: {a.error}" for a in report.failed]
    lines.append(_totals(report))
    return "\n".join(lines)


def write_report(report: BatchReport, json_path: str, markdown_path: str) -> None:
    """Write both report files atomically."""
    write_bytes_atomic(json_path, (json.dumps(to_json(report), indent=2, sort_keys=True) + "\n").encode())
    write_bytes_atomic(markdown_path, to_markdown(report).encode())
