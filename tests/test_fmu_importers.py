"""Importers we did not write: libcosim (FMI Library inside) runs the FMI 2 co-simulation FMU
and agrees with fmpy; the official XSD schemas (shipped with fmpy) accept both FMUs."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from wmr.adapters.fmi.archive import safe_extract
from wmr.build.fmus import BuildResult

N_STEPS, STEP_S = 100, 0.05


def _torques(k: int) -> list[float]:
    """A fixed, non-trivial torque sequence in N.m (the platform harness uses the same)."""
    return [((7 * k) % 11) / 10 - 0.5, ((5 * k) % 13) / 12 - 0.4]


def _fmpy_run(fmu: Path, tmp_path: Path) -> np.ndarray:
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    slave = FMU2Slave(guid=md.guid, unzipDirectory=str(safe_extract(fmu, tmp_path / "fmpy")),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="fmpy")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    rows = []
    for k in range(N_STEPS):
        slave.setReal([vr["tau_r"], vr["tau_l"]], _torques(k))
        slave.doStep(currentCommunicationPoint=k * STEP_S, communicationStepSize=STEP_S)
        rows.append(slave.getReal(outputs))
    slave.terminate()
    slave.freeInstance()
    return np.array(rows)


def test_libcosim_runs_the_fmi2_fmu_as_fmpy_does(built: BuildResult, tmp_path: Path) -> None:
    pytest.importorskip("libcosimpy", reason="libcosimpy is in the test extras: pip install "
                        "-e '.[test]'")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    fmu = built.fmus[2]
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    log_output_level(CosimLogLevel.WARNING)
    execution = CosimExecution.from_step_size(step_size=round(STEP_S * 1e9))  # nanoseconds
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name="robot"))
    override = CosimManipulator.create_override()
    execution.add_manipulator(manipulator=override)
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer=observer)
    rows = []
    for k in range(N_STEPS):
        # libcosim applies the override before the step, as fmpy's setReal before doStep.
        override.slave_real_values(index, [vr["tau_r"], vr["tau_l"]], _torques(k))
        assert execution.step()
        rows.append(observer.last_real_values(index, outputs))
    assert execution.status().current_time == round(N_STEPS * STEP_S * 1e9)
    cosim = np.array(rows)
    reference = _fmpy_run(fmu, tmp_path)
    assert np.ptp(reference, axis=0).min() > 1e-3  # the torques move every output
    difference = np.max(np.abs(cosim - reference) / np.maximum(1.0, np.abs(reference)))
    assert difference < 1e-12


_SCHEMA = {"modelDescription.xml": "fmi{v}ModelDescription.xsd",
           "sources/buildDescription.xml": "fmi{v}BuildDescription.xsd"}


@pytest.mark.parametrize("version", [2, 3])
def test_official_schemas_and_fmpy_validate_report_nothing(built: BuildResult,
                                                           version: int) -> None:
    import fmpy
    from lxml import etree

    fmu = built.fmus[version]
    assert validate_fmu(str(fmu)) == []
    schema_dir = Path(fmpy.__file__).parent / "schema" / f"fmi{version}"
    checked = 0
    with zipfile.ZipFile(fmu) as zf:
        for member, xsd in _SCHEMA.items():
            if member not in zf.namelist():
                continue
            schema = etree.XMLSchema(etree.parse(str(schema_dir / xsd.format(v=version))))
            document = etree.fromstring(zf.read(member))
            assert schema.validate(document), (member, list(schema.error_log))
            checked += 1
    assert checked == (1 if version == 2 else 2)


def test_the_schema_check_can_fail(built: BuildResult) -> None:
    """A model description with an attribute the standard does not know is rejected."""
    import fmpy
    from lxml import etree

    schema = etree.XMLSchema(etree.parse(
        str(Path(fmpy.__file__).parent / "schema" / "fmi3" / "fmi3ModelDescription.xsd")))
    with zipfile.ZipFile(built.fmus[3]) as zf:
        document = etree.fromstring(zf.read("modelDescription.xml"))
    document.set("notAnFmiAttribute", "1")
    assert not schema.validate(document)
