"""The warm start: a kinematic rotate-translate-rotate path with trapezoidal speed profiles
(and the cold start it falls back to)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from wmr.adapters.ocp.model import _initial_state, _model
from wmr.adapters.ocp.problem import MIN_FINAL_TIME_S, FloatArray, OptimalLimits
from wmr.adapters.ocp.result import OptimalResult
from wmr.core.plant import Pose, RobotParams

#: How near the goal a previous solution, moved rigidly onto the new start, must end for
#: :func:`_previous_guess` to take it: the same manoeuvre relative to the start, to
#: :data:`PREVIOUS_NEAR_M` and :data:`PREVIOUS_NEAR_HEADING_RAD` (a batch varying the robot or
#: its limits, not its poses).  Measured (10 m, 0 deg to the origin at 180 deg, the PI's
#: limits): from a nearby start (0.5 m, 1 m and 6 deg away) the previous solution, primal or
#: primal-dual, led IPOPT to worse local optima (11.237 s and 11.901 s where the kinematic
#: path found 11.227 s and 11.471 s) in as many iterations or more; on the same manoeuvre
#: with m = 40 kg it found the same optimum in 16 iterations, as the kinematic path does.
PREVIOUS_NEAR_M = 1e-3
PREVIOUS_NEAR_HEADING_RAD = 1e-3


def _wrap(a: float) -> float:
    """Angle wrapped to (-pi, pi]."""
    w = math.remainder(a, 2.0 * math.pi)
    return math.pi if w == -math.pi else w


def _trapezoid(dist: float, acc: float, vmax: float, t: float) -> tuple[float, float, float]:
    """(s, sdot, sddot) at time ``t`` of a rest-to-rest trapezoidal profile over ``dist`` >= 0."""
    if dist <= 0.0:
        return 0.0, 0.0, 0.0
    t_acc = min(vmax / acc, math.sqrt(dist / acc))
    v_top = acc * t_acc
    t_cruise = max(0.0, (dist - acc * t_acc**2) / v_top) if v_top > 0 else 0.0
    total = 2 * t_acc + t_cruise
    t = min(max(t, 0.0), total)
    if t < t_acc:
        return 0.5 * acc * t**2, acc * t, acc
    if t < t_acc + t_cruise:
        return 0.5 * acc * t_acc**2 + v_top * (t - t_acc), v_top, 0.0
    tr = total - t
    return dist - 0.5 * acc * tr**2, acc * tr, -acc


def _trapezoid_time(dist: float, acc: float, vmax: float) -> float:
    if dist <= 0.0:
        return 0.0
    if dist <= vmax**2 / acc:
        return 2.0 * math.sqrt(dist / acc)
    return dist / vmax + vmax / acc


@dataclass(frozen=True)
class _Guess:
    w0: FloatArray
    final_time_s: float



@lru_cache(maxsize=1)
def _gain_function() -> ca.Function:
    """``(x, p) -> (f(x, 0, p), df/du)``: the model's ODE is affine in the torques."""
    m = _model()
    nx, nu, npar = m.ode.size1_in(0), m.ode.size1_in(1), m.ode.size1_in(2)
    x, u, p = ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("p", npar)
    f = m.ode(x, u, p)
    f0 = ca.substitute(f, u, ca.DM.zeros(nu))
    return ca.Function("wmr_gain", [x, p], [f0, ca.jacobian(f, u)], ["x", "p"], ["f0", "B"])


def _segment_state(segs: list[tuple[str, float]], durations: list[float], acc: float,
                   alpha: float, vmax: float, wmax: float, t: float
                   ) -> tuple[float, float, float, float, float, float]:
    """(arc length, heading change, v, omega, vdot, omegadot) of the path at time ``t``."""
    pos = dth = v = w = vd = wd = 0.0
    t0 = 0.0
    for (kind, amount), d in zip(segs, durations, strict=True):
        local = t - t0
        inside = 0.0 <= local < d
        if kind == "rot":
            s, sd, sdd = _trapezoid(abs(amount), alpha, wmax, local)
            sg = math.copysign(1.0, amount)
            dth += sg * s
            if inside:
                w, wd = sg * sd, sg * sdd
        else:
            s, sd, sdd = _trapezoid(amount, acc, vmax, local)
            pos = s
            if inside:
                v, vd = sd, sdd
        t0 += d
    return pos, dth, v, w, vd, wd


def _kinematic_guess(start: Pose, goal: Pose, params: RobotParams, limits: OptimalLimits,
                     n: int, final_time_s: float | None, p: FloatArray,
                     allow_reverse: bool = False) -> _Guess:
    """Rotate onto the line, drive along it, rotate to the goal heading.

    The line is driven forward, or backward when ``allow_reverse`` and that turns less.

    Speeds follow rest-to-rest trapezoidal profiles at half the acceleration that the torque
    limit gives at the start (from the model's input gain) and at 80 % of the speed limits; the
    wheel angles integrate the model's own wheel speeds; the torques are the model's inverse
    dynamics at the middle of each interval, clipped to the limit.  With ``final_time_s`` the
    profile is stretched in time to it.
    """
    m = _model()
    gain = _gain_function()
    x0 = _initial_state(start, params)
    iv, iw, ix, iy, ith = m.sx("v"), m.sx("omega"), m.sx("x"), m.sx("y"), m.sx("theta")
    b = np.asarray(gain(x0, p)[1])
    tau = max(limits.torque_max_nm, 1e-6)
    acc = 0.5 * tau * float(abs(b[iv, 0]) + abs(b[iv, 1]))
    alpha = 0.5 * tau * float(abs(b[iw, 0]) + abs(b[iw, 1]))
    vmax = wmax = math.inf
    if limits.v_max_mps is not None:
        vmax = 0.8 * limits.v_max_mps
    if limits.omega_max_radps is not None:
        wmax = 0.8 * limits.omega_max_radps
    if limits.wheel_speed_max_radps is not None:
        vmax = min(vmax, 0.8 * limits.wheel_speed_max_radps * params.r)
        wmax = min(wmax, 0.8 * limits.wheel_speed_max_radps * params.r / params.L)
    dx, dy = goal.x_m - start.x_m, goal.y_m - start.y_m
    dist = math.hypot(dx, dy)
    sign = 1.0
    if dist > 1e-9:
        bearing = math.atan2(dy, dx)
        fwd = (_wrap(bearing - start.heading_rad), _wrap(goal.heading_rad - bearing), 1.0)
        back = bearing + math.pi
        bwd = (_wrap(back - start.heading_rad), _wrap(goal.heading_rad - back), -1.0)
        options = [fwd, bwd] if allow_reverse else [fwd]
        rot1, rot2, sign = min(options, key=lambda c: abs(c[0]) + abs(c[1]))
        ux, uy = dx / dist, dy / dist
    else:
        rot1, rot2, ux, uy = _wrap(goal.heading_rad - start.heading_rad), 0.0, 0.0, 0.0
    segs = [("rot", rot1), ("lin", dist), ("rot", rot2)]
    durations = [_trapezoid_time(abs(a), alpha, wmax) if kind == "rot"
                 else _trapezoid_time(a, acc, vmax) for kind, a in segs]
    total = max(sum(durations), MIN_FINAL_TIME_S)
    stretch = 1.0 if final_time_s is None else final_time_s / total
    t_final = total * stretch
    h = t_final / n

    def at(t_s: float) -> tuple[FloatArray, float, float]:
        pos, dth, v, w, vd, wd = _segment_state(segs, durations, acc, alpha, vmax, wmax,
                                                t_s / stretch)
        xs = x0.copy()
        xs[ix], xs[iy] = start.x_m + pos * ux, start.y_m + pos * uy
        xs[ith] = start.heading_rad + dth
        xs[iv], xs[iw] = sign * v / stretch, w / stretch
        return xs, sign * vd / stretch**2, wd / stretch**2

    times = np.linspace(0.0, t_final, n + 1)
    xs = np.column_stack([at(float(t))[0] for t in times])
    # the other states (the wheel angles): integrate the model's own rates along the guess
    pp = np.tile(p[:, None], (1, n + 1))
    rates = np.asarray(m.ode.map(n + 1)(xs, np.zeros((2, n + 1)), pp))
    for i in m.wheel_states():
        xs[i, :] = x0[i] + np.concatenate(
            ([0.0], np.cumsum(0.5 * h * (rates[i, 1:] + rates[i, :-1]))))
    us = np.zeros((2, n))
    rows = [iv, iw]
    for k in range(n):
        xm, vd, wd = at(float(times[k] + 0.5 * h))
        f0, bm = (np.asarray(a) for a in gain(xm, p))
        try:
            us[:, k] = np.linalg.solve(bm[rows, :], np.array([vd, wd]) - f0.ravel()[rows])
        except np.linalg.LinAlgError:
            us[:, k] = 0.0
    us = np.clip(us, -limits.torque_max_nm, limits.torque_max_nm)
    w0 = np.concatenate([xs.ravel(order="F"), us.ravel(order="F"), [t_final]])
    return _Guess(w0, t_final)


def _cold_guess(start: Pose, goal: Pose, params: RobotParams, n: int,
                final_time_s: float | None) -> _Guess:
    """No warm start: poses interpolated linearly (shortest turn), at rest, no torque, T = 10 s."""
    m = _model()
    x0 = _initial_state(start, params)
    t_final = 10.0 if final_time_s is None else final_time_s
    s = np.linspace(0.0, 1.0, n + 1)
    xs = np.tile(x0[:, None], (1, n + 1))
    xs[m.sx("x"), :] = start.x_m + s * (goal.x_m - start.x_m)
    xs[m.sx("y"), :] = start.y_m + s * (goal.y_m - start.y_m)
    xs[m.sx("theta"), :] = start.heading_rad + s * _wrap(goal.heading_rad - start.heading_rad)
    w0 = np.concatenate([xs.ravel(order="F"), np.zeros(2 * n), [t_final]])
    return _Guess(w0, t_final)


def _previous_guess(previous: OptimalResult, start: Pose, goal: Pose, n: int,
                    final_time_s: float | None) -> _Guess | None:
    """A solved earlier manoeuvre as the guess of this one, or None when it is not near.

    The dynamics are invariant under planar rigid motions, so the earlier solution is rotated
    and translated from its start onto ``start`` (speeds, wheel angles and torques unchanged);
    it is taken when its moved end lies at ``goal`` (:data:`PREVIOUS_NEAR_M`,
    :data:`PREVIOUS_NEAR_HEADING_RAD`): the same relative manoeuvre on another robot or with
    other limits.  With ``final_time_s`` its time is that one (the bounds
    fix it anyway).
    """
    if not previous.solved or previous.torques.shape[0] != n:
        return None
    m = _model()
    s0 = previous.start
    turn = start.heading_rad - s0.heading_rad
    c, s = math.cos(turn), math.sin(turn)

    def moved(x: FloatArray | float, y: FloatArray | float) -> tuple[FloatArray, FloatArray]:
        dx, dy = np.asarray(x) - s0.x_m, np.asarray(y) - s0.y_m
        return start.x_m + c * dx - s * dy, start.y_m + s * dx + c * dy

    gx, gy = moved(previous.goal.x_m, previous.goal.y_m)
    if math.hypot(float(gx) - goal.x_m, float(gy) - goal.y_m) > PREVIOUS_NEAR_M or abs(_wrap(
            previous.goal.heading_rad + turn - goal.heading_rad)) > PREVIOUS_NEAR_HEADING_RAD:
        return None
    xs = np.array([previous.states[name] for name in m.state_names], dtype=float)
    ix, iy, ith = m.sx("x"), m.sx("y"), m.sx("theta")
    xs[ix], xs[iy] = moved(xs[ix], xs[iy])
    xs[ith] = xs[ith] + turn
    t_final = previous.final_time_s if final_time_s is None else final_time_s
    w0 = np.concatenate([xs.ravel(order="F"), previous.torques.T.ravel(order="F"), [t_final]])
    return _Guess(w0, t_final)
