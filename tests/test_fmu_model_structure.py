"""The model structure of both model descriptions is the sparsity of the generated functions;
display units and the default tolerance are declared."""

from __future__ import annotations

import math
import re
import shutil
import tempfile
from typing import Any

import casadi as ca
import pytest
from fmpy import extract, instantiate_fmu, read_model_description

from wmr.build.flatten import FlatModel, flatten
from wmr.build.fmus import BuildResult
from wmr.infra import paths


@pytest.fixture(scope="module")
def model() -> FlatModel:
    return flatten(paths.modelica_dir())


def _pattern(fun: ca.Function, wrt: list[int], names: list[list[str]]) -> list[set[str]]:
    """For each output row of ``fun``, the names of the inputs it structurally depends on."""
    rows: list[set[str]] = [set() for _ in range(fun.numel_out(0))]
    for i, names_i in zip(wrt, names, strict=True):
        sp = fun.sparsity_jac(i, 0)
        for r, c in zip(*sp.get_triplet(), strict=True):
            rows[r].add(names_i[c])
    return rows


def _declared(unknowns: list[Any]) -> dict[str, set[str]]:
    return {u.variable.name: {d.name for d in u.dependencies} for u in unknowns}


@pytest.mark.parametrize("version", [2, 3])
def test_dependencies_are_the_sparsity_of_the_generated_functions(
        built: BuildResult, model: FlatModel, version: int) -> None:
    md = read_model_description(str(built.fmus[version]))
    states = [next(v.name for v in model.outputs if v.state == i)
              for i in range(len(model.state_names))]
    inputs = [v.name for v in model.inputs]
    params = [v.name for v in model.parameters]
    outputs = _pattern(model.out, [0, 1], [states, inputs])
    derivatives = _pattern(model.ode, [0, 1], [states, inputs])
    assert _declared(md.outputs) == {v.name: outputs[v.index] for v in model.outputs}
    assert _declared(md.derivatives) == {v.name: derivatives[v.index] for v in model.derivatives}
    # initialisation: the state is x0(p)
    p, u = ca.SX.sym("p", len(params)), ca.SX.sym("u", len(inputs))
    x0 = model.init(p)
    at_start = ca.Function("start", [u, p], [ca.vertcat(model.ode(x0, u, p), model.out(x0, u, p))])
    initial = _pattern(at_start, [0, 1], [inputs, params])
    nx = len(states)
    expected = {**{v.name: initial[v.index] for v in model.derivatives},
                **{v.name: initial[nx + v.index] for v in model.outputs}}
    assert _declared(md.initialUnknowns) == expected
    assert all(len(u.dependencies) == len(u.dependenciesKind)
               for u in [*md.outputs, *md.derivatives, *md.initialUnknowns])


@pytest.mark.parametrize("version", [2, 3])
def test_no_output_depends_directly_on_the_torques(built: BuildResult, version: int) -> None:
    md = read_model_description(str(built.fmus[version]))
    assert all(d.causality != "input" for o in md.outputs for d in o.dependencies)
    kinds = {(u.variable.name, d.name): k for u in [*md.outputs, *md.derivatives]
             for d, k in zip(u.dependencies, u.dependenciesKind, strict=True)}
    assert kinds[("x", "x")] == "constant"  # the output is the state
    assert kinds[("der(theta)", "omega")] == "constant"  # eq. 7
    assert kinds[("der(x)", "theta")] == "dependent"  # v cos(theta)
    assert kinds[("der(v)", "tau_r")] == "tunable"  # a torque over the (tunable) inertias
    # and the FMU agrees: setting the torques without a step changes no output
    tmp = extract(str(built.fmus[version]), tempfile.mkdtemp(prefix="wmr-ft-"))
    fmu: Any = instantiate_fmu(tmp, md, fmi_type="CoSimulation")
    try:
        outputs = [o.variable.valueReference for o in md.outputs]
        inputs = [v.valueReference for v in md.modelVariables if v.causality == "input"]
        get = fmu.getFloat64 if version == 3 else fmu.getReal
        put = fmu.setFloat64 if version == 3 else fmu.setReal
        if version == 3:
            fmu.enterInitializationMode()
        else:
            fmu.setupExperiment()
            fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        put(inputs, [1.0, -0.4])
        for k in range(5):
            fmu.doStep(0.01 * k, 0.01)
        before = get(outputs)
        put(inputs, [-3.0, 2.0])
        assert get(outputs) == before
        fmu.doStep(0.05, 0.01)
        assert get(outputs) != before  # the torques act through the states
        fmu.terminate()
        fmu.freeInstance()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@pytest.mark.parametrize("version", [2, 3])
def test_display_units_and_tolerance(built: BuildResult, version: int) -> None:
    md = read_model_description(str(built.fmus[version]))
    assert md.defaultExperiment is not None
    # the tolerance the FMU's own solver uses when the importer sets none
    rtol = re.search(r"#define SOLVER_DEFAULT_RTOL (\S+)",
                     (paths.fmu_src_dir() / "solver.h").read_text())
    assert rtol is not None
    assert float(md.defaultExperiment.tolerance) == float(rtol.group(1)) == 1e-9
    variables = {v.name: v for v in md.modelVariables}
    for name in ("theta", "phi_r", "phi_l", "theta0"):
        assert variables[name].displayUnit == "deg", name
    for name in ("omega_r", "omega_l"):
        assert variables[name].displayUnit == "rpm", name
    factors = {d.name: d.factor for u in md.unitDefinitions for d in u.displayUnits}
    assert factors["deg"] == pytest.approx(180 / math.pi, rel=1e-15)
    assert factors["rpm"] == pytest.approx(60 / (2 * math.pi), rel=1e-15)


_KIND_NUMBER = {"constant": 1, "fixed": 2, "tunable": 3, "discrete": 4, "dependent": 5}


def _xml_structure(path: str) -> tuple[dict[int, list[tuple[int, int]]],
                                       dict[int, list[tuple[int, int]]]]:
    """The FMI 3 ``ModelStructure`` read from the archive's XML by the standard's rules, not
    by our code: ``{unknown: [(known, kind number)]}`` at communication points and at
    initialisation.  An unknown without ``dependencies`` depends on every known (the
    continuous states and inputs; at initialisation the inputs and parameters)."""
    import xml.etree.ElementTree as ET
    import zipfile

    with zipfile.ZipFile(path) as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
    variables = list(root.iterfind("ModelVariables/*"))
    states = sorted(int(v.get("derivative", "")) for v in variables if v.get("derivative"))
    inputs = [int(v.get("valueReference", "")) for v in variables
              if v.get("causality") == "input"]
    params = [int(v.get("valueReference", "")) for v in variables
              if v.get("causality") == "parameter"]
    every = {False: sorted(states + inputs), True: sorted(inputs + params)}
    running: dict[int, list[tuple[int, int]]] = {}
    initial: dict[int, list[tuple[int, int]]] = {}
    for el in root.iterfind("ModelStructure/*"):
        is_initial = el.tag == "InitialUnknown"
        if el.get("dependencies") is None:
            deps = [(k, 5) for k in every[is_initial]]
        else:
            deps = [(int(k), _KIND_NUMBER[kind]) for k, kind in zip(
                el.get("dependencies", "").split(), el.get("dependenciesKind", "").split(),
                strict=True)]
        (initial if is_initial else running)[int(el.get("valueReference", ""))] = deps
    return running, initial


@pytest.mark.parametrize("product", ["robot", "controller"])
def test_fmi3_variable_dependency_functions_return_the_model_structure(
        built: BuildResult, product: str) -> None:
    """fmi3GetNumberOfVariableDependencies / fmi3GetVariableDependencies answer what the model
    description declares: the initial unknowns' before the end of initialisation, the outputs'
    and derivatives' after (both returned an error before)."""
    import ctypes

    from fmpy.fmi3 import fmi3DependencyKind, fmi3ValueReference

    path = str((built.fmus if product == "robot" else built.controllers)[3])
    running, initial = _xml_structure(path)
    md = read_model_description(path)
    unzipdir = extract(path)
    fmu = instantiate_fmu(unzipdir, md, fmi_type="CoSimulation")

    def ask(vr: int) -> list[tuple[int, int]]:
        n = ctypes.c_size_t(99)
        assert fmu.fmi3GetNumberOfVariableDependencies(fmu.component, vr, ctypes.byref(n)) == 0
        m = n.value
        dep_idx, idx = (ctypes.c_size_t * m)(), (ctypes.c_size_t * m)()
        knowns, kinds = (fmi3ValueReference * m)(), (fmi3DependencyKind * m)()
        assert fmu.fmi3GetVariableDependencies(fmu.component, vr, dep_idx, knowns, idx, kinds,
                                               m) == 0
        assert list(dep_idx) == [0] * m and list(idx) == [0] * m
        return list(zip(list(knowns), list(kinds), strict=True))

    try:
        assert {vr: ask(vr) for vr in initial} == initial
        fmu.enterInitializationMode()
        assert {vr: ask(vr) for vr in initial} == initial
        fmu.exitInitializationMode()
        assert {vr: ask(vr) for vr in running} == running
        parameter = next(v.valueReference for v in md.modelVariables
                         if v.causality == "parameter")
        n = ctypes.c_size_t(0)
        with pytest.raises(Exception, match="fmi3GetNumberOfVariableDependencies"):
            fmu.fmi3GetNumberOfVariableDependencies(fmu.component, parameter, ctypes.byref(n))
    finally:
        fmu.freeInstance()
        shutil.rmtree(unzipdir, ignore_errors=True)
