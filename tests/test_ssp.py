"""``wmr ssp export`` / ``wmr ssp run``: the closed loop as an SSP 1.0 package, run by masters
we did not write (libcosim through libcosimpy, Ecos through ecospy, fmpy's SSP simulator),
against ``wmr run``.

Every logged sample of the SSP runs must be within 5 mm and 0.2 deg of ``wmr run``'s path,
after the master's measured lag (libcosim and Ecos: 0 steps, fmpy: 1 step at the control
period, see docs/ssp.md).  A package steps its masters at the control period divided by
``DEFAULT_STEPS_PER_PERIOD`` unless a test exports it at the period itself (``n=1``), the
step the paper's figures and fmpy's one-step lag were measured at.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from wmr.adapters.mcap.reader import read_run
from wmr.adapters.ssp.agreement import (
    deviation,
    fmpy_path,
    libcosim_path,
    measured_lag,
    wmr_run_path,
)
from wmr.adapters.ssp.cosim import simulate_libcosim
from wmr.adapters.ssp.ecos import simulate_ecos
from wmr.adapters.ssp.export import (
    DEFAULT_STEPS_PER_PERIOD,
    controller_parameters,
    export_ssp,
    robot_parameters,
)
from wmr.adapters.ssp.package import read_package
from wmr.build.fmus import BuildResult
from wmr.cli import main
from wmr.config.scenario import load_scenario
from wmr.core.runspec import RunSpec
from wmr.core.signals import SIGNALS

POSITION_TOL_M = 5e-3
HEADING_TOL_RAD = math.radians(0.2)
#: A Jacobi master stepped at the control period hands the robot, after the controller's step
#: from t_k, its next sample on the measurement it holds, g(z_(k+1), y_k) (docs/ssp.md).  A
#: case over a bar would be a strict xfail with the measured figure (docs/ssp.md, "Measured
#: agreement").  libcosim and Ecos at the package's default step (a divisor of the period):
#: none (fig9-thd-090 was, 2.55 mm and 0.253 deg, at the period: 0.16 mm, 0.017 deg now);
#: fmpy, tested at the period (its own step, not the package's): Fig. 11.
_LAG = ("the controller's next sample on the previous measurement costs the heading more "
        "than a pure delay did")
_OVER_JACOBI: dict[str, str] = {}
_OVER_FMPY: dict[str, str] = {"fig11": f"{_LAG}: 1.28 mm, 0.244 deg"}


def _cases(over: dict[str, str]) -> list[object]:
    cases: list[object] = []
    for scenario, run in (("fig11", None), ("fig9", "fig9-thd-090"), ("fig9", "fig9-thd+045")):
        marks = [] if scenario == "fig11" else [pytest.mark.slow]
        if (run or scenario) in over:
            marks.append(pytest.mark.xfail(strict=True, raises=AssertionError,
                                           reason=over[run or scenario]))
        cases.append(pytest.param(scenario, run, marks=marks, id=run or scenario))
    return cases


LIBCOSIM_CASES = _cases(_OVER_JACOBI)
FMPY_CASES = _cases(_OVER_FMPY)


def _spec(scenario: str, run: str | None) -> RunSpec:
    return next(r for r in load_scenario(scenario).runs if run is None or r.name == run)


def _wmr_run(spec: RunSpec, robot_fmu: Path) -> npt.NDArray[np.float64]:
    """``wmr run``'s ``(x, y, theta)`` rows (the Python stabiliser on the robot FMU)."""
    status, path = wmr_run_path(spec, robot_fmu)
    assert status == "converged"
    return path


@pytest.fixture(scope="session")
def ssp_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("ssp")


def _export(built: BuildResult, spec: RunSpec, folder: Path, fmi: int = 2,
            steps_per_period: int = DEFAULT_STEPS_PER_PERIOD) -> Path:
    """The package of ``spec``, made once per session; its masters' step is the control
    period divided by ``steps_per_period`` (the package's default unless given)."""
    out = folder / f"{spec.name}-fmi{fmi}-n{steps_per_period}.ssp"
    if not out.exists():
        export_ssp(spec, out, built.fmus[fmi], built.controllers[fmi],
                   steps_per_period=steps_per_period)
    return out


@pytest.mark.parametrize("fmi", [2, 3])
def test_the_package_validates_against_the_ssp_schemas(built: BuildResult, ssp_dir: Path,
                                                       fmi: int) -> None:
    from fmpy.ssp.ssd import get_connections, read_ssd

    spec = _spec("fig9", "fig9-thd+045")
    path = _export(built, spec, ssp_dir, fmi)
    ssd = read_ssd(str(path), validate=True)  # SSD and both SSVs against the SSP 1.0 XSDs
    names = {c.name: c for c in ssd.system.elements}
    assert set(names) == {"robot", "controller"}
    assert names["robot"].source == f"resources/wmr_robot-fmi{fmi}.fmu"
    pairs = {(a.parent.name, a.name, b.parent.name, b.name)
             for a, b in get_connections(ssd.system)}
    measured = ("x", "y", "theta", "v", "omega", "omega_r", "omega_l")
    assert pairs == {("robot", n, "controller", n) for n in measured} | \
        {("controller", n, "robot", n) for n in ("tau_r", "tau_l")}
    package = read_package(path)
    assert package.components["robot"].parameters == robot_parameters(spec)
    ctrl = package.components["controller"].parameters
    assert ctrl["goal.heading_deg"] == pytest.approx(45.0, abs=1e-12)
    assert ctrl == {k: v for k, v in controller_parameters(spec).items() if k in ctrl}
    # the masters' step: the control period divided by the package's default (it was the
    # period itself, a whole period of lag in libcosim and Ecos: docs/ssp.md)
    assert package.stop_time_s == spec.t_max_s
    assert package.step_size_s == spec.period_s / DEFAULT_STEPS_PER_PERIOD
    with zipfile.ZipFile(path) as zf:
        packed = zf.read(f"resources/wmr_controller-fmi{fmi}.fmu")
    # the built controller FMU, every member byte for byte, but for the run's start values
    # (its model description's and resources/start_values.txt: a master that applies no
    # parameter set runs the package's run)
    import io

    with zipfile.ZipFile(io.BytesIO(packed)) as got, \
            zipfile.ZipFile(built.controllers[fmi]) as want:
        assert set(got.namelist()) == set(want.namelist()) | {"resources/start_values.txt"}
        for name in want.namelist():
            if name != "modelDescription.xml":
                assert got.read(name) == want.read(name), name


def test_the_schema_check_is_real(built: BuildResult, ssp_dir: Path, tmp_path: Path) -> None:
    """A package whose SSD breaks the schema is refused by the same validation."""
    from fmpy.ssp.ssd import read_ssd

    good = _export(built, _spec("fig11", None), ssp_dir)
    bad = tmp_path / "bad.ssp"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(bad, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "SystemStructure.ssd":
                data = data.replace(b'kind="input"', b'kind="sideways"', 1)
            dst.writestr(item, data)
    with pytest.raises(Exception, match="kind"):
        read_ssd(str(bad), validate=True)


@pytest.mark.parametrize(("scenario", "run"), LIBCOSIM_CASES)
def test_libcosim_traces_wmr_run(built: BuildResult, ssp_dir: Path, scenario: str,
                                 run: str | None) -> None:
    spec = _spec(scenario, run)
    ref = _wmr_run(spec, built.fmus[2])
    status, path = libcosim_path(_export(built, spec, ssp_dir))
    assert status == "converged"
    assert measured_lag(path, ref) == 0
    pos, head = deviation(path, ref, 0)
    assert pos <= POSITION_TOL_M and head <= HEADING_TOL_RAD, (pos, math.degrees(head))
    assert abs(len(path) - len(ref)) <= 2  # converges within a step or two of wmr run
    goal = spec.goal
    assert math.hypot(path[-1, 0] - goal.x_m, path[-1, 1] - goal.y_m) <= spec.stop_radius_m


def _ecos_cases() -> list[object]:
    cases: list[object] = [pytest.param("fig11", None, fmi, id=f"fig11-fmi{fmi}") for fmi in (2, 3)]
    for run in ("fig9-thd-090", "fig9-thd+045"):
        marks = [pytest.mark.slow]
        if run in _OVER_JACOBI:
            marks.append(pytest.mark.xfail(strict=True, raises=AssertionError,
                                           reason=_OVER_JACOBI[run]))
        cases.append(pytest.param("fig9", run, 3, id=f"{run}-fmi3", marks=marks))
    return cases


@pytest.mark.parametrize(("scenario", "run", "fmi"), _ecos_cases())
def test_ecos_traces_wmr_run(built: BuildResult, ssp_dir: Path, scenario: str,
                             run: str | None, fmi: int) -> None:
    """Ecos runs the FMI 3.0 (and 2.0) closed loop: unshifted, within the bars, converged
    within two steps of wmr run (the Python stabiliser on the robot FMU)."""
    spec = _spec(scenario, run)
    ref = _wmr_run(spec, built.fmus[2])
    result = simulate_ecos(_export(built, spec, ssp_dir, fmi=fmi))
    assert result.status == "converged"
    assert result.master.startswith("ecospy")
    path = result.block[:, [0, 1, 2]]
    assert measured_lag(path, ref) == 0
    pos, head = deviation(path, ref, 0)
    assert pos <= POSITION_TOL_M and head <= HEADING_TOL_RAD, (pos, math.degrees(head))
    assert abs(len(path) - len(ref)) <= 2


def test_ecos_and_libcosim_run_the_same_closed_loop(built: BuildResult, ssp_dir: Path) -> None:
    """The two masters (and FMI 2.0 against 3.0 in Ecos) give the same robot path."""
    spec = _spec("fig11", None)
    lib = simulate_libcosim(_export(built, spec, ssp_dir, fmi=2))
    for fmi in (2, 3):
        eco = simulate_ecos(_export(built, spec, ssp_dir, fmi=fmi))
        n = min(len(lib.block), len(eco.block))
        np.testing.assert_allclose(eco.block[:n, :3], lib.block[:n, :3], rtol=0, atol=1e-9)


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    """``wmr`` in a new process: what C libraries print on fd 1 and 2 is captured too."""
    code = "import sys; from wmr.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          timeout=300)


@pytest.mark.parametrize(("master", "fmi"), [("libcosim", 2), ("ecos", 2), ("ecos", 3),
                                             ("auto", 3)])
def test_wmr_ssp_run_json_prints_the_json_line_alone_and_no_library_error(
        built: BuildResult, ssp_dir: Path, tmp_path: Path, master: str, fmi: int) -> None:
    """Standard output is the JSON line alone; no FMI Library error on our FMUs anywhere
    (libcosim printed four "[error] [FMI Library: FMI2XML] Start attribute is required" lines
    on stdout, for the FMI 2 `time` variable)."""
    package = _export(built, _spec("fig11", None), ssp_dir, fmi=fmi)
    proc = _cli("ssp", "run", str(package), "--master", master, "--stop-time", "0.5", "--json",
                "--out", str(tmp_path / "run.mcap"))
    assert proc.returncode == 3, proc.stderr  # not converged in 0.5 s
    lines = proc.stdout.splitlines()
    assert len(lines) == 1, proc.stdout
    assert json.loads(lines[0])["status"] == "timeout"
    assert "[error]" not in proc.stderr and "FMI2XML" not in proc.stderr, proc.stderr


@pytest.mark.parametrize("master", ["libcosim", "ecos"])
def test_wmr_ssp_run_results_carry_the_energies_of_wmr_run(
        built: BuildResult, ssp_dir: Path, tmp_path: Path, master: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The energy fields of ``wmr run --json``, from the torques the robot held and its wheel
    speeds: within 1 % of wmr run's (the torques reach the robot one period late)."""
    from wmr.adapters.fmi.robot import FmuPlant
    from wmr.apps.run import run_to_log

    spec = _spec("fig11", None)
    with FmuPlant(built.fmus[2]) as plant:
        ref = run_to_log(spec, tmp_path / "ref.mcap", plant)
    package = _export(built, spec, ssp_dir)
    assert main(["ssp", "run", str(package), "--master", master, "--json",
                 "--out", str(tmp_path / "ssp.mcap")]) == 0
    record = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in ("energy_net_j", "energy_positive_j", "energy_abs_j"):
        assert math.isfinite(record[key]), key
    for key in ("energy_positive_j", "energy_abs_j"):
        assert record[key] == pytest.approx(ref[key], rel=0.01), key
    assert abs(record["energy_net_j"] - ref["energy_net_j"]) <= 0.01 * ref["energy_positive_j"]


@pytest.mark.parametrize(("scenario", "run"), FMPY_CASES)
def test_fmpy_simulate_ssp_traces_wmr_run_one_step_late(built: BuildResult, ssp_dir: Path,
                                                         scenario: str, run: str | None) -> None:
    """fmpy starts every connection at 0 and passes values after each step (Jacobi): the
    robot gets each torque one step late, so its path is ``wmr run``'s one step later."""
    spec = _spec(scenario, run)
    ref = _wmr_run(spec, built.fmus[2])
    converged, path = fmpy_path(_export(built, spec, ssp_dir, steps_per_period=1),
                                len(ref) * spec.period_s + 0.1)
    assert converged  # the controller's flag rose: it reached the goal
    assert measured_lag(path, ref) == 1
    pos, head = deviation(path, ref, 1)
    assert pos <= POSITION_TOL_M and head <= HEADING_TOL_RAD, (pos, math.degrees(head))


def _issue_variant_spec() -> RunSpec:
    """Issue 32's non-paper case: ``wmr ssp export fig11 --start 3 -2 170 --goal -4 5 -60``
    (it begins with a turn, away from the origin)."""
    from wmr.config.scenario import Overrides, with_overrides
    from wmr.core.plant import Pose

    spec = with_overrides(_spec("fig11", None),
                          Overrides(start=Pose(3.0, -2.0, math.radians(170.0)),
                                    goal=Pose(-4.0, 5.0, math.radians(-60.0))))
    return replace(spec, name="issue32-variant")


#: fmpy 0.3.32 measured on the variant at the package's default step (docs/ssp.md).
_FMPY_ZERO_START = ("fmpy's simulate_ssp starts every connection at 0.0 and sets the inputs "
                    "from them before the first doStep (fmpy/ssp/simulation.py lines 180 and "
                    "129): the controller's first sample sees the pose (0, 0, 0) and the "
                    "robot's first step no torque; measured 4.27 mm, 0.287 deg")


@pytest.mark.xfail(strict=True, raises=AssertionError, reason=_FMPY_ZERO_START)
def test_fmpy_runs_the_non_paper_variant_within_the_claim(built: BuildResult,
                                                          ssp_dir: Path) -> None:
    """Issue 32's done-when for fmpy: the variant's FMI 2.0 package at its default step, as
    ``wmr ssp check`` runs it.  Strict: an fmpy that starts its connections from the FMUs'
    outputs makes it pass, and docs/ssp.md's fmpy rows must then be measured again."""
    spec = _issue_variant_spec()
    ref = _wmr_run(spec, built.fmus[2])
    converged, path = fmpy_path(_export(built, spec, ssp_dir), len(ref) * spec.period_s + 0.1)
    assert converged
    pos, head = deviation(path, ref, measured_lag(path, ref))
    assert pos <= POSITION_TOL_M and head <= HEADING_TOL_RAD, (pos, math.degrees(head))


def test_fmpy_s_first_step_is_its_master_s_not_the_package_s(built: BuildResult,
                                                             ssp_dir: Path) -> None:
    """Why no package can bring fmpy within the claim on the variant, and what would.

    The package cannot: the controller's pose inputs given the start pose as start values (a
    parameter set may set an input's start before initialisation) give the same path bit for
    bit, because ``simulate_ssp`` sets every input from its connection, 0.0 at first, before
    each ``doStep``.  The master can: ``simulate_ssp``'s own loop (fmpy's ``instantiate_fmu``
    and ``do_step``) with the connections started from the FMUs' outputs after
    initialisation, in dependency order (the robot's outputs to the controller, then the
    controller's torques to the robot), follows libcosim's path to 1e-9."""
    from fmpy import extract
    from fmpy.ssp.simulation import (
        add_path,
        do_step,
        free_fmu,
        get_value,
        instantiate_fmu,
        set_value,
        simulate_ssp,
    )
    from fmpy.ssp.ssd import Parameter, find_components, find_connectors, get_connections, read_ssd

    from wmr.adapters.ssp.package import fmpy_parameter_set

    spec = _issue_variant_spec()
    package = _export(built, spec, ssp_dir)
    pkg = read_package(package)
    h, stop_s = pkg.step_size_s, 3.0  # the worst heading is at 0.78 s
    assert h is not None
    pose = ("robot.x", "robot.y", "robot.theta")
    plain = simulate_ssp(str(package), stop_time=stop_s, step_size=h,
                         parameter_set=fmpy_parameter_set(pkg))
    with_starts = fmpy_parameter_set(pkg)
    for name, value in zip(("x", "y", "theta"), (spec.start.x_m, spec.start.y_m,
                                                 spec.start.heading_rad), strict=True):
        with_starts.parameters.append(Parameter(name=f"controller.{name}", type="Real",
                                                value=value))
    started = simulate_ssp(str(package), stop_time=stop_s, step_size=h,
                           parameter_set=with_starts)
    for name in pose:
        assert np.array_equal(plain[name], started[name]), name

    ssd = read_ssd(str(package))
    add_path(ssd.system)
    components, connections = find_components(ssd.system), get_connections(ssd.system)
    assert [c.name for c in components] == ["robot", "controller"]  # dependency order
    for connector in find_connectors(ssd.system):
        connector.value = 0.0
    folder = extract(str(package))
    rows = []
    try:
        for component in components:
            instantiate_fmu(component, folder, 0.0, stop_s, fmpy_parameter_set(pkg))
        for component in components:  # the initial values, in dependency order
            for connector in component.connectors:
                if connector.kind == "input":
                    set_value(component, connector.name, connector.value)
            for connector in component.connectors:
                if connector.kind == "output":
                    connector.value = get_value(component, connector.name)
            for start, end in connections:
                end.value = start.value
        for k in range(round(stop_s / h)):
            for component in components:
                do_step(component, k * h, h)
            for start, end in connections:
                end.value = start.value
            rows.append([get_value(components[0], n) for n in ("x", "y", "theta")])
    finally:
        for component in components:
            free_fmu(component)
    stride = round(spec.period_s / h)
    ordered = np.vstack([[spec.start.x_m, spec.start.y_m, spec.start.heading_rad],
                         rows])[::stride]
    _, cosim = libcosim_path(package)
    n = len(ordered)
    assert len(cosim) >= n
    assert np.abs(ordered - cosim[:n]).max() <= 1e-9


def test_wmr_ssp_run_logs_the_layout_of_wmr_run(built: BuildResult, ssp_dir: Path,
                                                tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    spec = _spec("fig11", None)
    package = _export(built, spec, ssp_dir)
    log_path = tmp_path / "ssp.mcap"
    code = main(["ssp", "run", str(package), "--out", str(log_path), "--json"])
    record = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 0 and record["status"] == "converged"
    log = read_run(log_path)
    assert not log.truncated and log.n_steps == record["steps"]
    assert set(log.signals) == set(SIGNALS)
    assert all(np.isfinite(log.signals[name]).all() for name in SIGNALS)
    direct = simulate_libcosim(package)
    assert np.array_equal(log.block(), direct.block)  # the log holds the run bit for bit
    assert log.goal is not None and (log.goal.x_m, log.goal.y_m) == (20.0, 10.0)
    run_meta = log.metadata["run"]
    assert run_meta["master"].startswith("libcosimpy")
    assert json.loads(run_meta["gains"]) == {k: v for k, v in spec.gains.as_dict().items()}
    assert "SystemStructure.ssd" in log.attachments
    assert record["final_position_error_m"] <= spec.stop_radius_m


def test_wmr_ssp_export_writes_what_it_prints(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "f11.ssp"
    assert main(["ssp", "export", "fig11", "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert read_package(out).components["robot"].fmi_version == "2.0"


def _with_period(good: Path, bad: Path, period: bytes) -> None:
    """A copy of the package ``good`` whose controller has another ``control_period_s``."""
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(bad, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "resources/controller.ssv":
                data = data.replace(b'"control_period_s">\n      <ssv:Real value="0.01"',
                                    b'"control_period_s">\n      <ssv:Real value="' + period)
                assert b'value="' + period in data
            dst.writestr(item, data)


def test_a_controller_period_of_two_master_steps_samples_every_other_step(
        built: BuildResult, ssp_dir: Path, tmp_path: Path) -> None:
    """control_period_s = 0.02 s in a package stepped at 0.01 s (the controller FMU refused it
    before): Ecos reads after passing the values on, so it sees the sample at every grid point
    (even steps) and the same value held at the step after."""
    package = tmp_path / "slow.ssp"
    _with_period(_export(built, _spec("fig11", None), ssp_dir, steps_per_period=1), package,
                 b'0.02"')
    run = simulate_ecos(package, stop_time_s=2.0)
    tau = run.variables["controller"]["tau_r"]
    assert np.array_equal(tau[1::2], tau[0:-1:2])  # held between grid points
    assert np.count_nonzero(np.diff(tau[0::2])) > 20  # and it does control


@pytest.mark.parametrize(("damage", "expected"), [
    ("drop-fmu", "its FMU resources/wmr_controller-fmi2.fmu is missing from the package"),
    ("drop-ssv", "parameter set resources/robot.ssv is missing"),
    ("no-file", "no such file"),
    ("not-zip", "is not an SSP package"),
])
def test_a_broken_package_is_one_line(built: BuildResult, ssp_dir: Path, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str], damage: str,
                                      expected: str) -> None:
    good = _export(built, _spec("fig11", None), ssp_dir)
    bad = tmp_path / "bad.ssp"
    drop = {"drop-fmu": "resources/wmr_controller-fmi2.fmu",
            "drop-ssv": "resources/robot.ssv"}.get(damage)
    if damage == "not-zip":
        bad.write_text("not a zip")
    elif drop is not None:
        with zipfile.ZipFile(good) as src, zipfile.ZipFile(bad, "w") as dst:
            for item in src.infolist():
                if item.filename != drop:
                    dst.writestr(item, src.read(item))
    out = tmp_path / "x.mcap"
    code = main(["ssp", "run", str(bad), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 1 and len(err.splitlines()) == 1 and expected in err, err
    assert not out.exists()


def test_libcosim_refuses_fmi3_with_one_line(built: BuildResult, ssp_dir: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    package = _export(built, _spec("fig11", None), ssp_dir, fmi=3)
    assert main(["ssp", "run", str(package), "--master", "libcosim",
                 "--out", str(ssp_dir / "x.mcap")]) == 1
    err = capsys.readouterr().err.strip()
    assert "runs FMI 2.0 FMUs only" in err and "--master ecos" in err


def test_the_docs_list_what_the_package_holds(built: BuildResult, ssp_dir: Path) -> None:
    """docs/ssp.md names every member of an exported package and every parameter set entry."""
    doc = (Path(__file__).parents[1] / "docs" / "ssp.md").read_text()
    spec = _spec("fig11", None)
    package = ssp_dir / "doc.ssp"
    export_ssp(spec, package, built.fmus[2], built.controllers[2],
               scenario_file=load_scenario("fig11").path)
    with zipfile.ZipFile(package) as zf:
        for name in zf.namelist():
            assert f"`{name}`" in doc, name
    ctrl = read_package(package).components["controller"].parameters
    for name in ctrl:
        section = name.split(".")[0]
        assert f"`{name}`" in doc or f"`{section}.*`" in doc, name


def test_a_run_with_sensors_is_not_exported(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """The package wires true outputs to the controller: a sensed run would be another run."""
    scenario = tmp_path / "sensed.toml"
    scenario.write_text('start = [0.0, 0.0, 0.0]\ngoal = [5.0, 2.0, 0.0]\n'
                        '[sensors]\nestimator = "ekf"\ngps_sigma_m = 0.02\n')
    out = tmp_path / "s.ssp"
    assert main(["ssp", "export", str(scenario), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "sensors" in err and "perfect measurements" in err
    assert not out.exists()


def test_wmr_ssp_run_does_not_overwrite_the_log_of_wmr_run(
        built: BuildResult, ssp_dir: Path, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``wmr ssp run fig11.ssp`` without --out logs to runs/fig11-ssp.mcap, not over the
    runs/fig11.mcap of ``wmr run fig11``."""
    package = tmp_path / "fig11.ssp"
    package.write_bytes(_export(built, _spec("fig11", None), ssp_dir).read_bytes())
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "fig11.mcap").write_bytes(b"the log of wmr run")
    assert main(["ssp", "run", str(package), "--stop-time", "0.5"]) == 3
    assert (tmp_path / "runs" / "fig11.mcap").read_bytes() == b"the log of wmr run"
    assert read_run(tmp_path / "runs" / "fig11-ssp.mcap").n_steps == 50


def test_an_exported_package_has_the_mode_of_a_new_file(tmp_path: Path,
                                                        built: BuildResult) -> None:
    """0666 less the umask, as any file a command writes (it was 0600, from mkstemp)."""
    import os
    import stat

    old_mask = os.umask(0o022)
    try:
        out = export_ssp(_spec("fig11", None), tmp_path / "m.ssp", built.fmus[2],
                         built.controllers[2])
    finally:
        os.umask(old_mask)
    assert stat.S_IMODE(out.stat().st_mode) == 0o644
    assert [p.name for p in tmp_path.iterdir()] == ["m.ssp"]  # no temporary file left


def test_a_variant_package_is_named_and_documented_as_its_own_run(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """``wmr ssp export fig11 --goal 5 5 30``: the SSD, the parameter sets and ``wmr ssp run``
    carry the variant's name (as ``wmr run`` names it), and the provenance is its effective
    scenario, which reads back into the exported run (it was ``fig11`` and fig11.toml, with
    the unmodified goal)."""
    import tomllib

    from wmr.config.naming import run_name
    from wmr.config.scenario import Overrides, parse_scenario, with_overrides
    from wmr.core.plant import Pose

    monkeypatch.chdir(tmp_path)
    assert main(["ssp", "export", "fig11", "--goal", "5", "5", "30"]) == 0
    base = _spec("fig11", None)
    variant = with_overrides(base, Overrides(goal=Pose(5.0, 5.0, math.radians(30.0))))
    name = run_name(base, variant)
    assert name != "fig11"
    out = Path(capsys.readouterr().out.strip())
    assert out == Path("ssp") / f"{name}.ssp"
    assert read_package(out).name == name
    with zipfile.ZipFile(out) as zf:
        for ssv in ("resources/robot.ssv", "resources/controller.ssv"):
            assert f'name="{name}"'.encode() in zf.read(ssv), ssv
        tomls = [n for n in zf.namelist() if n.endswith(".toml")]
        assert tomls == [f"resources/{name}.toml"]
        runs = parse_scenario(tomllib.loads(zf.read(tomls[0]).decode())).runs
    assert list(runs) == [replace(variant, name=name)]
    assert main(["ssp", "run", str(out), "--stop-time", "0.5", "--json",
                 "--out", str(tmp_path / "v.mcap")]) == 3
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["name"] == name


def test_the_scenario_s_own_package_keeps_its_scenario_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "f11.ssp"
    assert main(["ssp", "export", "fig11", "--out", str(out)]) == 0
    with zipfile.ZipFile(out) as zf:
        assert zf.read("resources/fig11.toml") == load_scenario("fig11").path.read_bytes()
    assert read_package(out).name == "fig11"


@pytest.mark.parametrize("fmi", [2, 3])
def test_omsimulator_reads_a_weakly_coupled_system_stepped_at_the_package_s_step(
        built: BuildResult, ssp_dir: Path, fmi: int) -> None:
    """OMSimulator (src/OMSimulatorLib/Model.cpp, getSystemType; SystemWC.cpp,
    importFromSSD_SimulationInformation) finds the system's type by literal tag names: the
    ``ssd:System``'s ``ssd:Annotations/ssc:Annotation type="org.openmodelica"/oms:Annotations/
    oms:SimulationInformation/oms:FixedStepMaster`` with a ``description`` (the solver, "oms-ma")
    and a ``stepSize``.  Without it the system was oms_system_none and oms_importFile failed
    ("[NewSystem] internal error").  The same SSD validates against the SSP 1.0 XSDs
    (test_the_package_validates_against_the_ssp_schemas)."""
    from xml.dom import minidom

    spec = _spec("fig11", None)
    with zipfile.ZipFile(_export(built, spec, ssp_dir, fmi)) as zf:
        doc = minidom.parseString(zf.read("SystemStructure.ssd"))

    def children(node: minidom.Element, tag: str) -> list[minidom.Element]:
        return [c for c in node.childNodes
                if isinstance(c, minidom.Element) and c.tagName == tag]

    (system,) = children(doc.documentElement, "ssd:System")
    (annotations,) = children(system, "ssd:Annotations")
    vendor = [a for a in children(annotations, "ssc:Annotation")
              if a.getAttribute("type") == "org.openmodelica"]
    assert len(vendor) == 1
    (oms,) = children(vendor[0], "oms:Annotations")
    (info,) = children(oms, "oms:SimulationInformation")
    (master,) = children(info, "oms:FixedStepMaster")
    assert master.getAttribute("description") == "oms-ma"
    # the package's master step, as libcosim's (it was the period, the default before)
    assert float(master.getAttribute("stepSize")) == spec.period_s / DEFAULT_STEPS_PER_PERIOD
    assert float(master.getAttribute("stepSize")) == read_package(
        _export(built, spec, ssp_dir, fmi)).step_size_s
    # passed to every FMI 2.0 FMU as a defined tolerance (0 without it, which the robot
    # refused): the robot FMU's own default, as wmr run leaves it
    from fmpy import read_model_description

    tolerance = read_model_description(str(built.fmus[fmi])).defaultExperiment.tolerance
    assert float(master.getAttribute("relativeTolerance")) == float(tolerance) == 1e-9


def _turn_first_spec() -> RunSpec:
    """Issue 32's non-paper case: ``wmr ssp export fig11 --start 3 -2 170 --goal -4 5 -60``,
    a run that begins with a turn at saturated torque (about 22 s)."""
    from wmr.config.naming import run_name
    from wmr.config.scenario import Overrides, with_overrides

    base = _spec("fig11", None)
    spec = with_overrides(base, Overrides(start=(3.0, -2.0, 170.0), goal=(-4.0, 5.0, -60.0)))
    return replace(spec, name=run_name(base, spec))


@pytest.mark.parametrize("master", ["libcosim", pytest.param("ecos", marks=pytest.mark.slow)])
def test_the_default_step_keeps_a_lagging_master_within_the_claim_on_a_run_that_turns_first(
        built: BuildResult, ssp_dir: Path, master: str) -> None:
    """libcosim and Ecos are Jacobi: stepped at the control period (the package's step
    before) the robot held each torque one period late, 14.59 mm and 0.822 deg off ``wmr
    run``'s path on this case, over the 5 mm and 0.2 deg docs/ssp.md claims (issue 32 item
    6).  At the package's default step, a divisor of the period, the controller takes each
    sample on the measurement at its grid point and only the first master step of a period
    holds the late torque: the default run is within the claim, logged a row per period as
    ``wmr run``'s, and converges on the same sample."""
    spec = _turn_first_spec()
    ref = _wmr_run(spec, built.fmus[2])
    package = _export(built, spec, ssp_dir)
    run = simulate_libcosim(package) if master == "libcosim" else simulate_ecos(package)
    assert run.status == "converged"
    path = run.block[:, :3]
    assert measured_lag(path, ref) == 0
    pos, head = deviation(path, ref, 0)
    assert pos <= POSITION_TOL_M and head <= HEADING_TOL_RAD, (pos, math.degrees(head))
    assert len(path) == len(ref)  # the same converged sample
    assert run.steps_per_row == DEFAULT_STEPS_PER_PERIOD > 1
    assert np.array_equal(run.t_ns, np.round(np.arange(len(run.block)) * spec.period_s * 1e9))


@pytest.mark.slow
def test_libcosim_logs_the_converged_sample_when_it_falls_on_a_check_of_the_flag(
        built: BuildResult, tmp_path: Path) -> None:
    """libcosim's loop reads the ``converged`` flag every 100 master steps.  At a step shorter
    than the period the flag read at a grid point is the sample on the measurement one master
    step old, and the log's row is the sample the controller holds at the next point: when
    the flag first rose exactly at a check, that point was never stepped to and the run was
    logged as "not converged" (fig9-thd-030 at period / 5, 15100 steps)."""
    spec = _short_spec()
    ref = _wmr_run(spec, built.fmus[2])
    rows = len(ref) - 1  # the converged sample's row
    n = next(k for k in range(2, 101) if rows * k % 100 == 0)  # a check on its grid point
    package = tmp_path / "short.ssp"
    export_ssp(spec, package, built.fmus[2], built.controllers[2], steps_per_period=n)
    run = simulate_libcosim(package)
    assert run.status == "converged", (n, run.message)
    assert len(run.block) == len(ref) and run.steps_per_row == n
    assert math.isclose(run.time_to_goal_s or 0.0, rows * spec.period_s, rel_tol=1e-12)


def test_docs_name_the_default_master_step() -> None:
    """docs/ssp.md says which step a package gives its masters, and its measured table has
    a row for it in both lagging masters."""
    doc = " ".join((Path(__file__).parents[1] / "docs" / "ssp.md").read_text().split())
    n = DEFAULT_STEPS_PER_PERIOD
    assert f"the **master step**, `N` = {n} unless `--steps-per-period N`" in doc
    for master in ("libcosim", "Ecos"):
        assert f"| {master} | h/{n} (default) |" in doc, master


def test_wmr_ssp_export_steps_per_period_sets_the_masters_step(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--steps-per-period N``: libcosim's (OSP) and OMSimulator's step is the control period
    / N, the package still valid against the SSP 1.0 XSDs; N outside 1..100 is one line."""
    from xml.dom import minidom

    from fmpy.ssp.ssd import read_ssd

    period = _spec("fig11", None).period_s
    for n, out in ((1, tmp_path / "n1.ssp"), (5, tmp_path / "n5.ssp")):
        assert main(["ssp", "export", "fig11", "--steps-per-period", str(n),
                     "--out", str(out)]) == 0
        read_ssd(str(out), validate=True)
        assert read_package(out).step_size_s == period / n
        with zipfile.ZipFile(out) as zf:
            doc = minidom.parseString(zf.read("SystemStructure.ssd"))
        (oms,) = doc.getElementsByTagName("oms:FixedStepMaster")
        assert float(oms.getAttribute("stepSize")) == period / n
    capsys.readouterr()
    assert main(["ssp", "export", "fig11", "--steps-per-period", "0",
                 "--out", str(tmp_path / "n0.ssp")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--steps-per-period" in err[0] and "from 1 to 100" in err[0], err
    assert not (tmp_path / "n0.ssp").exists()


def test_every_master_run_to_the_stop_time_ends_where_wmr_run_stopped(
        built: BuildResult, ssp_dir: Path) -> None:
    """After its ``converged`` sample the controller FMU asks the master to stop (FMI 3
    terminateSimulation, FMI 2 fmi2Terminated) and, for the masters here that step on to the
    package's stop time (all of them), brakes the wheels to zero speed: the robot ends within
    the bars of ``wmr run``'s final pose (it kept regulating: 20.8 mm and 0.45 deg off)."""
    from fmpy.ssp.simulation import simulate_ssp

    from wmr.adapters.ssp.package import fmpy_parameter_set

    spec = _spec("fig11", None)
    end = _wmr_run(spec, built.fmus[2])[-1]
    finals: dict[str, npt.NDArray[np.float64]] = {}
    # stepped at the control period: the brake is the controller's, whatever the step, and
    # 120 s at the default step are four times the steps
    package2 = _export(built, spec, ssp_dir, fmi=2, steps_per_period=1)
    finals["libcosim"] = simulate_libcosim(package2, stop_at_convergence=False).block[-1, :3]
    for fmi in (2, 3):
        run = simulate_ecos(_export(built, spec, ssp_dir, fmi=fmi, steps_per_period=1),
                            stop_at_convergence=False)
        finals[f"ecos-fmi{fmi}"] = run.block[-1, :3]
    package = read_package(package2)
    out = simulate_ssp(str(package2), stop_time=package.stop_time_s,
                       step_size=package.step_size_s, parameter_set=fmpy_parameter_set(package))
    assert out["time"][-1] >= 119.0  # fmpy too ran to the stop time
    finals["fmpy"] = np.array([out["robot.x"][-1], out["robot.y"][-1], out["robot.theta"][-1]])
    for master, pose in finals.items():
        dist = math.hypot(pose[0] - end[0], pose[1] - end[1])
        assert dist <= POSITION_TOL_M and abs(pose[2] - end[2]) <= HEADING_TOL_RAD, (
            master, dist, math.degrees(pose[2] - end[2]))


def test_the_controller_fmu_asks_the_master_to_stop_after_its_converged_sample(
        built: BuildResult) -> None:
    """FMI 3: doStep's terminateSimulation; FMI 2: fmi2GetBooleanStatus(fmi2Terminated)."""
    import ctypes

    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave, fmi2Terminated
    from fmpy.fmi3 import FMU3Slave

    spec = _spec("fig11", None)
    values = controller_parameters(spec)
    goal = {"x": spec.goal.x_m, "y": spec.goal.y_m, "theta": spec.goal.heading_rad}
    for fmi in (2, 3):
        path = built.controllers[fmi]
        md = read_model_description(str(path))
        vr = {v.name: v.valueReference for v in md.modelVariables}
        cls = FMU2Slave if fmi == 2 else FMU3Slave
        slave = cls(guid=md.guid if fmi == 2 else md.instantiationToken,
                    unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="c")
        slave.instantiate()
        if fmi == 2:
            slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        names = [*values, *goal]
        refs = [vr[n] for n in names]
        vals = [*values.values(), *goal.values()]
        (slave.setReal if fmi == 2 else slave.setFloat64)(refs, vals)
        slave.exitInitializationMode()
        get = slave.getReal if fmi == 2 else slave.getFloat64
        h, requested, converged_at = spec.period_s, [], None
        for n in range(4):  # at the goal, at rest: alignment at sample 0, converged at 1
            converged = get([vr["converged"]])[0] == 1.0
            if converged and converged_at is None:
                converged_at = n
            if fmi == 3:
                requested.append(bool(slave.doStep(n * h, h)[1]))
            else:
                slave.doStep(n * h, h)
                flag = ctypes.c_int()
                slave.fmi2GetBooleanStatus(slave.component, fmi2Terminated, ctypes.byref(flag))
                requested.append(bool(flag.value))
        assert converged_at == 1, fmi
        assert requested == [False, True, True, True], (fmi, requested)
        assert get([vr["tau_r"], vr["tau_l"], vr["converged"]])[2] == 1.0
        slave.terminate()
        slave.freeInstance()


def _short_spec() -> RunSpec:
    """Fig. 11's robot and gains to a near goal (1, 0.5, 30 deg): about 6 s, 585 steps; a stop
    time of 12 s (fmpy runs a package to its stop time: at a quarter of the period, 120 s
    were 48000 steps)."""
    from wmr.config.scenario import Overrides, with_overrides
    from wmr.core.plant import Pose

    spec = with_overrides(_spec("fig11", None),
                          Overrides(goal=Pose(1.0, 0.5, math.radians(30.0)), max_time_s=12.0))
    return replace(spec, name="short")


@pytest.mark.parametrize("fmi", [2, 3])
def test_wmr_ssp_check_has_a_row_per_master_against_wmr_run_of_the_package_s_own_run(
        built: BuildResult, ssp_dir: Path, fmi: int,
        capsys: pytest.CaptureFixture[str]) -> None:
    """``wmr ssp check`` runs ``wmr run`` of the package's provenance scenario and the package
    in each master; a row's figures are those of the agreement helpers on the same runs, and a
    master that cannot load the package (FMI 3 in libcosim and fmpy) is a row saying so."""
    from wmr.apps.ssp_check import check_package

    spec = _short_spec()
    package = _export(built, spec, ssp_dir, fmi=fmi)
    report = check_package(package)
    status, ref = wmr_run_path(spec, built.fmus[fmi])
    assert status == "converged"
    assert report.name == "short" and report.reference.said.startswith("converged")
    rows = {r.master.split()[0]: r for r in report.rows}
    assert list(rows) == ["libcosim", "ecos", "fmpy", "omsimulator"]
    expected = {"ecos": simulate_ecos(package).block[:, :3]}
    if fmi == 2:
        expected["libcosim"] = simulate_libcosim(package).block[:, :3]
        expected["fmpy"] = fmpy_path(package, spec.t_max_s)[1]
    else:
        for master in ("libcosim", "fmpy"):
            assert not rows[master].ran and rows[master].agrees is None
            assert "cannot load it" in rows[master].said and "FMI 3.0" in rows[master].said
    for master, path in expected.items():
        row = rows[master]
        lag = measured_lag(path, ref)
        pos, head = deviation(path, ref, lag)
        assert row.ran and row.said == "ok" and row.lag_steps == lag, row
        assert row.worst_distance_mm == pytest.approx(pos * 1e3, rel=1e-12)
        assert row.worst_heading_deg == pytest.approx(math.degrees(head), rel=1e-12)
        assert row.final_distance_mm == pytest.approx(
            1e3 * math.hypot(*(path[-1, :2] - ref[-1, :2])), rel=1e-9, abs=1e-9)
        assert row.converged_at_s == pytest.approx(len(ref) * spec.period_s, abs=0.05)
        assert row.agrees
    # not run where it is not importable, within the bars where it is
    # (tests/test_ssp_omsimulator.py)
    assert rows["omsimulator"].agrees is not False, rows["omsimulator"]
    assert report.agrees
    assert main(["ssp", "check", str(package)]) == 0
    out = capsys.readouterr().out
    table = out.splitlines()
    assert table[1].split()[:2] == ["master", "FMI"] and table[2].startswith("wmr run")
    assert "within 5 mm and 0.2 deg of wmr run: " in table[-1] and "NOT" not in table[-1]


def test_wmr_ssp_check_shows_a_failing_master_as_a_row_and_exits_1(
        built: BuildResult, ssp_dir: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A master that raises is its row ("failed: ..."), the others still run, and the exit
    status is 1 with the verdict naming it; ``--json`` prints the same rows."""
    from wmr.apps import ssp_check
    from wmr.infra.errors import FmuError

    package = _export(built, _short_spec(), ssp_dir, fmi=2)

    def broken(ssp: Path, pkg: object) -> ssp_check.MasterRun:
        raise FmuError("Ecos failed at t = 1.5 s: an FMU returned an error\nsecond line")

    monkeypatch.setitem(ssp_check.MASTERS, "ecos", broken)
    assert main(["ssp", "check", str(package)]) == 1
    out = capsys.readouterr().out.splitlines()
    (ecos,) = [line for line in out if line.startswith("ecos")]
    assert ecos.endswith("failed: Ecos failed at t = 1.5 s: an FMU returned an error")
    assert "NOT within: ecos (failed)" in out[-1] and "libcosim, fmpy" in out[-1]
    assert main(["ssp", "check", str(package), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["agrees"] is False
    rows = {r["master"].split()[0]: r for r in report["rows"]}
    assert rows["ecos"]["agrees"] is False and rows["libcosim"]["agrees"] is True


def test_wmr_ssp_check_exits_1_when_a_master_is_over_the_bar(
        built: BuildResult, ssp_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Fig. 11 in fmpy stepped at the control period (a package exported with
    --steps-per-period 1): 0.244 deg of heading over the 0.2 deg bar (docs/ssp.md), so the
    check says so and fails, while libcosim and Ecos agree."""
    package = _export(built, _spec("fig11", None), ssp_dir, fmi=2, steps_per_period=1)
    assert main(["ssp", "check", str(package)]) == 1
    verdict = capsys.readouterr().out.splitlines()[-1]
    assert verdict.startswith("within 5 mm and 0.2 deg of wmr run: libcosim, ecos")
    assert "NOT within: fmpy (worst heading 0.244 deg)" in verdict


def test_wmr_ssp_check_refuses_a_package_without_its_scenario_in_one_line(
        built: BuildResult, ssp_dir: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    good = _export(built, _short_spec(), ssp_dir, fmi=2)
    bad = tmp_path / "noscenario.ssp"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(bad, "w") as dst:
        for item in src.infolist():
            if not item.filename.endswith(".toml"):
                dst.writestr(item, src.read(item))
    assert main(["ssp", "check", str(bad)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "carries 0 scenario files" in err, err
    assert "wmr ssp export" in err


def test_wmr_ssp_check_json_prints_the_json_line_alone(built: BuildResult,
                                                       ssp_dir: Path) -> None:
    """What the masters' C libraries print goes to standard error: standard output is the
    report, one JSON line, in a process of its own (fd 1 as a user's shell sees it)."""
    package = _export(built, _short_spec(), ssp_dir, fmi=2)
    proc = _cli("ssp", "check", str(package), "--json")
    assert proc.returncode == 0, proc.stderr
    (line,) = proc.stdout.splitlines()
    report = json.loads(line)
    assert report["agrees"] is True and report["name"] == "short"
    assert [r["master"].split()[0] for r in report["rows"]] == \
        ["libcosim", "ecos", "fmpy", "omsimulator"]


def _variant_spec() -> RunSpec:
    """A short run that is not the FMUs' compiled-in one (Fig. 11): another start and goal."""
    from wmr.config.scenario import Overrides, with_overrides
    from wmr.core.plant import Pose

    spec = with_overrides(_spec("fig11", None),
                          Overrides(start=Pose(0.5, -0.3, math.radians(170.0)),
                                    goal=Pose(-1.0, 0.5, math.radians(-60.0))))
    return replace(spec, name="variant")


def test_a_master_that_applies_no_parameter_set_runs_the_package_s_own_run(
        built: BuildResult, ssp_dir: Path) -> None:
    """fmpy's ``simulate_ssp`` without a parameter set and Ecos with the set unnamed apply no
    parameter binding: they ran the FMUs' compiled-in Fig. 11 (issue 32: the variant --start 3
    -2 170 --goal -4 5 -60 ended 24.5 m from its goal).  The package's FMUs now carry the run's
    start values (resources/start_values.txt, read by their C at instantiation, and their
    model descriptions' start): the same path, bit for bit, as with the parameters applied."""
    from fmpy.ssp.simulation import simulate_ssp

    from wmr.adapters.ssp.ecos import _ecospy
    from wmr.adapters.ssp.package import fmpy_parameter_set, unpacked_package

    spec = _variant_spec()
    # stepped at the control period, as the bare runs below are
    package = _export(built, spec, ssp_dir, fmi=2, steps_per_period=1)
    stop_s = 12.0
    bare = simulate_ssp(str(package), stop_time=stop_s, step_size=spec.period_s)
    applied = simulate_ssp(str(package), stop_time=stop_s, step_size=spec.period_s,
                           parameter_set=fmpy_parameter_set(read_package(package)))
    for name in ("robot.x", "robot.y", "robot.theta", "controller.converged"):
        assert np.array_equal(bare[name], applied[name]), name
    assert bare["controller.converged"][-1] == 1.0
    end = math.hypot(bare["robot.x"][-1] - spec.goal.x_m, bare["robot.y"][-1] - spec.goal.y_m)
    assert end <= spec.stop_radius_m, end
    ecospy = _ecospy()
    for fmi in (2, 3):
        named = simulate_ecos(_export(built, spec, ssp_dir, fmi=fmi, steps_per_period=1))
        with unpacked_package(_export(built, spec, ssp_dir, fmi=fmi, steps_per_period=1)) \
                as (_, folder):
            sim = ecospy.EcosSimulation(spec.period_s, ssp_path=str(folder))
            try:
                assert sim.init(0.0)  # no parameter set name: Ecos applies no binding
                xs = [sim.get_real("robot::x")]
                for _ in range(len(named.block) - 1):
                    sim.step(1)
                    xs.append(sim.get_real("robot::x"))
                sim.terminate()
            finally:
                sim.free()
        assert np.array_equal(np.array(xs), named.block[:, 0]), fmi


@pytest.mark.parametrize(("line", "expected"), [
    ("nosuch = 1.0", "nosuch is not a parameter of wmr_robot"),
    ("x = 1.0", "x is not a parameter of wmr_robot"),
    ("x0 = 1.0", "x0: the value is not the bits (0x...) of a finite number"),
    ("x0 = 0x7ff8000000000000", "x0: the value is not the bits (0x...) of a finite number"),
    ("x0 0x0", 'not "name = 0xBITS"'),
])
def test_start_values_an_fmu_cannot_use_refuse_the_instance(
        built: BuildResult, tmp_path: Path, line: str, expected: str) -> None:
    """An FMU whose resources/start_values.txt it cannot apply does not start (fmi2Instantiate
    returns NULL and logs the file, line and variable): it would run other parameters than
    its package's.  A good file is applied (the robot starts where it says)."""
    import ctypes

    import fmpy.fmi2 as fmi2
    from fmpy import extract, read_model_description

    md = read_model_description(str(built.fmus[2]))
    folder = Path(extract(str(built.fmus[2]), unzipdir=str(tmp_path / "fmu")))
    (folder / "resources").mkdir(exist_ok=True)
    messages: list[tuple[int, str]] = []

    def logger(_env: object, _name: bytes, status: int, _cat: bytes, message: bytes) -> None:
        messages.append((status, message.decode()))

    callbacks = fmi2.fmi2CallbackFunctions()
    callbacks.logger = fmi2.fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2.defaultCallbacks.allocateMemory
    callbacks.freeMemory = fmi2.defaultCallbacks.freeMemory
    fmi2.addLoggerProxy(ctypes.byref(callbacks))  # fmpy's: formats the FMU's varargs

    def slave() -> fmi2.FMU2Slave:
        s = fmi2.FMU2Slave(guid=md.guid, unzipDirectory=str(folder),
                           modelIdentifier=md.coSimulation.modelIdentifier, instanceName="r")
        s.instantiate(callbacks=callbacks)
        return s

    # the bits of -0.25, and a comment (as wmr ssp export writes it)
    (folder / "resources" / "start_values.txt").write_text("y0 = 0xbfd0000000000000  # -0.25")
    good = slave()
    good.setupExperiment(startTime=0.0)
    good.enterInitializationMode()
    good.exitInitializationMode()
    vr = {v.name: v.valueReference for v in md.modelVariables}
    assert good.getReal([vr["y"]]) == [-0.25]
    good.terminate()
    good.freeInstance()
    (folder / "resources" / "start_values.txt").write_text(f"y0 = 0x0\n{line}\n")
    messages.clear()
    with pytest.raises(Exception, match="instantiate"):
        slave()
    errors = [m for status, m in messages if status == 3]  # fmi2Error
    assert len(errors) == 1 and expected in errors[0], errors
    assert "start_values.txt line 2" in errors[0], errors
