"""Read an SSP package back: its components, their FMUs and their parameter sets.

Used by ``wmr ssp run`` to check a package before a master loads it (a missing FMU is one
clear line, not a master's crash) and to fill the log's ``run`` record, and by the tests to
give fmpy's SSP simulator the package's own parameter sets (fmpy does not apply an SSD's
parameter bindings itself).
"""

from __future__ import annotations

import math
import tomllib
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from wmr.adapters.fmi.varmap import VariableMap, parse_map
from wmr.adapters.ssp.export import CONTROLLER, MAP_NAME, NS, ROBOT, SSD_NAME
from wmr.infra.errors import ConfigError, FmuError


@dataclass(frozen=True)
class SspComponent:
    """One component: its FMU's path inside the package, FMI version, parameter values."""

    name: str
    source: str
    fmi_version: str
    parameters: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class SspPackage:
    """What ``wmr ssp run`` needs to know of a package."""

    path: Path
    name: str
    components: dict[str, SspComponent]
    start_time_s: float
    stop_time_s: float | None
    step_size_s: float | None
    #: The robot's variable map (a robot FMU of another tool), or ``None``: our names.
    robot_map: VariableMap | None = None

    def component(self, name: str) -> SspComponent:
        if name not in self.components:
            raise FmuError(f"{self.path}: has no component named {name!r} (it has "
                           f"{', '.join(self.components) or 'none'}); give a package made by "
                           "'wmr ssp export'")
        return self.components[name]


def _float(text: str | None, where: str) -> float:
    try:
        value = float(text) if text is not None else math.nan
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise FmuError(f"{where}: {text!r} is not a finite number")
    return value


def _parameter_set(zf: zipfile.ZipFile, source: str, where: str) -> dict[str, float]:
    try:
        root = ET.fromstring(zf.read(source))
    except KeyError:
        raise FmuError(f"{where}: parameter set {source} is missing from the package") from None
    values: dict[str, float] = {}
    for p in root.iterfind("ssv:Parameters/ssv:Parameter", NS):
        real = p.find("ssv:Real", NS)
        if real is not None:
            name = p.get("name", "")
            values[name] = _float(real.get("value"), f"{where}: {source} {name}")
    return values


def _fmi_version(zf: zipfile.ZipFile, source: str, where: str) -> str:
    import io

    try:
        data = zf.read(source)
    except KeyError:
        raise FmuError(f"{where}: its FMU {source} is missing from the package (export it "
                       "again with 'wmr ssp export')") from None
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as fmu:
            md = ET.fromstring(fmu.read("modelDescription.xml"))
    except (zipfile.BadZipFile, KeyError, ET.ParseError) as exc:
        raise FmuError(f"{where}: {source} is not an FMU ({exc})") from None
    return md.get("fmiVersion", "")


def read_package(path: str | Path) -> SspPackage:
    """Open and check an SSP package: every component's FMU and parameter set present.

    Raises
    ------
    ConfigError
        The file does not exist or is not an SSP package.
    FmuError
        A component's FMU or parameter set is missing or unreadable.
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError("SSP", f"no such file: {p}", "give a package made by 'wmr ssp export'")
    try:
        zf = zipfile.ZipFile(p)
    except (zipfile.BadZipFile, OSError) as exc:
        raise ConfigError("SSP", f"{p} is not an SSP package (a zip): {exc}",
                          "give a package made by 'wmr ssp export'") from None
    with zf:
        try:
            root = ET.fromstring(zf.read(SSD_NAME))
        except KeyError:
            raise ConfigError("SSP", f"{p} has no {SSD_NAME}",
                              "give a package made by 'wmr ssp export'") from None
        except ET.ParseError as exc:
            raise ConfigError("SSP", f"{p}: {SSD_NAME} is not XML: {exc}", "export it again") \
                from None
        components: dict[str, SspComponent] = {}
        for comp in root.iterfind("ssd:System/ssd:Elements/ssd:Component", NS):
            name, source = comp.get("name", ""), comp.get("source", "")
            where = f"{p}: component {name}"
            params: dict[str, float] = {}
            for b in comp.iterfind("ssd:ParameterBindings/ssd:ParameterBinding", NS):
                if b.get("source"):
                    params.update(_parameter_set(zf, str(b.get("source")), where))
            components[name] = SspComponent(name, source, _fmi_version(zf, source, where),
                                            params)
        robot_map = None
        if MAP_NAME in zf.namelist():
            try:
                robot_map = parse_map(tomllib.loads(zf.read(MAP_NAME).decode()),
                                      source=f"{p}: {MAP_NAME}")
            except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
                raise FmuError(f"{p}: {MAP_NAME} is not a map file: {exc}") from None
    experiment = root.find("ssd:DefaultExperiment", NS)
    start = stop = step = None
    if experiment is not None:
        start = experiment.get("startTime")
        stop = experiment.get("stopTime")
        fixed = experiment.find(".//osp:FixedStepAlgorithm", NS)
        step = fixed.get("baseStepSize") if fixed is not None else None
    return SspPackage(
        path=p, name=root.get("name", p.stem), components=components,
        start_time_s=_float(start, f"{p}: startTime") if start is not None else 0.0,
        stop_time_s=_float(stop, f"{p}: stopTime") if stop is not None else None,
        step_size_s=_float(step, f"{p}: baseStepSize") if step is not None else None,
        robot_map=robot_map)


def fmpy_parameter_set(package: SspPackage) -> Any:
    """The package's parameter sets as one :class:`fmpy.ssp.ssd.ParameterSet` for
    :func:`fmpy.ssp.simulation.simulate_ssp`, whose names are ``component.variable``."""
    from fmpy.ssp.ssd import Parameter, ParameterSet

    pset = ParameterSet(name=package.name)
    for comp in package.components.values():
        for name, value in comp.parameters.items():
            pset.parameters.append(Parameter(name=f"{comp.name}.{name}", type="Real",
                                             value=value))
    return pset


__all__ = ["CONTROLLER", "ROBOT", "SspComponent", "SspPackage", "fmpy_parameter_set",
           "read_package"]
