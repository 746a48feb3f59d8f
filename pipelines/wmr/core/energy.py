r"""The one definition of the motors' energy, shared by ``wmr run``, ``wmr optimal``,
``wmr benchmark`` and the batch summaries.

The mechanical power of wheel :math:`i` is :math:`p_i = \tau_i \omega_i` (motor torque times
wheel speed).  Over a step of length :math:`h` the torque :math:`\tau_k` is held and the wheel
speed goes from :math:`\omega_k` to :math:`\omega_{k+1}`; each integral below is the trapezoid
rule on the power at the two ends of the step, summed over both wheels and every step:

``energy_net_j``
    :math:`\int \sum_i p_i\,dt`: net work.  The kinetic energy gained plus what friction took;
    about 0 for a rest-to-rest manoeuvre without friction (braking gives it all back).
``energy_positive_j``
    :math:`\int \sum_i \max(p_i, 0)\,dt`: the work the motors deliver, none recovered when
    braking.  **The** energy of a manoeuvre: what the controllers and the optimum are compared
    on (``energy_ratio`` of ``wmr benchmark``).
``energy_abs_j``
    :math:`\int \sum_i |p_i|\,dt`: driving and braking both cost (motors that brake by
    counter-torque); equals ``2 energy_positive_j - energy_net_j``.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

#: The energy keys of every result record, in this order.
ENERGY_KEYS: Final = ("energy_net_j", "energy_positive_j", "energy_abs_j")


def step_work(h_s: float, tau_r_nm: float, tau_l_nm: float, w_r0: float, w_r1: float,
              w_l0: float, w_l1: float) -> tuple[float, float, float]:
    """Net, positive and absolute work (J) of one step of ``h_s`` s with held torques.

    ``w_r0``, ``w_r1`` (``w_l0``, ``w_l1``): right (left) wheel speed at the start and end of
    the step, rad/s.  Scalar form of :func:`wheel_work` for the master loop's hot path.
    """
    a, b = tau_r_nm * w_r0, tau_r_nm * w_r1
    c, d = tau_l_nm * w_l0, tau_l_nm * w_l1
    half = 0.5 * h_s
    net = half * (a + b + c + d)
    pos = half * (max(a, 0.0) + max(b, 0.0) + max(c, 0.0) + max(d, 0.0))
    return net, pos, 2.0 * pos - net


def wheel_work(tau_nm: npt.ArrayLike, omega_radps: npt.ArrayLike,
               dt_s: npt.ArrayLike) -> dict[str, float]:
    """The :data:`ENERGY_KEYS` of a run, J.

    Parameters
    ----------
    tau_nm
        (n, 2) torques (right, left), N m, each held over one step.
    omega_radps
        (n + 1, 2) wheel speeds (right, left) at the step boundaries, rad/s.
    dt_s
        Step length(s), s: a scalar or (n,).
    """
    tau = np.asarray(tau_nm, dtype=np.float64).reshape(-1, 2)
    w = np.asarray(omega_radps, dtype=np.float64).reshape(-1, 2)
    if w.shape[0] != tau.shape[0] + 1:
        raise ValueError(f"{tau.shape[0]} steps need {tau.shape[0] + 1} wheel speeds, "
                         f"got {w.shape[0]}")
    half = 0.5 * np.broadcast_to(np.asarray(dt_s, dtype=np.float64), (tau.shape[0],))
    p0, p1 = tau * w[:-1], tau * w[1:]
    net = float(np.sum(half * np.sum(p0 + p1, axis=1)))
    pos = float(np.sum(half * np.sum(np.maximum(p0, 0.0) + np.maximum(p1, 0.0), axis=1)))
    return {"energy_net_j": net, "energy_positive_j": pos, "energy_abs_j": 2.0 * pos - net}


__all__ = ["ENERGY_KEYS", "step_work", "wheel_work"]
