"""One optimal manoeuvre end to end (``wmr optimal``, :func:`wmr.api.optimal`): solve the OCP
under the PI's limits, replay its torques open-loop on the FMU, log the replay to MCAP."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from wmr.apps.request import Overrides
from wmr.core.control import Limits
from wmr.core.plant import Pose, RobotParams
from wmr.core.record import RECORD_KEYS, RunFigures, record
from wmr.core.runspec import RunSpec
from wmr.infra.errors import ConfigError

if TYPE_CHECKING:
    from wmr.adapters.ocp import OptimalProblem

#: The advice of a failed solve, for users of this function and of the command line (who
#: have no n_intervals, warm_start or max_iter to change).
_CASE_ADVICE = "the goal may be too far or the limits too tight for the solver"


def optimal_limits(torque_limit_nm: float | None = None, torque_only: bool = False,
                   pi: Limits | None = None) -> Any:
    """The PI's limits ``pi`` (default :class:`Limits`) as
    :class:`wmr.adapters.ocp.OptimalLimits` (only the torque's when ``torque_only``), the
    torque limit replaced by ``torque_limit_nm`` if given."""
    from wmr.adapters.ocp import OptimalLimits

    pi = Limits() if pi is None else pi
    torque = pi.torque_max_nm if torque_limit_nm is None else torque_limit_nm
    if not math.isfinite(torque) or torque <= 0.0:
        raise ConfigError("torque_limit_nm", f"must be > 0, got {torque!r}")
    if torque_only:
        return OptimalLimits(torque_max_nm=torque)
    return OptimalLimits(torque_max_nm=torque, wheel_speed_max_radps=pi.wheel_speed_max_radps,
                         v_max_mps=pi.v_max_mps, omega_max_radps=pi.omega_max_radps)


#: ``wmr optimal``'s default start and goal, ``(x_m, y_m, heading_deg)``.
DEFAULT_START: Final = (0.0, 0.0, 0.0)
DEFAULT_GOAL: Final = (20.0, 10.0, 0.0)

def _degrees(pose: Pose) -> tuple[float, float, float]:
    """A run's pose as typed on the command line, ``(x_m, y_m, heading_deg)``."""
    return (pose.x_m, pose.y_m, math.degrees(pose.heading_rad))


def _pose(value: Sequence[float] | None, default: tuple[float, float, float],
          field: str) -> tuple[float, float, float]:
    """``(x_m, y_m, heading_deg)``, finite; ``default`` for None."""
    if value is None:
        return default
    if len(value) != 3:
        raise ConfigError(field, f"must be (x_m, y_m, heading_deg), got {value!r}")
    for label, v in zip(("x", "y", "theta_deg"), value, strict=True):
        if not math.isfinite(v):
            raise ConfigError(f"{field} {label}", f"must be finite, got {v!r}")
    return (float(value[0]), float(value[1]), float(value[2]))


def optimal_name(start: tuple[float, float, float], goal: tuple[float, float, float], *,
                 objective: str = "time", torque_limit_nm: float | None = None,
                 torque_only: bool = False, final_time_s: float | None = None,
                 period_s: float = 0.01, fmi: int = 3,
                 fmu: str | Path | None = None, extra: Sequence[str] = ()) -> str:
    """``optimal-OBJECTIVE`` and a token per input that changes the manoeuvre
    (:mod:`wmr.config.naming`); poses ``(x_m, y_m, heading_deg)``."""
    from wmr.config.naming import fmu_tokens, pose_token, variant_name

    tokens = []
    for label, given, default in (("from", start, DEFAULT_START), ("to", goal, DEFAULT_GOAL)):
        if given != default:
            tokens.append(pose_token(label, Pose(given[0], given[1], math.radians(given[2]))))
    if torque_limit_nm is not None:
        tokens.append(f"torque_max_nm={torque_limit_nm:.10g}")
    if torque_only:
        tokens.append("torque_only")
    if final_time_s is not None:
        tokens.append(f"T={final_time_s:.10g}")
    if period_s != 0.01:
        tokens.append(f"period={period_s:.10g}")
    tokens.extend(extra)  # --param and --limit, NAME=VALUE
    return variant_name(f"optimal-{objective}",
                        [*tokens, *fmu_tokens(fmi, None if fmu is None else str(fmu))])


@dataclass(frozen=True)
class OptimalRequest:
    """One optimal manoeuvre, as ``wmr optimal`` and :func:`wmr.optimal` ask for it.

    Errors name its fields by the API's keywords (``final_time_s``, ``goal``); the command
    line names them by its options (:func:`wmr.cli.shared.errors_as_options`).

    Attributes
    ----------
    scenario, run
        The start, goal, robot and limits of this run of this scenario (a name or TOML file,
        resolved as ``wmr run`` does); ``None``: the overrides alone.
    overrides
        Its ``start`` and ``goal`` ``(x_m, y_m, heading_deg)`` (default :data:`DEFAULT_START`,
        :data:`DEFAULT_GOAL` or the run's), ``params`` and ``limits`` by name (as ``wmr run
        --param/--limit``); a request with any other override is refused.
    objective, final_time_s
        ``time`` or ``energy`` (in ``final_time_s``, default 1.5 x the minimum time).
    torque_limit_nm, torque_only
        The torque limit (default the PI's), and whether the other limits are dropped.
    period_s
        The longest FMU step of the replay, s.
    out
        The log (default ``runs/<name>.mcap``, :func:`optimal_name`).
    fmi, fmu
        The project's FMI 2 or 3 build, or another robot FMU.
    """

    scenario: str | Path | None = None
    run: str | None = None
    overrides: Overrides = field(default_factory=Overrides)
    objective: str = "time"
    torque_limit_nm: float | None = None
    torque_only: bool = False
    final_time_s: float | None = None
    period_s: float = 0.01
    out: str | Path | None = None
    fmi: int = 3
    fmu: str | Path | None = None

    def __post_init__(self) -> None:
        o = self.overrides
        for name in ("name", "gains", "period_s", "stop_radius_m", "max_time_s",
                     "heading_tolerance_deg", "controller", "controller_gains", "sensors",
                     "sensor"):
            if getattr(o, name) not in (None, {}):
                raise ConfigError(name, "has no meaning for the optimal manoeuvre",
                                  "give start, goal, params and limits only")


def optimal_command(request: OptimalRequest,
                    progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """What ``wmr optimal`` and :func:`wmr.optimal` both do: check the request, name the
    case, solve, replay and log (:func:`optimal_to_log`); return the record. ``progress``
    receives a line at least every few seconds while IPOPT iterates.

    Raises
    ------
    ConfigError
        A bad input, one line, naming the request's field (``final_time_s``).
    """
    from wmr.apps.run import default_fmu
    from wmr.config.naming import default_log_path
    from wmr.infra.outputs import check_output

    r, o = request, request.overrides
    start, goal = (_degrees(p) if isinstance(p, Pose) else p for p in (o.start, o.goal))
    spec = None
    if r.scenario is not None or r.run is not None or o.params or o.limits:
        from wmr.apps.run import select_run
        from wmr.config.scenario import load_scenario, with_overrides

        base = (select_run(load_scenario(r.scenario), r.run) if r.scenario is not None
                or r.run is not None else RunSpec(name="", start=Pose(0.0, 0.0, 0.0),
                                                  goal=Pose(0.0, 0.0, 0.0)))
        spec = with_overrides(base, Overrides(params=o.params, limits=o.limits))
        if start is None and r.scenario is not None:
            start = _degrees(spec.start)
        if goal is None and r.scenario is not None:
            goal = _degrees(spec.goal)
    start_deg = _pose(start, DEFAULT_START, "start")
    goal_deg = _pose(goal, DEFAULT_GOAL, "goal")
    if not math.isfinite(r.period_s) or r.period_s <= 0.0:
        raise ConfigError("period_s", f"must be > 0, got {r.period_s!r}")
    changed = [] if spec is None else [
        *(f"{k}={v:.10g}" for k, v in sorted((o.params or {}).items())),
        *(f"{k}={v:.10g}" for k, v in sorted((o.limits or {}).items()))]
    name = optimal_name(start_deg, goal_deg, objective=r.objective,
                        torque_limit_nm=r.torque_limit_nm, torque_only=r.torque_only,
                        final_time_s=r.final_time_s, period_s=r.period_s, fmi=r.fmi, fmu=r.fmu,
                        extra=changed)
    path = check_output(r.out if r.out else default_log_path(name), "out", suffix=".mcap")
    if r.objective == "time" and r.final_time_s is not None:
        raise ConfigError("final_time_s", "the time objective leaves the final time free",
                          "drop final_time_s or use objective=energy")
    start_pose, goal_pose = (Pose(x, y, math.radians(h)) for x, y, h in (start_deg, goal_deg))
    try:
        from wmr.adapters.ocp import OptimalProblem

        limits = optimal_limits(r.torque_limit_nm, r.torque_only,
                                None if spec is None else spec.limits)
        problem = OptimalProblem(start_pose, goal_pose,
                                 RobotParams() if spec is None else spec.params,
                                 objective=r.objective,  # type: ignore[arg-type]
                                 limits=limits, final_time_s=r.final_time_s)
        return optimal_to_log(problem, path,
                              Path(r.fmu) if r.fmu is not None else default_fmu(r.fmi),
                              name=name, period_s=r.period_s, progress=progress)
    except ConfigError as exc:
        # solve_optimal's advice, for a caller who has no n_intervals to raise
        raise ConfigError(exc.field, exc.problem, exc.fix.replace(
            "raise n_intervals", "raise n_intervals in the Python API "
            "(wmr.adapters.ocp.solve_optimal)")) from None


def optimal_to_log(problem: OptimalProblem, out: Path, fmu_path: Path, *, name: str,
                   period_s: float = 0.01,
                   progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Solve ``problem``, replay on the FMU at ``fmu_path`` and log to ``out``; return the
    result record.

    The energy objective without a ``final_time_s`` takes 1.5 times the minimum time.  The
    record is the record of a run (:data:`wmr.core.record.RECORD_KEYS`, ``docs/results.md``)
    of the open-loop FMU replay (``status`` the solver's, ``time_to_goal_s`` the optimum's
    final time), then the optimal's own fields (``objective``, ``final_time_s``, the
    optimiser's ``ocp_*`` estimates, ``solve_time_s``, ``iterations``, ``limits``,
    ``time_to_radius_s``, ``final_speed_mps``); the log, with the scene topics
    (:mod:`wmr.adapters.mcap.scene`), is written only when the solve succeeded.

    Parameters
    ----------
    problem
        The manoeuvre (:class:`~wmr.adapters.ocp.OptimalProblem`; the PI's limits:
        :func:`optimal_limits`).
    out, fmu_path
        The log to write and the robot FMU of the replay.
    name
        The run's name in the record and the log.
    period_s
        The longest FMU step of the replay, s.
    progress
        Receives a line at least every few seconds while IPOPT iterates
        (:func:`wmr.adapters.ocp.solve_optimal`).
    """
    from wmr.adapters.fmi.robot import FmuPlant
    from wmr.adapters.ocp import FAILED_ADVICE, replay_open_loop, solve_optimal
    from wmr.apps.benchmark import (
        optimal_metadata,
        optimal_scenario,
        replay_figures,
        write_optimal_log,
    )

    start, goal, params, limits = problem.start, problem.goal, problem.params, problem.limits
    objective = problem.objective
    note = ""
    if objective == "energy" and problem.final_time_s is None:
        t_min = solve_optimal(replace(problem, objective="time"), progress=progress)
        if t_min.status != "solved":
            raise ConfigError("final_time_s", "no minimum time to base the energy run on "
                              f"({t_min.status}: {t_min.message})", "give the final time")
        problem = replace(problem, final_time_s=1.5 * t_min.final_time_s)
        note = f"final time 1.5 x the minimum time {t_min.final_time_s:.3f} s"
    res = solve_optimal(problem, progress=progress)
    res.message = res.message.replace(FAILED_ADVICE, _CASE_ADVICE)
    message = res.message + (f"; {note}" if note else "")
    own: dict[str, Any] = {
        "objective": res.objective,
        "final_time_s": res.final_time_s if res.status == "solved" else None,
        "ocp_path_length_m": res.path_length_m,
        "ocp_energy_positive_j": res.energy_positive_j,
        "solve_time_s": res.solve_time_s,
        "iterations": res.iterations, "limits": res.summary()["limits"],
    }
    if res.status != "solved":
        return {**dict.fromkeys(RECORD_KEYS), "name": name, "status": res.status,
                "message": message, "steps": 0, **own}
    with FmuPlant(fmu_path) as plant:
        replay = replay_open_loop(res, plant, params=params, start=start,
                                  control_period_s=period_s)
        figures = replay_figures(replay, goal, 0.05)
        # an open-loop replay has no stabiliser: what it "believed" is the truth
        done = {**record(RunFigures(
                    name=name, status=res.status, message=message,
                    final_position_error_m=figures["final_position_error_m"],
                    final_heading_error_rad=figures["final_heading_error_rad"],
                    time_to_goal_s=res.final_time_s, path_length_m=figures["path_length_m"],
                    energy_net_j=figures["energy_net_j"],
                    energy_positive_j=figures["energy_positive_j"],
                    energy_abs_j=figures["energy_abs_j"],
                    torque_sq_integral_n2m2s=figures["torque_sq_integral_n2m2s"],
                    peak_torque_nm=figures["peak_torque_nm"], steps=len(replay.t_s),
                    estimated_final_position_error_m=figures["final_position_error_m"],
                    estimated_final_heading_error_rad=figures["final_heading_error_rad"],
                    mcap=str(out))),
                **own, "time_to_radius_s": figures["time_to_radius_s"],
                "final_speed_mps": replay.final_speed_mps}
        write_optimal_log(out, res, replay, plant,
                          optimal_metadata(name, "", start, goal, params, limits, objective,
                                           plant, period_s),
                          {k: v for k, v in done.items() if not isinstance(v, dict)},
                          scenario=optimal_scenario(name, "", start, goal, params, limits,
                                                    period_s), scene=True)
    return done


#: The summary columns of the optimum (:func:`optimum_fields`), name -> kind.
OPTIMUM_COLUMNS: Final = {"optimal_status": "string", "optimal_message": "string",
                          "optimal_time_s": "float", "optimal_energy_j": "float",
                          "time_gap": "float", "energy_gap": "float"}


def _gap(value: object, optimum: float) -> float | None:
    """``value / optimum``; None when either is missing or the optimum is not positive."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    if not (math.isfinite(value) and math.isfinite(optimum) and optimum > 0.0):
        return None
    return float(value) / optimum


def optimum_fields(spec: RunSpec, objective: str, record: dict[str, Any],
                   previous: Any = None) -> tuple[dict[str, Any], Any]:
    r"""The optimum beside a batch's run: its summary fields (:data:`OPTIMUM_COLUMNS`) and the
    solution (an :class:`~wmr.adapters.ocp.OptimalResult`, to warm-start the next, or None).

    The OCP is the run's own: its start, goal, robot parameters and limits (all four of
    :class:`~wmr.core.control.Limits`).  ``optimal_time_s`` is always the minimum time;
    ``optimal_energy_j`` the positive motor work (:mod:`wmr.core.energy`, the run's
    ``energy_positive_j``) of the minimum-time manoeuvre (``"time"``), or of the minimum-effort
    one (``"energy"``: least :math:`\int \tau_r^2 + \tau_l^2 dt`) in the run's own time to
    goal, or 1.5 times the minimum time for a run that did not converge.  ``time_gap`` and
    ``energy_gap`` are the run's over the optimum's, for a converged run; a solver that fails
    is ``optimal_status`` ``failed`` or ``infeasible`` with its message, never a bare NaN.
    """
    from wmr.adapters.ocp import FAILED_ADVICE, OptimalLimits, OptimalProblem, solve_optimal

    out: dict[str, Any] = dict.fromkeys(OPTIMUM_COLUMNS)
    problem = OptimalProblem(spec.start, spec.goal, spec.params,
                             limits=OptimalLimits.like(spec.limits))
    try:
        res = solve_optimal(problem, previous=previous)
        t_min = res.final_time_s
        if res.status == "solved" and objective == "energy":
            t_run = record.get("time_to_goal_s") if record.get("status") == "converged" else None
            t_fixed = t_run if isinstance(t_run, float) and t_run >= t_min > 0.0 \
                else 1.5 * t_min
            res = solve_optimal(replace(problem, objective="energy", final_time_s=t_fixed))
    except Exception as exc:  # the solver's failure is the row's, not the batch's
        out.update(optimal_status="failed", optimal_message=f"{type(exc).__name__}: {exc}")
        return out, None
    out["optimal_status"] = res.status
    out["optimal_message"] = res.message.replace(FAILED_ADVICE, _CASE_ADVICE)
    if res.status != "solved":
        return out, None
    out["optimal_time_s"] = t_min
    out["optimal_energy_j"] = res.energy_positive_j
    if record.get("status") == "converged":
        out["time_gap"] = _gap(record.get("time_to_goal_s"), t_min)
        out["energy_gap"] = _gap(record.get("energy_positive_j"), res.energy_positive_j)
    return out, res if res.objective == "time" else None


__all__ = ["DEFAULT_GOAL", "DEFAULT_START", "OPTIMUM_COLUMNS", "OptimalRequest",
           "optimal_command", "optimal_limits", "optimal_name", "optimal_to_log",
           "optimum_fields"]
