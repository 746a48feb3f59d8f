"""The optimum replayed open-loop on the FMU (:func:`replay_open_loop`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from wmr.adapters.ocp.problem import FloatArray, _finite
from wmr.adapters.ocp.result import OptimalResult
from wmr.adapters.ocp.warmstart import _wrap
from wmr.core.plant import OUTPUT_NAMES, Pose, RobotParams
from wmr.infra.errors import ConfigError


@dataclass
class OpenLoopReplay:
    """The optimal torques applied open-loop to an FMU.

    Attributes
    ----------
    t_s
        (K + 1,) communication points, s.
    outputs
        FMU output name (:data:`wmr.core.plant.OUTPUT_NAMES`) -> (K + 1,) array, SI units.
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
                     control_period_s: float = 0.01) -> OpenLoopReplay:
    """Drive the FMU open-loop with the optimal torques.

    Each torque interval of length h is applied in ``ceil(h / control_period_s)`` equal FMU
    steps (the interval is split when it is longer than the control period).

    Parameters
    ----------
    result
        A solved :class:`OptimalResult`.
    fmu_path
        The ``.fmu`` file, or an open :class:`wmr.adapters.fmi.robot.FmuPlant` (left open).
    params, start
        Robot parameters and start pose of the FMU run; default: the result's.
    control_period_s
        Longest FMU step, s.

    Returns
    -------
    OpenLoopReplay
        FMU outputs at every step and the final errors against ``result.goal``.

    Raises
    ------
    ConfigError
        ``result`` is not solved, or ``control_period_s`` is not positive.
    """
    from wmr.adapters.fmi.robot import FmuPlant

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
    return OpenLoopReplay(
        t_s=np.array(times), outputs=outputs, torques=np.array(taus).reshape(-1, 2),
        final_position_error_m=math.hypot(outputs["x"][-1] - goal.x_m,
                                          outputs["y"][-1] - goal.y_m),
        final_heading_error_rad=_wrap(float(outputs["theta"][-1]) - goal.heading_rad),
        final_speed_mps=float(outputs["v"][-1]), final_omega_radps=float(outputs["omega"][-1]))
