"""Read an SSP package back: its components, their FMUs and their parameter sets.

Used by ``wmr ssp run`` to check a package before a master loads it (a missing FMU is one
clear line, not a master's crash) and to fill the log's ``run`` record, and by the tests to
give fmpy's SSP simulator the package's own parameter sets (fmpy does not apply an SSD's
parameter bindings itself).

A package is a stranger's archive.  :func:`unpacked_package` extracts it through the one
archive door (:func:`wmr.adapters.fmi.archive.open_archive`: every member checked, sizes
counted while inflating) into a private temporary folder, checks every component's FMU through
the same door (sharing one budget with the package) and writes it again as a plain archive of
the members it checked, so that a master given that folder (libcosim) never reads a byte of
the stranger's zip files with its own zip reader.  The SSD and SSVs are read with
:func:`~wmr.adapters.fmi.archive.parse_xml` (bounded size and depth, no DTD, no entities).
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import tomllib
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any, Final

from wmr.adapters.fmi.archive import (
    MAX_XML_BYTES,
    Budget,
    CheckedArchive,
    XmlGuard,
    open_archive,
    parse_xml,
)
from wmr.adapters.fmi.varmap import VariableMap, parse_map
from wmr.adapters.ssp.export import CONTROLLER, MAP_NAME, NS, ROBOT, SSD_NAME
from wmr.infra.errors import ConfigError, FmuError

#: Components a package may have: ``wmr ssp run`` runs the closed loop (robot and controller);
#: a master loads every component's FMU, so thousands would take minutes and gigabytes.
MAX_COMPONENTS: Final = 64
#: The documents kept in memory for the log's attachments (SSD, SSVs, TOML files), in all.
MAX_ATTACHMENT_BYTES: Final = 64 * (1 << 20)
_ATTACHED: Final = {".ssd": "application/xml", ".ssv": "application/xml",
                    ".toml": "application/toml"}


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
    #: SHA-256 of the package file, read once when it was opened.
    sha256: str = ""
    #: The package's SSD, SSV and TOML members (name -> (media type, bytes)) for the log.
    attachments: dict[str, tuple[str, bytes]] = field(default_factory=dict)

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


def _member(folder: Path, source: str, where: str, what: str) -> Path:
    """The extracted file of member ``source`` (a relative URI in the package), or a line
    saying it is missing; a source outside the package is refused."""
    pure = PurePosixPath(source)
    if not source or pure.is_absolute() or ".." in pure.parts or ":" in source \
            or "\\" in source:
        raise FmuError(f"{where}: its {what} {source!r} is not a path inside the package: "
                       "refused")
    path = folder / pure
    if not path.is_file():
        raise FmuError(f"{where}: its {what} {source} is missing from the package (export it "
                       "again with 'wmr ssp export')")
    return path


def _read_small(path: Path, where: str) -> bytes:
    """A document we parse ourselves, at most :data:`MAX_XML_BYTES`."""
    size = path.stat().st_size
    if size > MAX_XML_BYTES:
        raise FmuError(f"{where}: {size} bytes, more than {MAX_XML_BYTES}: refused")
    return path.read_bytes()


def _parameter_set(folder: Path, source: str, where: str) -> dict[str, float]:
    path = _member(folder, source, where, "parameter set")
    root = parse_xml(_read_small(path, f"{where}: {source}"), f"{where}: {source}")
    values: dict[str, float] = {}
    for p in root.iterfind("ssv:Parameters/ssv:Parameter", NS):
        real = p.find("ssv:Real", NS)
        if real is not None:
            name = p.get("name", "")
            values[name] = _float(real.get("value"), f"{where}: {source} {name}")
    return values


def _rewrite(archive: CheckedArchive, target: Path) -> str:
    """Write the checked members of ``archive`` as a new, plain archive at ``target`` (stored:
    the master only unpacks it); return the FMI version of its model description."""
    if "modelDescription.xml" not in archive.members:
        raise FmuError(f"{archive.where}: not an FMU (no modelDescription.xml at the top level)")
    archive.check()  # every member inflated and counted first: a bomb never reaches the disk
    md = XmlGuard(f"{archive.where}: modelDescription.xml")
    fd, tmp = tempfile.mkstemp(prefix=".", suffix=".fmu", dir=target.parent)
    with os.fdopen(fd, "wb") as raw, zipfile.ZipFile(raw, "w", zipfile.ZIP_STORED,
                                                     allowZip64=True) as out:
        for folder in sorted(archive.folders):
            out.writestr(zipfile.ZipInfo(folder + "/"), b"")
        for name in archive.members:
            guard = md if name == "modelDescription.xml" else None
            with out.open(zipfile.ZipInfo(name), "w", force_zip64=True) as stream:
                for chunk in archive.chunks(name, archive.members[name].file_size, guard,
                                            charge=False):
                    stream.write(chunk)
    os.replace(tmp, target)
    return md.root_attributes.get("fmiVersion", "")


def _fmi_version(folder: Path, source: str, where: str, budget: Budget) -> str:
    """Check the component's FMU through the archive door, rewrite it as the checked members,
    and return its FMI version."""
    path = _member(folder, source, where, "FMU")
    with open_archive(path, "FMU", budget, where=f"{where}: {source}") as archive:
        return _rewrite(archive, path)


def _read(p: Path, folder: Path, sha256: str, budget: Budget) -> SspPackage:
    """The package extracted in ``folder``."""
    ssd = folder / SSD_NAME
    if not ssd.is_file():
        raise ConfigError("SSP", f"{p} has no {SSD_NAME}",
                          "give a package made by 'wmr ssp export'")
    root = parse_xml(_read_small(ssd, f"{p}: {SSD_NAME}"), f"{p}: {SSD_NAME}")
    elements = root.findall("ssd:System/ssd:Elements/ssd:Component", NS)
    if len(elements) > MAX_COMPONENTS:
        raise FmuError(f"{p}: {len(elements)} components, more than {MAX_COMPONENTS}: refused "
                       "('wmr ssp run' runs the robot and controller of 'wmr ssp export')")
    components: dict[str, SspComponent] = {}
    versions: dict[str, str] = {}  # each FMU checked once, however many components use it
    for comp in elements:
        name, source = comp.get("name", ""), comp.get("source", "")
        where = f"{p}: component {name}"
        params: dict[str, float] = {}
        for b in comp.iterfind("ssd:ParameterBindings/ssd:ParameterBinding", NS):
            if b.get("source"):
                params.update(_parameter_set(folder, str(b.get("source")), where))
        if source not in versions:
            versions[source] = _fmi_version(folder, source, where, budget)
        components[name] = SspComponent(name, source, versions[source], params)
    robot_map = None
    if (folder / MAP_NAME).is_file():
        text = _read_small(folder / MAP_NAME, f"{p}: {MAP_NAME}")
        try:
            robot_map = parse_map(tomllib.loads(text.decode()), source=f"{p}: {MAP_NAME}")
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise FmuError(f"{p}: {MAP_NAME} is not a map file: {exc}") from None
    attachments: dict[str, tuple[str, bytes]] = {}
    total = 0
    for path in sorted(folder.rglob("*")):
        kind = _ATTACHED.get(path.suffix)
        if kind is None or not path.is_file():
            continue
        name = path.relative_to(folder).as_posix()
        data = _read_small(path, f"{p}: {name}")
        total += len(data)
        if total > MAX_ATTACHMENT_BYTES:
            raise FmuError(f"{p}: its SSD, SSV and TOML members hold more than "
                           f"{MAX_ATTACHMENT_BYTES} bytes: refused")
        # TOML files by their own name, as 'wmr run' attaches its scenario
        attachments[path.name if path.suffix == ".toml" else name] = (kind, data)
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
        robot_map=robot_map, sha256=sha256, attachments=attachments)


@contextmanager
def unpacked_package(path: str | os.PathLike[str]) -> Iterator[tuple[SspPackage, Path]]:
    """Extract and check an SSP package; yield it and the private folder that holds it
    (removed on exit), the only thing to give a master.

    Raises
    ------
    ConfigError
        The file does not exist, or has no SSD.
    FmuError
        The file is no zip archive, a member is refused (its path, kind, size, XML), or a
        component's FMU or parameter set is missing, refused or unreadable.
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError("SSP", f"no such file: {p}", "give a package made by 'wmr ssp export'")
    tmp = Path(tempfile.mkdtemp(prefix="wmr-ssp-"))  # 0700: nobody else writes in it
    try:
        folder = tmp / "package"
        folder.mkdir()
        budget = Budget()  # the package and every FMU in it, together
        with open_archive(p, "SSP package", budget) as archive:
            sha256 = archive.sha256()
            archive.extract(folder)
        yield _read(p, folder, sha256, budget), folder
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def read_package(path: str | Path) -> SspPackage:
    """Open and check an SSP package: every member, every component's FMU and parameter set
    (:func:`unpacked_package`, its folder removed at once).

    Raises
    ------
    ConfigError, FmuError
        As :func:`unpacked_package`.
    """
    with unpacked_package(path) as (package, _):
        return package


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


__all__ = ["CONTROLLER", "MAX_COMPONENTS", "ROBOT", "SspComponent", "SspPackage",
           "fmpy_parameter_set", "read_package", "unpacked_package"]
