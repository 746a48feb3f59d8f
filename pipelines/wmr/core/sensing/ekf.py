r"""An extended Kalman filter of the planar pose, driven by wheel odometry, corrected by
position and heading fixes applied at their measurement time.

State :math:`s = (x, y, \theta)` of point B (m, m, rad).  One :meth:`PoseEKF.predict` per
control step, with the wheel travels :math:`\Delta_r = r\Delta\varphi_r`,
:math:`\Delta_l = r\Delta\varphi_l` since the last step (zero when no encoder sample fell in
it).  The motion model is the midpoint (second-order) odometry of a differential drive:

.. math::

    \Delta s = \tfrac12(\Delta_r + \Delta_l),\quad \Delta\theta = (\Delta_r - \Delta_l)/(2L),
    \quad s^+ = s + (\Delta s\cos\bar\theta,\ \Delta s\sin\bar\theta,\ \Delta\theta),
    \quad \bar\theta = \theta + \Delta\theta/2,

exact for a step of constant curvature whose chord is taken as its arc (and exact on straight
lines).  Odometry noise is the classic model of Thrun et al. (*Probabilistic Robotics*,
ch. 5): each wheel's travel has variance ``k2 * |Delta_w|`` (``k2`` in m, a random walk per
metre rolled), mapped through the Jacobian of the motion model with respect to the wheel
travels, plus the variance of the encoder quantisation of each increment.

Latency: the filter keeps the last ``history_steps`` steps (prior state and covariance, wheel
travels and the fixes measured in that step).  A fix measured ``d`` steps ago is filed in its
step, and the filter is re-run from there with the stored travels: exactly what it would have
computed had the fix arrived without delay (tested).  ``compensate_latency=False`` applies
fixes on arrival instead, as a filter unaware of the latency would (the tests' baseline).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

Vec = npt.NDArray[np.float64]


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@dataclass
class _Fix:
    kind: str  # "xy" or "theta"
    z: tuple[float, ...]
    var: float  # variance per component, m^2 or rad^2


@dataclass
class _Step:
    prior_s: Vec
    prior_p: Vec
    travel_r_m: float
    travel_l_m: float
    fixes: list[_Fix] = field(default_factory=list)


class PoseEKF:
    """EKF of ``(x_m, y_m, theta_rad)`` with odometry prediction and delayed fixes.

    Parameters
    ----------
    s0
        Initial estimate ``(x_m, y_m, theta_rad)``.
    p0
        Initial covariance, 3 x 3 (m^2, rad^2).
    half_track_m
        ``L``, half the distance between the wheels, m.
    odometry_var_per_m
        ``k2``: variance of a wheel's travel per metre rolled, m^2/m.
    quantum_m
        Wheel travel of one encoder count, m (``0``: exact angles).
    history_steps
        Steps kept for fixes measured in the past (at least the largest latency, in steps).
    compensate_latency
        File fixes at their measurement step (``True``) or apply them on arrival.
    """

    #: Floor of a fix variance, so that an exact fix on an exact state stays well defined.
    MIN_VAR = 1e-14

    def __init__(self, s0: tuple[float, float, float], p0: npt.ArrayLike, half_track_m: float,
                 odometry_var_per_m: float = 0.0, quantum_m: float = 0.0,
                 history_steps: int = 1, compensate_latency: bool = True) -> None:
        self._half_track = float(half_track_m)
        self._k2 = float(odometry_var_per_m)
        # each increment is the difference of two quantised readings: twice q^2/12
        self._q_var = 2.0 * quantum_m * quantum_m / 12.0
        self._compensate = compensate_latency
        s = np.array(s0, dtype=np.float64)
        p = np.array(p0, dtype=np.float64)
        self.step_index = 0
        self._hist: deque[_Step] = deque([_Step(s.copy(), p.copy(), 0.0, 0.0)],
                                         maxlen=max(1, int(history_steps)) + 1)
        self.s = s
        self.p = p

    # -- model -------------------------------------------------------------------------------
    def _predict(self, s: Vec, p: Vec, d_r: float, d_l: float) -> tuple[Vec, Vec]:
        ds = 0.5 * (d_r + d_l)
        dth = (d_r - d_l) / (2.0 * self._half_track)
        th_m = s[2] + 0.5 * dth
        c, sn = math.cos(th_m), math.sin(th_m)
        s_new = np.array([s[0] + ds * c, s[1] + ds * sn, s[2] + dth])
        f = np.array([[1.0, 0.0, -ds * sn], [0.0, 1.0, ds * c], [0.0, 0.0, 1.0]])
        # d s_new / d (d_r, d_l)
        a = 0.5 * c
        b = 0.5 * sn
        e = ds * sn / (4.0 * self._half_track)
        g = ds * c / (4.0 * self._half_track)
        inv = 1.0 / (2.0 * self._half_track)
        w = np.array([[a - e, a + e], [b + g, b - g], [inv, -inv]])
        var_r = self._k2 * abs(d_r) + (self._q_var if d_r or d_l else 0.0)
        var_l = self._k2 * abs(d_l) + (self._q_var if d_r or d_l else 0.0)
        p_new = f @ p @ f.T + (w * np.array([var_r, var_l])) @ w.T
        return s_new, p_new

    @classmethod
    def _update(cls, s: Vec, p: Vec, fix: _Fix) -> tuple[Vec, Vec]:
        var = max(fix.var, cls.MIN_VAR)
        if fix.kind == "xy":
            h = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
            innov = np.array([fix.z[0] - s[0], fix.z[1] - s[1]])
            r = np.eye(2) * var
        else:
            h = np.array([[0.0, 0.0, 1.0]])
            innov = np.array([_wrap(fix.z[0] - s[2])])
            r = np.array([[var]])
        sk = h @ p @ h.T + r
        k = np.linalg.solve(sk, h @ p).T  # P H^T S^-1 (S and P symmetric)
        s_new = s + k @ innov
        ikh = np.eye(3) - k @ h
        p_new = ikh @ p @ ikh.T + k @ r @ k.T  # Joseph form: stays symmetric positive
        return s_new, p_new

    # -- interface ---------------------------------------------------------------------------
    def predict(self, travel_r_m: float, travel_l_m: float) -> None:
        """Advance one control step with the wheel travels since the last one, m."""
        s, p = self._predict(self.s, self.p, travel_r_m, travel_l_m)
        self._hist.append(_Step(s, p, float(travel_r_m), float(travel_l_m)))
        self.step_index += 1
        self.s, self.p = s.copy(), p.copy()

    def _file(self, fix: _Fix, step: int) -> None:
        first = self.step_index - len(self._hist) + 1
        if not self._compensate or step >= self.step_index:
            step = self.step_index
        i = max(step, first) - first  # older than the history: the oldest step kept
        self._hist[i].fixes.append(fix)
        entry = self._hist[i]
        s, p = entry.prior_s, entry.prior_p
        for f in entry.fixes:
            s, p = self._update(s, p, f)
        for j in range(i + 1, len(self._hist)):
            entry = self._hist[j]
            s, p = self._predict(s, p, entry.travel_r_m, entry.travel_l_m)
            entry.prior_s, entry.prior_p = s, p
            for f in entry.fixes:
                s, p = self._update(s, p, f)
        self.s, self.p = s, p

    def update_position(self, x_m: float, y_m: float, sigma_m: float, step: int) -> None:
        """A position fix measured at control step ``step`` (per-axis noise ``sigma_m``)."""
        self._file(_Fix("xy", (float(x_m), float(y_m)), sigma_m * sigma_m), step)

    def update_heading(self, theta_rad: float, sigma_rad: float, step: int) -> None:
        """A heading fix measured at control step ``step``."""
        self._file(_Fix("theta", (float(theta_rad),), sigma_rad * sigma_rad), step)

    @property
    def pose(self) -> tuple[float, float, float]:
        """The current estimate ``(x_m, y_m, theta_rad)``, heading wrapped to (-pi, pi]."""
        return float(self.s[0]), float(self.s[1]), _wrap(float(self.s[2]))


__all__ = ["PoseEKF"]
