"""One run asked for, as the command line and the API ask for it: a frozen request checked when
made, that :func:`wmr.apps.run.resolve_run` turns into what the run needs.

``wmr run`` and :func:`wmr.run` build the same :class:`RunRequest` from their options and
keywords (the keywords are the options' names). Errors name a request's fields by their
keywords (``controller_fmu``, ``log_every``); the command line names them by its options
(``--controller-fmu``), translating the field of the error it is given: nothing below the
front doors knows which door it was called from.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from wmr.infra.errors import ConfigError

#: ``(x_m, y_m, heading_deg)``, as on the command line.
PoseDeg = tuple[float, float, float]


def _pose(value: Sequence[float] | None, name: str) -> PoseDeg | None:
    if value is None:
        return None
    if isinstance(value, str | bytes) or len(value) != 3:
        raise ConfigError(name, f"must be (x_m, y_m, heading_deg), got {value!r}",
                          "give three numbers: x and y in metres, the heading in degrees")
    return (float(value[0]), float(value[1]), float(value[2]))


def _by_name(value: Mapping[str, float] | None, name: str) -> dict[str, float] | None:
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise ConfigError(name, f"must map names to numbers, got {type(value).__name__}",
                          f"give e.g. {name}={{'NAME': VALUE}}")
    return dict(value)


@dataclass(frozen=True)
class Overrides:
    """What a request changes of its scenario's run; ``None`` keeps the scenario's.

    Attributes
    ----------
    start, goal
        ``(x_m, y_m, heading_deg)``.
    params, gains, limits
        Robot parameters, PI gains and limits by name.
    period_s, stop_radius_m, max_time_s
        The control period, the stop radius epsilon and the run's time limit, s and m.
    controller, controller_gains
        The controller by its registered name, and its own gains by name.
    sensors, sensor
        A sensor preset (``gps``, ``raw``) or ``off``, and fields of the ``[sensors]`` table
        over it (``docs/sensing.md``).
    """

    start: Sequence[float] | None = None
    goal: Sequence[float] | None = None
    params: Mapping[str, float] | None = None
    gains: Mapping[str, float] | None = None
    limits: Mapping[str, float] | None = None
    period_s: float | None = None
    stop_radius_m: float | None = None
    max_time_s: float | None = None
    controller: str | None = None
    controller_gains: Mapping[str, float] | None = None
    sensors: str | None = None
    sensor: Mapping[str, float | str] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", _pose(self.start, "start"))
        object.__setattr__(self, "goal", _pose(self.goal, "goal"))
        for name in ("params", "gains", "limits", "controller_gains"):
            object.__setattr__(self, name, _by_name(getattr(self, name), name))
        if self.sensor is not None and not isinstance(self.sensor, Mapping):
            raise ConfigError("sensor", f"must map [sensors] fields to values, got "
                              f"{type(self.sensor).__name__}",
                              "give e.g. sensor={'gps_sigma_m': 0.05}")
        for name in ("period_s", "stop_radius_m", "max_time_s"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool)
                                      or not isinstance(value, int | float)
                                      or not math.isfinite(value)):
                raise ConfigError(name, f"must be a finite number, got {value!r}",
                                  "give a number in the unit its name ends in")


@dataclass(frozen=True)
class RunRequest:
    """One closed-loop run of a scenario, as ``wmr run`` and :func:`wmr.run` ask for it.

    Attributes
    ----------
    scenario, run
        A scenario's name or file (default ``fig11``) and one of its runs by name.
    overrides
        What changes of that run (:class:`Overrides`).
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
