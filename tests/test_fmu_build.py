"""The Modelica-to-FMU build: outputs, reuse, validation, model descriptions, sources."""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from wmr.adapters.fmi.archive import check_archive
from wmr.adapters.fmi.robot import FmuPlant
from wmr.build.fmus import BuildResult, build_fmus
from wmr.cli import main
from wmr.infra.errors import FmuError

INTERFACE = {  # the public interface (docs/formats.md)
    "tau_r": ("input", "N.m"), "tau_l": ("input", "N.m"),
    "x": ("output", "m"), "y": ("output", "m"), "theta": ("output", "rad"),
    "v": ("output", "m/s"), "omega": ("output", "rad/s"),
    "omega_r": ("output", "rad/s"), "omega_l": ("output", "rad/s"),
    "phi_r": ("output", "rad"), "phi_l": ("output", "rad"),
    "x_G": ("output", "m"), "y_G": ("output", "m"),
    "m": ("parameter", "kg"), "r": ("parameter", "m"), "L": ("parameter", "m"),
    "l": ("parameter", "m"), "Ig": ("parameter", "kg.m2"), "Iwm": ("parameter", "kg.m2"),
    "b_f": ("parameter", "N.m.s/rad"), "tau_c": ("parameter", "N.m"),
    "x0": ("parameter", "m"), "y0": ("parameter", "m"), "theta0": ("parameter", "rad"),
    "v0": ("parameter", "m/s"), "omega0": ("parameter", "rad/s"),
}
PAPER_DEFAULTS = {"m": 25.0, "r": 0.15, "L": 0.3, "l": 0.35, "Ig": 0.25, "Iwm": 0.01,
                  "b_f": 0.0, "tau_c": 0.0}


def test_both_fmus_pass_fmpy_validation(built: BuildResult) -> None:
    assert sorted(built.fmus) == [2, 3]
    for path in built.fmus.values():
        assert validate_fmu(str(path)) == []


def test_rebuild_is_skipped_when_nothing_changed(built: BuildResult, fmu_dir: Path) -> None:
    again = build_fmus(fmu_dir)
    assert again.reused
    assert again.digest == built.digest
    assert again.fmus == built.fmus
    assert again.controllers == built.controllers


def test_cli_prints_one_path_per_line(fmu_dir: Path, built: BuildResult,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fmu", "build", "--out", str(fmu_dir)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [Path(p) for p in lines] == [built.fmus[2], built.fmus[3], built.controllers[2],
                                        built.controllers[3]]


@pytest.mark.parametrize("version", [2, 3])
def test_model_description_has_the_public_interface(built: BuildResult, version: int) -> None:
    md = read_model_description(str(built.fmus[version]))
    assert md.fmiVersion == f"{version}.0"
    variables = {v.name: v for v in md.modelVariables}
    for name, (causality, unit) in INTERFACE.items():
        assert variables[name].causality == causality, name
        assert variables[name].unit == unit, name
    for name, value in PAPER_DEFAULTS.items():
        assert float(variables[name].start) == value, name
    units = {u.name for u in md.unitDefinitions}
    assert {v.unit for v in md.modelVariables if v.unit} <= units
    vrs = [v.valueReference for v in md.modelVariables]
    assert len(vrs) == len(set(vrs))
    assert md.defaultExperiment is not None and float(md.defaultExperiment.stepSize) == 0.01
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    assert {u.variable.name for u in md.outputs} == {n for n, (c, _) in INTERFACE.items()
                                             if c == "output"} | {"E_kin"}
    token = md.guid
    assert token.startswith("{") and token[1:9] == built.digest[:8]


def test_fmi2_and_fmi3_share_guid_and_value_references(built: BuildResult) -> None:
    md2 = read_model_description(str(built.fmus[2]))
    md3 = read_model_description(str(built.fmus[3]))
    assert md2.guid == md3.guid
    assert ({v.name: v.valueReference for v in md2.modelVariables}
            == {v.name: v.valueReference for v in md3.modelVariables})


@pytest.mark.parametrize("version", [2, 3])
def test_only_fmi_symbols_are_exported(built: BuildResult, version: int, tmp_path: Path) -> None:
    with zipfile.ZipFile(built.fmus[version]) as zf:
        so = next(n for n in zf.namelist() if n.endswith(".so"))
        (tmp_path / "lib.so").write_bytes(zf.read(so))
    out = subprocess.run(["nm", "-D", "--defined-only", str(tmp_path / "lib.so")],
                         capture_output=True, text=True, check=True).stdout
    names = [line.split()[-1] for line in out.splitlines() if line.strip()]
    assert names and all(n.startswith("fmi") for n in names if not n.startswith("_"))
    assert any(n.startswith(f"fmi{version}DoStep") for n in names)


@pytest.mark.parametrize("version", [2, 3])
def test_sources_in_the_fmu_compile_on_their_own(built: BuildResult, version: int,
                                                 tmp_path: Path) -> None:
    import fmpy

    with zipfile.ZipFile(built.fmus[version]) as zf:
        zf.extractall(tmp_path)
    src = tmp_path / "sources"
    if version == 2:
        root = ET.parse(tmp_path / "modelDescription.xml").getroot()
        names = [f.get("name") for f in root.iter("File")]
        # Model Exchange and Co-Simulation list the same sources
        assert names[: len(names) // 2] == names[len(names) // 2:]
        names = names[: len(names) // 2]
    else:
        root = ET.parse(src / "buildDescription.xml").getroot()
        names = [f.get("name") for f in root.iter("SourceFile")]
    headers = Path(fmpy.__file__).parent / "c-code"
    cmd = ["gcc", "-shared", "-fPIC", "-O1", f"-I{src}", f"-I{headers}",
           *(str(src / str(n)) for n in names), "-o", str(tmp_path / "rebuilt.so"), "-lm"]
    subprocess.run(cmd, check=True, capture_output=True)
    assert (tmp_path / "rebuilt.so").stat().st_size > 0


def _zip(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return path


def test_hostile_archives_are_refused(tmp_path: Path) -> None:
    with pytest.raises(FmuError, match="outside"):
        check_archive(_zip(tmp_path / "slip.fmu",
                           {"modelDescription.xml": b"<x/>", "../evil.so": b"x"}))
    with pytest.raises(FmuError, match="outside"):
        check_archive(_zip(tmp_path / "abs.fmu",
                           {"modelDescription.xml": b"<x/>", "/etc/evil": b"x"}))
    with pytest.raises(FmuError, match="no modelDescription"):
        check_archive(_zip(tmp_path / "empty.fmu", {"readme.txt": b"x"}))
    (tmp_path / "text.fmu").write_text("not a zip")
    with pytest.raises(FmuError, match="not a zip"):
        check_archive(tmp_path / "text.fmu")
    with pytest.raises(FmuError, match="no such FMU"):
        FmuPlant(tmp_path / "missing.fmu")
