"""One optimal manoeuvre end to end (``wmr optimal``, :func:`wmr.api.optimal`): solve the OCP
under the PI's limits, replay its torques open-loop on the FMU, log the replay to MCAP."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from wmr.core.control import Limits
from wmr.core.plant import Pose, RobotParams
from wmr.core.record import RECORD_KEYS, record
from wmr.infra.errors import ConfigError

#: The advice of a failed solve, for users of this function and of the command line (who
#: have no n_intervals, warm_start or max_iter to change).
_CASE_ADVICE = "the goal may be too far or the limits too tight for the solver"


def optimal_limits(torque_limit_nm: float | None = None, torque_only: bool = False) -> Any:
    """The PI's limits as :class:`wmr.adapters.ocp.OptimalLimits` (only the torque's when
    ``torque_only``), the torque limit replaced by ``torque_limit_nm`` if given."""
    from wmr.adapters.ocp import OptimalLimits

    pi = Limits()
    torque = pi.torque_max_nm if torque_limit_nm is None else torque_limit_nm
    if not math.isfinite(torque) or torque <= 0.0:
        raise ConfigError("torque_limit_nm", f"must be > 0, got {torque!r}")
    if torque_only:
        return OptimalLimits(torque_max_nm=torque)
    return OptimalLimits(torque_max_nm=torque, wheel_speed_max_radps=pi.wheel_speed_max_radps,
                         v_max_mps=pi.v_max_mps, omega_max_radps=pi.omega_max_radps)


def optimal_to_log(start: Pose, goal: Pose, out: Path, fmu_path: Path, *, name: str,
                   objective: str = "time", torque_limit_nm: float | None = None,
                   torque_only: bool = False, final_time_s: float | None = None,
                   period_s: float = 0.01,
                   params: RobotParams | None = None,
                   progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Solve, replay on the FMU at ``fmu_path`` and log to ``out``; return the result record.

    ``objective="energy"`` without ``final_time_s`` takes 1.5 times the minimum time.  The
    record is the record of a run (:data:`wmr.core.record.RECORD_KEYS`, ``docs/results.md``)
    of the open-loop FMU replay (``status`` the solver's, ``time_to_goal_s`` the optimum's
    final time), then the optimal's own fields (``objective``, ``final_time_s``, the
    optimiser's ``ocp_*`` estimates, ``solve_time_s``, ``iterations``, ``limits``,
    ``time_to_radius_s``, ``final_speed_mps``); the log, with the scene topics
    (:mod:`wmr.adapters.mcap.scene`), is written only when the solve succeeded.
    ``progress`` receives a line at least every few seconds while IPOPT iterates
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

    params = RobotParams() if params is None else params
    limits = optimal_limits(torque_limit_nm, torque_only)
    note = ""
    if objective == "energy" and final_time_s is None:
        t_min = solve_optimal(start, goal, params, objective="time", limits=limits,
                              progress=progress)
        if t_min.status != "solved":
            raise ConfigError("final_time_s", "no minimum time to base the energy run on "
                              f"({t_min.status}: {t_min.message})", "give the final time")
        final_time_s = 1.5 * t_min.final_time_s
        note = f"final time 1.5 x the minimum time {t_min.final_time_s:.3f} s"
    res = solve_optimal(start, goal, params, objective=objective,  # type: ignore[arg-type]
                        limits=limits, final_time_s=final_time_s, progress=progress)
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
        done = {**record(name=name, status=res.status, message=message,
                         final_position_error_m=figures["final_position_error_m"],
                         final_heading_error_rad=figures["final_heading_error_rad"],
                         time_to_goal_s=res.final_time_s,
                         path_length_m=figures["path_length_m"],
                         energy_net_j=figures["energy_net_j"],
                         energy_positive_j=figures["energy_positive_j"],
                         energy_abs_j=figures["energy_abs_j"],
                         torque_sq_integral_n2m2s=figures["torque_sq_integral_n2m2s"],
                         peak_torque_nm=figures["peak_torque_nm"], steps=len(replay.t_s),
                         estimated_final_position_error_m=figures["final_position_error_m"],
                         estimated_final_heading_error_rad=figures["final_heading_error_rad"],
                         mcap=str(out)),
                **own, "time_to_radius_s": figures["time_to_radius_s"],
                "final_speed_mps": replay.final_speed_mps}
        write_optimal_log(out, res, replay, plant,
                          optimal_metadata(name, "", start, goal, params, limits, objective,
                                           plant, period_s),
                          {k: v for k, v in done.items() if not isinstance(v, dict)},
                          scenario=optimal_scenario(name, "", start, goal, params, limits,
                                                    period_s), scene=True)
    return done


__all__ = ["optimal_limits", "optimal_to_log"]
