"""The one column layout of a closed-loop run.

The master loop fills a ``(n_steps, len(SIGNALS))`` float64 block with these columns, in this
order; the MCAP writer maps each column to its topic and field, and the reader gives them back
under the same names.  Names carry their unit.
"""

from __future__ import annotations

from typing import Final

#: Plant outputs, in the order of :data:`wmr.core.plant.OUTPUT_NAMES` (the FMU's output names).
PLANT_SIGNALS: Final = (
    "x_m",
    "y_m",
    "theta_rad",
    "v_mps",
    "omega_radps",
    "omega_r_radps",
    "omega_l_radps",
    "phi_r_rad",
    "phi_l_rad",
    "x_G_m",
    "y_G_m",
    "E_kin_J",
)

#: Stabiliser quantities of Section 4 (RPC eqs. 25 to 27, ROC), the PI terms of eq. 29, the
#: wheel references of eq. 28, the actuator torques, and the points D and R of Figs. 4 and 6.
CONTROL_SIGNALS: Final = (
    "dr_m",  # distance to the goal, Delta r
    "e_s_m",  # distance error e_s
    "e_theta_rad",  # angular error e_theta (= gamma under ROC)
    "alpha_rad",  # direction to the goal
    "beta_rad",  # theta_d - alpha
    "gamma_rad",  # 2 alpha - theta_d - theta
    "u_s_mps",  # PI output of the distance loop (commanded ds/dt)
    "u_theta_radps",  # PI output of the angle loop (commanded dtheta/dt)
    "p_s_mps",  # proportional term of u_s
    "i_s_mps",  # integral term of u_s
    "p_theta_radps",  # proportional term of u_theta
    "i_theta_radps",  # integral term of u_theta
    "omega_r_ref_radps",  # wheel speed references, eq. 28
    "omega_l_ref_radps",
    "tau_r_nm",  # motor torques sent to the plant
    "tau_l_nm",
    "D_x_m",  # point D on the heading line (Fig. 4)
    "D_y_m",
    "R_x_m",  # reference point R of the orientation control (Fig. 6)
    "R_y_m",
)

#: What a point stabiliser fills (:meth:`wmr.core.control.Stabiliser.update`): the
#: :data:`CONTROL_SIGNALS` but the two torques, which the wheel servos add.  A controller of
#: :mod:`wmr.core.control.registry` names the ones it fills; the rest are logged as NaN.
LAW_SIGNALS: Final = tuple(s for s in CONTROL_SIGNALS if s not in ("tau_r_nm", "tau_l_nm"))
#: Index of each of :data:`LAW_SIGNALS` in the stabiliser's tuple.
LAW_INDEX: Final = {name: i for i, name in enumerate(LAW_SIGNALS)}
#: The two a stabiliser must fill: the wheel speed references of eq. 28, the servos' inputs.
WHEEL_REFERENCES: Final = ("omega_r_ref_radps", "omega_l_ref_radps")

SIGNALS: Final = PLANT_SIGNALS + CONTROL_SIGNALS
COLUMN: Final = {name: i for i, name in enumerate(SIGNALS)}
