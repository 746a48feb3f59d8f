r"""Optimal point-to-point manoeuvres of the robot: the CasADi/IPOPT reference for the PI loop.

The optimal control problem (OCP) runs on the dynamics of the Modelica model itself: the
explicit ODE :math:`\dot x = f(x, u, p)` that :func:`wmr.build.flatten.flatten` derives from
``modelica/WMR`` with pymoca, the same CasADi function the FMUs are generated from.  States,
parameters and outputs are looked up by name, never by position.

Transcription: direct multiple shooting on ``n_intervals`` intervals of equal length
:math:`h = T / N`, torques piecewise constant per interval, ``rk_substeps`` classical RK4
sub-steps per interval; the interval map is a ``casadi.Function.map`` and the NLP is expanded to
SX and solved by IPOPT.  One NLP is built per ``(n_intervals, rk_substeps)`` and process and
reused: start, goal, robot parameters and limits enter as NLP parameters and bounds.

Modules, one concern each: :mod:`~wmr.adapters.ocp.problem` (inputs, limits, the paper's cases),
:mod:`~wmr.adapters.ocp.model` (the ODE in CasADi, RK4, :func:`simulate`),
:mod:`~wmr.adapters.ocp.transcription` (the NLP and one IPOPT run),
:mod:`~wmr.adapters.ocp.warmstart`
(the initial guesses), :mod:`~wmr.adapters.ocp.result` (:class:`OptimalResult`),
:mod:`~wmr.adapters.ocp.solve` (:func:`solve_optimal`), :mod:`~wmr.adapters.ocp.replay`
(:func:`replay_open_loop`).  Everything public is importable from ``wmr.optimal``.

See ``docs/optimal.md`` for the formulation, the warm start and what the optimum says.
"""

from __future__ import annotations

from wmr.adapters.ocp.model import _model, simulate
from wmr.adapters.ocp.problem import (
    DEFAULT_INTERVALS,
    DEFAULT_PARAMS,
    DEFAULT_RK_SUBSTEPS,
    FAILED_ADVICE,
    FIG9_HEADINGS_DEG,
    FIG10_BEARINGS_DEG,
    FIG10_RADIUS_M,
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
    OptimalProblem,
    SolverOptions,
    Status,
    fig9_cases,
    fig10_cases,
)
from wmr.adapters.ocp.replay import OpenLoopReplay, replay_open_loop
from wmr.adapters.ocp.result import OptimalResult
from wmr.adapters.ocp.solve import min_time_bound_s, solve_optimal
from wmr.adapters.ocp.transcription import _nlp
from wmr.adapters.ocp.warmstart import _kinematic_guess, _wrap

__all__ = [
    "DEFAULT_INTERVALS",
    "DEFAULT_PARAMS",
    "DEFAULT_RK_SUBSTEPS",
    "FAILED_ADVICE",
    "FIG9_HEADINGS_DEG",
    "FIG10_BEARINGS_DEG",
    "FIG10_RADIUS_M",
    "MAX_FINAL_TIME_S",
    "MAX_INTERVAL_S",
    "MIN_FINAL_TIME_S",
    "OBJECTIVES",
    "SAME_POSE_TOL",
    "SPOT_TURN_CREEP_MPS",
    "SPOT_TURN_RADIUS_M",
    "FloatArray",
    "Objective",
    "OpenLoopReplay",
    "OptimalLimits",
    "OptimalProblem",
    "OptimalResult",
    "SolverOptions",
    "Status",
    "_kinematic_guess",
    "_model",
    "_nlp",
    "_wrap",
    "fig9_cases",
    "fig10_cases",
    "min_time_bound_s",
    "replay_open_loop",
    "simulate",
    "solve_optimal",
]

