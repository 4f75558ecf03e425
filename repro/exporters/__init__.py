"""Exporters: what leaves the harness for other tools, apart from the rendered tables.

- :mod:`repro.exporters.samples`: stored samples as BVH or ``.npz`` (``repro export``);
- :mod:`repro.exporters.mlflow_runs`: run records as MLflow runs (``repro runs export
  --mlflow``), with :mod:`repro.exporters.mlflow_store` checking the target store first.

They read the engine's run records and the report's views; nothing in ``repro`` below the
CLI imports them (docs/engine.md, "Layers").
"""
