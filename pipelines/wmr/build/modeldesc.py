"""Both model descriptions (FMI 2.0 and FMI 3.0) and the FMI 3 build description.

They are written from the one :class:`~wmr.build.flatten.FlatModel` that also writes the C
variable table, so value references, start values, bounds and units cannot drift apart.  The
model structure (``dependencies``, ``dependenciesKind``) is read off CasADi's Jacobians of the
generated functions (:func:`model_structure`), never written by hand.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeAlias

import casadi as ca

from wmr.build.flatten import MODEL_IDENTIFIER, FlatModel, Variable
from wmr.infra.version import __version__

if TYPE_CHECKING:
    from wmr.build.controller_interface import ControllerModel

    Model: TypeAlias = FlatModel | ControllerModel

# SI base-unit exponents of every unit the Modelica source uses (FMI 2.0 section 2.2.2).
_BASE_UNITS: dict[str, dict[str, float]] = {
    "m": {"m": 1},
    "kg": {"kg": 1},
    "s": {"s": 1},
    "rad": {"rad": 1},
    "J": {"kg": 1, "m": 2, "s": -2},
    "N": {"kg": 1, "m": 1, "s": -2},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "kg.m2": {"kg": 1, "m": 2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    # the controller FMU's gains, and its parameters in the scenario files' degrees
    "1/s": {"s": -1},
    "1/s2": {"s": -2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "deg": {"rad": 1, "factor": math.pi / 180.0},
}


def _identifier(model: Model) -> str:
    return getattr(model, "model_identifier", MODEL_IDENTIFIER)


def _sampled(model: Model) -> bool:
    """A sampled-data model (the controller): discrete outputs sampled on a fixed grid, no
    Model Exchange, no partial derivatives, no CasADi functions to read a structure from."""
    return not isinstance(model, FlatModel)


# Display units (Modelica's displayUnit): (unit, factor); value in display unit = factor * value.
_DISPLAY_UNITS: dict[str, tuple[str, float]] = {
    "deg": ("rad", 180.0 / math.pi),
    "rpm": ("rad/s", 30.0 / math.pi),
}


def _fmt(value: float) -> str:
    return repr(float(value))


def _units(model: Model) -> ET.Element:
    defs = ET.Element("UnitDefinitions")
    displays: dict[str, set[str]] = {}
    for v in model.variables:
        if v.display_unit:
            unit, _ = _DISPLAY_UNITS.get(v.display_unit, ("", 0.0))
            if unit != v.unit:
                raise ValueError(f"{v.name}: display unit {v.display_unit!r} is not defined for "
                                 f"unit {v.unit!r} in modeldesc.py")
            displays.setdefault(v.unit, set()).add(v.display_unit)
    for unit in sorted({v.unit for v in model.variables if v.unit} | {"s"}):
        if unit not in _BASE_UNITS:
            raise ValueError(f"unit {unit!r} has no base-unit definition in modeldesc.py")
        el = ET.SubElement(defs, "Unit", name=unit)
        ET.SubElement(el, "BaseUnit", {k: str(e) for k, e in _BASE_UNITS[unit].items()})
        for display in sorted(displays.get(unit, ())):
            ET.SubElement(el, "DisplayUnit", name=display,
                          factor=_fmt(_DISPLAY_UNITS[display][1]))
    return defs


@dataclass(frozen=True)
class Unknown:
    """One unknown of the model structure and the knowns it depends on (names, sorted by value
    reference), with the FMI ``dependenciesKind`` of each."""

    name: str
    dependencies: tuple[str, ...]
    kinds: tuple[str, ...]


@dataclass(frozen=True)
class ModelStructure:
    """Outputs and state derivatives (knowns: states and inputs) and the initial unknowns
    (knowns: inputs and parameters), in FMI order."""

    outputs: list[Unknown]
    derivatives: list[Unknown]
    initial_unknowns: list[Unknown]


def _kind(entry: ca.SX, varying: ca.SX, params: ca.SX, tunable: list[bool]) -> str:
    """FMI dependenciesKind of one Jacobian entry: how the known enters the unknown."""
    if entry.is_constant():
        return "constant"
    if ca.depends_on(entry, varying):
        return "dependent"
    uses = [tunable[k] for k in range(params.numel()) if ca.depends_on(entry, params[k])]
    return "tunable" if any(uses) else "fixed"


def model_structure(model: FlatModel) -> ModelStructure:
    """Dependencies of every output, state derivative and initial unknown, from the sparsity
    (and the entries) of CasADi's Jacobians of the generated functions.

    At communication points and in continuous-time mode, ``xdot = f(x, u, p)`` and
    ``y = g(x, u, p)`` are differentiated w.r.t. ``(x, u)``; in initialisation mode the state
    is ``x0(p)``, so ``f(x0(p), u, p)`` and ``g(x0(p), u, p)`` are differentiated w.r.t.
    ``(u, p)``.  FMI allows only ``constant`` and ``dependent`` for initial unknowns.
    """
    x = ca.SX.sym("x", model.ode.numel_in(0))
    u = ca.SX.sym("u", model.ode.numel_in(1))
    p = ca.SX.sym("p", model.ode.numel_in(2))
    vrs = model.value_references
    by_state = {v.state: v.name for v in model.outputs if v.state >= 0}
    tunable = [v.tunable for v in model.parameters]
    unknowns = [*model.derivatives, *model.outputs]

    def rows(fx: ca.SX, known: ca.SX, known_names: list[str], varying: ca.SX,
             initial: bool) -> dict[str, Unknown]:
        jac = ca.jacobian(fx, known)
        result = {}
        for r, var in enumerate(unknowns):
            deps = []
            for c in range(known.numel()):
                if jac.sparsity().has_nz(r, c):
                    kind = _kind(jac[r, c], varying, p, tunable)
                    deps.append((known_names[c], "dependent" if initial and kind != "constant"
                                 else kind))
            deps.sort(key=lambda d: vrs[d[0]])
            result[var.name] = Unknown(var.name, tuple(d[0] for d in deps),
                                       tuple(d[1] for d in deps))
        return result

    state_names = [by_state[i] for i in range(x.numel())]
    running = rows(ca.vertcat(model.ode(x, u, p), model.out(x, u, p)), ca.vertcat(x, u),
                   state_names + [v.name for v in model.inputs], ca.vertcat(x, u), False)
    x0 = model.init(p)
    initial = rows(ca.vertcat(model.ode(x0, u, p), model.out(x0, u, p)), ca.vertcat(u, p),
                   [v.name for v in model.inputs] + [v.name for v in model.parameters],
                   ca.vertcat(x, u), True)
    return ModelStructure(
        outputs=[running[v.name] for v in model.outputs],
        derivatives=[running[v.name] for v in model.derivatives],
        initial_unknowns=sorted((initial[v.name] for v in unknowns), key=lambda k: vrs[k.name]),
    )


def _causality(v: Variable, sampled: bool = False) -> tuple[str, str, str | None]:
    """(causality, variability, initial) of a variable."""
    if v.kind == "parameter":
        return "parameter", "tunable" if v.tunable else "fixed", "exact"
    if v.kind == "input":
        return "input", "continuous", None
    if v.kind == "derivative":
        return "local", "continuous", "calculated"
    return "output", "discrete" if sampled else "continuous", "calculated"


def _bounds(v: Variable) -> dict[str, str]:
    attrs = {}
    if v.unit:
        attrs["unit"] = v.unit
    if v.display_unit:
        attrs["displayUnit"] = v.display_unit
    if math.isfinite(v.min):
        attrs["min"] = _fmt(v.min)
    if math.isfinite(v.max):
        attrs["max"] = _fmt(v.max)
    if v.kind in ("parameter", "input"):
        attrs["start"] = _fmt(v.start)
    return attrs


def _log_categories() -> ET.Element:
    """The categories fmu/src/fmi_layer.c understands."""
    cats = ET.Element("LogCategories")
    for name, text in (("logStatusError", "Errors: always logged"),
                       ("logStatusWarning", "Warnings: always logged"),
                       ("logEvents", "Information, while debug logging is on"),
                       ("logAll", "Every category")):
        ET.SubElement(cats, "Category", name=name, description=text)
    return cats


def _experiment(model: Model) -> ET.Element:
    attrs = {"startTime": _fmt(model.start_time), "stopTime": _fmt(model.stop_time)}
    if isinstance(model, FlatModel):  # a sampled model has no solver to tune
        attrs["tolerance"] = _fmt(model.tolerance)
    return ET.Element("DefaultExperiment", attrs, stepSize=_fmt(model.step_size))


def _root(fmi_version: str, model: Model, token: str) -> ET.Element:
    key = "guid" if fmi_version == "2.0" else "instantiationToken"
    attrs = {
        "fmiVersion": fmi_version,
        "modelName": model.name,
        key: token,
        "description": model.description,
        "generationTool": f"wmr-cosim {__version__} "
                          f"({getattr(model, 'generated_by', 'pymoca, CasADi')})",
        "variableNamingConvention": "structured",
    }
    if fmi_version == "2.0":
        attrs["numberOfEventIndicators"] = "0"
    return ET.Element("fmiModelDescription", attrs)


def _to_bytes(root: ET.Element) -> bytes:
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def _dependency_attrs(unknown: Unknown, ref: dict[str, int]) -> dict[str, str]:
    if unknown.dependencies == _EVERY_KNOWN:
        return {}
    return {"dependencies": " ".join(str(ref[n]) for n in unknown.dependencies),
            "dependenciesKind": " ".join(unknown.kinds)}


def _structure(model: Model) -> ModelStructure:
    """:func:`model_structure`; for a sampled model every output and initial unknown without
    a ``dependencies`` list (the standard's "depends on every known": direct feedthrough)."""
    if isinstance(model, FlatModel):
        return model_structure(model)
    free = [Unknown(v.name, _EVERY_KNOWN, _EVERY_KNOWN) for v in model.outputs]
    return ModelStructure(outputs=free, derivatives=[], initial_unknowns=free)


#: ``Unknown.dependencies`` of an unknown that depends on every known: written without the
#: ``dependencies`` attribute, which is what its absence means in FMI.
_EVERY_KNOWN: tuple[str, ...] = ("*",)

#: ``fmi3DependencyKind`` number of each ``dependenciesKind``.
DEPENDENCY_KIND_NUMBERS: dict[str, int] = {"constant": 1, "fixed": 2, "tunable": 3,
                                           "discrete": 4, "dependent": 5}


@dataclass(frozen=True)
class DependencyRow:
    """The knowns of one unknown by value reference, as ``fmi3GetVariableDependencies``
    returns them: ``initial`` rows are the initial unknowns' (Instantiated and Initialization
    Mode), the others those at communication points and in continuous-time mode."""

    unknown: int
    initial: bool
    knowns: tuple[int, ...]
    kinds: tuple[str, ...]


def dependency_rows(model: Model) -> list[DependencyRow]:
    """The model structure of both model descriptions (:func:`_structure`) as the C tables of
    the FMI 3 dependency functions, so that the two cannot disagree.

    An unknown written without a ``dependencies`` attribute depends on every known: at
    communication points the continuous states and inputs, at initialisation the inputs and
    parameters (the knowns of :func:`model_structure`), each ``dependent``.
    """
    structure = _structure(model)
    vrs = model.value_references
    states = [v.name for v in sorted((v for v in model.outputs if v.state >= 0),
                                     key=lambda v: v.state)]
    every = {False: [*states, *(v.name for v in model.inputs)],
             True: [*(v.name for v in model.inputs), *(v.name for v in model.parameters)]}
    rows = []
    for initial, unknowns in ((False, [*structure.outputs, *structure.derivatives]),
                              (True, structure.initial_unknowns)):
        for unknown in unknowns:
            if unknown.dependencies == _EVERY_KNOWN:
                names = sorted(every[initial], key=lambda n: vrs[n])
                pairs = [(vrs[n], "dependent") for n in names]
            else:
                pairs = [(vrs[n], k) for n, k in zip(unknown.dependencies, unknown.kinds,
                                                      strict=True)]
            rows.append(DependencyRow(vrs[unknown.name], initial,
                                      tuple(p[0] for p in pairs), tuple(p[1] for p in pairs)))
    return rows


def fmi2_model_description(model: Model, token: str, sources: Sequence[str]) -> bytes:
    """``modelDescription.xml`` of the FMI 2.0 FMU: Model Exchange (if the model has continuous
    states) and Co-Simulation."""
    root = _root("2.0", model, token)
    sampled = _sampled(model)
    common = {"modelIdentifier": _identifier(model),
              "canNotUseMemoryManagementFunctions": "true",
              "canGetAndSetFMUstate": "true",
              "canSerializeFMUstate": "true",
              "providesDirectionalDerivative": "false" if sampled else "true"}
    interfaces = []
    if isinstance(model, FlatModel) and model.derivatives:
        interfaces.append(ET.SubElement(root, "ModelExchange", {
            **common, "completedIntegratorStepNotNeeded": "true"}))
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": _identifier(model),
        # a sampled-data model samples on its grid whatever the step (fmu/src/README.md)
        "canHandleVariableCommunicationStepSize": "true",
        "canInterpolateInputs": "false",
        "canRunAsynchronuously": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false",
        **common,
    })
    interfaces.append(cs)
    for element in interfaces:
        files = ET.SubElement(element, "SourceFiles")
        for name in sources:
            ET.SubElement(files, "File", name=name)
    root.append(_units(model))
    root.append(_log_categories())
    root.append(_experiment(model))
    mv = ET.SubElement(root, "ModelVariables")
    # No `time` variable: in FMI 2.0 the independent variable is optional ("if no variable is
    # defined as independent, it is implicitly present with name = time and unit = s"), and
    # FMI Library (libcosim's, fmi-library issue #21) logs an error for a declared one, whose
    # start the standard forbids.  Its value reference 0 stays reserved (the C table).
    vrs = model.value_references
    # ScalarVariable indices are 1-based positions in ModelVariables: the variables in
    # value-reference order from 1, so index = value reference.
    index = dict(vrs)
    state_of = {v.state: v.name for v in model.outputs if v.state >= 0}
    for v in model.variables:
        causality, variability, initial = _causality(v, _sampled(model))
        attrs = {"name": v.name, "valueReference": str(vrs[v.name]), "description": v.description,
                 "causality": causality, "variability": variability}
        if initial:
            attrs["initial"] = initial
        sv = ET.SubElement(mv, "ScalarVariable", attrs)
        real = _bounds(v)
        if v.kind == "derivative":
            real["derivative"] = str(index[state_of[v.index]])
        ET.SubElement(sv, "Real", real)
    structure = _structure(model)
    ms = ET.SubElement(root, "ModelStructure")
    for tag, unknowns in (("Outputs", structure.outputs), ("Derivatives", structure.derivatives),
                          ("InitialUnknowns", structure.initial_unknowns)):
        if unknowns:
            group = ET.SubElement(ms, tag)
            for unknown in unknowns:
                ET.SubElement(group, "Unknown", {"index": str(index[unknown.name]),
                                                 **_dependency_attrs(unknown, index)})
    return _to_bytes(root)


def fmi3_model_description(model: Model, token: str) -> bytes:
    """``modelDescription.xml`` of the FMI 3.0 FMU: Model Exchange (if the model has continuous
    states) and Co-Simulation."""
    root = _root("3.0", model, token)
    sampled = _sampled(model)
    derivatives = "false" if sampled else "true"
    common = {"modelIdentifier": _identifier(model),
              "canBeInstantiatedOnlyOncePerProcess": "false",
              "canGetAndSetFMUState": "true",
              "canSerializeFMUState": "true",
              "providesDirectionalDerivatives": derivatives,
              "providesAdjointDerivatives": derivatives}
    if isinstance(model, FlatModel) and model.derivatives:
        ET.SubElement(root, "ModelExchange", {**common, "needsCompletedIntegratorStep": "false"})
    cs = ET.SubElement(root, "CoSimulation", {
        **common,
        "canHandleVariableCommunicationStepSize": "true",
        "hasEventMode": "false",
        "providesIntermediateUpdate": "false",
        "canReturnEarlyAfterIntermediateUpdate": "false",
    })
    if sampled:
        cs.set("fixedInternalStepSize", _fmt(model.step_size))
    root.append(_units(model))
    root.append(_log_categories())
    root.append(_experiment(model))
    mv = ET.SubElement(root, "ModelVariables")
    ET.SubElement(mv, "Float64", name="time", valueReference="0", causality="independent",
                  variability="continuous", description="Simulation time", unit="s")
    vrs = model.value_references
    state_of = {v.state: v.name for v in model.outputs if v.state >= 0}
    for v in model.variables:
        causality, variability, initial = _causality(v, _sampled(model))
        attrs = {"name": v.name, "valueReference": str(vrs[v.name]), "description": v.description,
                 "causality": causality, "variability": variability}
        if initial:
            attrs["initial"] = initial
        attrs.update(_bounds(v))
        if v.kind == "derivative":
            attrs["derivative"] = str(vrs[state_of[v.index]])
        ET.SubElement(mv, "Float64", attrs)
    structure = _structure(model)
    ms = ET.SubElement(root, "ModelStructure")
    for tag, unknowns in (("Output", structure.outputs),
                          ("ContinuousStateDerivative", structure.derivatives),
                          ("InitialUnknown", structure.initial_unknowns)):
        for unknown in unknowns:
            ET.SubElement(ms, tag, {"valueReference": str(vrs[unknown.name]),
                                    **_dependency_attrs(unknown, vrs)})
    return _to_bytes(root)


def fmi3_build_description(sources: Sequence[str],
                           model_identifier: str = MODEL_IDENTIFIER) -> bytes:
    """``sources/buildDescription.xml`` of the FMI 3.0 FMU."""
    root = ET.Element("fmiBuildDescription", fmiVersion="3.0")
    cfg = ET.SubElement(root, "BuildConfiguration", modelIdentifier=model_identifier)
    fs = ET.SubElement(cfg, "SourceFileSet", language="C99")
    for name in sources:
        ET.SubElement(fs, "SourceFile", name=name)
    ET.SubElement(cfg, "Library", name="m", description="C maths library (libm)")
    return _to_bytes(root)


def token_from_digest(digest: str) -> str:
    """An FMI GUID/instantiation token ``{xxxxxxxx-...}`` derived from a content digest."""
    if not re.fullmatch(r"[0-9a-f]{32,}", digest):
        raise ValueError("digest must be lowercase hex, at least 32 digits")
    d = digest[:32]
    return "{" + f"{d[:8]}-{d[8:12]}-{d[12:16]}-{d[16:20]}-{d[20:32]}" + "}"
