"""wmr-cosim: co-simulation and log analysis of a two-wheeled differential-drive robot.

The notebook API (``docs/api.md``), loaded on first use so that ``import wmr`` stays fast::

    wmr.load_scenario(name_or_path)  # a scenario, validated and expanded
    wmr.run(scenario, ...)           # one closed-loop run on the FMU, logged -> RunResult
    wmr.read_log(path)               # a log's signals (pandas DataFrame) and metadata -> Log
    wmr.batch(spec, out, ...)        # many runs; the summary as a DataFrame -> BatchResult
    wmr.optimal(start, goal, ...)    # the optimal manoeuvre, replayed and logged -> RunResult
    wmr.replay(logs, ...)            # run logs in Rerun (a viewer or an .rrd) -> ReplayResult

The package is layered, each layer importing only those below it (``docs/architecture.md``):
:mod:`wmr.infra` < :mod:`wmr.core` < :mod:`wmr.config` < :mod:`wmr.build` < :mod:`wmr.adapters`
< :mod:`wmr.apps` < :mod:`wmr.api` and :mod:`wmr.cli`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time __getattr__ loads wmr.api
    from wmr.api import (
        BatchResult,
        Log,
        RunResult,
        batch,
        load_scenario,
        optimal,
        read_log,
        replay,
        run,
    )

__all__ = ["BatchResult", "Log", "RunResult", "__version__", "batch", "load_scenario", "optimal",
           "read_log", "replay", "run"]

from wmr.infra.version import __version__

#: Names of the API (wmr.api) that ``import wmr`` offers without importing it.
_API = ("load_scenario", "run", "read_log", "batch", "optimal", "replay", "Log", "RunResult",
        "BatchResult")


def __getattr__(name: str) -> object:
    import importlib

    if name in _API:
        return getattr(importlib.import_module("wmr.api"), name)
    raise AttributeError(f"module 'wmr' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
