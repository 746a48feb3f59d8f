r"""Optimal point-to-point manoeuvres of the robot: the CasADi/IPOPT reference for the PI loop.

The optimal control problem (OCP) runs on the dynamics of the Modelica model itself: the
explicit ODE :math:`\dot x = f(x, u, p)` that :func:`wmr.fmu.flatten.flatten` derives from
``modelica/WMR`` with pymoca, the same CasADi function the FMUs are generated from.  States,
parameters and outputs are looked up by name, never by position.

Transcription: direct multiple shooting on ``n_intervals`` intervals of equal length
:math:`h = T / N`, torques piecewise constant per interval, ``rk_substeps`` classical RK4
sub-steps per interval; the interval map is a ``casadi.Function.map`` and the NLP is expanded to
SX and solved by IPOPT.  One NLP is built per ``(n_intervals, rk_substeps)`` and process and
reused: start, goal, robot parameters and limits enter as NLP parameters and bounds.

See ``docs/optimal.md`` for the formulation, the warm start and what the optimum says.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Final, Literal

import casadi as ca
import numpy as np
import numpy.typing as npt

from wmr._callable import make_callable
from wmr.energy import wheel_work
from wmr.errors import ConfigError
from wmr.plant import OUTPUT_NAMES, Pose, RobotParams

Objective = Literal["time", "energy", "mix"]
Status = Literal["solved", "infeasible", "failed"]
FloatArray = npt.NDArray[np.float64]

OBJECTIVES: Final = ("time", "energy", "mix")
#: Default number of shooting intervals and RK4 sub-steps per interval.
DEFAULT_INTERVALS: Final = 60
DEFAULT_RK_SUBSTEPS: Final = 4
#: Start and goal closer than this (m, and rad for the heading) are the same pose.
SAME_POSE_TOL: Final = 1e-9
#: Bounds on the free final time (s).
MIN_FINAL_TIME_S: Final = 1e-2
MAX_FINAL_TIME_S: Final = 600.0
#: Longest torque interval T / N, s.  Measured on (0, 0, 0) to (d, d/2, 0) with the PI's limits
#: and N = 60: intervals of 0.95 s (d = 50 m) replay 1.2 cm from the goal, 1.9 s (100 m)
#: 9 cm, 3.8 s (200 m) 2.7 m; at 400 m IPOPT no longer converges.
MAX_INTERVAL_S: Final = 1.0
#: What the message of a failed solve advises (the command line replaces it: these are
#: arguments of the Python function, not options of ``wmr optimal``).
FAILED_ADVICE: Final = "try more n_intervals, warm_start=True or a larger max_iter/max_cpu_time_s"

#: Desired headings of the Fig. 9 runs, (0, 0, 0 deg) to (20, 10, theta_d), in deg.
FIG9_HEADINGS_DEG: Final = (-90.0, -60.0, -30.0, 0.0, 30.0, 60.0, 90.0)
#: Starts of the Fig. 10 runs: every 45 deg on a circle of radius 10 m about the goal (0, 0).
FIG10_RADIUS_M: Final = 10.0
FIG10_BEARINGS_DEG: Final = (0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0)

DEFAULT_PARAMS: Final = RobotParams()

_IPOPT_SOLVED: Final = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}
_IPOPT_INFEASIBLE: Final = {"Infeasible_Problem_Detected"}


def fig9_cases() -> list[tuple[str, Pose, Pose]]:
    """The Fig. 9 set: (name, start, goal) from (0, 0, 0) to (20 m, 10 m, theta_d)."""
    return [(f"fig9 theta_d={h:+.0f}", Pose(0.0, 0.0, 0.0), Pose(20.0, 10.0, math.radians(h)))
            for h in FIG9_HEADINGS_DEG]


def fig10_cases(start_headings_deg: tuple[float, ...] = (0.0,)) -> list[tuple[str, Pose, Pose]]:
    """The Fig. 10 set: starts around the origin, goal (0, 0) at 180 deg for x >= 0, else 0 deg.

    Parameters
    ----------
    start_headings_deg
        Headings (deg) tried at every start; the paper draws the robots heading along +x.
    """
    cases = []
    for b in FIG10_BEARINGS_DEG:
        x = round(FIG10_RADIUS_M * math.cos(math.radians(b)), 12)
        y = round(FIG10_RADIUS_M * math.sin(math.radians(b)), 12)
        goal = Pose(0.0, 0.0, math.pi if x >= 0.0 else 0.0)
        for h in start_headings_deg:
            cases.append((f"fig10 start=({x:+.1f},{y:+.1f},{h:+.0f})",
                          Pose(x, y, math.radians(h)), goal))
    return cases


# ----------------------------------------------------------------------------------------------
# Inputs
# ----------------------------------------------------------------------------------------------


def _finite(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(name, f"must be a finite number, got {value!r}")
    return float(value)


def _check_pose(name: str, pose: object) -> Pose:
    if not isinstance(pose, Pose):
        raise ConfigError(name, f"must be a wmr.plant.Pose, got {type(pose).__name__}")
    for f in ("x_m", "y_m", "heading_rad"):
        _finite(f"{name}.{f}", getattr(pose, f))
    return pose


def _optional_limit(name: str, value: float | None) -> float | None:
    if value is None:
        return None
    v = _finite(name, value)
    if v < 0.0:
        raise ConfigError(name, f"must be >= 0, got {value!r}",
                          "give a magnitude, or None for no limit")
    return v


@dataclass(frozen=True)
class OptimalLimits:
    """Actuator and speed limits of the OCP, symmetric about zero.

    Parameters
    ----------
    torque_max_nm
        Motor torque limit per wheel, N.m: :math:`|\\tau_{r,l}| \\le` this.
    wheel_speed_max_radps
        Wheel speed limit, rad/s: :math:`|\\omega_{r,l}| \\le` this at every node; None: none.
    v_max_mps
        Linear speed limit of B, m/s: :math:`|v| \\le` this; None: none.
    omega_max_radps
        Platform angular speed limit, rad/s: :math:`|\\omega| \\le` this; None: none.
    """

    torque_max_nm: float = 10.0
    wheel_speed_max_radps: float | None = None
    v_max_mps: float | None = None
    omega_max_radps: float | None = None

    def __post_init__(self) -> None:
        t = _finite("limits.torque_max_nm", self.torque_max_nm)
        if t < 0.0:
            raise ConfigError("limits.torque_max_nm", f"must be >= 0, got {t!r}",
                              "give the torque magnitude per wheel in N.m")
        _optional_limit("limits.wheel_speed_max_radps", self.wheel_speed_max_radps)
        _optional_limit("limits.v_max_mps", self.v_max_mps)
        _optional_limit("limits.omega_max_radps", self.omega_max_radps)

    @classmethod
    def like(cls, limits: Any) -> OptimalLimits:
        """The limits of another object with the same field names (the closed loop's ``Limits``).

        Fields it lacks keep their defaults here; ``torque_max_nm``, ``wheel_speed_max_radps``,
        ``v_max_mps`` and ``omega_max_radps`` are read when present.
        """
        kw = {f: getattr(limits, f) for f in ("torque_max_nm", "wheel_speed_max_radps",
                                             "v_max_mps", "omega_max_radps")
              if hasattr(limits, f)}
        return cls(**kw)

    def zero_limit(self) -> str | None:
        """The name of a limit that is exactly zero (the robot cannot move), else None."""
        for name in ("torque_max_nm", "wheel_speed_max_radps", "v_max_mps", "omega_max_radps"):
            if getattr(self, name) == 0.0:
                return name
        return None


# ----------------------------------------------------------------------------------------------
# The model
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Model:
    """The flattened Modelica model and the index maps the OCP needs."""

    ode: ca.Function  # (x, u, p) -> xdot
    out: ca.Function  # (x, u, p) -> y
    init: ca.Function  # (p) -> x0
    state_names: tuple[str, ...]
    param_names: tuple[str, ...]
    param_starts: tuple[float, ...]
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]

    def sx(self, name: str) -> int:
        return self.state_names.index(name)

    def oy(self, name: str) -> int:
        return self.output_names.index(name)

    def wheel_states(self) -> tuple[int, ...]:
        return tuple(i for i, n in enumerate(self.state_names)
                     if n not in ("x", "y", "theta", "v", "omega"))

    def param_vector(self, params: RobotParams, start: Pose) -> FloatArray:
        """The model's parameter vector for ``params`` and a start at rest at ``start``."""
        values = params.as_dict()
        values.update(x0=start.x_m, y0=start.y_m, theta0=start.heading_rad, v0=0.0, omega0=0.0)
        return np.array([values.get(n, s) for n, s in zip(self.param_names, self.param_starts,
                                                          strict=True)], dtype=float)


@lru_cache(maxsize=1)
def _model() -> _Model:
    """Flatten ``modelica/WMR`` once per process (about 0.3 s)."""
    from wmr import paths
    from wmr.fmu.flatten import flatten

    flat = flatten(paths.modelica_dir())
    model = _Model(ode=flat.ode, out=flat.out, init=flat.init, state_names=tuple(flat.state_names),
                   param_names=tuple(v.name for v in flat.parameters),
                   param_starts=tuple(float(v.start) for v in flat.parameters),
                   output_names=tuple(v.name for v in flat.outputs),
                   input_names=tuple(v.name for v in flat.inputs))
    needed = {"x", "y", "theta", "v", "omega"}
    if not needed <= set(model.state_names):
        raise ConfigError("modelica", f"the model's states {model.state_names} lack "
                          f"{sorted(needed - set(model.state_names))}")
    if model.input_names != ("tau_r", "tau_l"):
        raise ConfigError("modelica", f"the model's inputs are {model.input_names}, "
                          "expected (tau_r, tau_l)")
    return model


@lru_cache(maxsize=8)
def _rk4_function(substeps: int) -> ca.Function:
    """``(x, u, p, h) -> x(h)``: ``substeps`` classical RK4 steps of the model's ODE."""
    m = _model()
    nx, nu, npar = m.ode.size1_in(0), m.ode.size1_in(1), m.ode.size1_in(2)
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", nu)
    p = ca.SX.sym("p", npar)
    h = ca.SX.sym("h")
    dt = h / substeps
    xk = x
    for _ in range(substeps):
        k1 = m.ode(xk, u, p)
        k2 = m.ode(xk + dt / 2 * k1, u, p)
        k3 = m.ode(xk + dt / 2 * k2, u, p)
        k4 = m.ode(xk + dt * k3, u, p)
        xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("wmr_rk4", [x, u, p, h], [xk], ["x", "u", "p", "h"], ["xf"])


def simulate(start: Pose, torques_nm: npt.ArrayLike, interval_s: float,
             params: RobotParams = DEFAULT_PARAMS, rk_substeps: int = DEFAULT_RK_SUBSTEPS
             ) -> dict[str, FloatArray]:
    """Integrate the model from rest at ``start`` with the OCP's own RK4 integrator.

    Parameters
    ----------
    start
        Initial pose (m, rad); the robot starts at rest.
    torques_nm
        (K, 2) array of (tau_r, tau_l) in N.m, each held for ``interval_s``.
    interval_s
        Length of one torque interval, s.
    params
        Robot parameters.
    rk_substeps
        RK4 steps per interval.

    Returns
    -------
    dict
        State name -> (K + 1,) array at the interval boundaries (SI units).
    """
    m = _model()
    u = np.asarray(torques_nm, dtype=float).reshape(-1, 2)
    p = m.param_vector(params, start)
    x = np.asarray(_initial_state(start, params)).ravel()
    f = _rk4_function(int(rk_substeps))
    xs = [x]
    for k in range(u.shape[0]):
        x = np.asarray(f(x, u[k], p, interval_s)).ravel()
        xs.append(x)
    arr = np.array(xs)
    return {n: arr[:, i].copy() for i, n in enumerate(m.state_names)}


def _initial_state(start: Pose, params: RobotParams) -> FloatArray:
    """The model's own initial state (its ``init`` function) for a start at rest."""
    m = _model()
    return np.asarray(m.init(m.param_vector(params, start)), dtype=float).ravel()


# ----------------------------------------------------------------------------------------------
# The NLP
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Nlp:
    solver: ca.Function
    n: int
    nx: int
    nu: int
    n_x: int  # number of state variables in w
    n_u: int
    n_g_dyn: int


@lru_cache(maxsize=16)
def _nlp(n: int, substeps: int, max_iter: int, max_cpu_time_s: float) -> _Nlp:
    r"""Build (once) the multiple-shooting NLP on ``n`` intervals.

    Decision vector ``w = [vec(X) (nx (n+1)), vec(U) (2 n), T]``; NLP parameters
    ``[p (model), theta_d, w_T, w_E]``; objective :math:`w_T T + w_E h \sum_k |u_k|^2`.
    Constraints ``g``: continuity (``nx n``), :math:`\sin(\theta_N - \theta_d) = 0`,
    :math:`\cos(\theta_N - \theta_d) \ge 0`, wheel speeds at every node (``2 (n+1)``).
    Everything else (start, goal position, rest at the end, torque and speed limits, T range)
    is a variable bound.
    """
    m = _model()
    nx, nu, npar = m.ode.size1_in(0), m.ode.size1_in(1), m.ode.size1_in(2)
    X = ca.MX.sym("X", nx, n + 1)
    U = ca.MX.sym("U", nu, n)
    T = ca.MX.sym("T")
    P = ca.MX.sym("P", npar + 3)
    p, theta_d, w_t, w_e = P[:npar], P[npar], P[npar + 1], P[npar + 2]
    h = T / n
    step = _rk4_function(substeps).map(n, "serial")
    x_next = step(X[:, :n], U, ca.repmat(p, 1, n), ca.repmat(h, 1, n))
    dyn = ca.vec(x_next - X[:, 1:])
    dth = X[m.sx("theta"), n] - theta_d
    u_nodes = ca.horzcat(U, U[:, n - 1])
    y = m.out.map(n + 1, "serial")(X, u_nodes, ca.repmat(p, 1, n + 1))
    wheels = ca.vertcat(ca.vec(y[m.oy("omega_r"), :]), ca.vec(y[m.oy("omega_l"), :]))
    g = ca.vertcat(dyn, ca.sin(dth), ca.cos(dth), wheels)
    J = w_t * T + w_e * h * ca.sumsqr(U)
    w = ca.vertcat(ca.vec(X), ca.vec(U), T)
    opts: dict[str, Any] = {
        "expand": True,
        "print_time": False,
        # IPOPT recovers from a NaN in a trial step by itself; CasADi's warning per NaN
        # (dozens for a far goal) only buries the one line of the result
        "show_eval_warnings": False,
        "error_on_fail": False,
        "ipopt": {"print_level": 0, "sb": "yes", "max_iter": max_iter,
                  "max_cpu_time": max_cpu_time_s, "tol": 1e-8,
                  "acceptable_tol": 1e-6, "acceptable_iter": 10},
    }
    solver = ca.nlpsol("wmr_ocp", "ipopt", {"x": w, "p": P, "f": J, "g": g}, opts)
    return _Nlp(solver, n, nx, nu, nx * (n + 1), nu * n, nx * n)


# ----------------------------------------------------------------------------------------------
# Warm start: a kinematic rotate-translate-rotate path with trapezoidal speed profiles
# ----------------------------------------------------------------------------------------------


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


# ----------------------------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------------------------


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
        Work the motors deliver, J (:mod:`wmr.energy`: none recovered when braking; the net
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
# The solver
# ----------------------------------------------------------------------------------------------


def min_time_bound_s(start: Pose, goal: Pose, params: RobotParams,
                     limits: OptimalLimits) -> float:
    """A lower bound on the time from rest at ``start`` to rest at ``goal``, s.

    The larger of the distance at the top speed (``v_max_mps``, or the wheel speed limit at the
    rim) and the bang-bang time :math:`2\\sqrt{d / a}` at the largest acceleration
    :math:`a = 2 \tau_{max} / (r M_{11})`.
    """
    d = math.hypot(goal.x_m - start.x_m, goal.y_m - start.y_m)
    caps = [c for c in (limits.v_max_mps, None if limits.wheel_speed_max_radps is None
                        else limits.wheel_speed_max_radps * params.r) if c is not None]
    t_speed = d / min(caps) if caps and min(caps) > 0.0 else 0.0
    m11 = params.m + 2.0 * params.Iwm / params.r**2
    a_max = 2.0 * limits.torque_max_nm / (params.r * m11)
    t_accel = 2.0 * math.sqrt(d / a_max) if a_max > 0.0 else 0.0
    return max(t_speed, t_accel)


def _check_resolvable(start: Pose, goal: Pose, params: RobotParams, limits: OptimalLimits,
                      n_intervals: int, final_time_s: float | None) -> None:
    """Refuse at once a manoeuvre too long for ``n_intervals`` intervals of at most
    :data:`MAX_INTERVAL_S` (IPOPT would grind for a minute, then fail or miss by metres)."""
    longest = n_intervals * MAX_INTERVAL_S
    if final_time_s is not None:
        if final_time_s > longest:
            raise ConfigError("final_time_s", f"{final_time_s:g} s needs intervals longer than "
                              f"{MAX_INTERVAL_S:g} s with {n_intervals} intervals",
                              f"give at most {longest:g} s, or more n_intervals")
        return
    t_min = min_time_bound_s(start, goal, params, limits)
    if t_min > longest:
        d = math.hypot(goal.x_m - start.x_m, goal.y_m - start.y_m)
        raise ConfigError("goal", f"{d:.4g} m from the start takes at least {t_min:.4g} s "
                          f"under the limits, more than {n_intervals} intervals of "
                          f"{MAX_INTERVAL_S:g} s resolve ({longest:g} s)",
                          f"bring the goal within about {d * longest / t_min:.0f} m of the "
                          "start, or give more n_intervals")


def solve_optimal(
    start: Pose,
    goal: Pose,
    params: RobotParams = DEFAULT_PARAMS,
    objective: Objective = "time",
    torque_limit_nm: float = 10.0,
    wheel_speed_limit_radps: float | None = None,
    speed_limit_mps: float | None = None,
    final_time_s: float | None = None,
    n_intervals: int = DEFAULT_INTERVALS,
    warm_start: bool = True,
    *,
    omega_limit_radps: float | None = None,
    allow_reverse: bool = False,
    limits: OptimalLimits | None = None,
    mix_weight: float = 0.005,
    rk_substeps: int = DEFAULT_RK_SUBSTEPS,
    max_iter: int = 1000,
    max_cpu_time_s: float = 60.0,
) -> OptimalResult:
    r"""The optimal rest-to-rest manoeuvre from ``start`` to ``goal`` under the limits.

    Parameters
    ----------
    start, goal
        Poses of B (m, m, rad); the robot starts and ends at rest.  The goal heading is met
        modulo :math:`2\pi` (180 deg and -180 deg are the same goal).
    params
        Robot parameters (the model's defaults are the paper's).
    objective
        ``"time"``: minimum final time T.  ``"energy"``: minimum effort
        :math:`\int (\tau_r^2 + \tau_l^2) dt` in the given ``final_time_s``.  ``"mix"``:
        minimum :math:`T + w \int (\tau_r^2 + \tau_l^2) dt` with ``w = mix_weight``.
    torque_limit_nm
        :math:`|\tau_{r,l}|` limit per wheel, N.m (default 10).
    wheel_speed_limit_radps
        :math:`|\omega_{r,l}|` limit at the nodes, rad/s; None: no limit.
    speed_limit_mps
        :math:`|v|` limit, m/s; None: no limit.
    final_time_s
        The fixed duration, s; required for ``"energy"``, not allowed otherwise.
    n_intervals
        Shooting intervals N (torques are constant over T / N).
    warm_start
        Start IPOPT from the kinematic rotate-translate-rotate path (True) or from the straight
        interpolation of the poses at rest with zero torques and T = 10 s (False).
    omega_limit_radps
        :math:`|\omega|` limit of the platform, rad/s; None: no limit.
    allow_reverse
        Allow :math:`v < 0`.  Off by default: the PI stabiliser drives forward only, and with
        the centre of gravity ahead of the axle (``l > 0``) driving backward is open-loop
        unstable (:math:`\dot\omega = m l |v| \omega / J_B + \dots`), so a replay of a
        reversing optimum on the FMU drifts away from the goal.
    limits
        All limits at once (e.g. ``OptimalLimits.like(closed_loop_limits)``); overrides the four
        ``*_limit_*`` arguments.
    mix_weight
        Weight w of the effort in the ``"mix"`` objective, 1/(N^2 m^2).
    rk_substeps
        RK4 steps per interval.
    max_iter, max_cpu_time_s
        IPOPT's iteration and CPU-time limits: a solve never hangs.

    Returns
    -------
    OptimalResult
        ``status`` is ``"solved"``, ``"infeasible"`` or ``"failed"`` with a message; a start
        equal to the goal is solved at once with T = 0 and no torques; a limit of exactly zero is
        infeasible at once.

    Raises
    ------
    ConfigError
        A bad argument, naming it (e.g. ``goal.x_m`` for a NaN goal).
    """
    start = _check_pose("start", start)
    goal = _check_pose("goal", goal)
    if not isinstance(params, RobotParams):
        raise ConfigError("params", f"must be a wmr.plant.RobotParams, got {type(params).__name__}")
    if objective not in OBJECTIVES:
        raise ConfigError("objective", f"must be one of {', '.join(OBJECTIVES)}, got {objective!r}")
    if isinstance(n_intervals, bool) or not isinstance(n_intervals, int) or n_intervals < 2:
        raise ConfigError("n_intervals", f"must be an integer >= 2, got {n_intervals!r}")
    if isinstance(rk_substeps, bool) or not isinstance(rk_substeps, int) or rk_substeps < 1:
        raise ConfigError("rk_substeps", f"must be an integer >= 1, got {rk_substeps!r}")
    if objective == "energy":
        if final_time_s is None:
            raise ConfigError("final_time_s", "is required for the energy objective",
                              "give the duration of the manoeuvre in s")
        if _finite("final_time_s", final_time_s) <= 0.0:
            raise ConfigError("final_time_s", f"must be > 0, got {final_time_s!r}")
    elif final_time_s is not None:
        raise ConfigError("final_time_s", f"the {objective} objective leaves T free",
                          "drop final_time_s, or use objective 'energy'")
    if _finite("mix_weight", mix_weight) < 0.0:
        raise ConfigError("mix_weight", f"must be >= 0, got {mix_weight!r}")
    if _finite("max_cpu_time_s", max_cpu_time_s) <= 0.0:
        raise ConfigError("max_cpu_time_s", f"must be > 0, got {max_cpu_time_s!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, int) or max_iter < 1:
        raise ConfigError("max_iter", f"must be an integer >= 1, got {max_iter!r}")
    if limits is None:
        tl = _finite("torque_limit_nm", torque_limit_nm)
        if tl < 0.0:
            raise ConfigError("torque_limit_nm", f"must be >= 0, got {torque_limit_nm!r}")
        limits = OptimalLimits(
            torque_max_nm=tl,
            wheel_speed_max_radps=_optional_limit("wheel_speed_limit_radps",
                                                  wheel_speed_limit_radps),
            v_max_mps=_optional_limit("speed_limit_mps", speed_limit_mps),
            omega_max_radps=_optional_limit("omega_limit_radps", omega_limit_radps))
    elif not isinstance(limits, OptimalLimits):
        raise ConfigError("limits", f"must be an OptimalLimits, got {type(limits).__name__}",
                          "use OptimalLimits.like(other_limits)")

    T_fixed = float(final_time_s) if final_time_s is not None else None
    _check_resolvable(start, goal, params, limits, n_intervals, T_fixed)
    m = _model()
    d_pos = math.hypot(goal.x_m - start.x_m, goal.y_m - start.y_m)
    d_head = abs(_wrap(goal.heading_rad - start.heading_rad))
    if d_pos <= SAME_POSE_TOL and d_head <= SAME_POSE_TOL:
        if T_fixed is None:
            return _empty_result("solved", "start equals goal: nothing to do (T = 0)", objective,
                                 start, goal, params, limits, 0.0)
        # energy at a fixed T: staying at rest costs nothing and is optimal
        n = n_intervals
        x0 = _initial_state(start, params)
        t = np.linspace(0.0, T_fixed, n + 1)
        return OptimalResult(
            status="solved", message="start equals goal: staying at rest is optimal",
            objective=objective, start=start, goal=goal, params=params, limits=limits, t_s=t,
            states={nm: np.full(n + 1, x0[i]) for i, nm in enumerate(m.state_names)},
            torques=np.zeros((n, 2)), final_time_s=T_fixed, path_length_m=0.0,
            energy_positive_j=0.0, effort_N2m2s=0.0, solve_time_s=0.0, iterations=0,
            rk_substeps=rk_substeps,
            max_wheel_speed_radps=0.0, rollout_error_m=0.0)
    zero = limits.zero_limit()
    if zero is not None:
        return _empty_result("infeasible", f"the limit {zero} is 0: the robot cannot move from "
                             "the start to the goal", objective, start, goal, params, limits,
                             math.nan)

    n = n_intervals
    nlp = _nlp(n, rk_substeps, max_iter, float(max_cpu_time_s))
    p = m.param_vector(params, start)
    guess = (_kinematic_guess(start, goal, params, limits, n, T_fixed, p, allow_reverse)
             if warm_start
             else _cold_guess(start, goal, params, n, T_fixed))
    nx = nlp.nx
    inf = math.inf
    lbx = np.full(nlp.n_x + nlp.n_u + 1, -inf)
    ubx = np.full_like(lbx, inf)
    lx, ux = lbx[:nlp.n_x].reshape(nx, n + 1, order="F"), ubx[:nlp.n_x].reshape(nx, n + 1,
                                                                                  order="F")
    x0 = _initial_state(start, params)
    lx[:, 0] = ux[:, 0] = x0
    for name, value in (("x", goal.x_m), ("y", goal.y_m), ("v", 0.0), ("omega", 0.0)):
        lx[m.sx(name), n] = ux[m.sx(name), n] = value
    if limits.v_max_mps is not None:
        lx[m.sx("v"), 1:n] = -limits.v_max_mps
        ux[m.sx("v"), 1:n] = limits.v_max_mps
    if not allow_reverse:
        lx[m.sx("v"), 1:n] = 0.0
    if limits.omega_max_radps is not None:
        lx[m.sx("omega"), 1:n] = -limits.omega_max_radps
        ux[m.sx("omega"), 1:n] = limits.omega_max_radps
    lbx[nlp.n_x:nlp.n_x + nlp.n_u] = -limits.torque_max_nm
    ubx[nlp.n_x:nlp.n_x + nlp.n_u] = limits.torque_max_nm
    if T_fixed is not None:
        lbx[-1] = ubx[-1] = T_fixed
    else:
        lbx[-1], ubx[-1] = MIN_FINAL_TIME_S, MAX_FINAL_TIME_S
    n_wheel = 2 * (n + 1)
    wlim = inf if limits.wheel_speed_max_radps is None else limits.wheel_speed_max_radps
    lbg = np.concatenate([np.zeros(nlp.n_g_dyn), [0.0, 0.0], np.full(n_wheel, -wlim)])
    ubg = np.concatenate([np.zeros(nlp.n_g_dyn), [0.0, inf], np.full(n_wheel, wlim)])
    w_t, w_e = {"time": (1.0, 0.0), "energy": (0.0, 1.0), "mix": (1.0, mix_weight)}[objective]
    pn = np.concatenate([p, [goal.heading_rad, w_t, w_e]])

    first = _solve_nlp(nlp, guess, lbx, ubx, lbg, ubg, pn, objective, start, goal, params,
                       limits, rk_substeps, T_fixed)
    if first.status == "solved" or not warm_start:
        return first
    # a local failure from the kinematic guess: one retry from the cold guess
    second = _solve_nlp(nlp, _cold_guess(start, goal, params, n, T_fixed), lbx, ubx, lbg, ubg,
                        pn, objective, start, goal, params, limits, rk_substeps, T_fixed)
    second.solve_time_s += first.solve_time_s
    second.iterations += first.iterations
    if second.status == "solved":
        second.message += f" (after {first.return_status} from the warm start)"
        return second
    first.solve_time_s, first.iterations = second.solve_time_s, second.iterations
    first.message += f"; a retry from the cold start also ended in {second.return_status}"
    return first


def _solve_nlp(nlp: _Nlp, guess: _Guess, lbx: FloatArray, ubx: FloatArray, lbg: FloatArray,
               ubg: FloatArray, pn: FloatArray, objective: Objective, start: Pose, goal: Pose,
               params: RobotParams, limits: OptimalLimits, rk_substeps: int,
               T_fixed: float | None) -> OptimalResult:
    """One IPOPT run from ``guess``, classified."""
    m = _model()
    n, nx = nlp.n, nlp.nx
    w0 = np.clip(guess.w0, lbx, ubx)
    t0 = time.perf_counter()
    sol = nlp.solver(x0=w0, p=pn, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    solve_time = time.perf_counter() - t0
    stats = nlp.solver.stats()
    ret = str(stats.get("return_status", "unknown"))
    iters = int(stats.get("iter_count", -1))
    w = np.asarray(sol["x"]).ravel()
    xs = w[:nlp.n_x].reshape(nx, n + 1, order="F")
    us = w[nlp.n_x:nlp.n_x + nlp.n_u].reshape(2, n, order="F").T.copy()
    T = float(w[-1])
    g = np.asarray(sol["g"]).ravel()
    viol = float(max(np.max(lbg - g), np.max(g - ubg), 0.0))
    if ret in _IPOPT_SOLVED:
        status: Status = "solved"
        message = f"IPOPT: {ret} in {iters} iterations"
    elif ret in _IPOPT_INFEASIBLE:
        status = "infeasible"
        message = (f"IPOPT: {ret}: no trajectory meets the limits and the goal "
                   f"(constraint violation {viol:.3g}); relax the limits"
                   + (" or give a longer final_time_s" if T_fixed is not None else ""))
    else:
        status = "failed"
        message = (f"IPOPT: {ret} after {iters} iterations (constraint violation {viol:.3g}); "
                   + FAILED_ADVICE)
    length, work, wmax, miss = _integrals(start, goal, params, us, T / n, rk_substeps)
    effort = float(T / n * np.sum(us**2))
    return OptimalResult(
        status=status, message=message, objective=objective, start=start, goal=goal,
        params=params, limits=limits, t_s=np.linspace(0.0, T, n + 1),
        states={nm: xs[i].copy() for i, nm in enumerate(m.state_names)}, torques=us,
        final_time_s=T if status == "solved" else math.nan,
        path_length_m=length, energy_positive_j=work, effort_N2m2s=effort, solve_time_s=solve_time,
        iterations=iters, rk_substeps=rk_substeps, return_status=ret,
        max_wheel_speed_radps=wmax, rollout_error_m=miss, extra={"constraint_violation": viol,
                                           "guess_final_time_s": guess.final_time_s})


# ----------------------------------------------------------------------------------------------
# Open-loop replay on the FMU
# ----------------------------------------------------------------------------------------------


@dataclass
class ReplayResult:
    """The optimal torques applied open-loop to an FMU.

    Attributes
    ----------
    t_s
        (K + 1,) communication points, s.
    outputs
        FMU output name (:data:`wmr.plant.OUTPUT_NAMES`) -> (K + 1,) array, SI units.
    torques
        (K, 2) torques (tau_r, tau_l) of each FMU step, N.m.
    final_position_error_m, final_heading_error_rad
        Distance of B from the goal at the end, m; heading error wrapped to (-pi, pi], rad.
    final_speed_mps, final_omega_radps
        v and omega at the end (the OCP ends at rest).
    """

    t_s: FloatArray
    outputs: dict[str, FloatArray]
    torques: FloatArray
    final_position_error_m: float
    final_heading_error_rad: float
    final_speed_mps: float
    final_omega_radps: float

    @property
    def final_pose(self) -> Pose:
        return Pose(float(self.outputs["x"][-1]), float(self.outputs["y"][-1]),
                    float(self.outputs["theta"][-1]))


def replay_open_loop(result: OptimalResult, fmu_path: str | Path | Any,
                     params: RobotParams | None = None, start: Pose | None = None,
                     control_period_s: float = 0.01) -> ReplayResult:
    """Drive the FMU open-loop with the optimal torques.

    Each torque interval of length h is applied in ``ceil(h / control_period_s)`` equal FMU
    steps (the interval is split when it is longer than the control period).

    Parameters
    ----------
    result
        A solved :class:`OptimalResult`.
    fmu_path
        The ``.fmu`` file, or an open :class:`wmr.fmu.plant.FmuPlant` (left open).
    params, start
        Robot parameters and start pose of the FMU run; default: the result's.
    control_period_s
        Longest FMU step, s.

    Returns
    -------
    ReplayResult
        FMU outputs at every step and the final errors against ``result.goal``.

    Raises
    ------
    ConfigError
        ``result`` is not solved, or ``control_period_s`` is not positive.
    """
    from wmr.fmu.plant import FmuPlant

    if result.status != "solved":
        raise ConfigError("result.status", f"is {result.status!r}: only a solved result can be "
                          "replayed")
    if _finite("control_period_s", control_period_s) <= 0.0:
        raise ConfigError("control_period_s", f"must be > 0, got {control_period_s!r}")
    params = result.params if params is None else params
    start = result.start if start is None else start
    own = not isinstance(fmu_path, FmuPlant)
    plant: Any = FmuPlant(fmu_path) if own else fmu_path
    try:
        rows = [plant.reset(params, start).copy()]
        times = [0.0]
        taus: list[tuple[float, float]] = []
        h = result.interval_s
        k = max(1, math.ceil(h / control_period_s - 1e-9)) if h > 0 else 0
        for i, (tau_r, tau_l) in enumerate(result.torques):
            for j in range(k):
                rows.append(plant.step(float(tau_r), float(tau_l), h / k).copy())
                times.append(i * h + (j + 1) * h / k)
                taus.append((float(tau_r), float(tau_l)))
    finally:
        if own:
            plant.close()
    arr = np.array(rows)
    outputs = {n: arr[:, i].copy() for i, n in enumerate(OUTPUT_NAMES)}
    goal = result.goal
    return ReplayResult(
        t_s=np.array(times), outputs=outputs, torques=np.array(taus).reshape(-1, 2),
        final_position_error_m=math.hypot(outputs["x"][-1] - goal.x_m,
                                          outputs["y"][-1] - goal.y_m),
        final_heading_error_rad=_wrap(float(outputs["theta"][-1]) - goal.heading_rad),
        final_speed_mps=float(outputs["v"][-1]), final_omega_radps=float(outputs["omega"][-1]))


# ``wmr.optimal(...)`` is the API function (wmr.api); see wmr._callable.
make_callable(__name__)
