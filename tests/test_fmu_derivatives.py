"""Directional and adjoint derivatives of the FMUs: CasADi's exact Jacobian, checked against
CasADi itself (1e-12) and against central finite differences of the FMU (1e-6), through both
interfaces of FMI 2.0 and FMI 3.0."""

from __future__ import annotations

import ctypes
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from fmpy import extract, instantiate_fmu, read_model_description
from fmpy.fmi1 import FMICallException

from wmr.build.codegen import jacobian_function
from wmr.build.flatten import FlatModel, flatten
from wmr.build.fmus import BuildResult
from wmr.infra import paths

Array = npt.NDArray[np.float64]
START = {"b_f": 0.02, "tau_c": 0.05, "l": 0.1}  # friction and offset centre of gravity
X = np.array([0.3, -0.2, 1.0, -0.5, 0.7, 0.4, -0.6])  # phi_r, phi_l, x, y, theta, v, omega
U = np.array([0.8, -0.3])


@pytest.fixture(scope="module")
def model() -> FlatModel:
    return flatten(paths.modelica_dir())


class Instance:
    """One FMU instance in continuous-time mode (ME) or step mode (CS), through fmpy."""

    def __init__(self, fmu: Path, fmi_type: str) -> None:
        self.md = read_model_description(str(fmu))
        self.v3 = self.md.fmiVersion.startswith("3")
        self.tmp = extract(str(fmu), tempfile.mkdtemp(prefix="wmr-jac-"))
        self.fmu: Any = instantiate_fmu(self.tmp, self.md, fmi_type=fmi_type)
        vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.states = [d.variable.derivative.valueReference for d in self.md.derivatives]
        self.derivatives = [d.variable.valueReference for d in self.md.derivatives]
        self.outputs = [o.variable.valueReference for o in self.md.outputs]
        self.inputs = [vr["tau_r"], vr["tau_l"]]
        self.parameter = vr["m"]
        if self.v3:
            self.fmu.setFloat64([vr[n] for n in START], list(START.values()))
            self.fmu.enterInitializationMode()
        else:
            self.fmu.setupExperiment()
            self.fmu.setReal([vr[n] for n in START], list(START.values()))
            self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        if fmi_type == "ModelExchange":
            if self.v3:
                self.fmu.updateDiscreteStates()
            else:
                self.fmu.newDiscreteStates()
            self.fmu.enterContinuousTimeMode()

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()
        shutil.rmtree(self.tmp, ignore_errors=True)

    def set(self, x: Array | None, u: Array) -> None:
        if x is not None:
            xc = np.ascontiguousarray(x, dtype=float)
            self.fmu.setContinuousStates(xc.ctypes.data_as(ctypes.POINTER(ctypes.c_double)),
                                         len(xc))
        (self.fmu.setFloat64 if self.v3 else self.fmu.setReal)(self.inputs, list(u))

    def state(self) -> Array:
        return np.array((self.fmu.getFloat64 if self.v3 else self.fmu.getReal)(self.states))

    def unknowns(self) -> Array:
        """Rows of the model core's Jacobian: state derivatives, then outputs."""
        get = self.fmu.getFloat64 if self.v3 else self.fmu.getReal
        return np.array(get(self.derivatives + self.outputs))

    def directional(self, seed: Array) -> Array:
        unknowns, knowns = self.derivatives + self.outputs, self.states + self.inputs
        return np.array(self.fmu.getDirectionalDerivative(unknowns, knowns, list(seed)))

    def adjoint(self, seed: Array) -> Array:
        unknowns, knowns = self.derivatives + self.outputs, self.states + self.inputs
        # the sensitivity has one entry per known (fmpy's default sizes it by the unknowns)
        return np.array(self.fmu.getAdjointDerivative(unknowns, knowns, list(seed),
                                                      nSensitivity=len(knowns)))


@pytest.fixture(params=[(2, "ModelExchange"), (3, "ModelExchange"), (2, "CoSimulation"),
                        (3, "CoSimulation")], ids=["fmi2-me", "fmi3-me", "fmi2-cs", "fmi3-cs"])
def instance(request: pytest.FixtureRequest, built: BuildResult) -> Iterator[Instance]:
    version, fmi_type = request.param
    inst = Instance(built.fmus[version], fmi_type)
    if fmi_type == "ModelExchange":
        inst.set(X, U)
    else:  # states cannot be set: drive the robot somewhere first
        inst.set(None, U)
        for k in range(50):
            inst.fmu.doStep(0.01 * k, 0.01)
    yield inst
    inst.close()


def _casadi_jacobian(model: FlatModel, x: Array, u: Array) -> Array:
    p = [START.get(v.name, v.start) for v in model.parameters]
    return np.array(jacobian_function(model)(x, u, p))


def test_directional_derivatives_are_casadis_jacobian(instance: Instance,
                                                      model: FlatModel) -> None:
    x = instance.state()
    expected = _casadi_jacobian(model, x, U)
    assert expected.shape == (19, 9) and np.count_nonzero(expected) > 30
    columns = np.column_stack([instance.directional(e) for e in np.eye(9)])
    scale = np.maximum(1.0, np.abs(expected))
    assert np.max(np.abs(columns - expected) / scale) < 1e-12
    seed = np.linspace(-1.0, 2.0, 9)  # all knowns at once
    assert np.max(np.abs(instance.directional(seed) - expected @ seed)) < 1e-12 * np.max(
        np.abs(expected) @ np.abs(seed))


@pytest.mark.parametrize("instance", [(3, "ModelExchange"), (3, "CoSimulation")],
                         ids=["fmi3-me", "fmi3-cs"], indirect=True)  # FMI 3 only
def test_adjoint_derivatives_are_the_transposed_jacobian(instance: Instance,
                                                         model: FlatModel) -> None:
    expected = _casadi_jacobian(model, instance.state(), U)
    rows = np.vstack([instance.adjoint(e) for e in np.eye(19)])
    assert np.max(np.abs(rows - expected) / np.maximum(1.0, np.abs(expected))) < 1e-12
    seed = np.linspace(1.0, -1.0, 19)
    assert np.max(np.abs(instance.adjoint(seed) - seed @ expected)) < 1e-12 * np.max(
        np.abs(seed) @ np.abs(expected))


def test_directional_derivatives_match_central_differences(built: BuildResult) -> None:
    for version in (2, 3):
        inst = Instance(built.fmus[version], "ModelExchange")
        try:
            inst.set(X, U)
            jac = np.column_stack([inst.directional(e) for e in np.eye(9)])
            fd = np.empty_like(jac)
            for j in range(9):
                h = 1e-6 * max(1.0, abs(np.concatenate([X, U])[j]))
                values = []
                for sign in (1.0, -1.0):
                    x, u = X.copy(), U.copy()
                    if j < 7:
                        x[j] += sign * h
                    else:
                        u[j - 7] += sign * h
                    inst.set(x, u)
                    values.append(inst.unknowns())
                fd[:, j] = (values[0] - values[1]) / (2 * h)
            assert np.max(np.abs(fd - jac)) < 1e-6
        finally:
            inst.close()


def test_a_parameter_is_no_known(built: BuildResult) -> None:
    inst = Instance(built.fmus[2], "ModelExchange")
    try:
        with pytest.raises(FMICallException):
            inst.fmu.getDirectionalDerivative(inst.outputs[:1], [inst.parameter], [1.0])
    finally:
        inst.close()
