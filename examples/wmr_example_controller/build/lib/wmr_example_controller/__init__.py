r"""A proportional "turn then drive" point stabiliser for wmr, plugged in by an entry point.

Three phases, each a proportional law on the platform rates :math:`(v, \omega)`:

1. **turn**: in place towards the goal, :math:`v = 0`, :math:`\omega = k_\omega e`, with
   :math:`e = \mathrm{wrap}(\mathrm{atan2}(\Delta y, \Delta x) - \theta)` the bearing error,
   until :math:`|e| \le` ``turn_tolerance_rad``;
2. **drive**: :math:`v = k_v \Delta r \cos e` (never backwards), :math:`\omega = k_\omega e`;
3. **align**: inside half the stop radius, turn to the goal heading,
   :math:`\omega = k_\omega\,\mathrm{wrap}(\theta_d - \theta)`, while
   :math:`v = k_v (\Delta x \cos\theta + \Delta y \sin\theta)` holds the robot on the goal;
   back to the turn if it is pushed out of twice the stop radius.

:math:`(v, \omega)` are clipped to the run's command limits and turned into the two wheel speed
references (:math:`\omega_{r,l} = (v \pm L\omega)/r`, scaled together to the wheel speed
limit), which wmr's wheel servos track: wmr puts every registered law on the same servos.

The law fills seven of wmr's signals (:data:`SIGNALS`); wmr logs the others as NaN.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

from wmr.core.control.registry import ControllerInfo, Gain
from wmr.core.control.stabiliser import wrap_angle

if TYPE_CHECKING:
    from wmr.core.runspec import RunSpec

TURN, DRIVE, ALIGN = 0, 2, 1  # ALIGN = 1: wmr's scene draws phase 1 as the final alignment
#: wmr's at-rest thresholds of a converged run (wmr.core.control.stabiliser).
V_REST_MPS, OMEGA_REST_RADPS = 0.01, 0.02

#: What :meth:`TurnThenDrive.update` returns, in this order (names of wmr.core.signals).
SIGNALS = ("dr_m", "e_s_m", "e_theta_rad", "alpha_rad", "u_s_mps", "u_theta_radps",
           "omega_r_ref_radps", "omega_l_ref_radps")


class TurnThenDrive:
    """The law of one run: pose in, the :data:`SIGNALS` out (a wmr ``Stabiliser``)."""

    def __init__(self, spec: RunSpec, gains: Mapping[str, float]) -> None:
        self.xd, self.yd, self.theta_d = spec.goal.x_m, spec.goal.y_m, spec.goal.heading_rad
        self.k_v, self.k_w = gains["k_v"], gains["k_w"]
        self.turn_tolerance = gains["turn_tolerance_rad"]
        self.v_max, self.w_max = spec.limits.v_max_mps, spec.limits.omega_max_radps
        self.wheel_max = spec.limits.wheel_speed_max_radps
        self.r, self.L = spec.params.r, spec.params.L
        self.eps = spec.stop_radius_m
        self.phase = TURN

    def reset(self) -> None:
        self.phase = TURN

    def update(self, x: float, y: float, theta: float) -> tuple[float, ...]:
        dx, dy = self.xd - x, self.yd - y
        dr = math.hypot(dx, dy)
        if self.phase != ALIGN and dr <= 0.5 * self.eps:
            self.phase = ALIGN
        elif self.phase == ALIGN and dr > 2.0 * self.eps:
            self.phase = TURN
        bearing = math.atan2(dy, dx)
        if self.phase == ALIGN:
            e = wrap_angle(self.theta_d - theta)
            e_s = dx * math.cos(theta) + dy * math.sin(theta)
            v = self.k_v * e_s
        else:
            e = wrap_angle(bearing - theta)
            if self.phase == TURN and abs(e) <= self.turn_tolerance:
                self.phase = DRIVE
            e_s = dr * math.cos(e)
            v = self.k_v * max(e_s, 0.0) if self.phase == DRIVE else 0.0
        w = self.k_w * e
        v = min(max(v, -self.v_max), self.v_max)
        w = min(max(w, -self.w_max), self.w_max)
        w_r, w_l = (v + self.L * w) / self.r, (v - self.L * w) / self.r
        peak = max(abs(w_r), abs(w_l))
        if peak > self.wheel_max:
            w_r, w_l = w_r * self.wheel_max / peak, w_l * self.wheel_max / peak
        return dr, e_s, e, bearing, v, w, w_r, w_l

    def converged(self, x: float, y: float, theta: float, v: float, omega: float,
                  heading_tolerance_rad: float) -> bool:
        """Aligning, inside the stop radius, heading within tolerance, at rest."""
        return (self.phase == ALIGN and math.hypot(self.xd - x, self.yd - y) <= self.eps
                and abs(wrap_angle(theta - self.theta_d)) <= heading_tolerance_rad
                and abs(v) <= V_REST_MPS and abs(omega) <= OMEGA_REST_RADPS)

    def heading_error(self, theta: float) -> float:
        return wrap_angle(theta - self.theta_d)


def _check(gains: Mapping[str, float]) -> None:
    from wmr.infra.errors import ConfigError

    for name in ("k_v", "k_w", "turn_tolerance_rad"):
        if gains[name] <= 0.0:
            raise ConfigError(f"controller_gains.{name}", f"must be > 0, got {gains[name]!r}",
                              "give a positive value")


#: The declaration wmr finds through the entry point ``turn-then-drive`` (pyproject.toml).
CONTROLLER = ControllerInfo(
    name="turn-then-drive",
    summary="turn in place towards the goal, drive to it, turn to its heading (proportional)",
    make=TurnThenDrive,
    gains=(Gain("k_v", 0.5, "1/s", (0.05, 5.0), "speed per metre to the goal"),
           Gain("k_w", 2.0, "1/s", (0.2, 20.0), "turn rate per radian of heading error"),
           Gain("turn_tolerance_rad", 0.1, "rad", None, "bearing error at which it drives")),
    signals=SIGNALS,
    check=_check,
)
