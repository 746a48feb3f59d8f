"""wmr-cosim: co-simulation and log analysis of a two-wheeled differential-drive robot.

The notebook API (``docs/api.md``), loaded on first use so that ``import wmr`` stays fast::

    wmr.load_scenario(name_or_path)  # a scenario, validated and expanded
    wmr.run(scenario, ...)           # one closed-loop run on the FMU, logged -> RunResult
    wmr.read_log(path)               # a log's signals (pandas DataFrame) and metadata -> Log
    wmr.batch(spec, out, ...)        # many runs; the summary as a DataFrame -> BatchResult
    wmr.optimal(start, goal, ...)    # the optimal manoeuvre, replayed and logged -> RunResult

``wmr.run``, ``wmr.batch`` and ``wmr.optimal`` are also the modules of those names (the
library's); calling them calls the API function (:mod:`wmr._callable`).
"""

from __future__ import annotations

__version__ = "0.1.0"

#: Names of the API (wmr.api) that ``import wmr`` offers without importing it.
_API = ("load_scenario", "read_log", "Log", "RunResult", "BatchResult")
#: API functions that share their name with a module of the package (made callable).
_CALLABLE_MODULES = ("run", "batch", "optimal")


def __getattr__(name: str) -> object:
    import importlib

    if name in _API:
        return getattr(importlib.import_module("wmr.api"), name)
    if name in _CALLABLE_MODULES:
        return importlib.import_module(f"wmr.{name}")
    raise AttributeError(f"module 'wmr' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API, *_CALLABLE_MODULES])
