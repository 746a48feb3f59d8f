"""The optimal control problem's inputs: objectives, constants, the paper's cases, the
limits (:class:`OptimalLimits`), the problem (:class:`OptimalProblem`), the solver's options
(:class:`SolverOptions`) and the argument checks."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from wmr.core.plant import Pose, RobotParams
from wmr.infra.errors import ConfigError

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
#: A goal within this distance of the start (m) is a turn on the spot: forward only
#: (``allow_reverse=False``) then bounds v >= -:data:`SPOT_TURN_CREEP_MPS` instead of v >= 0.
#: A spot turn's optimum has v = 0 at every node, on the bound v >= 0, and the goal position
#: then pins x and y at the end as well: the constraints are degenerate and IPOPT failed
#: (Maximum_Iterations_Exceeded after 1000-1900 iterations) on every spot turn from 10 to 90 deg
#: either way.  With the creep allowed, every turn from 10 to 180 deg solves in 10-20
#: iterations (benchmarks/short_manoeuvres.py, docs/optimal.md).
SPOT_TURN_RADIUS_M: Final = 0.1
#: The backward speed a spot turn may use, m/s.  Its optimum rocks by a few cm/s and ends
#: within millimetres of the start; reversing at 5 cm/s grows omega at m l |v| / J_B = 0.13 1/s,
#: harmless over the 1-3 s of a turn (the open-loop replay on the FMU ends within 1 cm).
SPOT_TURN_CREEP_MPS: Final = 0.05
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




def _finite(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(name, f"must be a finite number, got {value!r}")
    return float(value)


def _check_pose(name: str, pose: object) -> Pose:
    if not isinstance(pose, Pose):
        raise ConfigError(name, f"must be a wmr.core.plant.Pose, got {type(pose).__name__}")
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


@dataclass(frozen=True)
class OptimalProblem:
    r"""One rest-to-rest manoeuvre to optimise: what :func:`~wmr.adapters.ocp.solve_optimal`
    solves.  Checked by the solve, each error naming its field (``goal.x_m`` for a NaN goal).

    Attributes
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
    limits
        The torque, wheel speed, speed and turn rate limits (default a torque limit of
        10 N.m alone; ``OptimalLimits.like(closed_loop_limits)`` for the PI's).
    final_time_s
        The fixed duration, s; required for ``"energy"``, not allowed otherwise.
    allow_reverse
        Allow :math:`v < 0`.  Off by default: the PI stabiliser drives forward only, and with
        the centre of gravity ahead of the axle (``l > 0``) driving backward is open-loop
        unstable (:math:`\dot\omega = m l |v| \omega / J_B + \dots`), so a replay of a
        reversing optimum on the FMU drifts away from the goal.
        A turn on the spot (goal within :data:`SPOT_TURN_RADIUS_M` of the start) may still
        reverse at up to :data:`SPOT_TURN_CREEP_MPS`: with v >= 0 its optimum sits on the bound
        at every node and IPOPT does not converge.
    mix_weight
        Weight w of the effort in the ``"mix"`` objective, 1/(N^2 m^2).
    """

    start: Pose
    goal: Pose
    params: RobotParams = DEFAULT_PARAMS
    objective: Objective = "time"
    limits: OptimalLimits = OptimalLimits()
    final_time_s: float | None = None
    allow_reverse: bool = False
    mix_weight: float = 0.005


@dataclass(frozen=True)
class SolverOptions:
    """How :func:`~wmr.adapters.ocp.solve_optimal` transcribes and solves a problem.  Checked
    by the solve, each error naming its field.

    Attributes
    ----------
    n_intervals
        Shooting intervals N (torques are constant over T / N).
    warm_start
        Start IPOPT from the kinematic rotate-translate-rotate path (True) or from the straight
        interpolation of the poses at rest with zero torques and T = 10 s (False).
    rk_substeps
        RK4 steps per interval.
    max_iter, max_cpu_time_s
        IPOPT's iteration and CPU-time limits: a solve never hangs.
    """

    n_intervals: int = DEFAULT_INTERVALS
    warm_start: bool = True
    rk_substeps: int = DEFAULT_RK_SUBSTEPS
    max_iter: int = 1000
    max_cpu_time_s: float = 60.0
