"""Model Exchange (fmpy integrates the FMU's derivatives) agrees with Co-Simulation (the FMU's
own Dormand-Prince) on a torque profile with steps, in FMI 2.0 and FMI 3.0."""

from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fmpy import extract, instantiate_fmu, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException

from wmr.build.fmus import BuildResult

# Torque steps fall on communication points (multiples of 0.01 s): Co-Simulation holds each
# value over a step, Model Exchange sees them as input events, so both integrate the same ODE.
PROFILE = np.array([(0.0, 1.0, 0.8), (0.5, 1.0, 0.8), (0.5, -0.5, 0.6), (1.2, -0.5, 0.6),
                    (1.2, 0.3, -0.3), (2.0, 0.3, -0.3)],
                   dtype=[("time", float), ("tau_r", float), ("tau_l", float)])
OUTPUTS = ["x", "y", "theta", "v", "omega", "omega_r", "omega_l", "phi_r", "phi_l", "x_G", "y_G",
           "E_kin"]
FRICTION = {"b_f": 0.02, "tau_c": 0.05}  # the tanh friction term is exercised too


def _run(fmu: str, fmi_type: str, stop_s: float, **kwargs: Any) -> np.ndarray:
    return simulate_fmu(fmu, fmi_type=fmi_type, stop_time=stop_s, input=PROFILE,
                        output=OUTPUTS, start_values=FRICTION, **kwargs)


def _at(result: np.ndarray, times: np.ndarray) -> np.ndarray:
    """The rows of ``result`` at ``times`` (after an input event, the row after it); fmpy's
    fixed-step time is a running sum, so it may lie a rounding error below the sample time."""
    idx = np.searchsorted(result["time"], times + 1e-9, side="right") - 1
    assert np.allclose(result["time"][idx], times, rtol=0, atol=1e-9)
    return result[idx]


def _max_difference(a: np.ndarray, b: np.ndarray) -> float:
    return max(float(np.max(np.abs(a[n] - b[n]))) for n in OUTPUTS)


@pytest.mark.parametrize("version", [2, 3])
def test_both_interfaces_are_declared(built: BuildResult, version: int) -> None:
    md = read_model_description(str(built.fmus[version]))
    assert md.modelExchange is not None and md.coSimulation is not None
    assert md.numberOfContinuousStates == 7 and md.numberOfEventIndicators == 0
    states = [d.variable.derivative.name for d in md.derivatives]
    assert states == ["phi_r", "phi_l", "x", "y", "theta", "v", "omega"]
    assert [d.variable.name for d in md.derivatives] == [f"der({s})" for s in states]


@pytest.mark.parametrize("version", [2, 3])
def test_cvode_agrees_with_co_simulation(built: BuildResult, version: int) -> None:
    fmu = str(built.fmus[version])
    cs = _run(fmu, "CoSimulation", 2.0, output_interval=0.01)
    me = _run(fmu, "ModelExchange", 2.0, solver="CVode", output_interval=0.01,
              relative_tolerance=1e-10)
    assert abs(cs["x"][-1]) > 0.3  # the robot moved: the comparison is not of zeros
    assert _max_difference(cs, _at(me, cs["time"])) < 1e-7


@pytest.mark.parametrize("version", [2, 3])
def test_euler_converges_to_co_simulation(built: BuildResult, version: int) -> None:
    """fmpy's forward Euler (one step per output interval) is first order: its error halves
    with the step, and Richardson's extrapolation of the two agrees to 1e-7.  (Plain Euler
    would need steps of about 1e-8 s to reach 1e-7.)"""
    fmu = str(built.fmus[version])
    stop_s = 0.6
    cs = _run(fmu, "CoSimulation", stop_s, output_interval=0.01)
    coarse, fine = (_at(_run(fmu, "ModelExchange", stop_s, solver="Euler", step_size=h,
                             output_interval=h), cs["time"]) for h in (1e-4, 5e-5))
    err_coarse, err_fine = _max_difference(cs, coarse), _max_difference(cs, fine)
    assert 1.8 < err_coarse / err_fine < 2.2
    extrapolated = {n: 2 * fine[n] - coarse[n] for n in OUTPUTS}
    assert max(float(np.max(np.abs(cs[n] - extrapolated[n]))) for n in OUTPUTS) < 1e-7


@pytest.mark.parametrize("version", [2, 3])
def test_model_exchange_calls_are_checked(built: BuildResult, version: int,
                                          tmp_path: Path) -> None:
    md = read_model_description(str(built.fmus[version]))
    fmu: Any = instantiate_fmu(extract(str(built.fmus[version]), str(tmp_path)), md,
                               fmi_type="ModelExchange")
    if version == 2:
        fmu.setupExperiment()
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    with pytest.raises(FMICallException):  # ContinuousTimeMode is entered from EventMode only
        fmu.completedIntegratorStep()
    fmu.newDiscreteStates() if version == 2 else fmu.updateDiscreteStates()
    fmu.enterContinuousTimeMode()

    def states(n: int = 7) -> np.ndarray:
        x = np.zeros(n)
        fmu.getContinuousStates(x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), n)
        return x

    def set_states(x: np.ndarray) -> None:
        fmu.setContinuousStates(x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), len(x))

    good = np.linspace(0.1, 0.7, 7)
    set_states(good)
    saved = fmu.getFMUState() if version == 3 else fmu.getFMUstate()
    with pytest.raises(FMICallException):
        set_states(good[:6])
    with pytest.raises(FMICallException):
        set_states(np.where(np.arange(7) == 3, np.nan, good))
    assert np.array_equal(states(), good)  # a refused set changes nothing
    set_states(-good)
    fmu.setFMUState(saved) if version == 3 else fmu.setFMUstate(saved)
    assert np.array_equal(states(), good)
    mass = next(v.valueReference for v in md.modelVariables if v.name == "m")
    set_real = fmu.setFloat64 if version == 3 else fmu.setReal
    with pytest.raises(FMICallException):  # parameters wait for EventMode
        set_real([mass], [30.0])
    fmu.enterEventMode()
    set_real([mass], [30.0])
    fmu.terminate()
    fmu.freeInstance()
