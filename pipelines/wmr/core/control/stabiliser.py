r"""The paper's point stabiliser (Section 4): RPC, ROC, two PI controllers, eq. 28.

Block structure of Figs. 5 and 7, one control period ``h``::

    pose -> errors (eqs. 25-27, ROC) -> PI (eq. 29) -> D^-1 (eq. 28) -> wheel speed refs
                                                                       -> wheel servos (actuator.py)

Every equation below carries the paper's number; the corrections of the
paper's errata (``docs/model.md``) are applied (eq. 27: ``atan2`` and wrapping; ROC: ``gamma``
wrapped).

Interpretation of eq. 28
------------------------
The paper writes :math:`[\theta_r, \theta_l]^T = D^{-1}[s, \theta]^T` for wheel
*displacements* and substitutes the PI outputs :math:`[u_s, u_\theta]`.  Here the PI outputs
are the commanded *rates* :math:`u_s = \dot s` (m/s) and :math:`u_\theta = \dot\theta` (rad/s),
and eq. 28 differentiated in time gives wheel *speed* references
:math:`[\omega_{r,ref}, \omega_{l,ref}]^T = D^{-1}[u_s, u_\theta]^T` for the wheel speed servos.
Read as displacements, the PI output would be a position command: at rest on the goal the
errors are zero, yet the integral term stays at its final value, so the wheel position
references keep a standing offset (and the robot drives away from the goal until the integral
unwinds); read as rates, a zero error and a settled integral mean the robot stops.

Our extensions to the paper's law (each documented in ``docs/control.md``)
-------------------------------------------------------------------------
* **Stop radius and alignment.**  Inside :math:`\Delta r \le \varepsilon` the paper stops;
  ``alpha`` is undefined at :math:`\Delta r = 0`.  We stop translating (:math:`u_s = 0`) and
  turn in place to :math:`\theta_d` with the same angle PI on
  :math:`e_\theta = \mathrm{wrap}(\theta_d - \theta)`.  The phase switches back to the
  approach only if the robot is pushed out of :math:`2\varepsilon` (hysteresis).
* **Forward only.**  :math:`e_s < 0` (goal behind the heading line) would make the robot
  reverse while the angle loop turns it; we clamp :math:`u_s \ge 0`, so it turns towards R in
  place first, then drives.
* **Clamp of beta.**  With :math:`\gamma \to 0` the ROC keeps :math:`\sin\beta / \Delta r`
  constant, so for :math:`|\beta| \to \pi` (goal pose facing away from the robot) the robot
  drives away from the goal for ever, and for :math:`|\beta| > \pi/2` it first swings
  out.  We clamp :math:`|\beta| \le \beta_{max} = \pi/3`: the robot then keeps the goal at
  the bearing :math:`\pm\beta_{max}` and spirals in around it until
  :math:`|\beta| < \beta_{max}`, after which the paper's law holds unchanged.  (With
  :math:`\beta_{max} = \pi/2` it would circle at constant distance: paths up to 3 times
  longer; smaller clamps shorten the path but leave more heading for the final alignment.)
* **Hysteresis near** :math:`\pm\pi`.  :math:`\gamma`, :math:`\beta` and the alignment error
  are unwrapped against their previous value within a band, so that an angle near
  :math:`\pm\pi` does not flip sign each step (turn-direction chattering).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Final

from wmr.infra.errors import ConfigError

TWO_PI: Final = 2.0 * math.pi

#: Phase of the stabiliser: approach (RPC/ROC) and final alignment inside the stop radius.
APPROACH: Final = 0
ALIGN: Final = 1

#: |beta| clamp of the ROC (rad): beyond it the robot circles the goal (see module doc).
BETA_MAX_RAD: Final = math.pi / 3.0
#: Half-width (rad) of the band near +-pi where an angle keeps the sign of its previous value.
HYSTERESIS_BAND_RAD: Final = 0.3
#: "Nearly at rest" thresholds of the convergence test.
V_REST_MPS: Final = 0.01
OMEGA_REST_RADPS: Final = 0.02


def wrap_angle(a: float) -> float:
    r"""Wrap an angle to :math:`(-\pi, \pi]`.

    Exact for multiples: ``wrap_angle(a + 2*k*pi) == wrap_angle(a)`` up to the rounding of
    the sum itself.
    """
    w = math.remainder(a, TWO_PI)  # in [-pi, pi], exact
    if w <= -math.pi:
        w += TWO_PI
    return w


def unwrap_near(a: float, previous: float) -> float:
    r"""Hysteresis near :math:`\pm\pi`: keep the sign of ``previous`` for a wrapped angle.

    ``a`` is wrapped to :math:`(-\pi, \pi]`.  If it lies within :data:`HYSTERESIS_BAND_RAD`
    of :math:`\pm\pi` and has the other sign than ``previous``, it is shifted by
    :math:`2\pi` towards ``previous``; the result lies in
    :math:`(-\pi - b, \pi + b)` for the band :math:`b`.  Without it, an angle that hovers
    around :math:`\pm\pi` flips sign each step and the robot chatters between turning left and
    right.
    """
    if a > math.pi - HYSTERESIS_BAND_RAD:
        if previous < 0.0:
            return a - TWO_PI
    elif a < HYSTERESIS_BAND_RAD - math.pi and previous > 0.0:
        return a + TWO_PI
    return a


# The hot path's names, bound once (a module attribute lookup per call is measurable there).
_remainder, _hypot, _atan2, _cos, _sin = math.remainder, math.hypot, math.atan2, math.cos, math.sin
_PI: Final = math.pi
_BAND_HI: Final = math.pi - HYSTERESIS_BAND_RAD
_BAND_LO: Final = HYSTERESIS_BAND_RAD - math.pi


def _wrapped_near(a: float, previous: float) -> float:
    """``unwrap_near(wrap_angle(a), previous)`` in one call, operation for operation."""
    w = _remainder(a, TWO_PI)
    if w <= -_PI:
        w += TWO_PI
    if w > _BAND_HI:
        if previous < 0.0:
            return w - TWO_PI
    elif w < _BAND_LO and previous > 0.0:
        return w + TWO_PI
    return w


def _check_fields(obj: object, section: str, positive: tuple[str, ...]) -> None:
    for f in fields(obj):  # type: ignore[arg-type]
        value = getattr(obj, f.name)
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value):
            raise ConfigError(f"{section}.{f.name}", f"must be a finite number, got {value!r}",
                              "give a real number")
        if value < 0.0 or (f.name in positive and value == 0.0):
            bound = "> 0" if f.name in positive else ">= 0"
            raise ConfigError(f"{section}.{f.name}", f"must be {bound}, got {value!r}",
                              "use a non-negative gain or a positive limit")


@dataclass(frozen=True)
class Gains:
    """Gains of the two PI controllers of eq. 29 and of the wheel speed servos.

    The paper gives none.  Tuned for the paper's robot at a 10 ms period (``docs/control.md``):
    the angle loop crosses over at ``K_ptheta`` = 2 rad/s, four times the distance loop
    (``K_ps`` = 0.5 1/s) so that the heading tracks R, and each PI zero sits a decade below its
    crossover (``K_i = K_p^2 / 10``).  The wheel servos cross over at 20 rad/s, ten times the
    angle loop: ``K_pw = J * 20`` with the effective wheel inertia ``J`` of 0.35 kg m^2, and
    the servo's PI zero at 4 rad/s.
    """

    K_ps: float = 0.5  # 1/s, distance loop, eq. 29
    K_is: float = 0.025  # 1/s^2
    K_ptheta: float = 2.0  # 1/s, angle loop, eq. 29
    K_itheta: float = 0.4  # 1/s^2
    K_pw: float = 7.0  # N m s/rad, wheel speed servo
    K_iw: float = 28.0  # N m /rad

    def __post_init__(self) -> None:
        _check_fields(self, "gains", ())

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}  # no deep copies


@dataclass(frozen=True)
class Limits:
    """Actuator and command limits (the paper gives none).

    ``torque_max_nm``: 8 N m per wheel, 107 N of traction (4 m/s^2) on the 25.9 kg robot;
    ``wheel_speed_max_radps``: 10 rad/s, 1.5 m/s at the rim; the PI outputs are limited to
    ``v_max_mps`` and ``omega_max_radps`` so that ``v + L omega`` stays within the wheel limit
    for the paper's geometry (1.0 + 0.3 * 1.5 = 1.45 m/s < 1.5 m/s).
    """

    v_max_mps: float = 1.0
    omega_max_radps: float = 1.5
    wheel_speed_max_radps: float = 10.0
    torque_max_nm: float = 8.0

    def __post_init__(self) -> None:
        _check_fields(self, "limits", tuple(f.name for f in fields(self)))

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}  # no deep copies


class PointStabiliser:
    r"""RPC + ROC with the PI controllers of eq. 29 and the :math:`D^{-1}` of eq. 28.

    One call of :meth:`update` per control period; pure ``math`` on floats.

    Anti-windup: **conditional integration** (clamping).  The saturations of :math:`u_s` and
    :math:`u_\theta` are this controller's own command limits, known exactly at the point
    where the integral is formed, so the integral is simply frozen while the output is at a
    limit and the error would push it further (it still integrates when the error drives the
    output back inside).  It needs no extra tuning parameter (back-calculation's tracking time
    constant) and cannot overshoot the limit.  The integrals are reset at each phase change.

    Parameters
    ----------
    goal_x_m, goal_y_m, goal_heading_rad
        Desired posture :math:`(x_d, y_d, \theta_d)`.
    gains, limits
        PI gains (eq. 29) and command limits.
    r_m, L_m
        Wheel radius and half track, for :math:`D^{-1}` (eq. 28).
    period_s
        Control period ``h``.
    stop_radius_m
        :math:`\varepsilon`, radius of the circular region of Section 4.
    """

    __slots__ = (
        "K_is",
        "K_itheta",
        "K_ps",
        "K_ptheta",
        "L",
        "align_radius",
        "eps",
        "exit_radius",
        "h",
        "i_s",
        "i_theta",
        "inv_r",
        "omega_max",
        "phase",
        "prev_beta",
        "prev_gamma",
        "r",
        "theta_d",
        "v_max",
        "wheel_max",
        "xd",
        "yd",
    )

    def __init__(self, goal_x_m: float, goal_y_m: float, goal_heading_rad: float,
                 gains: Gains, limits: Limits, r_m: float, L_m: float, period_s: float,
                 stop_radius_m: float) -> None:
        self.xd = float(goal_x_m)
        self.yd = float(goal_y_m)
        self.theta_d = float(goal_heading_rad)
        self.K_ps = gains.K_ps
        self.K_is = gains.K_is
        self.K_ptheta = gains.K_ptheta
        self.K_itheta = gains.K_itheta
        self.v_max = limits.v_max_mps
        self.omega_max = limits.omega_max_radps
        self.wheel_max = limits.wheel_speed_max_radps
        self.r = r_m
        self.inv_r = 1.0 / r_m
        self.L = L_m
        self.h = period_s
        self.eps = stop_radius_m
        self.align_radius = 0.5 * stop_radius_m
        self.exit_radius = 2.0 * stop_radius_m
        self.phase = APPROACH
        self.i_s = 0.0
        self.i_theta = 0.0
        self.prev_gamma = 0.0
        self.prev_beta = 0.0

    def reset(self) -> None:
        """Forget the integrals and the phase (start of a run)."""
        self.phase = APPROACH
        self.i_s = 0.0
        self.i_theta = 0.0
        self.prev_gamma = 0.0
        self.prev_beta = 0.0

    def update(self, x: float, y: float, theta: float) -> tuple[float, ...]:
        r"""One control step: pose of B in, wheel speed references out.

        Errors, in the approach phase (:math:`\Delta r > \varepsilon`):

        * eq. 26: :math:`\Delta r = \sqrt{\Delta x^2 + \Delta y^2}`,
          :math:`\Delta x = x_d - x`, :math:`\Delta y = y_d - y`;
        * eq. 27 (corrected): :math:`\alpha = \mathrm{atan2}(\Delta y, \Delta x)`,
          :math:`e_\phi = \mathrm{wrap}(\alpha - \theta)`;
        * ROC: :math:`\beta = \mathrm{wrap}(\theta_d - \alpha)` (clamped to
          :math:`\pm\beta_{max}`), :math:`\gamma = \mathrm{wrap}(e_\phi - \beta)
          = \mathrm{wrap}(2\alpha - \theta_d - \theta)`,
          :math:`e_s = \Delta r\cos\gamma`, :math:`e_\theta = \gamma`
          (the RPC's eqs. 25/26 :math:`e_s = \Delta r \cos\phi` are the case
          :math:`\beta = 0`);
        * eq. 29: :math:`u_s = K_{ps} e_s + K_{is}\int e_s\,dt`,
          :math:`u_\theta = K_{p\theta} e_\theta + K_{i\theta}\int e_\theta\,dt`,
          with :math:`0 \le u_s \le v_{max}`, :math:`|u_\theta| \le \omega_{max}`;
        * eq. 28 (as rates): :math:`\omega_{r,ref} = (u_s + L u_\theta)/r`,
          :math:`\omega_{l,ref} = (u_s - L u_\theta)/r`, scaled down together if either
          exceeds the wheel speed limit (keeps the curvature :math:`u_\theta/u_s`).

        Returns
        -------
        tuple of float
            ``(dr, e_s, e_theta, alpha, beta, gamma, u_s, u_theta, p_s, i_s, p_theta,
            i_theta, omega_r_ref, omega_l_ref, D_x, D_y, R_x, R_y)``, the
            :data:`wmr.core.signals.CONTROL_SIGNALS` without the torques.
        """
        dx = self.xd - x
        dy = self.yd - y
        dr = _hypot(dx, dy)  # eq. 26, Delta r
        phase = self.phase
        if phase == APPROACH:
            if dr <= self.align_radius:
                phase = self.phase = ALIGN
                self.i_s = 0.0
                self.i_theta = 0.0
                self.prev_gamma = 0.0
        elif dr > self.exit_radius:
            phase = self.phase = APPROACH
            self.i_s = 0.0
            self.i_theta = 0.0
            self.prev_gamma = 0.0

        alpha = _atan2(dy, dx)  # eq. 27 (corrected): direction to the goal
        # ROC: beta = theta_d - alpha, wrapped, with hysteresis near +-pi, then clamped
        beta = _wrapped_near(self.theta_d - alpha, self.prev_beta)
        self.prev_beta = beta
        if beta > BETA_MAX_RAD:
            beta_c = BETA_MAX_RAD
        elif beta < -BETA_MAX_RAD:
            beta_c = -BETA_MAX_RAD
        else:
            beta_c = beta
        # the reference point R: the goal rotated by beta about B (Fig. 6)
        a_r = alpha - beta_c
        rx = x + dr * _cos(a_r)
        ry = y + dr * _sin(a_r)

        if phase == APPROACH:
            # ROC: gamma = e_phi - beta = 2 alpha - theta_d - theta, wrapped (errata)
            gamma = _wrapped_near(a_r - theta, self.prev_gamma)
            self.prev_gamma = gamma
            e_s = dr * _cos(gamma)  # ROC distance error (eq. 26 with gamma for phi)
            e_theta = gamma
            s_lo = 0.0  # forward only: turn towards R in place rather than reverse
            s_hi = self.v_max
            k_is = self.K_is
            k_itheta = self.K_itheta
        else:
            # extension: alignment in place inside the stop radius
            gamma = _wrapped_near(self.theta_d - theta, self.prev_gamma)
            self.prev_gamma = gamma
            # hold B at the goal along the heading line (defined for dr = 0, unlike alpha)
            e_s = dx * _cos(theta) + dy * _sin(theta)
            e_theta = gamma
            s_hi = self.v_max
            s_lo = -s_hi
            # P only: the heading is an integrator and the wheel servos integrate, so P alone
            # has no steady-state error here, and an integral would only overshoot
            k_is = k_itheta = 0.0

        # eq. 29: two PI controllers, conditional integration against the output limits
        h = self.h
        p_s = self.K_ps * e_s
        i_s = self.i_s
        u = p_s + i_s
        if u > s_hi:
            u_s = s_hi
            if e_s < 0.0:
                self.i_s = i_s + k_is * e_s * h
        elif u < s_lo:
            u_s = s_lo
            if e_s > 0.0:
                self.i_s = i_s + k_is * e_s * h
        else:
            u_s = u
            self.i_s = i_s + k_is * e_s * h

        p_theta = self.K_ptheta * e_theta
        i_theta = self.i_theta
        u = p_theta + i_theta
        w_max = self.omega_max
        if u > w_max:
            u_theta = w_max
            if e_theta < 0.0:
                self.i_theta = i_theta + k_itheta * e_theta * h
        elif u < -w_max:
            u_theta = -w_max
            if e_theta > 0.0:
                self.i_theta = i_theta + k_itheta * e_theta * h
        else:
            u_theta = u
            self.i_theta = i_theta + k_itheta * e_theta * h

        # eq. 28, D^-1 as rates: wheel speed references
        inv_r = self.inv_r
        w_r = (u_s + self.L * u_theta) * inv_r
        w_l = (u_s - self.L * u_theta) * inv_r
        abs_r, abs_l = abs(w_r), abs(w_l)
        peak = abs_l if abs_l > abs_r else abs_r  # max(|w_r|, |w_l|), as max() picks
        if peak > self.wheel_max:
            k = self.wheel_max / peak
            w_r *= k
            w_l *= k

        # point D on the heading line (Fig. 4)
        d_x = x + e_s * _cos(theta)
        d_y = y + e_s * _sin(theta)
        return (dr, e_s, e_theta, alpha, beta, gamma, u_s, u_theta, p_s, i_s, p_theta,
                i_theta, w_r, w_l, d_x, d_y, rx, ry)

    def heading_error(self, theta: float) -> float:
        """Wrapped heading error ``theta - theta_d`` in (-pi, pi]."""
        return wrap_angle(theta - self.theta_d)

    def converged(self, x: float, y: float, theta: float, v: float, omega: float,
                  heading_tolerance_rad: float) -> bool:
        """Inside the stop radius, heading within tolerance, and nearly at rest."""
        return (self.phase == ALIGN
                and math.hypot(self.xd - x, self.yd - y) <= self.eps
                and abs(wrap_angle(theta - self.theta_d)) <= heading_tolerance_rad
                and abs(v) <= V_REST_MPS and abs(omega) <= OMEGA_REST_RADPS)
