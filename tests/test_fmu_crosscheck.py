"""``wmr fmu crosscheck``: the FMI Cross-Check layout, and references that re-simulate."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu
from fmpy.cross_check.validate_vendor_repo import validate_test_fmu
from fmpy.util import read_csv, read_ref_opt_file

from wmr import __version__
from wmr.build.crosscheck import REFERENCE_OUTPUTS
from wmr.build.fmus import BuildResult, summarize
from wmr.cli import main


@pytest.fixture(scope="module")
def crosscheck(built: BuildResult,
               tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path]]:
    out = tmp_path_factory.mktemp("xc")
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(["fmu", "crosscheck", "--out", str(out),
                     "--fmu-dir", str(built.fmus[2].parent)]) == 0
    return out, [Path(line) for line in stdout.getvalue().splitlines()]


def test_layout_follows_the_cross_check_rules(built: BuildResult,
                                              crosscheck: tuple[Path, list[Path]]) -> None:
    out, folders = crosscheck
    kinds = {"co-simulation": "cs", "model exchange": "me"}
    expected = {out / "fmus" / s.fmi_version / kinds[i] / p / "wmr-cosim" / __version__
                / "wmr_robot" for s in map(summarize, built.fmus.values())
                for i in s.interfaces for p in s.platforms}
    assert any(f.parts[len(out.parts) + 2] == "cs" for f in expected)
    assert set(folders) == expected and len(folders) == len(expected)
    for folder in folders:
        names = {p.name for p in folder.iterdir()}
        assert {"wmr_robot.fmu", "wmr_robot_in.csv", "wmr_robot_ref.csv", "wmr_robot_ref.opt",
                "ReadMe.md"} <= names
        opts = read_ref_opt_file(str(folder / "wmr_robot_ref.opt"))
        assert (opts["StartTime"], opts["StopTime"], opts["StepSize"]) == (0.0, 10.0, 0.01)
        fmi3 = folder.parts[len(out.parts) + 1] == "3.0"
        assert ("notCompliantWithLatestRules" in names) == fmi3
        if not fmi3:  # fmpy's check of a vendor repository (FMI 1.0 and 2.0 only)
            assert validate_test_fmu(str(folder)) == []
        assert all(p.stat().st_size < 1e6 for p in folder.iterdir() if p.suffix == ".csv")
    for folder in folders:  # fmpy re-imported each host-platform entry and passed it
        fmi, kind, platform = folder.parts[len(out.parts) + 1:len(out.parts) + 4]
        if platform in ("linux64", "x86_64-linux"):
            marker = out / "results" / fmi / kind / platform / "FMPy"
            assert len(list(marker.glob(f"*/wmr-cosim/{__version__}/wmr_robot/passed"))) == 1


@pytest.mark.parametrize("fmi", ["2.0", "3.0"])
def test_the_fmu_with_the_input_reproduces_the_reference(crosscheck: tuple[Path, list[Path]],
                                                         fmi: str) -> None:
    """Co-simulation, as any importer would run it from the files alone."""
    out, _ = crosscheck
    host = "linux64" if fmi == "2.0" else "x86_64-linux"
    folder = next((out / "fmus" / fmi / "cs" / host).glob("*/*/wmr_robot"))
    opts = read_ref_opt_file(str(folder / "wmr_robot_ref.opt"))
    reference = read_csv(folder / "wmr_robot_ref.csv")
    assert reference.dtype.names is not None
    assert set(reference.dtype.names) == {"time", *REFERENCE_OUTPUTS}
    result = simulate_fmu(str(folder / "wmr_robot.fmu"), start_time=opts["StartTime"],
                          stop_time=opts["StopTime"], output_interval=opts["StepSize"],
                          input=read_csv(folder / "wmr_robot_in.csv"), fmi_type="CoSimulation",
                          output=list(REFERENCE_OUTPUTS))
    assert np.array_equal(result["time"], reference["time"])
    for name in REFERENCE_OUTPUTS:
        assert np.ptp(reference[name]) > 1e-2, name  # the inputs move every output
        scale = np.maximum(1.0, np.abs(reference[name]))
        assert np.max(np.abs(result[name] - reference[name]) / scale) < 1e-12, name


@pytest.mark.parametrize("fmi", ["2.0", "3.0"])
def test_the_model_exchange_reference_is_the_exact_hold_input_solution(
        crosscheck: tuple[Path, list[Path]], fmi: str) -> None:
    """The ME reference against an independent integrator: SciPy's DOP853 at 1e-13 on the
    hand-written physics (``wmr.core.physics``), restarted at each output point with the input
    of ``_in.csv`` there, held to the next.  The old reference (fmpy's CVode, not restarted,
    integrating past each output point with the old input) was 5.17 mm off in x, 4.8e-3
    relative in phi_r."""
    from wmr.core.physics import ReferencePlant
    from wmr.core.plant import OUTPUT_NAMES, Pose, RobotParams

    out, _ = crosscheck
    host = "linux64" if fmi == "2.0" else "x86_64-linux"
    folder = next((out / "fmus" / fmi / "me" / host).glob("*/*/wmr_robot"))
    reference = read_csv(folder / "wmr_robot_ref.csv")
    signal = read_csv(folder / "wmr_robot_in.csv")
    t = reference["time"]
    held = [np.interp(t, signal["time"], signal[n]) for n in ("tau_r", "tau_l")]
    plant = ReferencePlant(rtol=1e-13, atol=1e-13)
    rows = [plant.reset(RobotParams(), Pose(0.0, 0.0, 0.0))]
    for k in range(len(t) - 1):
        rows.append(plant.step(held[0][k], held[1][k], t[k + 1] - t[k]))
    exact = np.array(rows)
    for name in REFERENCE_OUTPUTS:
        column = exact[:, OUTPUT_NAMES.index(name)]
        scale = np.maximum(1.0, np.abs(column))
        assert np.max(np.abs(reference[name] - column) / scale) < 1e-9, name
