"""Issue 21, "Names and places": where the commands write, and what their names and lists say."""

from __future__ import annotations

import argparse
import json
import re
from dataclasses import fields, replace
from pathlib import Path

import pytest

import wmr
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import read_run
from wmr.adapters.mcap.scene import GOAL_TOPIC, PATH_TOPIC, ROBOT_TOPIC
from wmr.adapters.ssp.package import read_package
from wmr.apps.benchmark import run_logged
from wmr.apps.run import LISTED_RUNS, run_to_log
from wmr.build.fmus import BuildResult
from wmr.cli import main
from wmr.cli.run import add_run_overrides
from wmr.config.naming import (
    LISTED_NAMES,
    MAX_SENSOR_CHARS,
    SENSOR_ALIASES,
    name_list,
    run_name,
)
from wmr.config.scenario import load_scenario
from wmr.core.plant import Pose, RobotParams
from wmr.core.sensing.config import SensorConfig, override_sensors
from wmr.infra.errors import ConfigError
from wmr.infra.paths import _REPO_ROOT


def test_param_help_names_every_robot_parameter() -> None:
    """``wmr run --help`` lists every field of ``RobotParams`` under ``--param`` (``w_c`` was
    missing from a hand-written list)."""
    parser = argparse.ArgumentParser()
    add_run_overrides(parser)
    (param,) = [a for a in parser._actions if a.dest == "param"]
    listed = re.search(r"\(([^)]*)\)", param.help or "")
    assert listed is not None, param.help
    assert listed.group(1).split(", ") == [f.name for f in fields(RobotParams)]


def test_api_run_lists_how_many_runs_and_names_them_all() -> None:
    """``wmr.run("fig10")`` says it has 12 runs and names every one: a name cut short cannot
    be given back as ``run=`` (up to ``LISTED_RUNS``; longer lists end in ``...``, below)."""
    names = [r.name for r in load_scenario("fig10").runs]
    assert LISTED_NAMES < len(names) <= LISTED_RUNS  # the old cut would have shortened it
    for kwargs in ({}, {"run": "no-such-run"}):
        with pytest.raises(ConfigError) as info:
            wmr.run("fig10", **kwargs)  # type: ignore[arg-type]
        msg = str(info.value)
        assert f"{len(names)} runs" in msg
        assert "..." not in msg, msg
        assert all(n in msg for n in names)


def test_name_list_shows_a_whole_short_list_without_dots() -> None:
    assert name_list(["a", "b"]) == "its 2 runs: a, b"
    assert name_list(["a"], shown=1) == "its 1 run: a"
    assert name_list(["a", "b"], shown=1) == "its 2 runs: a, ..."


def test_wmr_ssp_export_writes_into_ssp_by_default(
        built: BuildResult, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """``ssp/NAME.ssp`` as ``runs/NAME.mcap``, never into the current folder; a variant
    (another goal, FMI 3) is named as ``wmr run`` names it and leaves the scenario's package."""
    monkeypatch.chdir(tmp_path)
    assert main(["ssp", "export", "fig11"]) == 0
    own = Path("ssp", "fig11.ssp")
    assert capsys.readouterr().out.strip() == str(own)
    package = own.read_bytes()
    assert main(["ssp", "export", "fig11", "--goal", "5", "5", "30", "--fmi", "3"]) == 0
    variant = Path("ssp", "fig11-to_5_5_30deg-fmi3.ssp")
    assert capsys.readouterr().out.strip() == str(variant)
    assert read_package(variant).components["robot"].fmi_version.startswith("3")
    assert own.read_bytes() == package
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ssp"]


def _documented_record_keys() -> list[str]:
    """The keys of the table "The record of a run" of docs/results.md."""
    text = (_REPO_ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    table = text.split("## The record of a run", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `(\w+)` \|", table, flags=re.M)


def test_a_benchmark_log_is_wmr_run_s_log_byte_for_byte(built: BuildResult,
                                                         tmp_path: Path) -> None:
    """``benchmark.run_logged`` is ``run_to_log``: its log is the one ``wmr run`` writes of
    the same run, byte for byte (the documented record of docs/results.md, the effective
    scenario, the scene), and so is its record; before, it wrote a log of its own (no
    scenario, no scene, ``time_to_radius_s`` and ``benchmark_label`` added)."""
    keys = _documented_record_keys()
    assert {"name", "torque_sq_integral_n2m2s", "steps", "mcap"} <= set(keys)
    spec = replace(load_scenario("fig11").runs[0], t_max_s=0.5)
    path = tmp_path / "run.mcap"
    with FmuPlant(built.fmus[3]) as plant:
        bench, t_radius_s = run_logged(spec, plant, path)
        by_benchmark = path.read_bytes()
        own = run_to_log(spec, path, plant)
        unlogged, _ = run_logged(spec, plant, None)
    assert path.read_bytes() == by_benchmark
    assert list(own) == keys  # the one record of both paths is the documented one
    assert json.dumps(bench) == json.dumps(own) == json.dumps({**unlogged, "mcap": str(path)})
    assert t_radius_s is None  # 0.5 s of a 22 m manoeuvre: never inside the radius


def _topics(path: Path) -> set[str]:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return {c.topic for c in make_reader(f).get_summary().channels.values()}


#: The drawable topics every log of a robot path carries (wmr.adapters.mcap.scene).
SCENE_TOPICS = {ROBOT_TOPIC, PATH_TOPIC, GOAL_TOPIC}


def test_an_ssp_log_holds_the_documented_record_and_the_scene(built: BuildResult,
                                                             tmp_path: Path) -> None:
    """``wmr ssp run``'s record is the record of a run, then ``master``; its log draws."""
    from wmr.adapters.ssp.cosim import log_ssp_run, simulate_libcosim
    from wmr.adapters.ssp.export import export_ssp

    keys = _documented_record_keys()
    spec = load_scenario("fig11").runs[0]
    package = export_ssp(spec, tmp_path / "fig11.ssp", built.fmus[2], built.controllers[2])
    record = log_ssp_run(simulate_libcosim(package, stop_time_s=1.0), tmp_path / "ssp.mcap")
    assert list(record) == [*keys, "master"]
    log = read_run(tmp_path / "ssp.mcap")
    assert record["torque_sq_integral_n2m2s"] > 0.0 and record["steps"] == log.n_steps
    assert list(log.metadata["result"]) == list(record)
    assert SCENE_TOPICS <= _topics(tmp_path / "ssp.mcap")


def test_an_optimal_log_holds_the_documented_record_and_the_scene(built: BuildResult,
                                                                 tmp_path: Path) -> None:
    """``wmr optimal``'s record is the record of a run (its figures the FMU replay's), then
    its own fields; its log holds the record (but the ``limits`` table) and draws."""
    from wmr.adapters.ocp import OptimalProblem
    from wmr.apps.optimal import optimal_limits, optimal_to_log

    keys = _documented_record_keys()
    out = tmp_path / "o.mcap"
    problem = OptimalProblem(Pose(0.0, 0.0, 0.0), Pose(2.0, 1.0, 0.0), limits=optimal_limits())
    record = optimal_to_log(problem, out, built.fmus[3], name="o")
    assert record["status"] == "solved"
    assert list(record)[:len(keys)] == keys
    logged = read_run(out).metadata["result"]
    assert list(logged) == [k for k in record if k != "limits"]
    assert logged["torque_sq_integral_n2m2s"] == str(record["torque_sq_integral_n2m2s"])
    assert SCENE_TOPICS <= _topics(out)


def _sensors_name(preset: str | None, *items: str) -> str:
    base = load_scenario("fig11").runs[0]
    spec = replace(base, sensors=override_sensors(base.sensors, preset, list(items)))
    return run_name(base, spec)


#: ``wmr run --sensors ... --sensor ...`` cases: all differ in their sensors.
SENSOR_CASES: list[tuple[str | None, tuple[str, ...]]] = [
    ("gps", ()), ("raw", ()), (None, ("gps_sigma_m=0.05",)),
    ("gps", ("gps_sigma_m=0.1",)), ("gps", ("gps_sigma_m=0.1", "estimator=none",
                                            "heading=compass")),
    *(("gps", ("seed=3", "gps_rate_hz=5", "gps_dropout_probability=0.1",
               "wheel_radius_error_frac=0.01", "odometry_noise_m2_per_m=0.001",
               f"initial_heading_sigma_deg={deg}")) for deg in (2, 3)),
]


def test_a_sensors_run_has_a_short_readable_name() -> None:
    """``wmr run --sensors gps`` is ``fig11-sensors_gps``, not the 104 characters of every
    field in full (``fig11-sensors-estimator=ekf-gps_latency_s=0.05-...``), which Rerun's
    entity paths escaped."""
    rerun = pytest.importorskip("rerun")
    assert _sensors_name("gps") == "fig11-sensors_gps"
    assert rerun.escape_entity_path_part("fig11-sensors_gps") == "fig11-sensors_gps"
    assert _sensors_name(None, "gps_sigma_m=0.05") == "fig11-sensors-gps_sd=0.05"
    for preset, items in SENSOR_CASES:
        assert len(_sensors_name(preset, *items)) <= len("fig11-") + MAX_SENSOR_CHARS


def test_sensors_run_names_stay_unique() -> None:
    """Every case its own name: the two long ones differ past the cut, in a field the name
    no longer spells out, and only the hash tells them apart."""
    names = [_sensors_name(preset, *items) for preset, items in SENSOR_CASES]
    assert len(set(names)) == len(names), names
    numeric = [f.name for f in fields(SensorConfig)
               if f.name not in ("estimator", "heading", "gps_dropout_windows")]
    one_field = {_sensors_name(None, "estimator=ekf"),
                 *(_sensors_name(None, f"{name}={0.25 if 'frac' in name or 'prob' in name else 2}")
                   for name in numeric)}
    assert len(one_field) == len(numeric) + 1


def test_every_sensor_field_has_one_short_alias() -> None:
    assert list(SENSOR_ALIASES) == [f.name for f in fields(SensorConfig)]
    assert len(set(SENSOR_ALIASES.values())) == len(SENSOR_ALIASES)
