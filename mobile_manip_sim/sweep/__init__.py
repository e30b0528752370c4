"""Sweeps: thousands of runs of one scene with varied keys, on a Dask cluster.

spec (the sweep file; its keys set in the scene document by `scene_overrides`, validated by the
scene parser) → runner (one run on a worker, `headless.run` as `simulate` runs it) → results
(runs.parquet, resumable) → report (REPORT.md and its plots); cli ties them together. Only runner
and cli import Dask.
"""
