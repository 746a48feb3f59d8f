"""The ``[sensors]`` table of a scenario: what the stabiliser is told instead of the truth.

::

    [sensors]                          # absent: perfect state feedback (the default)
    estimator = "ekf"                  # "none": raw latest fixes; "ekf": odometry + fixes
    seed = 0                           # with the start and goal, seeds every noise stream
    gps_rate_hz = 10.0                 # position fix rate
    gps_latency_s = 0.05               # from measurement to arrival (rounded up to a step)
    gps_sigma_m = 0.02                 # white noise per axis, 1 sigma
    gps_bias_walk_m_per_sqrt_s = 0.0   # bias random walk per axis: its sigma grows as sqrt(t)
    gps_dropout_probability = 0.0      # each fix lost with this probability
    gps_dropout_windows = [[20.0, 25.0]]   # no fix measured in these [t0, t1] s (scenario only)
    heading = "none"                   # "compass", or "none" (then the EKF estimates it)
    compass_sigma_deg = 1.0
    compass_rate_hz = 10.0
    compass_latency_s = 0.0
    encoder_counts_per_rev = 4096      # wheel encoder quantisation; 0: exact angles
    encoder_rate_hz = 100.0            # at most the control rate; 0: the control rate
    odometry_noise_m2_per_m = 1e-4     # the EKF's odometry noise: variance per metre rolled
    wheel_radius_error_frac = 0.0      # the estimator's wheel radius is r (1 + this): odometry
                                       # scale error, as a tyre worn or inflated differently
    initial_heading_sigma_deg = 1.0    # how well the start heading is known (no compass)

Every numeric field is also a batch field (``[grid.sensors]``, ``[[list]] sensors = {...}``,
``[random.sensors]``); ``estimator`` and ``heading`` take their names in ``[grid]`` and
``[[list]]``.  Every error is a :class:`~wmr.infra.errors.ConfigError` naming the field.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any, Final

from wmr.infra.errors import ConfigError

#: ``estimator`` values.
ESTIMATORS: Final = ("none", "ekf")
#: ``heading`` values.
HEADINGS: Final = ("compass", "none")
#: Fields whose value is a name, not a number.
NAME_FIELDS: Final = ("estimator", "heading")
#: ``wmr run --sensors PRESET``: a named ``[sensors]`` table.
PRESETS: Final[dict[str, dict[str, Any]]] = {
    # the reference receiver: 2 cm, 10 Hz, 50 ms; no compass; 4096-count encoders
    "gps": {"estimator": "ekf", "gps_rate_hz": 10.0, "gps_latency_s": 0.05,
            "gps_sigma_m": 0.02, "heading": "none", "encoder_counts_per_rev": 4096.0},
    # the same fixes fed raw to the stabiliser, heading from a 1 deg compass
    "raw": {"estimator": "none", "gps_rate_hz": 10.0, "gps_latency_s": 0.05,
            "gps_sigma_m": 0.02, "heading": "compass", "compass_sigma_deg": 1.0,
            "compass_rate_hz": 10.0, "compass_latency_s": 0.05,
            "encoder_counts_per_rev": 4096.0},
}


@dataclass(frozen=True)
class SensorConfig:
    """The sensors between plant and stabiliser, and the estimator; SI units, angles in deg.

    Validated on construction (except the rates against the control rate: see :meth:`check`).
    """

    estimator: str = "none"
    seed: int = 0
    gps_rate_hz: float = 10.0
    gps_latency_s: float = 0.0
    gps_sigma_m: float = 0.0
    gps_bias_walk_m_per_sqrt_s: float = 0.0
    gps_dropout_probability: float = 0.0
    gps_dropout_windows: tuple[tuple[float, float], ...] = ()
    heading: str = "compass"
    compass_sigma_deg: float = 0.0
    compass_rate_hz: float = 10.0
    compass_latency_s: float = 0.0
    encoder_counts_per_rev: float = 0.0
    encoder_rate_hz: float = 0.0
    odometry_noise_m2_per_m: float = 1e-4
    wheel_radius_error_frac: float = 0.0
    initial_heading_sigma_deg: float = 1.0

    def __post_init__(self) -> None:
        for name, allowed in (("estimator", ESTIMATORS), ("heading", HEADINGS)):
            value = getattr(self, name)
            if value not in allowed:
                raise ConfigError(f"sensors.{name}", f"unknown value {value!r}",
                                  f"use one of: {', '.join(allowed)}")
        if self.estimator == "none" and self.heading == "none":
            raise ConfigError("sensors.heading", 'is "none" but estimator = "none" has no '
                              "other source of heading", 'use heading = "compass" or '
                              'estimator = "ekf"')
        seed = self.seed
        if isinstance(seed, float) and math.isfinite(seed) and seed == round(seed):
            object.__setattr__(self, "seed", int(seed))
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError("sensors.seed", f"must be a non-negative integer, got {seed!r}",
                              "write e.g. seed = 1")
        for f in fields(self):
            if f.name in (*NAME_FIELDS, "seed", "gps_dropout_windows"):
                continue
            if f.name == "wheel_radius_error_frac":
                _finite_fraction(self.wheel_radius_error_frac)
                continue
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float) \
                    or not math.isfinite(value):
                raise ConfigError(f"sensors.{f.name}", f"must be a finite number, got {value!r}",
                                  "write a plain number")
            if value < 0.0:
                raise ConfigError(f"sensors.{f.name}", f"must be >= 0, got {value!r}",
                                  "give a non-negative value")
        for name in ("gps_rate_hz", "compass_rate_hz"):
            if getattr(self, name) <= 0.0:
                raise ConfigError(f"sensors.{name}", f"must be > 0, got {getattr(self, name)!r}",
                                  "give a rate in Hz")
        if self.gps_dropout_probability >= 1.0:
            raise ConfigError("sensors.gps_dropout_probability",
                              f"must be < 1, got {self.gps_dropout_probability!r}",
                              "give a probability in [0, 1)")
        if not math.isclose(self.encoder_counts_per_rev, round(self.encoder_counts_per_rev),
                            rel_tol=0.0, abs_tol=0.0):
            raise ConfigError("sensors.encoder_counts_per_rev",
                              f"must be a whole number, got {self.encoder_counts_per_rev!r}",
                              "write e.g. 4096 (0: exact angles)")
        object.__setattr__(self, "gps_dropout_windows",
                           _windows(self.gps_dropout_windows))

    def check(self, period_s: float) -> None:
        """Check the sample rates against the control period ``period_s`` (s).

        Raises
        ------
        ConfigError
            A rate above the control rate (a sensor cannot report more often than the
            stabiliser runs in this master).
        """
        control_hz = 1.0 / period_s
        for name in ("gps_rate_hz", "compass_rate_hz", "encoder_rate_hz"):
            rate = getattr(self, name)
            if rate > control_hz * (1.0 + 1e-9):
                raise ConfigError(f"sensors.{name}", f"{rate!r} Hz is above the control rate "
                                  f"({control_hz:g} Hz)", f"give at most {control_hz:g} Hz")

    def encoder_hz(self, period_s: float) -> float:
        """The encoder rate, Hz (``0`` means the control rate)."""
        return self.encoder_rate_hz or 1.0 / period_s

    def as_dict(self) -> dict[str, Any]:
        """Field -> value (windows as lists), for the log's ``run`` record."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["gps_dropout_windows"] = [list(w) for w in self.gps_dropout_windows]
        return d


def _finite_fraction(value: object) -> None:
    where = "sensors.wheel_radius_error_frac"
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(where, f"must be a finite number, got {value!r}",
                          "write a plain number")
    if not -0.5 < value < 0.5:
        raise ConfigError(where, f"must be within (-0.5, 0.5), got {value!r}",
                          "give a relative error, e.g. 0.01 for 1 %")


def _windows(value: object) -> tuple[tuple[float, float], ...]:
    where = "sensors.gps_dropout_windows"
    if not isinstance(value, list | tuple):
        raise ConfigError(where, f"must be a list of [t0_s, t1_s], got {value!r}",
                          "write e.g. [[20.0, 25.0]]")
    out: list[tuple[float, float]] = []
    for i, w in enumerate(value):
        if not isinstance(w, list | tuple) or len(w) != 2 or not all(
                isinstance(t, int | float) and not isinstance(t, bool) and math.isfinite(t)
                for t in w) or not 0.0 <= w[0] <= w[1]:
            raise ConfigError(f"{where}[{i}]", f"must be [t0_s, t1_s] with 0 <= t0 <= t1, "
                              f"got {w!r}", "write e.g. [20.0, 25.0]")
        out.append((float(w[0]), float(w[1])))
    return tuple(out)


def sensor_config(values: Mapping[str, Any], base: SensorConfig | None = None) -> SensorConfig:
    """A :class:`SensorConfig` from a ``[sensors]`` table (or overrides of ``base``).

    Raises
    ------
    ConfigError
        An unknown field, a wrong type or a value out of range, naming ``sensors.<field>``.
    """
    allowed = tuple(f.name for f in fields(SensorConfig))
    for key, value in values.items():
        if key not in allowed:
            raise ConfigError(f"sensors.{key}", "unknown field",
                              f"allowed fields: {', '.join(allowed)}")
        if key in NAME_FIELDS and not isinstance(value, str):
            example = ESTIMATORS[1] if key == "estimator" else HEADINGS[0]
            raise ConfigError(f"sensors.{key}", f"must be a name, got {value!r}",
                              f'write e.g. {key} = "{example}"')
    return replace(base or SensorConfig(), **values)


def preset(name: str) -> SensorConfig:
    """The ``[sensors]`` table named ``name`` (:data:`PRESETS`)."""
    if name not in PRESETS:
        raise ConfigError("sensors", f"unknown preset {name!r}",
                          f"use one of: {', '.join(PRESETS)}")
    return SensorConfig(**PRESETS[name])


def override_sensors(current: SensorConfig | None, preset_name: str | None,
                     items: list[str] | None) -> SensorConfig | None:
    """A run's sensors with a preset (``sensors``: ``wmr run --sensors PRESET|off``) and
    fields (``sensor``: ``--sensor NAME=VALUE``) over them; errors name ``sensors`` and
    ``sensor`` (``sensor NAME`` for one field's value).

    ``off`` removes them (perfect state feedback); a preset replaces them; each ``NAME=VALUE``
    then replaces one field (of the defaults when the run has no sensors).
    """
    cfg = current
    if preset_name == "off":
        cfg = None
    elif preset_name is not None:
        cfg = preset(preset_name)
    values: dict[str, Any] = {}
    for item in items or []:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ConfigError("sensor", f"{item!r} is not NAME=VALUE",
                              "e.g. sensor=gps_sigma_m=0.05")
        if name in NAME_FIELDS:
            values[name] = text.strip()
            continue
        try:
            values[name] = float(text)
        except ValueError:
            raise ConfigError(f"sensor {name}", f"{text!r} is not a number",
                              "give a plain number") from None
    return sensor_config(values, cfg) if values else cfg


__all__ = ["ESTIMATORS", "HEADINGS", "NAME_FIELDS", "PRESETS", "SensorConfig",
           "override_sensors", "preset", "sensor_config"]
