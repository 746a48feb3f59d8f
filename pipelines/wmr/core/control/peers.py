r"""Peer point stabilisers in the same framework as the paper's PI, for a fair benchmark.

Each peer replaces only the block "errors -> PI" of Figs. 5 and 7: it computes the commanded
platform rates :math:`[v_{ref}, \omega_{ref}]` and hands them to the **same** :math:`D^{-1}`
(eq. 28 as rates, with the same common scaling at the wheel speed limit) and the **same** two
:class:`~wmr.core.control.actuator.WheelServo` s with the same gains and torque limit.  So a
benchmark run differs from the PI's only in the kinematic law.

Peers
-----
``astolfi``
    The polar-coordinate law of Astolfi, as given in Siegwart & Nourbakhsh, *Introduction to
    Autonomous Mobile Robots* (MIT Press, 2004), Section 3.6.2.4, and in PythonRobotics'
    ``Control/move_to_pose``:

    .. math::

        \rho = \sqrt{\Delta x^2 + \Delta y^2},\quad
        \alpha = \mathrm{wrap}(\mathrm{atan2}(\Delta y, \Delta x) - \theta),\quad
        \beta = \mathrm{wrap}(\theta_d - \theta - \alpha),

        v = k_\rho \rho,\qquad \omega = k_\alpha \alpha + k_\beta \beta .

    Default gains: the book's :math:`(k_\rho, k_\alpha, k_\beta) = (3, 8, -1.5)`
    (PythonRobotics uses :math:`(9, 15, -3)`).  Locally exponentially stable for
    :math:`k_\rho > 0`, :math:`k_\beta < 0`, :math:`k_\alpha - k_\rho > 0`; the book's
    *strong stability* condition :math:`k_\alpha + \tfrac53 k_\beta - \tfrac2\pi k_\rho > 0`
    keeps :math:`\alpha` in its initial interval, so the direction of travel never changes.
    **Backward driving** (the book's: decided once at the start): when
    :math:`\alpha \notin (-\pi/2, \pi/2]` at :math:`t = 0` the robot runs the same law in the
    reversed frame :math:`\theta' = \theta + \pi`, :math:`\theta_d' = \theta_d + \pi`, i.e.
    :math:`\alpha' = \mathrm{wrap}(\alpha + \pi)`, :math:`\beta' = \mathrm{wrap}(\beta + \pi)`,
    :math:`v = -k_\rho \rho`, :math:`\omega = k_\alpha \alpha' + k_\beta \beta'`.
    (PythonRobotics only negates ``v`` step by step, which is not the book's law.)

``graceful``
    The smooth control law of Park & Kuipers, "A smooth control law for graceful motion of
    differential wheeled mobile robots in 2D environments" (ICRA 2011), as implemented in
    nav2's ``nav2_graceful_controller`` (``smooth_control_law.cpp``).  Egocentric polar
    coordinates: :math:`r = \Delta r`, :math:`\phi = \mathrm{wrap}(\theta_d - \alpha_w)` (goal
    heading to the line of sight), :math:`\delta = \mathrm{wrap}(\theta - \alpha_w)` (robot
    heading to the line of sight), :math:`\alpha_w = \mathrm{atan2}(\Delta y, \Delta x)`;

    .. math::

        \kappa = -\frac1r\Big[k_\delta\big(\delta - \arctan(-k_\phi\phi)\big)
                 + \Big(1 + \frac{k_\phi}{1 + (k_\phi\phi)^2}\Big)\sin\delta\Big],

        v = \mathrm{clip}\Big(\min\Big(\frac{v_{max}}{1 + \beta|\kappa|^\lambda},
              v_{max}\frac{r}{r_{slow}}\Big), v_{min}, v_{max}\Big),\qquad
        \omega = \kappa v .

    Default gains: nav2's defaults :math:`k_\phi = 2`, :math:`k_\delta = 1`, :math:`\beta = 0.4`,
    :math:`\lambda = 2`, :math:`r_{slow} = 1.5` m, :math:`v_{min} = 0.1` m/s (Park & Kuipers'
    examples use :math:`\beta = 0.4, \lambda = 2` too).  Forward only (nav2's default
    ``allow_backward = false``); no initial in-place rotation (a nav2 path-follower option, not
    part of the law).

What we add to every peer (the same as the PI's extensions, ``docs/control.md``)
-------------------------------------------------------------------------------
* **Command limits by time scaling.**  :math:`(v, \omega)` is scaled by one factor
  :math:`s = \min(1, v_{max}/|v|, \omega_{max}/|\omega|)`: the curvature :math:`\omega / v`,
  hence the path of the kinematic law, is unchanged; only its speed along the path is
  limited (nav2 does the same for :math:`\omega`).  The limits are the PI's ``Limits``.
* **Stop radius and final alignment.**  Both laws are singular at :math:`\rho = 0`.  Inside
  :math:`\rho \le \varepsilon/2` every peer switches to the PI's alignment rule: turn in
  place, :math:`\omega = k_{a\theta}\,\mathrm{wrap}(\theta_d - \theta)`, while
  :math:`v = k_{as}(\Delta x\cos\theta + \Delta y\sin\theta)` holds B on the goal, with the
  PI's default gains :math:`k_{a\theta} = 2` 1/s, :math:`k_{as} = 0.5` 1/s, and back to the
  approach only outside :math:`2\varepsilon`.  The convergence test (stop radius, heading
  tolerance, at rest) is the PI's.  So all controllers meet the same heading bar the same way
  and the benchmark compares the approach laws.
* **Hysteresis near** :math:`\pm\pi` on the angles (:func:`~wmr.core.control.unwrap_near`), as for
  the PI, so a goal straight behind does not make the turn direction chatter.

Signals
-------
The peers fill the same 20 :data:`wmr.core.signals.CONTROL_SIGNALS` columns:

=====================  ==================  ==========================  ======================
column                 PI                  astolfi                     graceful
=====================  ==================  ==========================  ======================
``dr_m``               :math:`\Delta r`    :math:`\rho`                :math:`r`
``e_s_m``              :math:`e_s`         :math:`\rho`                :math:`r`
``e_theta_rad``        :math:`\gamma`      :math:`\alpha` (driving     :math:`\delta`
                                           frame)
``alpha_rad``          bearing to goal     bearing to goal             bearing to goal
``beta_rad``           ROC :math:`\beta`   :math:`\beta` (driving      :math:`\phi`
                                           frame)
``gamma_rad``          :math:`\gamma`      NaN                         :math:`\delta -
                                                                       \arctan(-k_\phi\phi)`
``u_s_mps``            :math:`u_s`         :math:`v_{ref}`             :math:`v_{ref}`
``u_theta_radps``      :math:`u_\theta`    :math:`\omega_{ref}`        :math:`\omega_{ref}`
``p_s_mps``            P term              :math:`\pm k_\rho\rho`      speed law before the
                                           (unlimited)                 :math:`\omega` bound
``p_theta_radps``      P term              :math:`k_\alpha\alpha +     :math:`\kappa v` before
                                           k_\beta\beta` (unlimited)   the bound
``i_s_mps``,           I terms             NaN                         NaN
``i_theta_radps``
``D_*``, ``R_*``       points D, R         NaN                         NaN
=====================  ==================  ==========================  ======================

In the alignment phase all three log ``e_s`` = distance along the heading line and
``e_theta`` = ``gamma`` = :math:`\mathrm{wrap}(\theta_d - \theta)`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Final

from wmr.core.control.stabiliser import (
    ALIGN,
    APPROACH,
    OMEGA_REST_RADPS,
    V_REST_MPS,
    Limits,
    unwrap_near,
    wrap_angle,
)
from wmr.core.plant import Pose, RobotParams
from wmr.infra.errors import ConfigError

NAN: Final = math.nan
#: PI default alignment gains, shared by the peers' final alignment (1/s).
ALIGN_K_THETA: Final = 2.0
ALIGN_K_S: Final = 0.5


def _finite(section: str, name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{section}.{name}", f"must be a finite number, got {value!r}",
                          "give a real number")
    return float(value)


@dataclass(frozen=True)
class AstolfiGains:
    r"""Gains of Astolfi's polar law (Siegwart & Nourbakhsh, Section 3.6.2.4).

    Parameters
    ----------
    k_rho
        :math:`k_\rho`, 1/s (book: 3).
    k_alpha
        :math:`k_\alpha`, 1/s (book: 8).
    k_beta
        :math:`k_\beta`, 1/s, negative (book: -1.5).
    reverse
        Allow backward driving (decided at the start; the book's law).  1 (True) by default.
    k_align_theta, k_align_s
        Gains of the final alignment inside :math:`\varepsilon/2`, 1/s (the PI's defaults).

    Raises
    ------
    ConfigError
        Unless :math:`k_\rho > 0`, :math:`k_\beta < 0` and :math:`k_\alpha - k_\rho > 0`
        (local exponential stability).
    """

    k_rho: float = 3.0
    k_alpha: float = 8.0
    k_beta: float = -1.5
    reverse: bool = True
    k_align_theta: float = ALIGN_K_THETA
    k_align_s: float = ALIGN_K_S

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name != "reverse":
                _finite("controller_gains", f.name, getattr(self, f.name))
        if not (self.k_rho > 0.0 and self.k_beta < 0.0 and self.k_alpha > self.k_rho):
            raise ConfigError("controller_gains",
                              f"k_rho={self.k_rho}, k_alpha={self.k_alpha}, "
                              f"k_beta={self.k_beta} violate the stability condition",
                              "need k_rho > 0, k_beta < 0 and k_alpha > k_rho")
        if self.k_align_theta <= 0.0 or self.k_align_s <= 0.0:
            raise ConfigError("controller_gains.k_align_*", "must be > 0")

    @property
    def strongly_stable(self) -> bool:
        r""":math:`k_\alpha + \tfrac53 k_\beta - \tfrac2\pi k_\rho > 0` (the book's condition)."""
        return self.k_alpha + 5.0 / 3.0 * self.k_beta - 2.0 / math.pi * self.k_rho > 0.0

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class GracefulGains:
    r"""Gains of Park & Kuipers' graceful law (defaults: nav2's ``nav2_graceful_controller``).

    Parameters
    ----------
    k_phi
        :math:`k_\phi`, weight of the goal orientation in the virtual control (nav2: 2).
    k_delta
        :math:`k_\delta`, gain of the steering error (nav2: 1).
    beta
        :math:`\beta`, how fast the speed drops with the curvature, m^λ (nav2: 0.4).
    lam
        :math:`\lambda`, exponent of the speed law (nav2: 2).
    slowdown_radius_m
        :math:`r_{slow}`, m: the speed falls linearly with r inside it (nav2: 1.5).
    v_min_mps
        :math:`v_{min}`, m/s, lower clamp of the speed law (nav2: 0.1).
    k_align_theta, k_align_s
        Gains of the final alignment, 1/s (the PI's defaults).
    """

    k_phi: float = 2.0
    k_delta: float = 1.0
    beta: float = 0.4
    lam: float = 2.0
    slowdown_radius_m: float = 1.5
    v_min_mps: float = 0.1
    k_align_theta: float = ALIGN_K_THETA
    k_align_s: float = ALIGN_K_S

    def __post_init__(self) -> None:
        for f in fields(self):
            v = _finite("controller_gains", f.name, getattr(self, f.name))
            if v < 0.0 or (v == 0.0 and f.name in ("k_delta", "slowdown_radius_m",
                                                   "k_align_theta", "k_align_s", "lam")):
                raise ConfigError(f"controller_gains.{f.name}", f"out of range: {v!r}",
                                  "give a positive value")

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


class PolarStabiliser:
    r"""Common part of the peers: phases, alignment, limits and :math:`D^{-1}`.

    Subclasses implement :meth:`approach`, the kinematic law.  :meth:`update` returns the
    same 18-tuple as :meth:`wmr.core.control.PointStabiliser.update`.
    """

    def __init__(self, goal: Pose, limits: Limits, params: RobotParams, period_s: float,
                 stop_radius_m: float, k_align_theta: float, k_align_s: float) -> None:
        self.xd = float(goal.x_m)
        self.yd = float(goal.y_m)
        self.theta_d = float(goal.heading_rad)
        self.v_max = limits.v_max_mps
        self.omega_max = limits.omega_max_radps
        self.wheel_max = limits.wheel_speed_max_radps
        self.inv_r = 1.0 / params.r
        self.L = params.L
        self.h = period_s
        self.eps = stop_radius_m
        self.align_radius = 0.5 * stop_radius_m
        self.exit_radius = 2.0 * stop_radius_m
        self.k_align_theta = k_align_theta
        self.k_align_s = k_align_s
        self.phase = APPROACH
        self.prev_align = 0.0

    def reset(self) -> None:
        """Start of a run."""
        self.phase = APPROACH
        self.prev_align = 0.0

    def approach(self, dx: float, dy: float, dr: float, theta: float
                 ) -> tuple[float, float, float, float, float, float, float, float, float]:
        """The law: ``(v, omega, e_s, e_theta, alpha, beta, gamma, p_s, p_theta)``."""
        raise NotImplementedError

    def update(self, x: float, y: float, theta: float) -> tuple[float, ...]:
        r"""One control period: pose in, wheel speed references and signals out.

        The law's :math:`(v, \omega)` is scaled by
        :math:`s = \min(1, v_{max}/|v|, \omega_{max}/|\omega|)` (same curvature), then
        :math:`\omega_{r,ref} = (v + L\omega)/r`, :math:`\omega_{l,ref} = (v - L\omega)/r`,
        both scaled down together to the wheel speed limit (as the PI's eq. 28).
        """
        dx = self.xd - x
        dy = self.yd - y
        dr = math.hypot(dx, dy)
        if self.phase == APPROACH:
            if dr <= self.align_radius:
                self.phase = ALIGN
                self.prev_align = 0.0
        elif dr > self.exit_radius:
            self.phase = APPROACH
            self.reset_approach()
        if self.phase == APPROACH:
            v, w, e_s, e_theta, alpha, beta, gamma, p_s, p_theta = self.approach(
                dx, dy, dr, theta)
            s = 1.0
            if abs(v) > self.v_max:
                s = self.v_max / abs(v)
            if abs(w) * s > self.omega_max:
                s = self.omega_max / abs(w)
            v *= s
            w *= s
        else:
            e_theta = gamma = unwrap_near(wrap_angle(self.theta_d - theta), self.prev_align)
            self.prev_align = gamma
            e_s = dx * math.cos(theta) + dy * math.sin(theta)
            alpha = math.atan2(dy, dx)
            beta = wrap_angle(self.theta_d - alpha)
            p_s = self.k_align_s * e_s
            p_theta = self.k_align_theta * e_theta
            v = min(max(p_s, -self.v_max), self.v_max)
            w = min(max(p_theta, -self.omega_max), self.omega_max)
        w_r = (v + self.L * w) * self.inv_r
        w_l = (v - self.L * w) * self.inv_r
        peak = max(abs(w_r), abs(w_l))
        if peak > self.wheel_max:
            k = self.wheel_max / peak
            w_r *= k
            w_l *= k
        return (dr, e_s, e_theta, alpha, beta, gamma, v, w, p_s, NAN, p_theta, NAN, w_r, w_l,
                NAN, NAN, NAN, NAN)

    def reset_approach(self) -> None:
        """Back to the approach phase after being pushed out of :math:`2\\varepsilon`."""

    def heading_error(self, theta: float) -> float:
        """Wrapped heading error ``theta - theta_d`` in (-pi, pi]."""
        return wrap_angle(theta - self.theta_d)

    def converged(self, x: float, y: float, theta: float, v: float, omega: float,
                  heading_tolerance_rad: float) -> bool:
        """The PI's test: aligned phase, inside the stop radius, heading within tolerance, at
        rest."""
        return (self.phase == ALIGN
                and math.hypot(self.xd - x, self.yd - y) <= self.eps
                and abs(wrap_angle(theta - self.theta_d)) <= heading_tolerance_rad
                and abs(v) <= V_REST_MPS and abs(omega) <= OMEGA_REST_RADPS)


class AstolfiStabiliser(PolarStabiliser):
    r"""Astolfi's law :math:`v = k_\rho\rho`, :math:`\omega = k_\alpha\alpha + k_\beta\beta`.

    See the module docstring for the definitions, the backward frame and the defaults.
    """

    def __init__(self, goal: Pose, gains: AstolfiGains, limits: Limits, params: RobotParams,
                 period_s: float, stop_radius_m: float) -> None:
        super().__init__(goal, limits, params, period_s, stop_radius_m, gains.k_align_theta,
                         gains.k_align_s)
        self.k_rho = gains.k_rho
        self.k_alpha = gains.k_alpha
        self.k_beta = gains.k_beta
        self.allow_reverse = bool(gains.reverse)
        self.direction = 0.0  # +1 forward, -1 backward, 0 undecided
        self.prev_beta = 0.0

    def reset(self) -> None:
        super().reset()
        self.direction = 0.0
        self.prev_beta = 0.0

    def reset_approach(self) -> None:
        self.direction = 0.0

    def approach(self, dx: float, dy: float, dr: float, theta: float
                 ) -> tuple[float, float, float, float, float, float, float, float, float]:
        r""":math:`\rho, \alpha, \beta` in the driving frame, then the law (unlimited)."""
        bearing = math.atan2(dy, dx)
        alpha = wrap_angle(bearing - theta)
        if self.direction == 0.0:
            forward = -0.5 * math.pi < alpha <= 0.5 * math.pi
            self.direction = 1.0 if forward or not self.allow_reverse else -1.0
        if self.direction < 0.0:
            alpha = wrap_angle(alpha + math.pi)
        # reversed frame: theta' = theta + pi, theta_d' = theta_d + pi, so the pi's cancel
        beta = unwrap_near(wrap_angle(self.theta_d - theta - alpha), self.prev_beta)
        self.prev_beta = beta
        v = self.direction * self.k_rho * dr
        w = self.k_alpha * alpha + self.k_beta * beta
        return v, w, dr, alpha, bearing, beta, NAN, v, w


class GracefulStabiliser(PolarStabiliser):
    r"""Park & Kuipers' graceful law: curvature :math:`\kappa(r, \phi, \delta)`,
    :math:`v = v_{max}/(1 + \beta|\kappa|^\lambda)`, :math:`\omega = \kappa v`.

    See the module docstring for the definitions and the defaults.
    """

    def __init__(self, goal: Pose, gains: GracefulGains, limits: Limits, params: RobotParams,
                 period_s: float, stop_radius_m: float) -> None:
        super().__init__(goal, limits, params, period_s, stop_radius_m, gains.k_align_theta,
                         gains.k_align_s)
        self.k_phi = gains.k_phi
        self.k_delta = gains.k_delta
        self.beta = gains.beta
        self.lam = gains.lam
        self.r_slow = gains.slowdown_radius_m
        self.v_min = min(gains.v_min_mps, self.v_max)
        self.prev_phi = 0.0
        self.prev_delta = 0.0

    def reset(self) -> None:
        super().reset()
        self.prev_phi = 0.0
        self.prev_delta = 0.0

    def approach(self, dx: float, dy: float, dr: float, theta: float
                 ) -> tuple[float, float, float, float, float, float, float, float, float]:
        r"""Egocentric :math:`(r, \phi, \delta)`, curvature, speed law (nav2's order)."""
        bearing = math.atan2(dy, dx)
        phi = unwrap_near(wrap_angle(self.theta_d - bearing), self.prev_phi)
        delta = unwrap_near(wrap_angle(theta - bearing), self.prev_delta)
        self.prev_phi = phi
        self.prev_delta = delta
        kp = self.k_phi
        err = delta - math.atan(-kp * phi)
        kappa = -(self.k_delta * err
                  + (1.0 + kp / (1.0 + (kp * phi) ** 2)) * math.sin(delta)) / dr
        v = self.v_max / (1.0 + self.beta * abs(kappa) ** self.lam)
        v = min(v, self.v_max * dr / self.r_slow)
        v = min(max(v, self.v_min), self.v_max)
        return v, kappa * v, dr, delta, bearing, phi, err, v, kappa * v


__all__ = [
    "AstolfiGains",
    "AstolfiStabiliser",
    "GracefulGains",
    "GracefulStabiliser",
    "PolarStabiliser",
]
