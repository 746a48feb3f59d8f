"""``wmr ssp run``: an SSP package in a master we did not write, logged like ``wmr run``.

Two masters: libcosim (DNV's Open Simulation Platform, through ``libcosimpy``; FMI 2.0) here,
and Ecos (``ecospy``; FMI 2.0 and 3.0) in :mod:`wmr.adapters.ssp.ecos`.  Each loads the
package, applies its parameter sets and steps both FMUs with its fixed-step algorithm at the
package's ``baseStepSize``; every step is recorded, and the run stops at the controller's
``converged`` flag (as ``wmr run`` does) or at the default experiment's stop time.  The log
has a row per control period (:func:`steps_per_row`), as ``wmr run``'s, whatever the step.

Timing.  Both masters step their components side by side (Jacobi): before the step from
``t_k`` they set every input from the outputs read after the step before, and read the outputs
after the step.  Their initialisation passes the controller's first sample ``u_0`` to the
robot, so the robot's first step is on time.  After its step from ``t_k`` (on the measurement
``y_k``) the controller is at the grid point ``t_{k+1}`` and its outputs are the next sample
on the measurement it holds, ``g(z_{k+1}, y_k)`` (fmu/src/README.md); the robot holds those
torques over ``[t_{k+1}, t_{k+2})``.  A log row ``k`` is the robot's outputs at ``t_k`` and
the controller's outputs observed after its step from ``t_k`` (the torques the robot holds
next).

A step of ``h / n`` (``n > 1`` master steps per control period ``h``, the package's default):
the controller's step from the grid point ``t_k`` takes its sample there on the measurement
set at ``t_k``, on time (``y_k = g(z_k, y(t_k))``, ``z_{k+1} = f(z_k, y(t_k))``, as ``wmr
run``), and holds it; only the robot's first master step from ``t_k`` holds what the
controller showed before that, ``g(z_k, y(t_k - h / n))``.  A log row ``k`` is then the robot
at ``t_k`` and the controller's sample ``y_k``: ``wmr run``'s layout, in either master.

Standard output.  The masters' C libraries print to the process's standard output (fd 1);
:func:`c_stdout_to_stderr` sends it to standard error around their calls, so that ``wmr ssp
run --json`` prints the JSON line alone.
"""

from __future__ import annotations

import ctypes
import math
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from wmr.adapters.fmi.varmap import PARAMETER_NAMES, MapEntry
from wmr.adapters.ssp.package import CONTROLLER, ROBOT, SspPackage, unpacked_package
from wmr.build.controller_interface import SIGNAL_OUTPUTS
from wmr.core.energy import ENERGY_KEYS, wheel_work
from wmr.core.plant import OUTPUT_NAMES, RobotParams
from wmr.core.record import RunFigures, record
from wmr.core.runlog import LogHeader
from wmr.core.signals import COLUMN, CONTROL_SIGNALS, PLANT_SIGNALS, SIGNALS
from wmr.infra.errors import ConfigError, FmuError

#: The controller FMU's output of each :data:`wmr.core.signals.CONTROL_SIGNALS` column.
CONTROL_OUTPUTS = SIGNAL_OUTPUTS
_STEPS_PER_CHECK = 100


@dataclass
class SspRunData:
    """One SSP run: the rows in :data:`wmr.core.signals.SIGNALS` layout and every variable.

    ``variables[component][name]`` holds the variable at every communication point
    ``0 .. steps`` (index ``s`` is ``s * step_size_s``); ``block`` has a row every
    ``steps_per_row`` communication points (the control period, :func:`steps_per_row`): row
    ``k`` pairs the robot at ``t_k = k * steps_per_row * step_size_s`` with the controller's
    outputs after its step from there.  ``held_torque_nm[s]`` is the (right, left) torque the
    robot held over the master step from point ``s``, and ``wheel_speeds_radps[s]`` its
    (right, left) wheel speeds at point ``s`` (for the energies).
    """

    package: SspPackage
    t_ns: npt.NDArray[np.int64]
    block: npt.NDArray[np.float64]
    variables: dict[str, dict[str, npt.NDArray[np.float64]]]
    status: str
    message: str
    master: str = "libcosim"
    time_to_goal_s: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    held_torque_nm: npt.NDArray[np.float64] = field(
        default_factory=lambda: np.empty((0, 2), dtype=np.float64))
    step_size_s: float = math.nan
    steps_per_row: int = 1
    wheel_speeds_radps: npt.NDArray[np.float64] = field(
        default_factory=lambda: np.empty((0, 2), dtype=np.float64))


@contextmanager
def c_stdout_to_stderr() -> Iterator[None]:
    """Send what C code prints on the process's standard output (fd 1) to standard error
    meanwhile: the masters' libraries print there, and ``--json`` promises one line."""
    sys.stdout.flush()
    libc = ctypes.CDLL(None)
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        libc.fflush(None)  # C stdio buffers written meanwhile go to stderr too
        os.dup2(saved, 1)
        os.close(saved)


def step_size(package: SspPackage) -> float:
    """The package's communication step (its OSP annotation, else the control period)."""
    h = package.step_size_s or package.component(CONTROLLER).parameters.get("control_period_s")
    if h is None or not h > 0:
        raise FmuError(f"{package.path}: no step size (no OSP FixedStepAlgorithm and no "
                       "control_period_s): export it again with 'wmr ssp export'")
    return h


#: How close to a whole number of master steps the control period must be to log a row per
#: period (relative): the step is written as ``repr`` of ``period / n``.
_WHOLE_REL = 1e-9


def steps_per_row(package: SspPackage, h: float) -> int:
    """Master steps (of ``h``) per log row: the number ``n`` of them in the controller's
    ``control_period_s`` when it is a whole one (the log then has ``wmr run``'s row per
    period), else 1 (a row per master step)."""
    period = package.component(CONTROLLER).parameters.get("control_period_s")
    if period is None or not h > 0:
        return 1
    n = round(period / h)
    return n if n >= 1 and abs(n * h - period) <= _WHOLE_REL * period else 1


def n_steps(package: SspPackage, h: float, stop_time_s: float | None) -> int:
    """The number of steps to ``stop_time_s`` (default: the package's stop time)."""
    stop = stop_time_s if stop_time_s is not None else package.stop_time_s
    if stop is None:
        raise FmuError(f"{package.path}: no stop time: give one")
    return max(1, round((stop - package.start_time_s) / h))


def _require_libcosim() -> None:
    try:
        import libcosimpy  # noqa: F401
    except ImportError:
        raise ConfigError("libcosimpy", "not installed: wmr ssp run needs libcosim",
                          "pip install 'wmr-cosim[ssp]'") from None


def _quiet_libcosim() -> None:
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

    log_output_level(CosimLogLevel.ERROR)  # its default (debug) prints every FMI call


def _libcosim_version() -> str:
    from importlib.metadata import version

    return f"libcosimpy {version('libcosimpy')}"


def simulate_libcosim(ssp_path: str | os.PathLike[str], *, stop_time_s: float | None = None,
                      stop_at_convergence: bool = True) -> SspRunData:
    """Run a package of ``wmr ssp export`` in libcosim.

    Parameters
    ----------
    ssp_path
        The ``.ssp`` file.
    stop_time_s
        End of the run, s; default the package's default experiment (``max_time_s``).
    stop_at_convergence
        End at the first sample whose ``converged`` output is 1, like ``wmr run``.

    Raises
    ------
    ConfigError, FmuError
        The package is missing, refused by the archive door, incomplete (an FMU absent),
        not FMI 2.0, or libcosim refuses it.
    """
    _require_libcosim()
    # libcosim gets the folder we extracted and checked, never the package itself
    with unpacked_package(ssp_path) as (package, folder):
        return _simulate(package, folder, stop_time_s, stop_at_convergence)


def _simulate(package: SspPackage, folder: Path, stop_time_s: float | None,
              stop_at_convergence: bool) -> SspRunData:
    for component in (package.component(ROBOT), package.component(CONTROLLER)):
        if not component.fmi_version.startswith("2"):
            raise FmuError(f"{package.path}: component {component.name} is FMI "
                           f"{component.fmi_version}; "
                           f"libcosim ({_libcosim_version()}) runs FMI 2.0 FMUs only: run it "
                           "with --master ecos (or export the package with --fmi 2)")
    h = step_size(package)
    n_max = n_steps(package, h, stop_time_s)
    _quiet_libcosim()
    with c_stdout_to_stderr():
        variables, steps = _libcosim_loop(package, folder, h, n_max, stop_at_convergence)
    # libcosim observes after each step, before it passes the values on
    return log_rows(package, variables, steps, h, stop_at_convergence, _libcosim_version(),
                    after_transfer=False)


def _libcosim_loop(package: SspPackage, folder: Path, h: float, n_max: int,
                   stop_at_convergence: bool
                   ) -> tuple[dict[str, dict[str, npt.NDArray[np.float64]]], int]:
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver

    try:
        execution = CosimExecution.from_ssp_file(str(folder), step_size=round(h * 1e9))
    except AssertionError:
        raise FmuError(f"{package.path}: libcosim cannot load the package (run with a "
                       "libcosim log level of debug to see why)") from None
    index = {name: execution.slave_index_from_instance_name(name) for name in (ROBOT, CONTROLLER)}
    refs: dict[str, dict[str, int]] = {}
    series = CosimObserver.create_time_series(buffer_size=n_max + 2)
    last = CosimObserver.create_last_value()
    execution.add_observer(series)
    execution.add_observer(last)
    for comp, slave in index.items():
        refs[comp] = {v.name.decode(): v.reference for v in execution.slave_variables(slave)
                      if v.type == CosimVariableType.REAL.value}
        for ref in refs[comp].values():
            series.start_time_series(slave, ref, CosimVariableType.REAL)
    converged_ref = refs[CONTROLLER]["converged"]
    steps = 0
    converged = False

    def step(n: int) -> None:
        nonlocal steps
        if not execution.step(n):
            raise FmuError(f"{package.path}: libcosim failed to step at t = {steps * h:g} s "
                           "(an FMU returned an error)")
        steps += n

    def flag() -> bool:
        return bool(last.last_real_values(index[CONTROLLER], [converged_ref])[0] >= 0.5)

    while steps < n_max and not converged:
        step(min(_STEPS_PER_CHECK, n_max - steps))
        if stop_at_convergence and flag():
            # observed at a grid point, the flag is of the sample on the measurement of one
            # master step before; the log's row shows the sample the controller takes there
            # on the measurement passed on, which it holds at the next point (log_rows)
            step(1)
            converged = flag()
    variables = {comp: {name: _samples(series, index[comp], ref, steps)
                        for name, ref in refs[comp].items()} for comp in (ROBOT, CONTROLLER)}
    return variables, steps


def _samples(series: Any, slave: int, ref: int, steps: int) -> npt.NDArray[np.float64]:
    """The variable at communication points ``0 .. steps``.

    libcosimpy drops a sample whose step number is 0 from the end of what it returns (it
    counts the zeros of the step numbers as unfilled), so step 0 is read on its own.
    """
    _, _, first = series.time_series_real_samples(slave, ref, 0, 2)
    _, step_numbers, rest = series.time_series_real_samples(slave, ref, 1, steps)
    if len(first) != 1 or len(rest) != steps or list(step_numbers[:1]) != [1]:
        raise FmuError(f"libcosim's observer returned {len(first) + len(rest)} samples of "
                       f"{steps + 1}: enlarge its buffer")
    return np.array([first[0], *rest], dtype=np.float64)


def _in_our_names(package: SspPackage, values: dict[str, Any],
                  names: tuple[str, ...]) -> dict[str, Any]:
    """The robot's ``values`` (by its names, in its units) under our ``names`` and units,
    through the package's variable map; an unmapped name is NaN, an absent one left out."""
    vm = package.robot_map
    if vm is None:
        return {n: values[n] for n in names if n in values}
    out: dict[str, Any] = {}
    for n in names:
        entry = vm.entries.get(n, MapEntry(n))
        if n in vm.unmapped:
            out[n] = math.nan
        elif entry.name in values:
            out[n] = entry.scale * values[entry.name] + entry.offset
    return out


def log_rows(package: SspPackage, variables: dict[str, dict[str, npt.NDArray[np.float64]]],
             steps: int, h: float, stop_at_convergence: bool, master: str, *,
             after_transfer: bool) -> SspRunData:
    """The log rows of a run recorded at communication points ``0 .. steps`` (of ``h``): a row
    every :func:`steps_per_row` points, the control grid when the period is a whole number
    of steps.

    ``after_transfer``: the master recorded after passing the outputs on to the inputs (Ecos),
    so that index ``s`` holds the controller's outputs at ``t_s`` on the inputs set there and
    the robot's torque inputs for the step from ``t_s``; otherwise before (libcosim): the
    controller's outputs after its step from ``t_s`` are at index ``s + 1``, and so are the
    robot's inputs of the step from ``t_s``.  A row shows the controller at the index of its
    robot plus that offset; a run ends at the first row whose ``converged`` output is 1.
    """
    robot = _in_our_names(package, variables[ROBOT], (*OUTPUT_NAMES, "tau_r", "tau_l"))
    ctrl = variables[CONTROLLER]
    missing = [n for n in OUTPUT_NAMES if n not in robot] + \
        [n for n in (*CONTROL_OUTPUTS, "converged") if n not in ctrl]
    if missing:
        raise FmuError(f"{package.path}: the components lack the outputs {', '.join(missing)}")
    off = 0 if after_transfer else 1  # index of the controller's values of row 0
    stride = steps_per_row(package, h)
    n_rows = (steps - off) // stride + 1  # rows whose controller values were recorded
    robot_at = np.arange(n_rows) * stride  # index of each row's robot values
    flags = ctrl["converged"][robot_at + off]
    hit = np.flatnonzero(flags >= 0.5)
    status, message, time_to_goal = "timeout", f"not converged within {steps * h:g} s", None
    if stop_at_convergence and hit.size:
        n_rows = int(hit[0]) + 1
        robot_at = robot_at[:n_rows]
        time_to_goal = hit[0] * stride * h
        status, message = "converged", f"converged at t = {time_to_goal:.2f} s"
    held = np.full((steps, 2), np.nan)
    for j, name in enumerate(("tau_r", "tau_l")):
        if np.ndim(robot.get(name, math.nan)):
            held[:, j] = robot[name][off:steps + off]
    wheels = np.full((steps + 1, 2), np.nan)
    for j, name in enumerate(("omega_r", "omega_l")):
        if np.ndim(robot[name]):
            wheels[:, j] = robot[name][:steps + 1]
    block = np.empty((n_rows, len(SIGNALS)), dtype=np.float64)
    for i, name in enumerate(OUTPUT_NAMES):
        values = robot[name]  # NaN (a float) where the map leaves the output unmapped
        block[:, COLUMN[PLANT_SIGNALS[i]]] = values[robot_at] if np.ndim(values) else values
    for col, name in zip(CONTROL_SIGNALS, CONTROL_OUTPUTS, strict=True):
        block[:, COLUMN[col]] = ctrl[name][robot_at + off]
    if status == "converged":
        # as in wmr run: the last row shows the robot at rest with zero torque
        block[-1, COLUMN["tau_r_nm"]] = block[-1, COLUMN["tau_l_nm"]] = 0.0
    t_ns = np.round(robot_at * h * 1e9).astype(np.int64)
    return SspRunData(package=package, t_ns=t_ns, block=block, variables=variables,
                      status=status, message=message, master=master,
                      time_to_goal_s=time_to_goal, step_size_s=h, held_torque_nm=held,
                      steps_per_row=stride, wheel_speeds_radps=wheels)


def _goal(package: SspPackage) -> tuple[float, float, float]:
    p = package.component(CONTROLLER).parameters
    return (p.get("goal.x_m", math.nan), p.get("goal.y_m", math.nan),
            math.radians(p.get("goal.heading_deg", math.nan)))


def run_record(run: SspRunData) -> dict[str, object]:
    """The ``run`` metadata record of the log: the package's parameters under the names of
    ``wmr run``'s record, and the master."""
    package = run.package
    rp = _in_our_names(package, package.component(ROBOT).parameters, PARAMETER_NAMES)
    cp = package.component(CONTROLLER).parameters
    goal = _goal(package)

    def section(prefix: str) -> dict[str, float]:
        return {k[len(prefix) + 1:]: v for k, v in cp.items() if k.startswith(prefix + ".")}

    return {
        "name": package.name,
        "scenario": package.name,
        "start": {"x_m": rp.get("x0"), "y_m": rp.get("y0"), "heading_rad": rp.get("theta0")},
        "goal": {"x_m": goal[0], "y_m": goal[1], "heading_rad": goal[2]},
        "params": {k: v for k, v in rp.items() if math.isfinite(v) and k not in (
            "x0", "y0", "theta0", "v0", "omega0")},
        "gains": section("gains"),
        "controller": "pi",
        "limits": section("limits"),
        "control_period_s": cp.get("control_period_s"),
        "stop_radius_m": cp.get("stop_radius_m"),
        "heading_tolerance_rad": math.radians(cp.get("heading_tolerance_deg", math.nan)),
        "ssp_file": package.path.name,
        "ssp_sha256": package.sha256,
        "fmi_version": package.component(ROBOT).fmi_version,
        "master": run.master,
        "lag_steps": 1,
    }


def result_record(run: SspRunData, mcap: Path) -> dict[str, object]:
    """The ``result`` record: the record of ``wmr run`` (:func:`wmr.core.record.record`,
    ``docs/results.md``) from the rows and the torques the robot held, then the ``master``.

    The torque figures are those of the held torques over each step between the rows, as
    the energies are; no sensors: the estimated errors are the true ones.
    """
    b = run.block
    x, y, theta = b[:, COLUMN["x_m"]], b[:, COLUMN["y_m"]], b[:, COLUMN["theta_rad"]]
    gx, gy, gth = _goal(run.package)
    position_error_m = math.hypot(gx - float(x[-1]), gy - float(y[-1]))
    heading_error_rad = abs(math.remainder(float(theta[-1]) - gth, 2 * math.pi))
    held = run.held_torque_nm[:(b.shape[0] - 1) * run.steps_per_row]
    work = energies(run)
    return {
        **record(RunFigures(
            name=run.package.name, status=run.status, message=run.message,
            final_position_error_m=position_error_m, final_heading_error_rad=heading_error_rad,
            time_to_goal_s=run.time_to_goal_s,
            path_length_m=float(np.hypot(np.diff(x), np.diff(y)).sum()),
            energy_net_j=work["energy_net_j"], energy_positive_j=work["energy_positive_j"],
            energy_abs_j=work["energy_abs_j"],
            torque_sq_integral_n2m2s=float(run.step_size_s * np.sum(held**2)),
            peak_torque_nm=float(np.max(np.abs(held))) if held.size else 0.0,
            steps=int(b.shape[0]), estimated_final_position_error_m=position_error_m,
            estimated_final_heading_error_rad=heading_error_rad, mcap=str(mcap))),
        "master": run.master,
    }


def energies(run: SspRunData) -> dict[str, float]:
    """The :data:`~wmr.core.energy.ENERGY_KEYS` of the run (as ``wmr run``'s): the torques the
    robot held over each master step to the last logged row, times its wheel speeds at both
    ends (trapezoid).  NaN where the robot's map leaves a wheel speed unmapped."""
    n = (run.block.shape[0] - 1) * run.steps_per_row  # master steps to the last row
    if n < 1 or run.held_torque_nm.shape[0] < n or run.wheel_speeds_radps.shape[0] <= n:
        return dict.fromkeys(ENERGY_KEYS, math.nan if n >= 1 else 0.0)
    return wheel_work(run.held_torque_nm[:n], run.wheel_speeds_radps[:n + 1], run.step_size_s)


def log_ssp_run(run: SspRunData, mcap_path: str | os.PathLike[str]) -> dict[str, object]:
    """Write ``run`` to an MCAP log of ``wmr run``'s layout; return the result record."""
    from wmr.adapters.mcap import McapOpener

    path = Path(mcap_path)
    record = result_record(run, path)
    meta = run_record(run)
    # run_record's typed values, as the scene draws them
    params = cast("dict[str, float]", meta["params"])
    header = LogHeader(run=meta, goal=_goal(run.package),
                       attachments=tuple((name, media_type, data) for name, (media_type, data)
                                         in run.package.attachments.items()),
                       half_track_m=params.get("L", RobotParams.L),
                       wheel_radius_m=params.get("r", RobotParams.r),
                       stop_radius_m=cast("float | None", meta["stop_radius_m"]))
    with McapOpener(path)(header) as log:
        log.write_block(run.t_ns, run.block)
        log.close(record)
    return record


__all__ = ["CONTROL_OUTPUTS", "SspRunData", "c_stdout_to_stderr", "energies", "log_rows",
           "log_ssp_run", "n_steps", "simulate_libcosim", "step_size", "steps_per_row"]
