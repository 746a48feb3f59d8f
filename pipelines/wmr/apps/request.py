"""One run asked for, as the command line and the API ask for it: a frozen request checked when
made, that :func:`wmr.apps.run.resolve_run` turns into what the run needs.

``wmr run`` and :func:`wmr.run` build the same :class:`RunRequest` from their options and
keywords (the keywords are the options' names). Errors name a request's fields by their
keywords (``controller_fmu``, ``log_every``); the command line names them by its options
(``--controller-fmu``), translating the field of the error it is given: nothing below the
front doors knows which door it was called from.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from wmr.config.scenario import Overrides, PoseDeg
from wmr.infra.errors import ConfigError


@dataclass(frozen=True)
class RunRequest:
    """One closed-loop run of a scenario, as ``wmr run`` and :func:`wmr.run` ask for it.

    Attributes
    ----------
    scenario, run
        A scenario's name or file (default ``fig11``) and one of its runs by name.
    overrides
        What changes of that run (:class:`wmr.config.scenario.Overrides`, also importable
        from here).
    controller_fmu
        ``True``: the law in the built controller FMU; a path: in that FMU; ``False``: the
        Python law although the scenario names an FMU; ``None``: as the scenario says.
    fmi, fmu, fmu_map
        The project's FMI 2 or 3 build, or another robot FMU and its variable map (default:
        the scenario's).
    out
        The log (default ``runs/NAME.mcap``, named after the overrides).
    log, log_every
        The log policy (``full``, ``failed``, ``none``) and its every-K-steps thinning.
    view
        Show the run live in Rerun, saved as ``NAME.rrd`` beside the log.
    """

    scenario: str | Path | None = None
    run: str | None = None
    overrides: Overrides = field(default_factory=Overrides)
    controller_fmu: bool | str | Path | None = None
    fmi: int = 3
    fmu: str | Path | None = None
    fmu_map: str | Path | None = None
    out: str | Path | None = None
    log: str | None = None
    log_every: int | None = None
    view: bool = False

    def __post_init__(self) -> None:
        if self.fmi not in (2, 3) or isinstance(self.fmi, bool):
            raise ConfigError("fmi", f"must be 2 or 3, got {self.fmi!r}",
                              "give 3 (FMI 3.0, the default) or 2")


__all__ = ["Overrides", "PoseDeg", "RunRequest"]
