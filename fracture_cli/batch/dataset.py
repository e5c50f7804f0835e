"""The impacts dataset: one Parquet file per batch.

Parquet (through pyarrow) rather than JSON lines: a dataset of many assets
times many impacts is read column-wise by pandas, polars, DuckDB or Hugging
Face ``datasets`` without parsing text, and the fixed-size ``point`` and
``impulse`` vectors and the ``groups`` lists keep their types. One row per
impact, rows in the batch's asset order and then impact order, so the same
batch gives the same rows. Columns:

==================  ============================  ===========================================
column              type                          meaning
==================  ============================  ===========================================
asset               string                        input path relative to the manifest
recipe              string                        recipe name
impact              int32                         impact index within the asset
point               fixed_size_list<double>[3]    hit point on the input surface, asset units
impulse             fixed_size_list<double>[3]    impulse vector
threshold           double                        toughness used (runtime file default)
breaking_impulse    double                        smallest breaking magnitude along the impulse
site                int32                         nearest contact site of the runtime file
broken_bonds        int32                         bonds broken
num_groups          int32                         groups of fragments after the hit
groups              list<int32>                   group of each fragment (``fragment_000`` ...)
==================  ============================  ===========================================
"""

from __future__ import annotations

import os

import numpy as np

from fracture_cli import __version__
from fracture_cli.batch.impacts import SPREAD, ImpactRows
from fracture_cli.errors import FractureError
from fracture_cli.io.atomic import atomic_path


def _pyarrow():
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise FractureError("--impacts writes Parquet and needs pyarrow; install it with "
                            "pip install 'fracture-cli[batch]'") from None
    return pyarrow


def require_pyarrow() -> None:
    """Fail before any work when ``--impacts`` is asked for without pyarrow."""
    _pyarrow()


def _vectors(pa, array: np.ndarray):
    return pa.FixedSizeListArray.from_arrays(pa.array(np.ascontiguousarray(array, dtype=np.float64).ravel()), 3)


def _table(pa, asset: str, recipe: str, rows: ImpactRows):
    n, p = rows.groups.shape
    groups = pa.ListArray.from_arrays(pa.array(np.arange(n + 1, dtype=np.int32) * p),
                                      pa.array(rows.groups.ravel(), type=pa.int32()))
    num_groups = (rows.groups == np.arange(p, dtype=np.int32)).sum(axis=1).astype(np.int32)
    return pa.table({
        "asset": pa.array([asset] * n, type=pa.string()),
        "recipe": pa.array([recipe] * n, type=pa.string()),
        "impact": pa.array(np.arange(n, dtype=np.int32)),
        "point": _vectors(pa, rows.points),
        "impulse": _vectors(pa, rows.impulses),
        "threshold": pa.array(np.full(n, rows.threshold)),
        "breaking_impulse": pa.array(rows.breaking),
        "site": pa.array(rows.sites.astype(np.int32)),
        "broken_bonds": pa.array(rows.broken_bonds.astype(np.int32)),
        "num_groups": pa.array(num_groups),
        "groups": groups,
    })


def write_impacts(path: str, assets: list[tuple[str, str, ImpactRows]], impacts_per_asset: int) -> int:
    """Write the dataset atomically.

    Parameters
    ----------
    path : str
        Output ``.parquet`` file.
    assets : list of (asset name, recipe name, ImpactRows)
        In batch order.
    impacts_per_asset : int
        Recorded in the file's metadata.

    Returns
    -------
    int
        Number of rows written.
    """
    pa = _pyarrow()
    tables = [_table(pa, name, recipe, rows) for name, recipe, rows in assets]
    if tables:
        table = pa.concat_tables(tables)
    else:
        table = _table(pa, "", "", ImpactRows(points=np.zeros((0, 3)), impulses=np.zeros((0, 3)), threshold=0.0,
                                                breaking=np.zeros(0), sites=np.zeros(0, np.int32),
                                                broken_bonds=np.zeros(0, np.int32), groups=np.zeros((0, 0), np.int32)))
    table = table.replace_schema_metadata({
        "fracture.version": __version__,
        "fracture.impacts_per_asset": str(impacts_per_asset),
        "fracture.sampling": f"seed = asset content hash; points uniform on the input surface; random direction; "
                             f"magnitude log-uniform in [m*/{SPREAD:g}, m* x {SPREAD:g}], m* = breaking_impulse",
    })
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with atomic_path(path) as tmp:
        pa.parquet.write_table(table, tmp)
    return table.num_rows
