"""The controller FMU as a sampled-data model that any master can drive (issue 20).

An fmusim-like driver of our own (one FMU, inputs from a table held over each communication
step, outputs read at every communication point, any output interval) steps the FMU through
fmpy's FMI calls and compares with the Python stabiliser sampled on the same grid:

* the outputs are a function of the state and the inputs: no setter call is needed to see
  the next sample, and re-setting an input to its value changes nothing;
* a step of k periods is k samples with the inputs held, equal to k single steps;
* a step that is not a multiple of the period samples on the grid t0 + n h and holds the last
  sample between grid points.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest
from fmpy import extract, instantiate_fmu, read_model_description

from wmr.build.controller_interface import INPUTS, SIGNAL_OUTPUTS, controller_model
from wmr.build.fmus import BuildResult
from wmr.core.control import Gains, Limits, PIController
from wmr.core.plant import Pose, RobotParams

H = 0.01  # the default control period
#: Measurements near the goal (20, 10): no saturation, so the integrals move every sample.
U1 = (19.8, 9.9, 0.2, 0.0, 0.0, 1.0, 0.8)
U2 = (19.81, 9.9, 0.21, 0.0, 0.0, 1.1, 0.9)


class Driver:
    """One controller FMU instance driven like fmusim: set, read, doStep."""

    def __init__(self, path: Path) -> None:
        self.md = read_model_description(str(path))
        self.v3 = self.md.fmiVersion.startswith("3")
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.unzipdir = extract(str(path))
        self.fmu: Any = instantiate_fmu(self.unzipdir, self.md, fmi_type="CoSimulation")
        if not self.v3:
            self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.t = 0.0

    def set(self, u: Sequence[float], names: Sequence[str] = INPUTS) -> None:
        setter = self.fmu.setFloat64 if self.v3 else self.fmu.setReal
        setter([self.vr[n] for n in names], list(u))

    def outputs(self) -> list[float]:
        getter = self.fmu.getFloat64 if self.v3 else self.fmu.getReal
        return list(getter([self.vr[n] for n in SIGNAL_OUTPUTS]))

    def step(self, h: float) -> None:
        self.fmu.doStep(self.t, h)
        self.t += h

    def close(self) -> None:
        self.fmu.freeInstance()
        shutil.rmtree(self.unzipdir, ignore_errors=True)


@pytest.fixture(params=[2, 3], ids=["fmi2", "fmi3"])
def driver(request: pytest.FixtureRequest, built: BuildResult) -> Iterator[Driver]:
    d = Driver(built.controllers[request.param])
    yield d
    d.close()


def _python() -> PIController:
    """The Python stabiliser with the FMU's default parameters."""
    defaults = {v.name: v.start for v in controller_model().parameters}
    return PIController(Pose(defaults["goal.x_m"], defaults["goal.y_m"],
                           math.radians(defaults["goal.heading_deg"])), Gains(), Limits(),
                      RobotParams(), defaults["control_period_s"], defaults["stop_radius_m"])


def _sample(ctrl: PIController, u: Sequence[float]) -> list[float]:
    x, y, theta, _, _, w_r, w_l = u
    return list(ctrl.step(x, y, theta, w_r, w_l))


def test_outputs_follow_state_and_inputs_without_any_setter_call(driver: Driver) -> None:
    """Inputs set once, 50 steps without a set (as ecos does for unchanged inputs): the
    outputs at every communication point are the Python stabiliser's sample there; setting an
    input to the value it has changes nothing (before the fix the outputs froze at the
    first sample, and the set took the next one)."""
    ref = _python()
    driver.set(U1)
    for _ in range(50):
        assert driver.outputs() == pytest.approx(_sample(ref, U1), abs=1e-12)
        driver.step(H)
    expected = _sample(ref, U1)
    before = driver.outputs()
    assert before == pytest.approx(expected, abs=1e-12)
    driver.set(U1[:1], ["x"])  # the same value again
    assert driver.outputs() == before
    i_s = SIGNAL_OUTPUTS.index("i_s")
    assert before[i_s] != 0.0  # the integral moved: a frozen output would still be 0


@pytest.mark.parametrize("k", [2, 3, 24])
def test_a_step_of_k_periods_equals_k_single_steps(built: BuildResult, k: int) -> None:
    """doStep over k periods (24: the Compliance Checker's default 0.24 s) takes k samples with
    the inputs held: the same outputs and state as k single steps without a set."""
    for version in (2, 3):
        one, many = Driver(built.controllers[version]), Driver(built.controllers[version])
        try:
            for d in (one, many):
                d.set(U1)
            one.step(k * H)
            for _ in range(k):
                many.step(H)
            assert one.outputs() == pytest.approx(many.outputs(), abs=1e-12, rel=1e-12)
            one.set(U2)
            many.set(U2)
            assert one.outputs() == pytest.approx(many.outputs(), abs=1e-12, rel=1e-12)
            ref = _python()
            for _ in range(k):
                _sample(ref, U1)
            assert one.outputs() == pytest.approx(_sample(ref, U2), abs=1e-12)
        finally:
            one.close()
            many.close()


def test_steps_between_samples_sample_on_the_grid_and_hold(driver: Driver) -> None:
    """An output interval of 0.004 s (not a divisor of the 0.01 s period): the samples are
    taken at 0, 0.01, 0.02 with the inputs set at the start of the step that covers them;
    between grid points the outputs hold the last sample, whatever the inputs do."""
    ref = _python()
    driver.set(U1)
    first = _sample(ref, U1)
    assert driver.outputs() == pytest.approx(first, abs=1e-12)
    driver.step(0.004)  # samples t = 0
    driver.set(U2)  # between samples: held, no direct feedthrough
    assert driver.outputs() == pytest.approx(first, abs=1e-12)
    driver.step(0.004)  # [0.004, 0.008): no grid point
    assert driver.outputs() == pytest.approx(first, abs=1e-12)
    driver.set(U1)
    driver.step(0.004)  # [0.008, 0.012): samples t = 0.01 on U1 (set at 0.008)
    second = _sample(ref, U1)
    assert driver.outputs() == pytest.approx(second, abs=1e-12)
    driver.set(U2)
    driver.step(0.004)  # [0.012, 0.016)
    assert driver.outputs() == pytest.approx(second, abs=1e-12)
    driver.step(0.004)  # [0.016, 0.02): ends on the grid, the sample of 0.02 is due
    assert driver.t == pytest.approx(0.02)
    assert driver.outputs() == pytest.approx(_sample(ref, U2), abs=1e-12)


def test_the_model_descriptions_say_any_step_is_taken(built: BuildResult) -> None:
    """canHandleVariableCommunicationStepSize is true (it was false: one step size only), the
    period stays the default experiment's step and FMI 3's fixedInternalStepSize."""
    for version in (2, 3):
        md = read_model_description(str(built.controllers[version]))
        assert md.coSimulation.canHandleVariableCommunicationStepSize is True
        assert float(md.defaultExperiment.stepSize) == H
        if version == 3:
            assert float(md.coSimulation.fixedInternalStepSize) == H
