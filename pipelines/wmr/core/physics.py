r"""A second, hand-written implementation of the robot physics (paper, Section 3).

The FMUs are generated from the Modelica model ``modelica/WMR`` by one code path; this module
writes the same physics by hand, from the corrected eqs. 18 to 24, so that tests can check the
FMU against it and the master loop can be tested without an FMU.

State, in this order (:data:`STATE_NAMES`):
``x, y, theta, v, omega, phi_r, phi_l`` - position of B, the centre of the wheel axle, heading,
linear velocity of B, angular velocity of the platform, and the two wheel angles.

The model is the paper's eq. 23 with the corrected eq. 24 (see ``docs/model.md``):

.. math::

    M_{wm} \begin{bmatrix}\dot v \\ \dot\omega\end{bmatrix} + C(v) + B\,\tau_f = B\,\tau_m,

    M_{wm} = \begin{bmatrix} m + 2 I_{wm}/r^2 & 0 \\
                             0 & I_g + m l^2 + 2 L^2 I_{wm}/r^2 \end{bmatrix},\quad
    C(v) = \begin{bmatrix} -m l \omega^2 \\ m l v \omega \end{bmatrix},\quad
    B = \begin{bmatrix} 1/r & 1/r \\ L/r & -L/r \end{bmatrix}.

Where the paper is wrong
------------------------
* **Eq. 24** prints :math:`2 I_{wm}/r^2` in row 1, column 2 of :math:`M_{wm}` and nothing in
  row 2, column 1.  Substituting eq. 22 with the rolling constraint
  :math:`\dot\omega_{r,l} = (\dot v \pm L\dot\omega)/r` into eq. 20 gives
  :math:`F_d = (\tau_{mr}+\tau_{ml}-\tau_{fr}-\tau_{fl})/r - 2 I_{wm}\dot v/r^2` and
  :math:`\tau_d = L(\tau_{mr}-\tau_{ml}-\tau_{fr}+\tau_{fl})/r - 2 L^2 I_{wm}\dot\omega/r^2`:
  the wheel inertia adds :math:`2 I_{wm}/r^2` to the **(1, 1)** entry, and the matrix is
  diagonal.  The printed form is not even symmetric, so it cannot be the mass matrix of a
  Lagrangian system; with zero torque it does not conserve the kinetic energy
  (``tests/test_physics.py`` shows the drift).
* **Eq. 16** prints :math:`(v - l\dot\theta^2)`: the derivative of eq. 8 gives
  :math:`(\dot v - l\dot\theta^2)`, which eq. 18 then uses correctly.
* **Eq. 19** prints :math:`L(\tau_{mr} - \tau_{mr})/r`: the moment of the two wheel forces is
  :math:`\tau_d = L(\tau_r - \tau_l)/r`.
* Motor friction :math:`\tau_f` is named in eq. 22 but never modelled: here it is viscous plus
  tanh-smoothed Coulomb friction per wheel,
  :math:`\tau_f = b_f\,\omega_w + \tau_c \tanh(\omega_w / w_c)`, zero by default.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from wmr.core.plant import OUTPUT_NAMES, Pose, RobotParams

#: State variables of :func:`derivatives`, in order.
STATE_NAMES: Final = ("x", "y", "theta", "v", "omega", "phi_r", "phi_l")

State = npt.NDArray[np.float64] | list[float] | tuple[float, ...]


def mass_matrix_diag(params: RobotParams) -> tuple[float, float]:
    r"""Diagonal of the corrected :math:`M_{wm}` of eq. 24.

    .. math::

        M_{11} = m + \frac{2 I_{wm}}{r^2}, \qquad
        M_{22} = I_g + m l^2 + \frac{2 L^2 I_{wm}}{r^2}

    Products, not ``**``: a float power raises ``OverflowError`` where a product is ``inf``
    (``r = 1e308``), and the caller (:func:`wmr.config.scenario`'s sanity check) refuses a
    non-finite matrix naming the parameter.

    Returns
    -------
    tuple of float
        ``(M11, M22)`` in kg and kg m^2 (``inf`` when they overflow).
    """
    p = params
    r_sq = p.r * p.r
    m11 = p.m + 2.0 * p.Iwm / r_sq
    m22 = p.Ig + p.m * (p.l * p.l) + 2.0 * (p.L * p.L) * p.Iwm / r_sq
    return m11, m22


def wheel_speeds(v: float, omega: float, params: RobotParams) -> tuple[float, float]:
    r"""Wheel angular velocities from eq. 3 solved for the wheels (rolling without slip).

    .. math:: \omega_{r,l} = \frac{v \pm L\,\omega}{r}
    """
    return (v + params.L * omega) / params.r, (v - params.L * omega) / params.r


def friction_torque(omega_w: float, params: RobotParams) -> float:
    r"""Motor friction of one wheel, :math:`\tau_f` of eq. 22 (the paper leaves it open).

    .. math:: \tau_f = b_f\,\omega_w + \tau_c \tanh(\omega_w / w_c)
    """
    return params.b_f * omega_w + params.tau_c * math.tanh(omega_w / params.w_c)


def accelerations(v: float, omega: float, tau_r: float, tau_l: float,
                  params: RobotParams) -> tuple[float, float]:
    r"""Solve eq. 23 (corrected eq. 24) for :math:`(\dot v, \dot\omega)`.

    .. math::

        \dot v = \frac{(\tau_r - \tau_{fr} + \tau_l - \tau_{fl})/r + m l \omega^2}{M_{11}},
        \qquad
        \dot\omega = \frac{L(\tau_r - \tau_{fr} - \tau_l + \tau_{fl})/r - m l v \omega}{M_{22}}
    """
    p = params
    m11, m22 = mass_matrix_diag(p)
    w_r, w_l = wheel_speeds(v, omega, p)
    net_r = tau_r - friction_torque(w_r, p)
    net_l = tau_l - friction_torque(w_l, p)
    vdot = ((net_r + net_l) / p.r + p.m * p.l * omega * omega) / m11
    omegadot = (p.L * (net_r - net_l) / p.r - p.m * p.l * v * omega) / m22
    return vdot, omegadot


def derivatives(state: State, tau_r: float, tau_l: float,
                params: RobotParams) -> list[float]:
    r"""Time derivative of the state :data:`STATE_NAMES` under held motor torques.

    Kinematics (eq. 7 corrected, eq. 3):

    .. math::

        \dot x = v\cos\theta,\quad \dot y = v\sin\theta,\quad \dot\theta = \omega,\quad
        \dot\varphi_{r,l} = \omega_{r,l} = (v \pm L\omega)/r,

    dynamics: :func:`accelerations` (eq. 23 with the corrected eq. 24).

    Parameters
    ----------
    state
        ``[x, y, theta, v, omega, phi_r, phi_l]`` in SI units.
    tau_r, tau_l
        Right and left motor torque :math:`\tau_{mr}, \tau_{ml}` in N m.
    params
        Robot parameters.

    Returns
    -------
    list of float
        The seven derivatives, in state order.
    """
    theta = float(state[2])
    v = float(state[3])
    omega = float(state[4])
    vdot, omegadot = accelerations(v, omega, tau_r, tau_l, params)
    w_r, w_l = wheel_speeds(v, omega, params)
    return [v * math.cos(theta), v * math.sin(theta), omega, vdot, omegadot, w_r, w_l]


def kinetic_energy(v: float, omega: float, params: RobotParams) -> float:
    r"""Kinetic energy of platform, wheels and rotors (the FMU's ``E_kin``).

    .. math::

        T = \tfrac12 \left(m + \frac{2 I_{wm}}{r^2}\right) v^2
          + \tfrac12 \left(I_g + m l^2 + \frac{2 L^2 I_{wm}}{r^2}\right) \omega^2

    With zero motor and friction torque it is conserved (``docs/model.md``), while :math:`v` and
    :math:`\omega` exchange energy through the :math:`m l` terms of :math:`C(v)`.
    """
    m11, m22 = mass_matrix_diag(params)
    return 0.5 * m11 * v * v + 0.5 * m22 * omega * omega


def outputs(state: State, params: RobotParams) -> npt.NDArray[np.float64]:
    r"""Plant outputs in :data:`wmr.core.plant.OUTPUT_NAMES` order.

    Includes the centre of gravity of eq. 4, :math:`x_G + j y_G = x + j y + l e^{j\theta}`,
    and the kinetic energy :func:`kinetic_energy`.
    """
    x, y, theta, v, omega, phi_r, phi_l = (float(s) for s in state)
    w_r, w_l = wheel_speeds(v, omega, params)
    return np.array([
        x, y, theta, v, omega, w_r, w_l, phi_r, phi_l,
        x + params.l * math.cos(theta), y + params.l * math.sin(theta),
        kinetic_energy(v, omega, params),
    ], dtype=np.float64)


def equal_torque_solution(t: float, tau: float, params: RobotParams,
                          start: Pose | None = None) -> list[float]:
    r"""Exact state at time ``t`` for equal torques ``tau_r = tau_l = tau`` from rest.

    Without friction, :math:`\omega` stays zero (:math:`\dot\omega = -m l v\omega / M_{22} = 0`
    when :math:`\omega = 0`), so eq. 23 reduces to :math:`M_{11}\dot v = 2\tau/r`:

    .. math::

        v(t) = \frac{2\tau t}{r (m + 2 I_{wm}/r^2)},\qquad
        s(t) = \frac{\tau t^2}{r M_{11}},\qquad \varphi_{r,l}(t) = s(t)/r.

    Only valid with ``b_f = tau_c = 0``.
    """
    if start is None:
        start = Pose(0.0, 0.0, 0.0)
    m11, _ = mass_matrix_diag(params)
    v = 2.0 * tau * t / (params.r * m11)
    s = tau * t * t / (params.r * m11)
    c, sn = math.cos(start.heading_rad), math.sin(start.heading_rad)
    return [start.x_m + s * c, start.y_m + s * sn, start.heading_rad, v, 0.0,
            s / params.r, s / params.r]


def spin_solution(t: float, tau: float, params: RobotParams) -> tuple[float, float]:
    r"""Pure spin ``tau_r = -tau_l = tau`` from rest: what is exact, and what is not.

    With :math:`c = 2 L\tau / r`, eq. 23 reads

    .. math::

        M_{11}\dot v = m l \omega^2, \qquad M_{22}\dot\omega = c - m l v \omega .

    * If :math:`l = 0` (G on the axle) then :math:`v \equiv 0` and
      :math:`\omega(t) = c t / M_{22}` exactly.
    * If :math:`l \ne 0` the centrifugal term :math:`m l\omega^2` of :math:`C(v)` pushes B
      forward, so :math:`v` does **not** stay zero: a pure spin about B is not a solution.  The
      exact statements left are the power balance :math:`\dot T = c\,\omega` (the torques do
      no work on :math:`v` since :math:`\tau_r + \tau_l = 0`) and the Taylor series at
      :math:`t = 0`:

      .. math::

          \omega(t) = \frac{c t}{M_{22}} + O(t^4), \qquad
          v(t) = \frac{m l c^2 t^3}{3 M_{11} M_{22}^2} + O(t^5).

    Returns
    -------
    tuple of float
        ``(v, omega)``: exact when ``l == 0``, else the leading Taylor terms.
    """
    m11, m22 = mass_matrix_diag(params)
    c = 2.0 * params.L * tau / params.r
    omega = c * t / m22
    v = params.m * params.l * c * c * t**3 / (3.0 * m11 * m22 * m22)
    return v, omega


class ReferencePlant:
    """The :class:`wmr.core.plant.Plant` protocol on :func:`derivatives`, integrated by SciPy.

    Each :meth:`step` integrates the ODE over the control period with ``solve_ivp`` (DOP853)
    under zero-order-hold torques, the same contract as the FMU's ``doStep``.

    Parameters
    ----------
    rtol, atol
        Tolerances of ``solve_ivp``; the defaults make it a reference, not a fast plant.
    """

    def __init__(self, rtol: float = 1e-10, atol: float = 1e-10) -> None:
        self.rtol = rtol
        self.atol = atol
        self.params = RobotParams()
        self.t = 0.0
        self._state = np.zeros(7)

    @property
    def state(self) -> npt.NDArray[np.float64]:
        """A copy of the current state (:data:`STATE_NAMES`)."""
        return self._state.copy()

    def reset(self, params: RobotParams, start: Pose, v0_mps: float = 0.0,
              omega0_radps: float = 0.0) -> npt.NDArray[np.float64]:
        """Start at ``start`` with the given velocities and wheel angles zero; return outputs."""
        self.params = params
        self.t = 0.0
        self._state = np.array([start.x_m, start.y_m, start.heading_rad, v0_mps,
                                omega0_radps, 0.0, 0.0], dtype=np.float64)
        return outputs(self._state, params)

    def step(self, tau_r_nm: float, tau_l_nm: float, h_s: float) -> npt.NDArray[np.float64]:
        """Hold the torques for ``h_s`` seconds; return the outputs at the end of the step."""
        if not (math.isfinite(tau_r_nm) and math.isfinite(tau_l_nm)):
            raise ValueError(f"non-finite torque input ({tau_r_nm!r}, {tau_l_nm!r})")
        params = self.params
        tr, tl = float(tau_r_nm), float(tau_l_nm)

        def rhs(_t: float, s: npt.NDArray[np.float64]) -> list[float]:
            return derivatives(s, tr, tl, params)

        from scipy.integrate import solve_ivp  # 0.5 s of imports: only when integrating

        sol = solve_ivp(rhs, (0.0, h_s), self._state, method="DOP853",
                        rtol=self.rtol, atol=self.atol)
        if not sol.success:
            raise RuntimeError(f"ReferencePlant: solve_ivp failed at t={self.t:g}: {sol.message}")
        self._state = sol.y[:, -1].copy()
        self.t += h_s
        return outputs(self._state, params)

    def close(self) -> None:
        """Nothing to free."""


__all__ = [
    "OUTPUT_NAMES",
    "STATE_NAMES",
    "ReferencePlant",
    "accelerations",
    "derivatives",
    "equal_torque_solution",
    "friction_torque",
    "kinetic_energy",
    "mass_matrix_diag",
    "outputs",
    "spin_solution",
    "wheel_speeds",
]
