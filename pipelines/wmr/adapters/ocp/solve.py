"""The solver: :func:`solve_optimal`."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Final

import numpy as np

from wmr.adapters.ocp.model import _initial_state, _model
from wmr.adapters.ocp.problem import (
    DEFAULT_INTERVALS,
    DEFAULT_PARAMS,
    DEFAULT_RK_SUBSTEPS,
    MAX_FINAL_TIME_S,
    MAX_INTERVAL_S,
    MIN_FINAL_TIME_S,
    OBJECTIVES,
    SAME_POSE_TOL,
    SPOT_TURN_CREEP_MPS,
    SPOT_TURN_RADIUS_M,
    FloatArray,
    Objective,
    OptimalLimits,
    _check_pose,
    _finite,
    _optional_limit,
)
from wmr.adapters.ocp.result import OptimalResult, _empty_result
from wmr.adapters.ocp.transcription import _Nlp, _nlp, _nlp_built, _solve_nlp
from wmr.adapters.ocp.warmstart import (
    _cold_guess,
    _Guess,
    _kinematic_guess,
    _previous_guess,
    _wrap,
)
from wmr.core.plant import Pose, RobotParams
from wmr.infra.errors import ConfigError

#: The guesses of :func:`solve_optimal` as its messages name them.
_GUESS_NAMES: Final = {"previous": "the previous solution", "kinematic": "the warm start",
                       "cold": "the cold start"}


def min_time_bound_s(start: Pose, goal: Pose, params: RobotParams,
                     limits: OptimalLimits) -> float:
    r"""A lower bound on the time from rest at ``start`` to rest at ``goal``, s.

    The larger of the distance at the top speed (``v_max_mps``, or the wheel speed limit at the
    rim) and the bang-bang time :math:`2\sqrt{d / a}` at the largest acceleration
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
                              f"give at most {longest:g} s, or raise n_intervals")
        return
    t_min = min_time_bound_s(start, goal, params, limits)
    if t_min > longest:
        d = math.hypot(goal.x_m - start.x_m, goal.y_m - start.y_m)
        raise ConfigError("goal", f"{d:.4g} m from the start takes at least {t_min:.4g} s "
                          f"under the limits, more than {n_intervals} intervals of "
                          f"{MAX_INTERVAL_S:g} s resolve ({longest:g} s)",
                          f"bring the goal within about {d * longest / t_min:.0f} m of the "
                          "start, or raise n_intervals")


def _check_arguments(start: Pose, goal: Pose, params: RobotParams, objective: Objective,
                     torque_limit_nm: float, wheel_speed_limit_radps: float | None,
                     speed_limit_mps: float | None, final_time_s: float | None,
                     n_intervals: int, omega_limit_radps: float | None,
                     limits: OptimalLimits | None, mix_weight: float, rk_substeps: int,
                     max_iter: int, max_cpu_time_s: float,
                     ) -> tuple[Pose, Pose, OptimalLimits]:
    """The arguments of :func:`solve_optimal` checked, each error naming its argument; the
    poses as Poses and the limits as one :class:`OptimalLimits`."""
    start = _check_pose("start", start)
    goal = _check_pose("goal", goal)
    if not isinstance(params, RobotParams):
        raise ConfigError("params", "must be a wmr.core.plant.RobotParams, "
                          f"got {type(params).__name__}")
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

    return start, goal, limits


def _reverse_creep_mps(start: Pose, goal: Pose, allow_reverse: bool) -> float:
    """How far below 0 a forward-only manoeuvre may take v: :data:`SPOT_TURN_CREEP_MPS` for a
    turn on the spot (goal within :data:`SPOT_TURN_RADIUS_M`), else 0."""
    if allow_reverse:
        return math.inf
    d = math.hypot(goal.x_m - start.x_m, goal.y_m - start.y_m)
    return SPOT_TURN_CREEP_MPS if d < SPOT_TURN_RADIUS_M else 0.0


def _bounds(nlp: _Nlp, start: Pose, goal: Pose, params: RobotParams, limits: OptimalLimits,
            allow_reverse: bool, T_fixed: float | None,
            ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Bounds of the NLP's variables and constraints: the start and the goal at rest, the
    limits, forward only unless ``allow_reverse`` (but for the creep of a turn on the spot,
    :func:`_reverse_creep_mps`), and the final time."""
    m = _model()
    n = nlp.n
    nx = nlp.nx
    inf = math.inf
    lbx = np.full(nlp.n_x + nlp.n_u + 1, -inf)
    ubx = np.full_like(lbx, inf)
    lx, ux = lbx[:nlp.n_x].reshape(nx, n + 1, order="F"), ubx[:nlp.n_x].reshape(nx, n + 1,
                                                                                  order="F")
    lx[:, 0] = ux[:, 0] = _initial_state(start, params)
    for name, value in (("x", goal.x_m), ("y", goal.y_m), ("v", 0.0), ("omega", 0.0)):
        lx[m.sx(name), n] = ux[m.sx(name), n] = value
    if limits.v_max_mps is not None:
        lx[m.sx("v"), 1:n] = -limits.v_max_mps
        ux[m.sx("v"), 1:n] = limits.v_max_mps
    creep = _reverse_creep_mps(start, goal, allow_reverse)
    if math.isfinite(creep):
        lx[m.sx("v"), 1:n] = np.maximum(lx[m.sx("v"), 1:n], -creep)
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
    return lbx, ubx, lbg, ubg


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
    progress: Callable[[str], None] | None = None,
    previous: OptimalResult | None = None,
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
        A turn on the spot (goal within :data:`SPOT_TURN_RADIUS_M` of the start) may still
        reverse at up to :data:`SPOT_TURN_CREEP_MPS`: with v >= 0 its optimum sits on the bound
        at every node and IPOPT does not converge.
    limits
        All limits at once (e.g. ``OptimalLimits.like(closed_loop_limits)``); overrides the four
        ``*_limit_*`` arguments.
    mix_weight
        Weight w of the effort in the ``"mix"`` objective, 1/(N^2 m^2).
    rk_substeps
        RK4 steps per interval.
    max_iter, max_cpu_time_s
        IPOPT's iteration and CPU-time limits: a solve never hangs.
    progress
        Called with a line (IPOPT's iteration, T, the objective) at least every
        :data:`~wmr.adapters.ocp.transcription.PROGRESS_INTERVAL_S` while IPOPT runs, and when
        a failed solve is retried from the cold start; None: silent.
    previous
        An earlier solved manoeuvre (the last of a batch's worker): with ``warm_start``, IPOPT
        starts from it, moved rigidly onto ``start``, when it then ends near ``goal``
        (:func:`~wmr.adapters.ocp.warmstart._previous_guess`), else from the kinematic path.
        A failure from it is retried from the kinematic path, then the cold start.
        ``extra["guess"]`` of the result names the start that solved it.

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
    start, goal, limits = _check_arguments(
        start, goal, params, objective, torque_limit_nm, wheel_speed_limit_radps,
        speed_limit_mps, final_time_s, n_intervals, omega_limit_radps, limits, mix_weight,
        rk_substeps, max_iter, max_cpu_time_s)
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
    if progress is not None and not _nlp_built(n, rk_substeps, max_iter, float(max_cpu_time_s)):
        progress(f"building the NLP on {n} intervals (once per process)")
    nlp = _nlp(n, rk_substeps, max_iter, float(max_cpu_time_s))
    p = m.param_vector(params, start)
    lbx, ubx, lbg, ubg = _bounds(nlp, start, goal, params, limits, allow_reverse, T_fixed)
    w_t, w_e = {"time": (1.0, 0.0), "energy": (0.0, 1.0), "mix": (1.0, mix_weight)}[objective]
    pn = np.concatenate([p, [goal.heading_rad, w_t, w_e]])
    # the guesses in order, each tried only when the one before failed: the earlier solution
    # (when given and near), the kinematic path, the cold start
    guesses: list[tuple[str, Callable[[], _Guess | None]]] = []
    if warm_start and previous is not None:
        guesses.append(("previous", lambda: _previous_guess(previous, start, goal, n, T_fixed)))
    if warm_start:
        guesses.append(("kinematic", lambda: _kinematic_guess(
            start, goal, params, limits, n, T_fixed, p, allow_reverse)))
    guesses.append(("cold", lambda: _cold_guess(start, goal, params, n, T_fixed)))
    creep = _reverse_creep_mps(start, goal, allow_reverse)
    first: OptimalResult | None = None
    last: OptimalResult | None = None
    for label, make in guesses:
        guess = make()
        if guess is None:  # the earlier solution is another manoeuvre
            continue
        if last is not None and progress is not None:
            progress(f"IPOPT: {last.return_status} from {_GUESS_NAMES[last.extra['guess']]} "
                     f"after {last.solve_time_s:.0f} s; retrying from {_GUESS_NAMES[label]}")
        res = _solve_nlp(nlp, guess, lbx, ubx, lbg, ubg, pn, objective, start, goal, params,
                         limits, rk_substeps, T_fixed, progress)
        res.extra["guess"] = label
        if last is not None:
            res.solve_time_s += last.solve_time_s
            res.iterations += last.iterations
        if first is None:
            first = res
            if 0.0 < creep < math.inf:
                res.message += f" (a turn on the spot: reversing up to {creep:g} m/s allowed)"
                res.extra["reverse_creep_mps"] = creep
        elif res.status == "solved":
            res.message += (f" (after {first.return_status} from "
                            f"{_GUESS_NAMES[first.extra['guess']]})")
        if res.status == "solved":
            return res
        last = res
    assert first is not None and last is not None
    if last is not first:
        first.solve_time_s, first.iterations = last.solve_time_s, last.iterations
        first.message += (f"; a retry from {_GUESS_NAMES[last.extra['guess']]} also ended in "
                          f"{last.return_status}")
    return first
