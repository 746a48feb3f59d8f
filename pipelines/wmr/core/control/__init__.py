"""The paper's controller: stabiliser (Section 4) feeding two wheel speed servos.

Fig. 5 / Fig. 7 block structure, one period::

    errors (eqs. 25-27, ROC) -> PI (eq. 29) -> D^-1 (eq. 28) -> wheel actuators -> robot

:class:`PIController` wires :class:`~wmr.core.control.stabiliser.PointStabiliser` (errors, PI,
:math:`D^{-1}`) to one :class:`~wmr.core.control.actuator.WheelServo` per wheel.
"""

from __future__ import annotations

from typing import Protocol

from wmr.core.control.actuator import WheelServo
from wmr.core.control.stabiliser import (
    ALIGN,
    APPROACH,
    Gains,
    Limits,
    PointStabiliser,
    unwrap_near,
    wrap_angle,
)
from wmr.core.plant import Pose, RobotParams


class Stabiliser(Protocol):
    """A point-stabilising law that ends in wheel speed references (eq. 28's output)."""

    def reset(self) -> None: ...

    def update(self, x: float, y: float, theta: float) -> tuple[float, ...]:
        """The 18 stabiliser columns of :data:`wmr.core.signals.CONTROL_SIGNALS` (all but the two
        torques), ``omega_r_ref, omega_l_ref`` at positions 12 and 13."""
        ...

    def converged(self, x: float, y: float, theta: float, v: float, omega: float,
                  heading_tolerance_rad: float) -> bool:
        """At the goal, aligned and at rest: the master loop stops the run."""
        ...

    def heading_error(self, theta: float) -> float:
        """Heading minus the desired heading, wrapped, rad."""
        ...


class ServoedController:
    """Any stabiliser feeding the two wheel speed servos: the Fig. 7 structure.

    The paper's :class:`PIController` and the peer stabilisers (:mod:`wmr.core.control.peers`) share
    this class, so that a comparison differs only in the law, never in the actuators.

    Parameters
    ----------
    stabiliser
        The law: errors -> commands -> wheel references.
    gains, limits, params, period_s
        The servo gains ``K_pw, K_iw`` come from ``gains``, the torque limit from ``limits``,
        the friction feed-forward from ``params``.
    """

    __slots__ = ("left", "right", "stabiliser")

    def __init__(self, stabiliser: Stabiliser, gains: Gains, limits: Limits,
                 params: RobotParams, period_s: float) -> None:
        self.stabiliser = stabiliser
        servo = (gains.K_pw, gains.K_iw, limits.torque_max_nm, period_s, params.b_f,
                 params.tau_c, params.w_c)
        self.right = WheelServo(*servo)
        self.left = WheelServo(*servo)

    def reset(self) -> None:
        """Start of a run: forget integrals and phase."""
        self.stabiliser.reset()
        self.right.reset()
        self.left.reset()

    def step(self, x: float, y: float, theta: float, omega_r: float,
             omega_l: float) -> tuple[float, ...]:
        """One control period: measured pose and wheel speeds in.

        Returns
        -------
        tuple of float
            The :data:`wmr.core.signals.CONTROL_SIGNALS`, in order; ``tau_r, tau_l`` are items
            14 and 15.
        """
        # errors -> PI -> D^-1 (stabiliser.py)
        (dr, e_s, e_theta, alpha, beta, gamma, u_s, u_theta, p_s, i_s, p_theta, i_theta,
         w_r_ref, w_l_ref, d_x, d_y, r_x, r_y) = self.stabiliser.update(x, y, theta)
        # -> wheel actuators (actuator.py)
        tau_r = self.right.update(w_r_ref, omega_r)
        tau_l = self.left.update(w_l_ref, omega_l)
        return (dr, e_s, e_theta, alpha, beta, gamma, u_s, u_theta, p_s, i_s, p_theta,
                i_theta, w_r_ref, w_l_ref, tau_r, tau_l, d_x, d_y, r_x, r_y)


class PIController(ServoedController):
    """Stabiliser plus wheel actuators: the complete controller of Fig. 7.

    Parameters
    ----------
    goal
        Desired posture.
    gains, limits
        PI and servo gains, command and actuator limits.
    params
        Robot parameters the controller knows: ``r`` and ``L`` for eq. 28 and the friction
        for the servos' feed-forward.
    period_s, stop_radius_m
        Control period and the stop radius epsilon.
    """

    __slots__ = ()

    def __init__(self, goal: Pose, gains: Gains, limits: Limits, params: RobotParams,
                 period_s: float, stop_radius_m: float) -> None:
        super().__init__(PointStabiliser(goal.x_m, goal.y_m, goal.heading_rad, gains, limits,
                                         params.r, params.L, period_s, stop_radius_m),
                         gains, limits, params, period_s)


__all__ = [
    "ALIGN",
    "APPROACH",
    "Gains",
    "Limits",
    "PIController",
    "PointStabiliser",
    "ServoedController",
    "Stabiliser",
    "WheelServo",
    "unwrap_near",
    "wrap_angle",
]
