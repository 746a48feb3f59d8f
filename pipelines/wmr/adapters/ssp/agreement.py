"""How closely a master we did not write follows ``wmr run`` on an exported package.

The paths compared are ``(x, y, theta)`` at every control step.  ``wmr run`` is our master
loop driving the Python stabiliser on the robot FMU (FMI 2.0, as in the package);
:func:`libcosim_path` and :func:`fmpy_path` run the package in libcosim and in fmpy's SSP
simulator.  A master that passes connection values one step late gets its path compared
``lag`` steps later (:func:`deviation`); :func:`measured_lag` finds that shift.
``tests/test_ssp.py`` holds the bars (:data:`POSITION_BAR_M`, :data:`HEADING_BAR_RAD`, the
agreement docs/ssp.md claims), ``benchmarks/ssp_agreement.py`` prints the table and ``wmr ssp
check`` (:mod:`wmr.apps.ssp_check`) a package's.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import numpy.typing as npt

from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.fmi.varmap import VariableMap
from wmr.adapters.ssp.cosim import c_stdout_to_stderr, simulate_libcosim, steps_per_row
from wmr.adapters.ssp.package import fmpy_parameter_set, read_package
from wmr.core.closedloop import LoopOutcome, run_closed_loop
from wmr.core.control.from_spec import SpecController
from wmr.core.runlog import MemoryLog
from wmr.core.runspec import RunSpec
from wmr.core.signals import COLUMN

_POSE = [COLUMN["x_m"], COLUMN["y_m"], COLUMN["theta_rad"]]
#: The agreement docs/ssp.md claims of a master's path with ``wmr run``'s, after the master's
#: measured lag: the worst distance and the worst heading difference over the run.
POSITION_BAR_M = 5e-3
HEADING_BAR_RAD = math.radians(0.2)


def wmr_run_path(spec: RunSpec, robot_fmu: str | os.PathLike[str],
                 var_map: VariableMap | None = None) -> tuple[str, npt.NDArray[np.float64]]:
    """``wmr run``'s status and ``(x, y, theta)`` rows of ``spec`` on ``robot_fmu`` (through
    ``var_map`` for a robot FMU of another tool)."""
    result, path = wmr_run(spec, robot_fmu, var_map)
    return result.status, path


def wmr_run(spec: RunSpec, robot_fmu: str | os.PathLike[str],
            var_map: VariableMap | None = None) -> tuple[LoopOutcome, npt.NDArray[np.float64]]:
    """``wmr run``'s result and ``(x, y, theta)`` rows of ``spec`` on ``robot_fmu`` (through
    ``var_map`` for a robot FMU of another tool)."""
    rows = MemoryLog()  # the run's rows, recorded as a log would receive them
    with FmuPlant(Path(robot_fmu), var_map=var_map) as plant:
        result = run_closed_loop(spec, plant, sink=rows, controller=SpecController())
    return result, rows.block[:, _POSE]


def libcosim_path(ssp: str | os.PathLike[str]) -> tuple[str, npt.NDArray[np.float64]]:
    """libcosim's status and ``(x, y, theta)`` rows
    (:func:`wmr.adapters.ssp.cosim.simulate_libcosim`)."""
    run = simulate_libcosim(ssp)
    return run.status, run.block[:, _POSE]


def fmpy_path(ssp: str | os.PathLike[str], stop_time_s: float, step_size_s: float | None = None
              ) -> tuple[bool, npt.NDArray[np.float64]]:
    """fmpy's ``simulate_ssp`` on the package with its own parameter sets, stepped at
    ``step_size_s`` (default: the package's step; fmpy reads no step from a package).

    Returns whether the controller's ``converged`` flag rose, and ``(x, y, theta)`` at
    ``t_0, t_1, ...``, a row per control period when it is a whole number of steps
    (:func:`~wmr.adapters.ssp.cosim.steps_per_row`), else per step: fmpy's row ``k`` holds the
    values after its step from ``t_k`` (the robot at ``t_{k+1}``), so row 0 here is the start
    pose of the package.
    """
    converged_at_s, path = fmpy_run(ssp, stop_time_s, step_size_s)
    return converged_at_s is not None, path


def fmpy_run(ssp: str | os.PathLike[str], stop_time_s: float, step_size_s: float | None = None
             ) -> tuple[float | None, npt.NDArray[np.float64]]:
    """fmpy's ``simulate_ssp`` on the package with its own parameter sets, as
    :func:`fmpy_path`, but with the time of the first sample whose ``converged`` output is 1
    (fmpy's row ``k`` holds the controller's sample at ``t_(k+1)``), ``None`` if none is."""
    from fmpy.ssp.simulation import simulate_ssp

    package = read_package(Path(ssp))
    robot = package.components["robot"].parameters
    h = step_size_s if step_size_s is not None else package.step_size_s
    with c_stdout_to_stderr():  # what the FMUs' C prints is not our standard output
        out = simulate_ssp(str(ssp), stop_time=stop_time_s, step_size=h,
                           parameter_set=fmpy_parameter_set(package))
    start = np.array([[robot["x0"], robot["y0"], robot["theta0"]]])
    path = np.vstack([start, np.column_stack([out["robot.x"], out["robot.y"],
                                              out["robot.theta"]])])
    hit = np.flatnonzero(out["controller.converged"] >= 0.5)
    stride = steps_per_row(package, h) if h else 1
    return (float(out["time"][hit[0]]) if hit.size else None), path[::stride]


def deviation(path: npt.NDArray[np.float64], ref: npt.NDArray[np.float64], lag: int = 0
              ) -> tuple[float, float]:
    """Worst distance (m) and heading difference (rad) of ``path[k + lag]`` from ``ref[k]``
    over the samples both have."""
    n = min(len(path) - lag, len(ref))
    a, b = path[lag:lag + n], ref[:n]
    return (float(np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1]).max()),
            float(np.abs(a[:, 2] - b[:, 2]).max()))


def measured_lag(path: npt.NDArray[np.float64], ref: npt.NDArray[np.float64],
                 max_lag: int = 2) -> int:
    """The shift in steps (0 ... ``max_lag``) that brings ``path`` closest to ``ref``."""
    return min(range(max_lag + 1), key=lambda lag: deviation(path, ref, lag)[0])


__all__ = ["HEADING_BAR_RAD", "POSITION_BAR_M", "deviation", "fmpy_path", "fmpy_run",
           "libcosim_path", "measured_lag", "wmr_run", "wmr_run_path"]
