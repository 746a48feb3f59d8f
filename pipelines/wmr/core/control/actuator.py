r"""The wheel actuator control systems of Figs. 5 and 7, which the paper leaves open.

Eq. 28 turns the PI outputs into wheel speed references; each wheel then has its own PI speed
servo that turns the speed error :math:`\omega_{ref} - \omega_w` into a motor torque,
saturated at :math:`\pm\tau_{max}`, with a friction feed-forward:

.. math::

    \tau = \mathrm{sat}_{\tau_{max}}\Big(K_{pw}\,e + I + \hat\tau_f(\omega_{ref})\Big),\quad
    e = \omega_{ref} - \omega_w,\quad
    \hat\tau_f(\omega) = b_f\,\omega + \tau_c\tanh(\omega / w_c).

Tuning (``docs/control.md``): seen from one wheel the robot is an inertia; in wheel
coordinates the common mode (both wheels together) has :math:`J_c = r^2 M_{11}/2 = 0.29`
kg m^2 and the differential mode :math:`J_d = r^2 M_{22}/(2L^2) = 0.42` kg m^2 for the paper's
parameters.  With :math:`J \approx 0.35` kg m^2 and a crossover of 20 rad/s (ten times the
angle loop, and :math:`\omega_c h = 0.2` at 10 ms so that the sampling delay costs about 6
degrees of phase), :math:`K_{pw} = J\omega_c = 7` N m s/rad and the PI zero at
:math:`\omega_c/5`: :math:`K_{iw} = 28` N m/rad.

Anti-windup: **back-calculation**.  The torque limit is the physical actuator's; on a large
reference step (start, phase change) the torque stays saturated for a few hundred ms, and
back-calculation makes the integrator track the saturated torque with the time constant
:math:`T_t = 0.4\,T_i = 0.4 K_{pw}/K_{iw}` (0.1 s, ten periods), so that the torque leaves the
limit as soon as the speed error allows, without the delay of a wound-up integral.  With
:math:`T_t = T_i` a 0 to 10 rad/s step still overshoots by 8 %, with :math:`T_t = 0.4 T_i` it
does not (``tests/test_actuator.py``); without anti-windup it overshoots by 58 %.
"""

from __future__ import annotations

import math


class WheelServo:
    """PI speed servo of one wheel with torque saturation and back-calculation anti-windup.

    Parameters
    ----------
    K_p, K_i
        Proportional (N m s/rad) and integral (N m/rad) gains.
    torque_max
        Saturation of the motor torque (N m).
    period_s
        Sampling period ``h`` (s).
    b_ff, tau_c_ff, w_c
        Friction feed-forward: viscous coefficient, Coulomb torque and its tanh smoothing
        speed; zero friction, no feed-forward.
    """

    __slots__ = ("K_i", "K_p", "b_ff", "h", "integral", "k_t", "tau_c_ff", "torque_max", "w_c")

    def __init__(self, K_p: float, K_i: float, torque_max: float, period_s: float,
                 b_ff: float = 0.0, tau_c_ff: float = 0.0, w_c: float = 0.01) -> None:
        self.K_p = K_p
        self.K_i = K_i
        self.torque_max = torque_max
        self.h = period_s
        self.b_ff = b_ff
        self.tau_c_ff = tau_c_ff
        self.w_c = w_c
        # back-calculation gain h / T_t with T_t = 0.4 T_i = 0.4 K_p / K_i, capped at 1
        self.k_t = min(1.0, period_s * K_i / (0.4 * K_p)) if K_p > 0.0 else 1.0
        self.integral = 0.0

    def reset(self) -> None:
        """Forget the integral."""
        self.integral = 0.0

    def update(self, omega_ref: float, omega: float) -> float:
        """One servo step: wheel speed reference and measurement in, motor torque out."""
        e = omega_ref - omega
        ff = self.b_ff * omega_ref
        if self.tau_c_ff != 0.0:
            ff += self.tau_c_ff * math.tanh(omega_ref / self.w_c)
        v = self.K_p * e + self.integral + ff
        t_max = self.torque_max
        tau = t_max if v > t_max else (-t_max if v < -t_max else v)
        self.integral += self.K_i * self.h * e + self.k_t * (tau - v)
        return tau
