"""``wmr run --fmu OTHER --map FILE``: a robot FMU our build did not make, in its own units.

The other FMU is ``tests/other_fmus/CompassUnicycle.py`` packaged by ``pythonfmu``: a dynamic
unicycle with a compass heading in degrees, positions in mm, wheel speeds in rpm and torques
in N.cm, mapped by ``tests/other_fmus/compass_unicycle.toml``.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.fmi.varmap import load_map, parse_map
from wmr.adapters.mcap.reader import read_run
from wmr.build.fmus import BuildResult
from wmr.cli import main
from wmr.core.plant import OUTPUT_NAMES, Pose, RobotParams
from wmr.core.runlog import MemoryLog
from wmr.infra.errors import ConfigError

OTHER = Path(__file__).parent / "other_fmus"
MAP = OTHER / "compass_unicycle.toml"


@pytest.fixture(scope="session")
def unicycle_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """CompassUnicycle.fmu, packaged by pythonfmu (FMI 2.0 co-simulation)."""
    from pythonfmu import FmuBuilder

    out = tmp_path_factory.mktemp("pythonfmu")
    return Path(FmuBuilder.build_FMU(OTHER / "CompassUnicycle.py", dest=out))


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, dict[str, object]]:
    code = main(["run", *args, "--json"])
    return code, json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_the_stabiliser_converges_on_a_pythonfmu_unicycle(
        tmp_path: Path, unicycle_fmu: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "u.mcap"
    code, rec = _run(["--fmu", str(unicycle_fmu), "--map", str(MAP), "--out", str(out)], capsys)
    assert code == 0 and rec["status"] == "converged"
    assert isinstance(rec["final_position_error_m"], float)
    assert rec["final_position_error_m"] < 0.05  # the stop radius
    log = read_run(out)
    # the log is in our units: the start at the origin heading east, the end at the goal
    assert log.signals["theta_rad"][0] == pytest.approx(0.0, abs=1e-12)
    assert abs(log.signals["x_m"][-1] - 20.0) < 0.05
    assert abs(log.signals["y_m"][-1] - 10.0) < 0.05
    assert abs(log.signals["theta_rad"][-1]) < math.radians(0.5)
    assert np.isnan(log.signals["phi_r_rad"]).all()  # unmapped: NaN, never a made-up value
    recorded = json.loads(log.metadata["run"]["fmu_map"])
    assert recorded["variables"]["theta"]["name"] == "heading_deg"


def test_the_map_converts_every_unit(unicycle_fmu: Path) -> None:
    """Start pose in, outputs out, torques in: each through its own scale and offset."""
    params = RobotParams(r=0.2, L=0.25)
    j_kgm2, b_nms = 0.3, 0.05  # the unicycle's own wheel inertia and friction
    with FmuPlant(unicycle_fmu, var_map=load_map(MAP)) as plant:
        out = plant.reset(params, Pose(1.5, -2.0, math.radians(30.0)))
        assert out[:3] == pytest.approx([1.5, -2.0, math.radians(30.0)], abs=1e-12)
        tau_r, tau_l, h = 2.0, -1.0, 0.5
        out = plant.step(tau_r, tau_l, h)
        # each wheel: J dw/dt = tau - b w from rest
        w_r, w_l = (tau / b_nms * -math.expm1(-b_nms * h / j_kgm2) for tau in (tau_r, tau_l))
        got = dict(zip(OUTPUT_NAMES, out.tolist(), strict=True))
        assert got["omega_r"] == pytest.approx(w_r, rel=1e-9)
        assert got["omega_l"] == pytest.approx(w_l, rel=1e-9)
        # the map's r and L reached the FMU (eq. 28 kinematics with r = 0.2, L = 0.25)
        assert got["v"] == pytest.approx(0.2 * (w_r + w_l) / 2, rel=1e-9)
        assert got["omega"] == pytest.approx(0.2 * (w_r - w_l) / 0.5, rel=1e-9)
        assert got["theta"] > math.radians(30.0)  # right wheel faster: counter-clockwise
        assert np.isnan(out[OUTPUT_NAMES.index("E_kin")])


def test_an_identity_map_gives_our_fmu_bit_for_bit(tmp_path: Path, built: BuildResult) -> None:
    """Naming our own variables through a map changes nothing."""
    identity = parse_map({"variables": {n: {"name": n, "scale": 1.0} for n in
                                        ("tau_r", "tau_l", "x", "theta", "m")}})
    start = Pose(0.0, 0.0, 0.3)
    rows = []
    for var_map in (None, identity):
        with FmuPlant(built.fmus[2], var_map=var_map) as plant:
            plant.reset(RobotParams(), start)
            rows.append(np.array([plant.step(1.0, 0.5, 0.01).copy() for _ in range(50)]))
    assert np.array_equal(rows[0], rows[1])


def _bad_map(tmp_path: Path, old: str, new: str) -> Path:
    text = MAP.read_text()
    assert old in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(old, new, 1))
    return p


@pytest.mark.parametrize(("old", "new", "expected"), [
    ('"heading_deg"', '"heading"', ["variables.theta", "no variable 'heading'", "heading_deg"]),
    ('x = { name = "east_mm"', 'x = { name = "torque_R_Ncm"',
     ["variables.x", "causality 'input'", "needs causality 'output'", "east_mm"]),
    ('omega_l = { name = "wheel_L_rpm", scale = 0.10471975511965977 }', "",
     ["variable omega_l", "no output named 'omega_l'", "add omega_l"]),
    ('x = { name = "east_mm"', 'x = { name = "moving"',
     ["variables.x", "'moving' is of type Integer", "Real"]),
    ('r = { name = "wheel_radius_mm"', 'r = { name = "wheel_R_rpm"',
     ["variables.r", "causality 'output'", "needs causality 'parameter'"]),
    ('"E_kin", ', "", ["variable E_kin", "unmapped"]),
    ('tau_l = { name = "torque_L_Ncm", scale = 0.01 }', 'tau_l = { name = "torque_R_Ncm" }',
     ["tau_l", "same FMU variable"]),
    ('unmapped = ["phi_r"', 'unmapped = ["x", "phi_r"', ["unmapped", "x cannot be left unmapped"]),
    ('[variables]', '[variables]\nspeed = "speed_kmh"', ["variables.speed", "interface names"]),
    ('scale = 0.001 }                    # mm', 'scale = 0 }  # mm',
     ["variables.x.scale", "must not be 0"]),
])
def test_a_bad_map_is_one_line_naming_the_variable(
        tmp_path: Path, unicycle_fmu: Path, capsys: pytest.CaptureFixture[str], old: str,
        new: str, expected: list[str]) -> None:
    out = tmp_path / "u.mcap"
    code = main(["run", "--fmu", str(unicycle_fmu), "--map", str(_bad_map(tmp_path, old, new)),
                 "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 1 and len(err.splitlines()) == 1, err
    for part in expected:
        assert part in err, (part, err)
    assert not out.exists()


def test_unmapped_in_the_wrong_table_says_where_it_goes() -> None:
    with pytest.raises(ConfigError, match="move the unmapped"):
        parse_map({"variables": {"unmapped": ["phi_r"]}})


def test_a_scenario_names_the_fmu_and_its_map(tmp_path: Path, unicycle_fmu: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """``fmu`` and ``fmu_map`` in a scenario file, relative to the file."""
    shutil.copy(unicycle_fmu, tmp_path / "robot.fmu")
    shutil.copy(MAP, tmp_path / "robot.toml")
    scenario = tmp_path / "other.toml"
    scenario.write_text('start = [0.0, 0.0, 0.0]\ngoal = [3.0, 2.0, 0.0]\n'
                        'fmu = "robot.fmu"\nfmu_map = "robot.toml"\n')
    code, rec = _run([str(scenario), "--out", str(tmp_path / "s.mcap")], capsys)
    assert code == 0 and rec["status"] == "converged"
    assert json.loads(read_run(tmp_path / "s.mcap").metadata["run"]["fmu_map"])["source"] \
        .endswith("robot.toml")


def test_the_documented_map_is_the_tested_one() -> None:
    """docs/fmu_map.md shows the map these tests run: same entries, same unmapped names."""
    import re
    import tomllib

    doc = (Path(__file__).parents[1] / "docs" / "fmu_map.md").read_text()
    blocks = re.findall(r"```toml\n(.*?)```", doc, flags=re.S)
    documented = [parse_map(tomllib.loads(b)) for b in blocks if "[variables]" in b]
    assert len(documented) == 1
    tested = load_map(MAP)
    assert documented[0].entries == tested.entries
    assert documented[0].unmapped == tested.unmapped
    keys = tomllib.loads(next(b for b in blocks if "fmu_map =" in b))
    assert set(keys) == {"fmu", "fmu_map"}  # the scenario keys the docs name exist
    from wmr.config.scenario import TOP_FIELDS

    assert set(keys) <= set(TOP_FIELDS)


def test_a_batch_spec_names_the_fmu_and_its_map(tmp_path: Path, unicycle_fmu: Path) -> None:
    """The same keys in a batch spec: every run of the batch drives the mapped FMU."""
    from wmr.apps.batch import BatchOptions, load_batch, run_batch

    shutil.copy(unicycle_fmu, tmp_path / "robot.fmu")
    shutil.copy(MAP, tmp_path / "robot.toml")
    spec = tmp_path / "batch.toml"
    spec.write_text('start = [0.0, 0.0, 0.0]\ngoal = [2.0, 1.0, 0.0]\n'
                    'fmu = "robot.fmu"\nfmu_map = "robot.toml"\n'
                    '[[list]]\nname = "a"\ngoal = [2.0, 1.0, 0.0]\n'
                    '[[list]]\nname = "b"\ngoal = [1.0, -2.0, 90.0]\n')
    result = run_batch(load_batch(spec), tmp_path / "out", BatchOptions(workers=1), progress=False)
    assert result.counts["converged"] == 2
    for log in (tmp_path / "out" / "runs").glob("*.mcap"):
        meta = read_run(log).metadata["run"]
        assert meta["fmu_file"] == "robot.fmu"
        assert json.loads(meta["fmu_map"])["variables"]["x"]["name"] == "east_mm"


def test_an_ssp_of_the_other_fmu_runs_in_libcosim_with_its_units(
        tmp_path: Path, unicycle_fmu: Path, built: BuildResult) -> None:
    """``wmr ssp export --map``: the map's conversions become SSP linear transformations on
    the connections and its parameters the robot's parameter set in its units; libcosim runs
    our controller FMU on the pythonfmu unicycle and traces ``wmr run --map``."""
    from fmpy.ssp.ssd import get_connections, read_ssd

    from wmr.adapters.ssp.agreement import deviation, libcosim_path, wmr_run_path
    from wmr.adapters.ssp.export import export_ssp
    from wmr.adapters.ssp.package import read_package
    from wmr.config.scenario import load_scenario

    spec = next(iter(load_scenario("fig11").runs))
    var_map = load_map(MAP)
    package = export_ssp(spec, tmp_path / "uni.ssp", unicycle_fmu, built.controllers[2],
                         var_map=var_map)
    ssd = read_ssd(str(package), validate=True)
    theta = next(b for a, b in get_connections(ssd.system) if b.name == "theta")
    assert theta.parent.name == "controller"
    carried = read_package(package).robot_map  # the map travels in the package, unchanged
    assert carried is not None
    assert (carried.entries, carried.unmapped) == (var_map.entries, var_map.unmapped)
    robot = read_package(package).components["robot"].parameters
    assert robot["wheel_radius_mm"] == pytest.approx(150.0)
    assert robot["heading0_deg"] == pytest.approx(90.0)  # theta0 = 0: east is 90 deg
    status, ref = wmr_run_path(spec, unicycle_fmu, var_map)
    assert status == "converged"
    ssp_status, path = libcosim_path(package)
    assert ssp_status == "converged"
    pos, head = deviation(path, ref, 0)
    assert pos <= 5e-3 and head <= math.radians(0.2), (pos, math.degrees(head))


#: Our robot's names as another tool's export might spell them (fmu-manipulation-toolbox
#: renames the model description's variables without touching the binary).
_RENAMED = {"tau_r": "drive.torque_right", "tau_l": "drive.torque_left", "x": "body.pos_x",
            "y": "body.pos_y", "theta": "body.yaw", "v": "body.speed", "omega": "body.yaw_rate",
            "omega_r": "wheel_right.w", "omega_l": "wheel_left.w", "r": "wheel.radius",
            "L": "axle.half_track", "x0": "init.x", "y0": "init.y", "theta0": "init.yaw"}


@pytest.mark.parametrize("fmi", [2, 3])
def test_our_robot_renamed_by_fmu_manipulation_toolbox_gives_the_same_path(
        tmp_path: Path, built: BuildResult, fmi: int) -> None:
    """A robot FMU re-exported by another tool (fmu-manipulation-toolbox, renamed
    variables), driven through a map, gives our robot's path bit for bit."""
    from fmu_manipulation_toolbox.operations import FMU, OperationRenameFromCSV

    from wmr.config.scenario import load_scenario
    from wmr.core.closedloop import run_closed_loop
    from wmr.core.control.from_spec import SpecController

    csv_file = tmp_path / "rename.csv"
    csv_file.write_text("".join(f"{a};{b}\n" for a, b in _RENAMED.items()))
    renamed = tmp_path / f"renamed-fmi{fmi}.fmu"
    with FMU(str(built.fmus[fmi])) as fmu:
        fmu.apply_operation(OperationRenameFromCSV(str(csv_file)))
        fmu.repack(str(renamed))
    var_map = parse_map({"variables": dict(_RENAMED)}, source="renamed")
    spec = next(iter(load_scenario("fig11").runs))
    logs = []
    for path, vm in ((built.fmus[fmi], None), (renamed, var_map)):
        sink = MemoryLog()
        with FmuPlant(path, var_map=vm) as plant:
            assert run_closed_loop(spec, plant, sink=sink,
                                   controller=SpecController()).status == "converged"
        logs.append(sink.block)
    assert np.array_equal(logs[0], logs[1])  # every signal of every row
    with pytest.raises(ConfigError, match=r"no input named 'tau_r'.*drive\.torque_right"):
        FmuPlant(renamed)  # without the map: one line naming the variable and the candidates


def test_wmr_ssp_check_of_a_package_of_another_tool_s_robot_uses_only_its_map(
        tmp_path: Path, unicycle_fmu: Path, built: BuildResult) -> None:
    """``wmr ssp check`` of a ``--map`` package: ``wmr run`` of the package's scenario on the
    package's robot FMU through the package's map (the unicycle's names and units, none of
    ours), libcosim within the bars of it, fmpy and OMSimulator rows saying they ignore the
    transformations."""
    from dataclasses import replace

    from wmr.adapters.ssp.agreement import deviation, libcosim_path, wmr_run_path
    from wmr.adapters.ssp.export import export_ssp
    from wmr.apps.ssp_check import check_package
    from wmr.config.scenario import Overrides, load_scenario, with_overrides
    from wmr.core.plant import Pose

    base = next(iter(load_scenario("fig11").runs))
    spec = replace(with_overrides(base, Overrides(goal=Pose(1.0, 0.5, math.radians(30.0)))),
                   name="uni-short")
    var_map = load_map(MAP)
    package = export_ssp(spec, tmp_path / "uni.ssp", unicycle_fmu, built.controllers[2],
                         var_map=var_map)
    report = check_package(package)
    rows = {r.master.split()[0]: r for r in report.rows}
    status, ref = wmr_run_path(spec, unicycle_fmu, var_map)
    assert status == "converged" and report.reference.said.startswith("converged")
    _, path = libcosim_path(package)
    pos, _ = deviation(path, ref, 0)
    lib = rows["libcosim"]
    assert lib.agrees and lib.lag_steps == 0, lib
    assert lib.worst_distance_mm == pytest.approx(pos * 1e3, rel=1e-12)
    assert not rows["fmpy"].ran and "unit transformations" in rows["fmpy"].said
    assert rows["ecos"].agrees, rows["ecos"]  # Ecos applies the transformations too
    # OMSimulator ignores them (1.1 m off where it ran them): not run, or not importable
    oms = rows["omsimulator"]
    assert not oms.ran and oms.agrees is None, oms
    assert "unit transformations" in oms.said or "not importable" in oms.said, oms
