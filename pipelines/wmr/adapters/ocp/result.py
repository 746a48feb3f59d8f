"""What a solve returns (:class:`OptimalResult`) and the integrals of its torques."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from wmr.adapters.ocp.model import _initial_state, _model, _rk4_function
from wmr.adapters.ocp.problem import (
    DEFAULT_RK_SUBSTEPS,
    FloatArray,
    Objective,
    OptimalLimits,
    Status,
)
from wmr.core.energy import wheel_work
from wmr.core.plant import Pose, RobotParams


@dataclass
class OptimalResult:
    """One optimal manoeuvre.

    Attributes
    ----------
    status
        ``"solved"``, ``"infeasible"`` (no trajectory meets the limits) or ``"failed"``.
    message
        One line: IPOPT's return status and what it means, or why no NLP was solved.
    objective
        ``"time"``, ``"energy"`` or ``"mix"``.
    t_s
        (N + 1,) node times, s.
    states
        State name (the model's, e.g. ``x``, ``theta``, ``wheelR.phi``) -> (N + 1,) array, SI.
    torques
        (N, 2) motor torques (tau_r, tau_l) in N.m, each held over one interval.
    final_time_s
        Duration T of the manoeuvre, s (NaN unless solved).
    path_length_m
        Length of the path of B, :math:`\\int |v| dt`, m.
    energy_positive_j
        Work the motors deliver, J (:mod:`wmr.core.energy`: none recovered when braking; the net
        work is zero without friction, the robot starts and ends at rest).
    effort_N2m2s
        Control effort :math:`\\int (\\tau_r^2 + \\tau_l^2) dt`, N^2 m^2 s (the energy objective).
    max_wheel_speed_radps
        Largest :math:`|\\omega_{r,l}|` along the solution, rad/s.
    rollout_error_m
        Distance from the goal at T of the same torques integrated with 10 times finer RK4
        steps, m: the discretisation error an open-loop replay on the FMU sees.
    solve_time_s
        Wall time of the NLP solve, s (building the NLP, cached per process, excluded).
    iterations
        IPOPT iterations.
    """

    status: Status
    message: str
    objective: Objective
    start: Pose
    goal: Pose
    params: RobotParams
    limits: OptimalLimits
    t_s: FloatArray
    states: dict[str, FloatArray]
    torques: FloatArray
    final_time_s: float
    path_length_m: float
    energy_positive_j: float
    effort_N2m2s: float
    solve_time_s: float
    iterations: int
    rk_substeps: int = DEFAULT_RK_SUBSTEPS
    return_status: str = ""
    max_wheel_speed_radps: float = math.nan
    rollout_error_m: float = math.nan
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def interval_s(self) -> float:
        """Length of one torque interval, s (0 when there is none)."""
        return float(self.t_s[1] - self.t_s[0]) if self.t_s.size > 1 else 0.0

    @property
    def solved(self) -> bool:
        return self.status == "solved"

    def summary(self) -> dict[str, Any]:
        """JSON-ready fields (NaN becomes None)."""

        def num(v: float) -> float | None:
            return None if not math.isfinite(v) else float(v)

        return {
            "status": self.status,
            "message": self.message,
            "objective": self.objective,
            "final_time_s": num(self.final_time_s),
            "path_length_m": num(self.path_length_m),
            "energy_positive_j": num(self.energy_positive_j),
            "effort_N2m2s": num(self.effort_N2m2s),
            "solve_time_s": self.solve_time_s,
            "iterations": self.iterations,
            "n_intervals": int(self.torques.shape[0]),
            "limits": {k: getattr(self.limits, k) for k in
                       ("torque_max_nm", "wheel_speed_max_radps", "v_max_mps",
                        "omega_max_radps")},
        }


def _empty_result(status: Status, message: str, objective: Objective, start: Pose, goal: Pose,
                  params: RobotParams, limits: OptimalLimits, final_time_s: float,
                  ) -> OptimalResult:
    m = _model()
    x0 = _initial_state(start, params)
    solved = status == "solved"
    return OptimalResult(
        status=status, message=message, objective=objective, start=start, goal=goal,
        params=params, limits=limits,
        t_s=np.zeros(1) if solved else np.zeros(0),
        states={n: (np.array([x0[i]]) if solved else np.zeros(0))
                for i, n in enumerate(m.state_names)},
        torques=np.zeros((0, 2)), final_time_s=final_time_s,
        path_length_m=0.0 if solved else math.nan, energy_positive_j=0.0 if solved else math.nan,
        effort_N2m2s=0.0 if solved else math.nan, solve_time_s=0.0, iterations=0,
        max_wheel_speed_radps=0.0 if solved else math.nan,
        rollout_error_m=0.0 if solved else math.nan)


def _dense(start: Pose, params: RobotParams, torques: FloatArray, h: float, substeps: int,
           fine: int = 10) -> tuple[FloatArray, FloatArray, FloatArray]:
    """States and outputs on ``fine`` points per interval (the OCP's RK4, finer steps).

    Returns (t (K,), states (K, nx), outputs (K, ny)).
    """
    m = _model()
    p = m.param_vector(params, start)
    f = _rk4_function(max(1, math.ceil(substeps / fine)))
    x = _initial_state(start, params)
    xs, us = [x], [torques[0] if len(torques) else np.zeros(2)]
    for u in torques:
        for _ in range(fine):
            x = np.asarray(f(x, u, p, h / fine)).ravel()
            xs.append(x)
            us.append(u)
    xa, ua = np.array(xs), np.array(us)
    ys = np.asarray(m.out.map(xa.shape[0])(xa.T, ua.T, np.tile(p[:, None], (1, xa.shape[0]))))
    t = np.arange(xa.shape[0], dtype=float) * (h / fine)
    return t, xa, np.asarray(ys.T, dtype=float)


def _integrals(start: Pose, goal: Pose, params: RobotParams, torques: FloatArray, h: float,
               substeps: int) -> tuple[float, float, float, float]:
    """Path length (m), positive motor work (J), max |wheel speed| (rad/s) and final distance
    from the goal (m) of the solution's torques, integrated with 10 times finer RK4 steps."""
    m = _model()
    t, xa, ya = _dense(start, params, torques, h, substeps)
    speed = np.abs(xa[:, m.sx("v")])
    wr, wl = ya[:, m.oy("omega_r")], ya[:, m.oy("omega_l")]
    fine = (len(t) - 1) // max(len(torques), 1)
    u = np.repeat(torques, fine, axis=0)
    dt = np.diff(t)
    length = float(np.sum(0.5 * dt * (speed[1:] + speed[:-1])))
    work = wheel_work(u, np.column_stack([wr, wl]), dt)["energy_positive_j"]
    miss = math.hypot(xa[-1, m.sx("x")] - goal.x_m, xa[-1, m.sx("y")] - goal.y_m)
    return length, work, float(max(np.max(np.abs(wr)), np.max(np.abs(wl)))), miss


# ----------------------------------------------------------------------------------------------
