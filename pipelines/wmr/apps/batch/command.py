"""What ``wmr batch`` and :func:`wmr.batch` both do: check the options, load the spec, run it.

The command line parses and calls :func:`batch_command` (or, for ``--check``,
:func:`load_checked`); the API calls the same functions, so that both give the same one-line
errors, naming the keywords (``max_runs``), which the command line names by its options
(``--max-runs``).
"""

from __future__ import annotations

import math
import os
import socket
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from wmr.apps.batch.runner import (
    DEFAULT_RUN_TIMEOUT_S,
    BatchOptions,
    BatchOutcome,
    run_batch,
)
from wmr.apps.batch.spec import MAX_RUNS, BatchSpec, load_batch
from wmr.infra.errors import ConfigError

#: Dask's address schemes.
_SCHEMES: Final = ("tcp", "tls", "ws", "wss", "ucx", "inproc")


def _warn(field: str, message: str) -> None:
    print(f"wmr: warning: {field}={message}", file=sys.stderr)


def check_scheduler(address: str, timeout_s: float = 3.0, field: str = "scheduler") -> str:
    """``address`` if it is a Dask scheduler address that answers, else a ConfigError.

    A TCP-like address (``tcp://HOST:PORT``, or ``HOST:PORT``) is tried with one connection
    of at most ``timeout_s`` s, so that a wrong address fails now and not after Dask's own
    connect timeout.  ``field`` names the input in the error.
    """
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    fix = "give e.g. tcp://127.0.0.1:8786 (the address 'dask scheduler' prints)"
    if scheme not in _SCHEMES:
        raise ConfigError(field, f"{address!r}: unknown scheme {scheme!r}", fix)
    if scheme in ("ucx", "inproc"):
        return address
    host, colon, port = rest.rpartition(":")
    if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(field, f"{address!r} is not HOST:PORT", fix)
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise ConfigError(field, f"no scheduler answers at {address} "
                          f"({exc.strerror or exc})",
                          "start one with 'dask scheduler', or check the address") from None
    return address


def load_checked(spec: str | Path, *, workers: int | None = None,
                 scheduler: str | None = None, run_timeout_s: float | None = None,
                 max_runs: int | None = None,
                 warn: Callable[[str, str], None] = _warn
                 ) -> tuple[BatchSpec, str | None, float | None]:
    """Check the options of a batch and load its spec (every run checked as
    :func:`~wmr.apps.batch.spec.load_batch` does); ``warn(field, message)`` is told of an
    input that runs as given but looks wrong (more workers than cores).

    Returns
    -------
    (BatchSpec, str or None, float or None)
        The spec, the scheduler's address (it answered), and the per-run wall-clock limit
        (``run_timeout_s`` None: the default, 0: none).

    Raises
    ------
    ConfigError
        A bad option (named by its keyword), or a bad spec.
    """
    from wmr.config.naming import plural

    if max_runs is not None and max_runs < 1:
        raise ConfigError("max_runs", f"must be >= 1, got {max_runs}",
                          "give e.g. max_runs=2000000")
    if scheduler is not None and workers is not None:
        raise ConfigError("workers", "has no effect with scheduler=ADDRESS",
                          "size the Dask cluster instead")
    limit_s = DEFAULT_RUN_TIMEOUT_S if run_timeout_s is None else run_timeout_s
    if not math.isfinite(limit_s) or limit_s < 0:
        raise ConfigError("run_timeout_s",
                          f"must be >= 0 s, got {run_timeout_s!r}",
                          "give a wall-clock limit in s, or 0 for none")
    if workers is not None:
        if workers < 1:
            raise ConfigError("workers", f"must be >= 1, got {workers}",
                              "give e.g. workers=2")
        cores = os.cpu_count() or 1
        if workers > cores:
            warn("workers", f"{workers} on {plural(cores, 'core')}: the runs share the cores "
                 "(no faster, more memory)")
    address = None if scheduler is None else check_scheduler(scheduler)
    batch = load_batch(spec, max_runs=MAX_RUNS if max_runs is None else max_runs)
    return batch, address, (limit_s if limit_s > 0 else None)


@dataclass(frozen=True)
class BatchRequest:
    """A batch, as ``wmr batch`` and :func:`wmr.batch` ask for it (their options and
    keywords, ``docs/batch.md``); errors name its fields.

    Attributes
    ----------
    spec, out
        The batch spec (name or TOML file) and its folder (default ``batches/<spec name>``).
    workers, scheduler
        Local worker processes, or the address of a Dask scheduler (not both).
    run_timeout_s, max_runs
        The wall-clock limit of a run (None: :data:`DEFAULT_RUN_TIMEOUT_S`, 0: none), and the
        most runs the spec may expand to.
    fmi, fmu, fmu_map
        The project's FMI 2 or 3 build, or another robot FMU and its variable map.
    log, log_every
        The log policy over the spec's ``[log]``.
    """

    spec: str | Path
    out: str | Path | None = None
    workers: int | None = None
    scheduler: str | None = None
    run_timeout_s: float | None = None
    max_runs: int | None = None
    fmi: int = 3
    fmu: str | Path | None = None
    fmu_map: str | Path | None = None
    log: str | None = None
    log_every: int | None = None


def batch_command(request: BatchRequest, progress: bool | None = None,
                  warn: Callable[[str, str], None] = _warn) -> tuple[Path, BatchOutcome]:
    """Check the request, load the spec and run the batch, as ``wmr batch`` and
    :func:`wmr.batch` do; ``progress`` is :func:`~wmr.apps.batch.runner.run_batch`'s,
    ``warn`` :func:`load_checked`'s.  Returns the batch folder and what
    :func:`~wmr.apps.batch.runner.run_batch` did.
    """
    from wmr.adapters.fmi.varmap import load_map
    from wmr.apps.run import log_policy
    from wmr.infra.outputs import check_output

    r = request
    batch, address, limit_s = load_checked(r.spec, workers=r.workers, scheduler=r.scheduler,
                                           run_timeout_s=r.run_timeout_s,
                                           max_runs=r.max_runs, warn=warn)
    folder = check_output(r.out if r.out else Path("batches") / Path(r.spec).stem, "out",
                          "dir")
    policy = log_policy(r.log, r.log_every, batch.log)
    options = BatchOptions(workers=r.workers, scheduler=address, run_timeout_s=limit_s,
                           fmu_path=r.fmu, fmi_version=r.fmi,
                           var_map=load_map(r.fmu_map) if r.fmu_map is not None else None,
                           log=policy)
    result = run_batch(batch, folder, options, progress=progress)
    return folder, result


__all__ = ["BatchRequest", "batch_command", "check_scheduler", "load_checked"]
