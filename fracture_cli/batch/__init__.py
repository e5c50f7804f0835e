"""Batch baking on Dask: a manifest of assets, one task per asset, incremental.

``fracture batch MANIFEST -o OUTDIR`` (see :mod:`fracture_cli.cli.batch`)
calls :func:`~fracture_cli.batch.runner.run_batch`. One concern per module:

* :mod:`~fracture_cli.batch.manifest`: the TOML manifest, globs, recipes per entry;
* :mod:`~fracture_cli.batch.inputs`, :mod:`~fracture_cli.batch.state`: input hashes and the
  per-asset state that makes re-runs incremental;
* :mod:`~fracture_cli.batch.plan`: what to bake, refusing outputs that overwrite inputs;
* :mod:`~fracture_cli.batch.cluster`, :mod:`~fracture_cli.batch.execute`,
  :mod:`~fracture_cli.batch.task`, :mod:`~fracture_cli.batch.child`: Dask, one
  killable bake process per task;
* :mod:`~fracture_cli.batch.adapter`: the only caller of the bake API;
* :mod:`~fracture_cli.batch.impacts`, :mod:`~fracture_cli.batch.dataset`: ``--impacts`` (Parquet);
* :mod:`~fracture_cli.batch.report`: what the user reads (progress goes through
  :mod:`fracture_cli.system.progress`, like a bake's).

Dask and pyarrow come from the ``batch`` extra (``pip install 'fracture-cli[batch]'``)
and are imported only when a batch runs.
"""
