"""What one closed-loop run needs: :class:`RunSpec`, validated when it is made.

The scenario files (:mod:`wmr.config.scenario`) expand into run specs; the closed loop
(:mod:`wmr.core.closedloop`) runs one.  Every error is a :class:`~wmr.infra.errors.ConfigError`
that names the field of the scenario file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from wmr.core.control.registry import check_gains
from wmr.core.control.stabiliser import Gains, Limits
from wmr.core.plant import Pose, RobotParams
from wmr.core.sensing.config import SensorConfig
from wmr.infra.errors import ConfigError

DEFAULT_PERIOD_S = 0.01
DEFAULT_STOP_RADIUS_M = 0.05
DEFAULT_HEADING_TOLERANCE_DEG = 0.5
DEFAULT_MAX_TIME_S = 120.0
#: Upper bound on the number of control steps of one run (keeps a typo from hanging a run).
MAX_STEPS = 10_000_000


@dataclass(frozen=True)
class RunSpec:
    """Everything one closed-loop run needs.  Angles in rad, SI units."""

    name: str
    start: Pose
    goal: Pose
    params: RobotParams = field(default_factory=RobotParams)
    gains: Gains = field(default_factory=Gains)
    limits: Limits = field(default_factory=Limits)
    period_s: float = DEFAULT_PERIOD_S
    stop_radius_m: float = DEFAULT_STOP_RADIUS_M
    t_max_s: float = DEFAULT_MAX_TIME_S
    heading_tolerance_rad: float = math.radians(DEFAULT_HEADING_TOLERANCE_DEG)
    scenario: str = ""
    #: A name of :mod:`wmr.core.control.registry`: ``pi`` (the paper's), ``astolfi``,
    #: ``graceful`` or an installed plug-in's.
    controller: str = "pi"
    #: The controller's own gains as ``(name, value)`` pairs; empty: its defaults.
    controller_gains: tuple[tuple[str, float], ...] = ()
    #: ``None``: the Python controller; ``""``: the built controller FMU; else its path.
    controller_fmu: str | None = None
    #: The sensors and estimator (:mod:`wmr.core.sensing`); ``None``: perfect state feedback.
    sensors: SensorConfig | None = None

    def __post_init__(self) -> None:
        check_gains(self.controller, dict(self.controller_gains))
        if self.sensors is not None:
            self.sensors.check(self.period_s)
        check_positive("control_period_s", self.period_s)
        check_positive("stop_radius_m", self.stop_radius_m)
        check_positive("max_time_s", self.t_max_s)
        check_positive("heading_tolerance_deg", self.heading_tolerance_rad)
        if self.t_max_s < self.period_s:
            raise ConfigError("max_time_s", f"{self.t_max_s!r} s is shorter than one control "
                              f"period ({self.period_s!r} s)", "give a longer max_time_s")
        if self.t_max_s / self.period_s > MAX_STEPS:
            raise ConfigError("max_time_s", f"{self.t_max_s / self.period_s:.3g} control steps "
                              f"is more than {MAX_STEPS}",
                              "shorten max_time_s or lengthen control_period_s")
        for label, pose in (("start", self.start), ("goal", self.goal)):
            for f in fields(pose):
                check_finite(f"{label}.{f.name}", getattr(pose, f.name))
        _check_sanity(self)

    @property
    def n_steps_max(self) -> int:
        """Number of control periods in ``t_max_s`` (rounded to the nearest step)."""
        return max(1, round(self.t_max_s / self.period_s))


def _check_sanity(spec: RunSpec) -> None:
    """Refuse settings that are valid numbers but cannot give a meaningful run.

    * The period against the wheel servos: seen from a wheel the robot is an inertia J
      (``docs/control.md``: the smaller of the common mode r^2 M11 / 2 and the differential
      mode r^2 M22 / (2 L^2)); the sampled P loop of gain K_pw on it is stable only for
      K_pw h / J < 2.
    * The stop radius against the trip: a radius that reaches the start makes the run
      "converge" where it stands.
    """
    from wmr.core.physics import mass_matrix_diag

    p = spec.params
    for name in ("r", "L", "l"):  # lengths whose squares eq. 24 and eq. 28 take
        value = getattr(p, name)
        if not math.isfinite(value * value):
            raise ConfigError(f"params.{name}", f"{value:g} m is too large: its square "
                              "overflows (inf) in the mass matrix of eq. 24",
                              f"give {name} in metres, e.g. {getattr(RobotParams(), name):g}")
    m11, m22 = mass_matrix_diag(p)
    j_min = min(p.r * p.r * m11 / 2.0, p.r * p.r * m22 / (2.0 * p.L * p.L))
    if not all(math.isfinite(x) for x in (m11, m22, j_min)):
        name = _most_extreme(p)
        raise ConfigError(f"params.{name}", f"{getattr(p, name):g} overflows the mass matrix "
                          f"of eq. 24 (M11 = {m11:g} kg, M22 = {m22:g} kg m^2, wheel inertia "
                          f"{j_min:g} kg m^2)", f"give {name} in SI units, e.g. "
                          f"{getattr(RobotParams(), name):g}")
    if m22 <= 0.0:
        raise ConfigError("params.Ig", "the platform has no inertia about its vertical axis "
                          "(Ig + m l^2 + 2 L^2 Iwm / r^2 = 0): the mass matrix of eq. 24 is "
                          "singular", "give Ig > 0")
    loop = spec.gains.K_pw * spec.period_s / j_min
    if loop >= 2.0:
        raise ConfigError("control_period_s",
                          f"{spec.period_s:g} s is too long for the wheel servos: K_pw h / J = "
                          f"{loop:.3g} >= 2 (K_pw = {spec.gains.K_pw:g} N m s/rad, wheel "
                          f"inertia J = {j_min:.3g} kg m^2) makes the sampled servo unstable",
                          f"give a period below {2.0 * j_min / spec.gains.K_pw:.3g} s, or a "
                          "smaller K_pw")
    distance = math.hypot(spec.goal.x_m - spec.start.x_m, spec.goal.y_m - spec.start.y_m)
    if spec.stop_radius_m > DEFAULT_STOP_RADIUS_M and spec.stop_radius_m >= distance > 0.0:
        raise ConfigError("stop_radius_m",
                          f"{spec.stop_radius_m:g} m reaches the start, {distance:.3g} m from "
                          "the goal: the run would count as converged where it stands",
                          f"give a stop radius below {distance:.3g} m (default "
                          f"{DEFAULT_STOP_RADIUS_M:g})")


def _most_extreme(params: RobotParams) -> str:
    """The parameter furthest from its default, in orders of magnitude (the likeliest cause of
    an overflow that several parameters share)."""
    default = RobotParams()

    def distance(name: str) -> float:
        value, ref = getattr(params, name), getattr(default, name)
        return abs(math.log10(value / ref)) if value > 0.0 and ref > 0.0 else 0.0

    return max(("m", "r", "L", "l", "Ig", "Iwm"), key=distance)


def check_finite(field: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(field, f"must be a number, got {value!r}", "write a plain number")
    if not math.isfinite(value):
        raise ConfigError(field, f"must be finite, got {value!r}",
                          "replace nan/inf by a finite number")
    return float(value)


def check_positive(field: str, value: object) -> float:
    v = check_finite(field, value)
    if v <= 0.0:
        raise ConfigError(field, f"must be > 0, got {value!r}", "give a positive value")
    return v


__all__ = [
    "DEFAULT_HEADING_TOLERANCE_DEG",
    "DEFAULT_MAX_TIME_S",
    "DEFAULT_PERIOD_S",
    "DEFAULT_STOP_RADIUS_M",
    "MAX_STEPS",
    "RunSpec",
    "check_finite",
    "check_positive",
]
