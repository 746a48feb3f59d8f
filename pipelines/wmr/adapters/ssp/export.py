"""``wmr ssp export``: one closed-loop run as an SSP 1.0 package.

The package (a zip, ``FILE.ssp``) holds::

    SystemStructure.ssd            the system: two components, their connectors, the
                                   connections, the default experiment
    resources/wmr_robot-fmiN.fmu   the robot (inputs tau_r, tau_l; outputs x, y, theta, ...)
    resources/wmr_controller-fmiN.fmu
                                   the paper's stabiliser, sampled at control_period_s
    resources/robot.ssv            the robot's parameters: params.* and the start pose
                                   (x0, y0, theta0, v0, omega0)
    resources/controller.ssv       the controller's: goal, gains, limits, params.r/L/...,
                                   control_period_s, stop_radius_m, heading_tolerance_deg
    resources/SCENARIO.toml        provenance: the scenario file of the scenario's own run, or
                                   the run's effective scenario (NAME.toml, one run: a
                                   variant's start, goal and name), which 'wmr run' repeats
    resources/fmu_map.toml         the robot's variable map, for a robot FMU of another tool
                                   (its unit conversions are also on the connections)

Connections: every robot output the controller has an input of the same name for (the
measured pose, speeds and wheel speeds), and the controller's ``tau_r``, ``tau_l`` to the
robot's.  The parameter sets are bound to their component (``ParameterBinding source=``),
named with the FMU's own variable names, because libcosim ignores a binding's ``prefix``.
The default experiment runs ``[0, max_time_s]``; an OSP annotation gives libcosim its fixed
step, and OpenModelica's gives OMSimulator the same: ``control_period_s`` divided by
:data:`DEFAULT_STEPS_PER_PERIOD` unless the export asks for another divisor.  Why a divisor:
the masters are Jacobi, so at step ``h`` the robot holds over each master step the torque
computed on the measurement of one master step before; at ``h = control_period_s`` that lag
is a whole period (14.6 mm and 0.82 deg off ``wmr run``'s path on a run that begins with a
turn), at a divisor the controller's sample takes its measurement on time and only the first
master step of each period holds the late torque (docs/ssp.md, "Measured agreement").
"""

from __future__ import annotations

import io
import math
import os
import re
import struct
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

from wmr.adapters.fmi.archive import check_archive
from wmr.adapters.fmi.controller import controller_parameters
from wmr.adapters.fmi.varmap import INPUT_NAMES, ResolvedMap, VariableMap, resolve
from wmr.config.scenario_file import run_spec_toml
from wmr.core.plant import OUTPUT_NAMES
from wmr.core.runspec import RunSpec
from wmr.infra.durable import replacing
from wmr.infra.errors import ConfigError, FmuError
from wmr.infra.paths import safe_filename

ROBOT: Final = "robot"
CONTROLLER: Final = "controller"
SSD_NAME: Final = "SystemStructure.ssd"
#: The robot's variable map in a package of a robot FMU made by another tool.
MAP_NAME: Final = "resources/fmu_map.toml"

NS: Final = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
    # the URI OMSimulator's own SSP export declares for its annotations
    "oms": "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd",
}
#: Master steps per control period in a package: the fixed step the SSD's annotations give the
#: masters is ``control_period_s / DEFAULT_STEPS_PER_PERIOD``.  The smallest divisor whose
#: default run of every case measured (``benchmarks/ssp_agreement.py --steps``) is within
#: the agreement docs/ssp.md claims in libcosim and Ecos (the lagging masters).
DEFAULT_STEPS_PER_PERIOD: Final = 4
#: The most master steps per control period ``wmr ssp export`` writes.
MAX_STEPS_PER_PERIOD: Final = 100

#: OMSimulator's fixed-step master of a weakly coupled system (its solver ``oms_solver_wc_ma``).
OMS_FIXED_STEP_MASTER: Final = "oms-ma"
#: The relative tolerance given to OMSimulator for a robot FMU that declares none: its own
#: default (``OMSimulator --help``: ``--tolerance`` 1e-4).
OMS_DEFAULT_TOLERANCE: Final = 1e-4
for _prefix, _uri in NS.items():
    # libcosim and OMSimulator read the SSD with literal "ssd:", "ssc:", "ssv:", "osp:" and
    # "oms:" prefixes
    ET.register_namespace(_prefix, _uri)


def _q(tag: str) -> str:
    prefix, local = tag.split(":")
    return f"{{{NS[prefix]}}}{local}"


def _num(value: float) -> str:
    """Shortest text that reads back as the same double (the XSD's xs:double)."""
    return repr(float(value))


def robot_parameters(spec: RunSpec) -> dict[str, float]:
    """The robot FMU's parameter values of a run: ``params.*`` and the start pose (rad)."""
    values = spec.params.as_dict()
    values.update(x0=spec.start.x_m, y0=spec.start.y_m, theta0=spec.start.heading_rad,
                  v0=0.0, omega0=0.0)
    return values


def _model_description(fmu: Path) -> Any:
    from fmpy import read_model_description

    if not fmu.exists():  # a FIFO or a device is refused by the archive door, in its words
        raise FmuError(f"{fmu}: no such FMU (run 'wmr fmu build' or give an existing file)")
    check_archive(fmu)  # the package carries it to other masters: the door of 'wmr run --fmu'
    try:
        md = read_model_description(str(fmu))
    except Exception as exc:
        raise FmuError(f"{fmu}: unreadable model description: {exc}") from exc
    if md.coSimulation is None:
        raise FmuError(f"{fmu}: not a co-simulation FMU")
    return md


#: The member of an FMU of ours whose start values replace its compiled-in ones at
#: instantiation (``fmu/src/fmi_layer.c``, ``read_start_values``).
START_VALUES: Final = "resources/start_values.txt"


def _with_start_values(fmu: Path, values: Mapping[str, float]) -> bytes | None:
    """The FMU ``fmu`` (already through the archive door) whose defaults are ``values``: its
    model description's ``start`` of each of those parameters, and :data:`START_VALUES`, which
    its C reads when it is instantiated.  ``None`` for an FMU whose C does not read that file
    (its shipped ``sources/fmi_layer.c`` does not name it: another tool's, or an older
    build): its parameters reach it only through a master that applies the parameter sets.

    Why: a master that does not apply an SSD's parameter bindings (fmpy's ``simulate_ssp``,
    Ecos given no parameter set name) ran the FMUs' own defaults, another run (issue 32).
    """
    with zipfile.ZipFile(fmu) as zf:
        names = zf.namelist()
        if "sources/fmi_layer.c" not in names or \
                Path(START_VALUES).name.encode() not in zf.read("sources/fmi_layer.c"):
            return None
        md = zf.read("modelDescription.xml").decode()
        for name, value in values.items():
            # FMI 2: <ScalarVariable name=N ...><Real ... start=S; FMI 3: <Float64 name=N start=S
            pattern = (rf'(<(?:ScalarVariable|Float64) name="{re.escape(name)}"'
                       r'[^>]*?(?:>\s*<Real[^>]*?)?\bstart=")[^"]*(")')
            md, count = re.subn(pattern, rf"\g<1>{float(value)!r}\g<2>", md, count=1)
            if count != 1:
                raise FmuError(f"{fmu}: its model description has no start value of the "
                               f"parameter {name}")
        # the bits, exact and read without strtod (whose radix is the master's locale's)
        text = "".join(f"{name} = 0x{struct.unpack('<Q', struct.pack('<d', value))[0]:016x}"
                       f"  # {float(value)!r}\n" for name, value in values.items())
        members = {n: zf.read(n) for n in names if n != START_VALUES}
    members["modelDescription.xml"] = md.encode()
    members[START_VALUES] = ("# the package's run (wmr ssp export): the parameters a master "
                             "that sets none runs\n" + text).encode()
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for name, data in members.items():
            dst.writestr(zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0)), data,
                         compress_type=zipfile.ZIP_DEFLATED)
    return out.getvalue()


def _float_variables(md: Any, causality: str) -> list[Any]:
    return [v for v in md.modelVariables
            if v.causality == causality and v.type in ("Real", "Float64")]


def _bound(md: Any, values: Mapping[str, float], fmu: Path) -> dict[str, float]:
    """``values`` restricted to the FMU's parameters; every parameter must have a value."""
    params = [v.name for v in _float_variables(md, "parameter")]
    missing = [n for n in params if n not in values]
    if missing:
        raise FmuError(f"{fmu.name}: parameter {missing[0]} has no value in the scenario "
                       f"(the FMU is of another version than wmr: rebuild it with "
                       "'wmr fmu build --force')")
    return {n: values[n] for n in params}


def _connectors(parent: ET.Element, md: Any) -> None:
    connectors = ET.SubElement(parent, _q("ssd:Connectors"))
    for causality in ("input", "output", "parameter"):
        for v in _float_variables(md, causality):
            c = ET.SubElement(connectors, _q("ssd:Connector"), name=v.name, kind=causality)
            ET.SubElement(c, _q("ssc:Real"))


def _component(elements: ET.Element, name: str, source: str, md: Any, ssv: str) -> None:
    comp = ET.SubElement(elements, _q("ssd:Component"), name=name,
                         type="application/x-fmu-sharedlibrary", source=source,
                         implementation="CoSimulation")
    _connectors(comp, md)
    bindings = ET.SubElement(comp, _q("ssd:ParameterBindings"))
    ET.SubElement(bindings, _q("ssd:ParameterBinding"), source=ssv)


def parameter_set_xml(name: str, values: Mapping[str, float]) -> bytes:
    """An SSV file: one ``ssv:Real`` per value."""
    root = ET.Element(_q("ssv:ParameterSet"), version="1.0", name=name)
    params = ET.SubElement(root, _q("ssv:Parameters"))
    for pname, value in values.items():
        p = ET.SubElement(params, _q("ssv:Parameter"), name=pname)
        ET.SubElement(p, _q("ssv:Real"), value=_num(value))
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


#: A connection: start element and connector, end element and connector, and the linear
#: transformation ``end = factor * start + offset`` (SSP's ``ssc:LinearTransformation``).
Link = tuple[str, str, str, str, float, float]


def closed_loop_links(ctrl_md: Any, robot_map: ResolvedMap) -> list[Link]:
    """The connections: each controller input from the robot output that ``robot_map`` gives
    for it (our names: the measured pose and speeds), and the controller's torques to the
    robot's inputs, each with the map's unit conversion."""
    links: list[Link] = []
    for v in _float_variables(ctrl_md, "input"):
        if v.name not in OUTPUT_NAMES:
            raise FmuError(f"controller input {v.name} is none of the robot's outputs "
                           f"({', '.join(OUTPUT_NAMES)})")
        found = robot_map.outputs[OUTPUT_NAMES.index(v.name)]
        if found is None:
            raise FmuError(f"controller input {v.name} has no robot output: the map leaves "
                           "it unmapped")
        entry = found[1]
        links.append((ROBOT, entry.name, CONTROLLER, v.name, entry.scale, entry.offset))
    ctrl_out = {v.name for v in _float_variables(ctrl_md, "output")}
    for ours, (_, entry) in zip(INPUT_NAMES, robot_map.inputs, strict=True):
        if ours not in ctrl_out:
            raise FmuError(f"the controller FMU has no output {ours} for the robot's input")
        links.append((CONTROLLER, ours, ROBOT, entry.name, 1.0 / entry.scale,
                      -entry.offset / entry.scale))
    return links


def system_structure_xml(spec: RunSpec, robot: tuple[str, Any], controller: tuple[str, Any],
                         ssv: Mapping[str, str], links: list[Link],
                         steps_per_period: int = DEFAULT_STEPS_PER_PERIOD) -> bytes:
    """The SSD of the closed loop: ``robot`` and ``controller`` are ``(source, model
    description)``; ``ssv`` names each component's parameter set file; the masters' fixed
    step is ``spec.period_s / steps_per_period``."""
    step_s = master_step_s(spec.period_s, steps_per_period)
    robot_md, ctrl_md = robot[1], controller[1]
    root = ET.Element(_q("ssd:SystemStructureDescription"), version="1.0", name=spec.name)
    system = ET.SubElement(root, _q("ssd:System"), name="closed_loop",
                           description="the paper's PI stabiliser on the robot (wmr-cosim)")
    elements = ET.SubElement(system, _q("ssd:Elements"))
    _component(elements, ROBOT, robot[0], robot_md, ssv[ROBOT])
    _component(elements, CONTROLLER, controller[0], ctrl_md, ssv[CONTROLLER])
    connections = ET.SubElement(system, _q("ssd:Connections"))
    for start_el, start, end_el, end, factor, offset in links:
        c = ET.SubElement(connections, _q("ssd:Connection"), startElement=start_el,
                          startConnector=start, endElement=end_el, endConnector=end)
        if factor != 1.0 or offset != 0.0:
            ET.SubElement(c, _q("ssc:LinearTransformation"), factor=_num(factor),
                          offset=_num(offset))
    # OMSimulator takes the system's type from its vendor annotation alone: without it the
    # system is oms_system_none and oms_importFile fails ("[NewSystem] internal error"); a
    # fixed-step master makes it a weakly coupled system of co-simulation FMUs, stepped at
    # the package's master step as the OSP annotation below steps libcosim
    oms = ET.SubElement(ET.SubElement(system, _q("ssd:Annotations")), _q("ssc:Annotation"),
                        type="org.openmodelica")
    info = ET.SubElement(ET.SubElement(oms, _q("oms:Annotations")),
                         _q("oms:SimulationInformation"))
    # ... and its relativeTolerance is passed to every FMI 2.0 FMU as a defined tolerance
    # (fmi2SetupExperiment(toleranceDefined = true), ComponentFMUCS::instantiate): without it
    # 0, which our robot FMU refuses; the robot FMU's own default keeps its solver as wmr run
    # (which defines no tolerance) has it
    ET.SubElement(info, _q("oms:FixedStepMaster"), description=OMS_FIXED_STEP_MASTER,
                  stepSize=_num(step_s),
                  relativeTolerance=_num(_default_tolerance(robot_md)))
    experiment = ET.SubElement(root, _q("ssd:DefaultExperiment"), startTime="0.0",
                               stopTime=_num(spec.t_max_s))
    annotations = ET.SubElement(experiment, _q("ssd:Annotations"))
    osp = ET.SubElement(annotations, _q("ssc:Annotation"), type="com.opensimulationplatform")
    algorithm = ET.SubElement(osp, _q("osp:Algorithm"))
    ET.SubElement(algorithm, _q("osp:FixedStepAlgorithm"), baseStepSize=_num(step_s))
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


def _default_tolerance(md: Any) -> float:
    """The FMU's own relative tolerance (its ``DefaultExperiment``'s; ours: the solver's
    1e-9), else :data:`OMS_DEFAULT_TOLERANCE`."""
    experiment = getattr(md, "defaultExperiment", None)
    tolerance = getattr(experiment, "tolerance", None)
    try:
        value = float(tolerance) if tolerance is not None else math.nan
    except ValueError:
        value = math.nan
    return value if math.isfinite(value) and value > 0 else OMS_DEFAULT_TOLERANCE


def master_step_s(period_s: float, steps_per_period: int) -> float:
    """The masters' fixed step of a package, s: ``period_s / steps_per_period``.

    Raises
    ------
    ConfigError
        ``steps_per_period`` is not a whole number from 1 to :data:`MAX_STEPS_PER_PERIOD`.
    """
    if isinstance(steps_per_period, bool) or not isinstance(steps_per_period, int) or \
            not 1 <= steps_per_period <= MAX_STEPS_PER_PERIOD:
        raise ConfigError("steps_per_period", f"must be a whole number from 1 to "
                          f"{MAX_STEPS_PER_PERIOD}, got {steps_per_period!r}",
                          f"give e.g. steps_per_period={DEFAULT_STEPS_PER_PERIOD}")
    return period_s / steps_per_period


def export_ssp(spec: RunSpec, out: str | os.PathLike[str], robot_fmu: str | os.PathLike[str],
               controller_fmu: str | os.PathLike[str], *,
               scenario_file: Path | None = None, var_map: VariableMap | None = None,
               steps_per_period: int = DEFAULT_STEPS_PER_PERIOD) -> Path:
    """Write the SSP package of run ``spec`` to ``out``; return its path.

    ``scenario_file`` is the provenance of a scenario's own run, unchanged; without it the
    package carries the run's effective scenario (``resources/NAME.toml``, ``NAME`` the run's
    name): give it only when ``spec`` is the file's run as it is, never for a variant.

    ``var_map`` maps our names to those of a robot FMU made by another tool
    (:mod:`wmr.adapters.fmi.varmap`): the connections then carry its unit conversions as SSP linear
    transformations, and its parameter set holds the mapped parameters in its units (the
    others keep the FMU's values).

    ``steps_per_period``: the masters' fixed step (the SSD's OSP and OpenModelica annotations)
    is ``spec.period_s / steps_per_period``; the controller samples at ``spec.period_s``
    whatever the step.

    The file is written beside ``out`` and renamed into place, so an interrupted export
    never leaves a half-written package.

    Raises
    ------
    ConfigError
        ``out`` does not end in ``.ssp``, the run uses a controller the FMU does not have, or
        ``steps_per_period`` is not a whole number from 1 to :data:`MAX_STEPS_PER_PERIOD`.
    FmuError
        An FMU is missing, unreadable, or does not fit the other.
    """
    master_step_s(spec.period_s, steps_per_period)  # refused before any work
    target = Path(out)
    if target.suffix != ".ssp":
        raise ConfigError("out", f"{target} does not end in .ssp", "give FILE.ssp")
    if spec.controller != "pi":
        raise ConfigError("controller", f"the controller FMU is the paper's PI stabiliser, "
                          f"not {spec.controller!r}", 'export a scenario with controller = "pi"')
    if spec.sensors is not None:
        raise ConfigError("sensors", "the package connects the robot's outputs to the "
                          "controller directly (perfect measurements): it has no sensor models",
                          "export the run without sensors (--sensors off or no [sensors])")
    robot_path, ctrl_path = Path(robot_fmu), Path(controller_fmu)
    robot_md, ctrl_md = _model_description(robot_path), _model_description(ctrl_path)
    if robot_md.fmiVersion != ctrl_md.fmiVersion:
        raise FmuError(f"{robot_path.name} is FMI {robot_md.fmiVersion} but "
                       f"{ctrl_path.name} is FMI {ctrl_md.fmiVersion}: give one version")
    robot_map = resolve(var_map, robot_md, robot_path.name)
    if var_map is None:
        robot_values = _bound(robot_md, robot_parameters(spec), robot_path)
    else:
        ours = robot_parameters(spec)
        robot_values = {e.name: e.to_theirs(ours[n]) for n, (_, e) in
                        robot_map.parameters.items()}
    robot_src = f"resources/{robot_path.name}"
    ctrl_src = f"resources/{ctrl_path.name}"
    ssv = {ROBOT: "resources/robot.ssv", CONTROLLER: "resources/controller.ssv"}
    links = closed_loop_links(ctrl_md, robot_map)
    ctrl_values = _bound(ctrl_md, controller_parameters(spec), ctrl_path)
    members: dict[str, bytes] = {
        SSD_NAME: system_structure_xml(spec, (robot_src, robot_md), (ctrl_src, ctrl_md), ssv,
                                       links, steps_per_period),
        ssv[ROBOT]: parameter_set_xml(spec.name, robot_values),
        ssv[CONTROLLER]: parameter_set_xml(spec.name, ctrl_values),
    }
    if var_map is not None:
        members[MAP_NAME] = var_map.to_toml().encode()
    files: dict[str, Path] = {}
    fmus: dict[str, bytes] = {}
    for src, path, values in ((robot_src, robot_path, robot_values),
                              (ctrl_src, ctrl_path, ctrl_values)):
        data = _with_start_values(path, values)
        if data is None:
            files[src] = path
        else:
            fmus[src] = data
    if scenario_file is not None:
        files[f"resources/{scenario_file.name}"] = scenario_file
    else:  # the run itself, which 'wmr run' reads back into the same run
        members[f"resources/{safe_filename(spec.name)}.toml"] = run_spec_toml(spec).encode()
    target.parent.mkdir(parents=True, exist_ok=True)
    # a new file beside the target, renamed into place (mode 0666 less the umask)
    with replacing(target) as raw, zipfile.ZipFile(raw, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
        for name, data in fmus.items():  # zips already: stored, not deflated again
            zf.writestr(name, data, compress_type=zipfile.ZIP_STORED)
        for name, path in files.items():
            # the FMUs are zips already: stored, not deflated again
            zf.write(path, name, compress_type=zipfile.ZIP_STORED
                     if path.suffix == ".fmu" else zipfile.ZIP_DEFLATED)
    return target


__all__ = ["CONTROLLER", "DEFAULT_STEPS_PER_PERIOD", "MAX_STEPS_PER_PERIOD", "ROBOT",
           "controller_parameters", "export_ssp", "master_step_s", "robot_parameters"]
