"""The solver: :func:`solve_optimal`."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Final

import numpy as np

from wmr.adapters.ocp.model import _initial_state, _model
from wmr.adapters.ocp.problem import (
    MAX_FINAL_TIME_S,
    MAX_INTERVAL_S,
    MIN_FINAL_TIME_S,
    OBJECTIVES,
    SAME_POSE_TOL,
    SPOT_TURN_CREEP_MPS,
    SPOT_TURN_RADIUS_M,
    FloatArray,
    OptimalLimits,
    OptimalProblem,
    SolverOptions,
    _check_pose,
    _finite,
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


def _check_arguments(problem: OptimalProblem, options: SolverOptions) -> None:
    """The problem and the options of :func:`solve_optimal` checked, each error naming its
    field."""
    pr, op = problem, options
    _check_pose("start", pr.start)
    _check_pose("goal", pr.goal)
    if not isinstance(pr.params, RobotParams):
        raise ConfigError("params", "must be a wmr.core.plant.RobotParams, "
                          f"got {type(pr.params).__name__}")
    if pr.objective not in OBJECTIVES:
        raise ConfigError("objective",
                          f"must be one of {', '.join(OBJECTIVES)}, got {pr.objective!r}")
    n_intervals, rk_substeps, max_iter = op.n_intervals, op.rk_substeps, op.max_iter
    if isinstance(n_intervals, bool) or not isinstance(n_intervals, int) or n_intervals < 2:
        raise ConfigError("n_intervals", f"must be an integer >= 2, got {n_intervals!r}")
    if isinstance(rk_substeps, bool) or not isinstance(rk_substeps, int) or rk_substeps < 1:
        raise ConfigError("rk_substeps", f"must be an integer >= 1, got {rk_substeps!r}")
    if pr.objective == "energy":
        if pr.final_time_s is None:
            raise ConfigError("final_time_s", "is required for the energy objective",
                              "give the duration of the manoeuvre in s")
        if _finite("final_time_s", pr.final_time_s) <= 0.0:
            raise ConfigError("final_time_s", f"must be > 0, got {pr.final_time_s!r}")
    elif pr.final_time_s is not None:
        raise ConfigError("final_time_s", f"the {pr.objective} objective leaves T free",
                          "drop final_time_s, or use objective 'energy'")
    if _finite("mix_weight", pr.mix_weight) < 0.0:
        raise ConfigError("mix_weight", f"must be >= 0, got {pr.mix_weight!r}")
    if _finite("max_cpu_time_s", op.max_cpu_time_s) <= 0.0:
        raise ConfigError("max_cpu_time_s", f"must be > 0, got {op.max_cpu_time_s!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, int) or max_iter < 1:
        raise ConfigError("max_iter", f"must be an integer >= 1, got {max_iter!r}")
    if not isinstance(pr.limits, OptimalLimits):
        raise ConfigError("limits", f"must be an OptimalLimits, got {type(pr.limits).__name__}",
                          "use OptimalLimits(...) or OptimalLimits.like(other_limits)")


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


def solve_optimal(problem: OptimalProblem, options: SolverOptions | None = None, *,
                  progress: Callable[[str], None] | None = None,
                  previous: OptimalResult | None = None) -> OptimalResult:
    r"""The optimal rest-to-rest manoeuvre of ``problem`` (:class:`OptimalProblem`: from its
    start to its goal under its limits), solved as ``options`` say (:class:`SolverOptions`).

    Parameters
    ----------
    problem
        The manoeuvre, its objective and its limits.
    options
        The transcription (intervals, RK4 steps), the first guess and IPOPT's limits; None:
        :class:`SolverOptions`' defaults.
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
        A bad field of ``problem`` or ``options``, naming it (e.g. ``goal.x_m`` for a NaN
        goal).
    """
    options = SolverOptions() if options is None else options
    _check_arguments(problem, options)
    start, goal, params, limits = problem.start, problem.goal, problem.params, problem.limits
    objective, final_time_s, allow_reverse = (problem.objective, problem.final_time_s,
                                              problem.allow_reverse)
    n_intervals, rk_substeps, max_iter, max_cpu_time_s = (
        options.n_intervals, options.rk_substeps, options.max_iter, options.max_cpu_time_s)
    warm_start = options.warm_start
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
    w_t, w_e = {"time": (1.0, 0.0), "energy": (0.0, 1.0),
                "mix": (1.0, problem.mix_weight)}[objective]
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
        res = _solve_nlp(nlp, guess, (lbx, ubx, lbg, ubg), pn, problem, rk_substeps, progress)
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
