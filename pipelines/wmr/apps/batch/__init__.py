"""Batches of closed-loop runs: sweeps, explicit variants and Monte Carlo, locally or on Dask.

* :mod:`wmr.apps.batch.spec`: the spec file (a scenario plus ``[grid]``, ``[[list]]``, ``[random]``)
  expanded into runs with stable ids;
* :mod:`wmr.apps.batch.runner`: :func:`run_batch`, resumable, writing ``OUT/summary.parquet``;
* :mod:`wmr.apps.batch.local` and :mod:`wmr.apps.batch.dask_exec`: the two executors;
* :mod:`wmr.apps.batch.report`: ``wmr report``, the summary as Markdown and plots.

See ``docs/batch.md``.
"""

from __future__ import annotations

from wmr.apps.batch.runner import DEFAULT_RUN_TIMEOUT_S, BatchOptions, BatchOutcome, run_batch
from wmr.apps.batch.spec import BatchRun, BatchSpec, load_batch, parse_batch, spec_digest
from wmr.apps.batch.summary import read_summary

__all__ = [
    "DEFAULT_RUN_TIMEOUT_S",
    "BatchOptions",
    "BatchOutcome",
    "BatchRun",
    "BatchSpec",
    "load_batch",
    "parse_batch",
    "read_summary",
    "run_batch",
    "spec_digest",
]


