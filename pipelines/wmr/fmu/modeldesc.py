"""Both model descriptions (FMI 2.0 and FMI 3.0) and the FMI 3 build description.

They are written from the one :class:`~wmr.fmu.flatten.FlatModel` that also writes the C
variable table, so value references, start values, bounds and units cannot drift apart.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from typing import TYPE_CHECKING

from wmr import __version__
from wmr.fmu.codegen import MODEL_IDENTIFIER
from wmr.fmu.flatten import FlatModel, Variable

if TYPE_CHECKING:
    from wmr.fmu.controller import ControllerModel

    Model = FlatModel | ControllerModel

# SI base-unit exponents of every unit the Modelica source uses (FMI 2.0 section 2.2.2).
_BASE_UNITS: dict[str, dict[str, float]] = {
    "m": {"m": 1},
    "kg": {"kg": 1},
    "s": {"s": 1},
    "rad": {"rad": 1},
    "J": {"kg": 1, "m": 2, "s": -2},
    "N": {"kg": 1, "m": 1, "s": -2},
    "m/s": {"m": 1, "s": -1},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "kg.m2": {"kg": 1, "m": 2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    # the controller FMU's gains and its parameters in the scenario files' degrees
    "1/s": {"s": -1},
    "1/s2": {"s": -2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "deg": {"rad": 1, "factor": math.pi / 180.0},
}


def _identifier(model: Model) -> str:
    return getattr(model, "model_identifier", MODEL_IDENTIFIER)


def _sampled(model: Model) -> bool:
    """A sampled-data model (the controller): discrete outputs, one fixed step size."""
    return getattr(model, "period_parameter", None) is not None


def _fmt(value: float) -> str:
    return repr(float(value))


def _units(model: Model) -> ET.Element:
    defs = ET.Element("UnitDefinitions")
    for unit in sorted({v.unit for v in model.variables if v.unit} | {"s"}):
        if unit not in _BASE_UNITS:
            raise ValueError(f"unit {unit!r} has no base-unit definition in modeldesc.py")
        el = ET.SubElement(defs, "Unit", name=unit)
        ET.SubElement(el, "BaseUnit", {k: str(e) for k, e in _BASE_UNITS[unit].items()})
    return defs


def _causality(v: Variable, sampled: bool = False) -> tuple[str, str, str | None]:
    """(causality, variability, initial) of a variable."""
    if v.kind == "parameter":
        return "parameter", "tunable" if v.tunable else "fixed", "exact"
    if v.kind == "input":
        return "input", "continuous", None
    return "output", "discrete" if sampled else "continuous", "calculated"


def _bounds(v: Variable) -> dict[str, str]:
    attrs = {}
    if v.unit:
        attrs["unit"] = v.unit
    if math.isfinite(v.min):
        attrs["min"] = _fmt(v.min)
    if math.isfinite(v.max):
        attrs["max"] = _fmt(v.max)
    if v.kind != "output":
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
    return ET.Element("DefaultExperiment", startTime=_fmt(model.start_time),
                      stopTime=_fmt(model.stop_time), stepSize=_fmt(model.step_size))


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


def fmi2_model_description(model: Model, token: str, sources: Sequence[str]) -> bytes:
    """``modelDescription.xml`` of the FMI 2.0 co-simulation FMU."""
    root = _root("2.0", model, token)
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": _identifier(model),
        "canHandleVariableCommunicationStepSize": "false" if _sampled(model) else "true",
        "canInterpolateInputs": "false",
        "canRunAsynchronuously": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false",
        "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "true",
        "canSerializeFMUstate": "true",
        "providesDirectionalDerivative": "false",
    })
    files = ET.SubElement(cs, "SourceFiles")
    for name in sources:
        ET.SubElement(files, "File", name=name)
    root.append(_units(model))
    root.append(_log_categories())
    root.append(_experiment(model))
    mv = ET.SubElement(root, "ModelVariables")
    sv = ET.SubElement(mv, "ScalarVariable", name="time", valueReference="0",
                       causality="independent", variability="continuous",
                       description="Simulation time")
    ET.SubElement(sv, "Real", unit="s")
    vrs = model.value_references
    for v in model.variables:
        causality, variability, initial = _causality(v, _sampled(model))
        attrs = {"name": v.name, "valueReference": str(vrs[v.name]), "description": v.description,
                 "causality": causality, "variability": variability}
        if initial:
            attrs["initial"] = initial
        sv = ET.SubElement(mv, "ScalarVariable", attrs)
        ET.SubElement(sv, "Real", _bounds(v))
    ms = ET.SubElement(root, "ModelStructure")
    outs = ET.SubElement(ms, "Outputs")
    init = ET.SubElement(ms, "InitialUnknowns")
    # ScalarVariable indices are 1-based positions in ModelVariables; time is index 1.
    for i, v in enumerate(model.variables, start=2):
        if v.kind == "output":
            ET.SubElement(outs, "Unknown", index=str(i))
            ET.SubElement(init, "Unknown", index=str(i))
    return _to_bytes(root)


def fmi3_model_description(model: Model, token: str) -> bytes:
    """``modelDescription.xml`` of the FMI 3.0 co-simulation FMU."""
    root = _root("3.0", model, token)
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": _identifier(model),
        "canHandleVariableCommunicationStepSize": "false" if _sampled(model) else "true",
        "canBeInstantiatedOnlyOncePerProcess": "false",
        "canGetAndSetFMUState": "true",
        "canSerializeFMUState": "true",
        "providesDirectionalDerivatives": "false",
        "providesAdjointDerivatives": "false",
        "hasEventMode": "false",
        "providesIntermediateUpdate": "false",
        "canReturnEarlyAfterIntermediateUpdate": "false",
    })
    if _sampled(model):
        cs.set("fixedInternalStepSize", _fmt(model.step_size))
    root.append(_units(model))
    root.append(_log_categories())
    root.append(_experiment(model))
    mv = ET.SubElement(root, "ModelVariables")
    ET.SubElement(mv, "Float64", name="time", valueReference="0", causality="independent",
                  variability="continuous", description="Simulation time", unit="s")
    vrs = model.value_references
    for v in model.variables:
        causality, variability, initial = _causality(v, _sampled(model))
        attrs = {"name": v.name, "valueReference": str(vrs[v.name]), "description": v.description,
                 "causality": causality, "variability": variability}
        if initial:
            attrs["initial"] = initial
        attrs.update(_bounds(v))
        ET.SubElement(mv, "Float64", attrs)
    ms = ET.SubElement(root, "ModelStructure")
    for tag in ("Output", "InitialUnknown"):
        for v in model.outputs:
            ET.SubElement(ms, tag, valueReference=str(vrs[v.name]))
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
