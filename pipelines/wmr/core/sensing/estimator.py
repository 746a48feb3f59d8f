"""What the stabiliser knows: the sensors of a run and its estimator, stepped by the master.

:class:`Sensing` is built from a run's :class:`~wmr.core.sensing.config.SensorConfig`; the master
calls :meth:`Sensing.step` once per control step with the plant's outputs and gives the
stabiliser the returned pose and velocities instead of the true ones.  It also records what the
log shows: the position fixes (``/sensors/gps``) and the estimate with its covariance
(``/robot/pose_estimate``).

Estimators:

* ``none``: the latest position fix and the latest compass heading as they arrive (stale by
  their latency, noisy); the initial estimate until the first fix arrives;
* ``ekf``: :class:`~wmr.core.sensing.ekf.PoseEKF` predicting with the encoders' wheel travels and
  correcting with each fix at its measurement step.

Both start from the start pose as known when the robot is set down: the true start plus a
draw of ``N(0, P0)``, ``P0 = diag(gps_sigma^2, gps_sigma^2, heading_sigma^2)`` (the compass
sigma, or ``initial_heading_sigma_deg`` without a compass).  Speeds ``v``, ``omega`` for the
rest test come from the encoders (wheel travel over the last encoder interval).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wmr.core.plant import Pose, RobotParams
from wmr.core.sensing.config import SensorConfig
from wmr.core.sensing.ekf import PoseEKF
from wmr.core.sensing.models import Compass, Encoders, Gps, generators


@dataclass(frozen=True)
class SensingRecord:
    """What a run's sensing produced, for the log.

    Attributes
    ----------
    gps_t_ns, gps_arrival_ns
        Measurement and arrival time of each position fix, ns from the start, shape ``(k,)``.
    gps_xy_m
        The fixes, shape ``(k, 2)``.
    est_t_ns
        Time of each estimate (every control step), ns, shape ``(n,)``.
    est_pose
        ``(x_m, y_m, theta_rad)`` per step, shape ``(n, 3)``.
    est_cov
        Covariance ``(xx, xy, yy, theta theta)`` per step (m^2, rad^2), shape ``(n, 4)``;
        NaN under estimator ``none``.
    """

    gps_t_ns: npt.NDArray[np.int64]
    gps_arrival_ns: npt.NDArray[np.int64]
    gps_xy_m: npt.NDArray[np.float64]
    est_t_ns: npt.NDArray[np.int64]
    est_pose: npt.NDArray[np.float64]
    est_cov: npt.NDArray[np.float64]


class Sensing:
    """The sensors and the estimator of one run.

    Parameters
    ----------
    cfg
        The ``[sensors]`` table.
    period_s
        Control period, s.
    params
        The robot (wheel radius ``r`` and half track ``L`` for the odometry).
    start
        The true start pose.
    goal
        The goal pose: with ``start`` and ``cfg.seed``, seeds the noise
        (:func:`~wmr.core.sensing.models.generators`).
    """

    def __init__(self, cfg: SensorConfig, period_s: float, params: RobotParams, start: Pose,
                 goal: Pose) -> None:
        cfg.check(period_s)
        self.cfg = cfg
        self._h = period_s
        # the estimator's wheel radius: the odometry's scale error, if any
        self._r = params.r * (1.0 + cfg.wheel_radius_error_frac)
        self._half_track = params.L
        rngs = generators(cfg.seed, (start.x_m, start.y_m, start.heading_rad,
                                      goal.x_m, goal.y_m, goal.heading_rad))
        self.gps = Gps(cfg, period_s, rngs)
        self.compass = Compass(cfg, period_s, rngs) if cfg.heading == "compass" else None
        self.encoders = Encoders(cfg, period_s)
        heading_sigma = (self.compass.sigma_rad if self.compass is not None
                         else math.radians(cfg.initial_heading_sigma_deg))
        sig0 = np.array([cfg.gps_sigma_m, cfg.gps_sigma_m, heading_sigma])
        draw = rngs["initial"].normal(0.0, 1.0, 3) * sig0
        s0 = (start.x_m + float(draw[0]), start.y_m + float(draw[1]),
              start.heading_rad + float(draw[2]))
        self._pose = s0
        delays = [self.gps.schedule.delay_steps]
        if self.compass is not None:
            delays.append(self.compass.schedule.delay_steps)
        self.ekf = (PoseEKF(s0, np.diag(sig0 * sig0), params.L, cfg.odometry_noise_m2_per_m,
                            self.encoders.quantum_rad * params.r, max(delays) + 1)
                    if cfg.estimator == "ekf" else None)
        self._enc_prev: tuple[float, float] | None = None
        self._enc_prev_n = 0
        self._v = 0.0
        self._omega = 0.0
        self._gps: list[tuple[int, int, float, float]] = []
        self._est: list[tuple[float, ...]] = []

    def step(self, n: int, out: npt.NDArray[np.float64]
             ) -> tuple[float, float, float, float, float]:
        """Sense the plant's outputs ``out`` at step ``n``; the stabiliser's
        ``(x_m, y_m, theta_rad, v_mps, omega_radps)``."""
        x, y, theta = float(out[0]), float(out[1]), float(out[2])
        travel_r = travel_l = 0.0
        if self.encoders.schedule.samples(n):
            enc = (self.encoders.read(float(out[7])), self.encoders.read(float(out[8])))
            if self._enc_prev is not None:
                travel_r = self._r * (enc[0] - self._enc_prev[0])
                travel_l = self._r * (enc[1] - self._enc_prev[1])
                dt = (n - self._enc_prev_n) * self._h
                self._v = 0.5 * (travel_r + travel_l) / dt
                self._omega = (travel_r - travel_l) / (2.0 * self._half_track * dt)
            self._enc_prev, self._enc_prev_n = enc, n
        if self.ekf is not None and n:
            self.ekf.predict(travel_r, travel_l)
        self.gps.measure(n, x, y)
        if self.compass is not None:
            self.compass.measure(n, theta)
        ex, ey, eth = self._pose
        sigma = self.cfg.gps_sigma_m
        for fix in self.gps.arrivals(n):
            self._gps.append((fix.step, fix.arrival, fix.value[0], fix.value[1]))
            if self.ekf is not None:
                self.ekf.update_position(fix.value[0], fix.value[1], sigma, fix.step)
            else:
                ex, ey = fix.value
        if self.compass is not None:
            for fix in self.compass.arrivals(n):
                if self.ekf is not None:
                    self.ekf.update_heading(fix.value[0], self.compass.sigma_rad, fix.step)
                else:
                    eth = fix.value[0]
        if self.ekf is not None:
            ex, ey, eth = self.ekf.pose
            p = self.ekf.p
            self._est.append((ex, ey, eth, p[0, 0], p[0, 1], p[1, 1], p[2, 2]))
        else:
            self._est.append((ex, ey, eth, math.nan, math.nan, math.nan, math.nan))
        self._pose = (ex, ey, eth)
        return ex, ey, eth, self._v, self._omega

    @property
    def pose(self) -> Pose:
        """The latest estimate."""
        return Pose(*self._pose)

    def record(self) -> SensingRecord:
        """The fixes and the estimates so far."""
        h_ns = self._h * 1e9
        g = np.array(self._gps, dtype=np.float64).reshape(-1, 4)
        e = np.array(self._est, dtype=np.float64).reshape(-1, 7)
        return SensingRecord(
            gps_t_ns=np.rint(g[:, 0] * h_ns).astype(np.int64),
            gps_arrival_ns=np.rint(g[:, 1] * h_ns).astype(np.int64),
            gps_xy_m=g[:, 2:4].copy(),
            est_t_ns=np.rint(np.arange(len(e)) * h_ns).astype(np.int64),
            est_pose=e[:, :3].copy(), est_cov=e[:, 3:].copy())


__all__ = ["Sensing", "SensingRecord"]
