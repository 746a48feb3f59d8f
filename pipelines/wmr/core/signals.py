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

SIGNALS: Final = PLANT_SIGNALS + CONTROL_SIGNALS
COLUMN: Final = {name: i for i, name in enumerate(SIGNALS)}
