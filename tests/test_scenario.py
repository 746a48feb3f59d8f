"""Scenario files (wmr.config.scenario): loading, expansion, validation naming the field."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import pytest

from wmr.config.scenario import (
    Overrides,
    expand,
    load_scenario,
    parse_scenario,
    resolve_scenario_path,
    with_overrides,
)
from wmr.core.plant import Pose
from wmr.core.runspec import RunSpec
from wmr.infra.errors import ConfigError

BASE: dict[str, Any] = {"name": "t", "start": [0.0, 0.0, 0.0], "goal": [20.0, 10.0, 0.0]}


def test_shipped_scenarios_load() -> None:
    fig11 = load_scenario()  # the default
    assert fig11.name == "fig11"
    (run,) = expand(fig11)
    assert run.start == Pose(0.0, 0.0, 0.0)
    assert run.goal == Pose(20.0, 10.0, 0.0)
    assert run.period_s == 0.01 and run.stop_radius_m == 0.05
    fig9 = expand(load_scenario("fig9"))
    assert len(fig9) >= 7
    heads = sorted(round(math.degrees(r.goal.heading_rad)) for r in fig9)
    assert heads[0] == -90 and heads[-1] == 90
    assert all(r.start == Pose(0.0, 0.0, 0.0) for r in fig9)
    fig10 = expand(load_scenario("fig10"))
    assert len(fig10) >= 8
    for r in fig10:
        assert (r.goal.x_m, r.goal.y_m) == (0.0, 0.0)
        want = math.pi if r.start.x_m >= 0 else 0.0
        assert r.goal.heading_rad == pytest.approx(want)
    assert len({r.name for r in fig10}) == len(fig10)


def test_defaults_and_degrees() -> None:
    (run,) = parse_scenario({**BASE, "goal": [1.0, 2.0, 90.0]}).runs
    assert run.goal.heading_rad == pytest.approx(math.pi / 2)
    assert run.t_max_s == 120.0 and run.period_s == 0.01


def test_unknown_field_names_it_and_lists_the_allowed() -> None:
    with pytest.raises(ConfigError) as err:
        parse_scenario({**BASE, "stop_radius": 0.1})
    assert err.value.field == "stop_radius"
    assert "stop_radius_m" in err.value.fix
    with pytest.raises(ConfigError, match=r"gains\.K_p\b"):
        parse_scenario({**BASE, "gains": {"K_p": 1.0}})
    with pytest.raises(ConfigError, match=r"params\.mass"):
        parse_scenario({**BASE, "params": {"mass": 1.0}})
    with pytest.raises(ConfigError, match=r"runs\[1\]\.goall"):
        parse_scenario({**BASE, "runs": [{}, {"goall": [1, 2, 3]}]})


@pytest.mark.parametrize(("patch", "field"), [
    ({"control_period_s": -0.01}, "control_period_s"),
    ({"control_period_s": 0.0}, "control_period_s"),
    ({"stop_radius_m": math.nan}, "stop_radius_m"),
    ({"max_time_s": math.inf}, "max_time_s"),
    ({"start": [0.0, math.nan, 0.0]}, "start.y_m"),
    ({"goal": [0.0, 1.0]}, "goal"),
    ({"goal": [0.0, 1.0, "north"]}, "goal.heading_deg"),
    ({"gains": {"K_ps": math.inf}}, "gains.K_ps"),
    ({"limits": {"torque_max_nm": -1.0}}, "limits.torque_max_nm"),
    ({"params": {"r": 0.0}}, "params.r"),
    ({"params": {"m": True}}, "params.m"),
    ({"name": ""}, "name"),
    ({"runs": []}, "runs"),
    ({"max_time_s": 0.001}, "max_time_s"),
])
def test_bad_values_name_the_field(patch: dict[str, Any], field: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_scenario({**BASE, **patch})
    assert err.value.field == field
    assert err.value.fix


def test_missing_goal() -> None:
    with pytest.raises(ConfigError) as err:
        parse_scenario({"name": "t", "start": [0, 0, 0]})
    assert err.value.field == "goal"


def test_missing_file_says_what_exists(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as err:
        load_scenario(tmp_path / "nope.toml")
    assert err.value.field == "scenario"
    assert "fig11" in err.value.fix


def test_bad_toml(tmp_path: Path) -> None:
    f = tmp_path / "bad.toml"
    f.write_text("name = \n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_scenario(f)


def test_runs_inherit_and_override(tmp_path: Path) -> None:
    f = tmp_path / "s.toml"
    f.write_text('name = "s"\nstart = [1.0, 2.0, 0.0]\nmax_time_s = 50\n'
                 '[[runs]]\ngoal = [3.0, 4.0, 45.0]\n'
                 '[[runs]]\nname = "b"\nstart = [0.0, 0.0, 10.0]\ngoal = [5.0, 5.0, 0.0]\n'
                 'max_time_s = 10\n')
    a, b = expand(load_scenario(f))
    assert a.name == "s-00" and a.start == Pose(1.0, 2.0, 0.0) and a.t_max_s == 50
    assert b.name == "b" and b.start.heading_rad == pytest.approx(math.radians(10))
    assert b.t_max_s == 10
    assert resolve_scenario_path("fig9").name == "fig9.toml"


def test_with_overrides() -> None:
    (run,) = parse_scenario(BASE).runs
    new = with_overrides(run,
                         Overrides(start=(1.0, 1.0, 90.0), goal=Pose(5.0, 5.0, 0.0),
                                   gains={"K_ps": 0.8}, limits={"torque_max_nm": 5.0},
                                   params={"m": 30.0}, max_time_s=60.0))
    assert new.start.heading_rad == pytest.approx(math.pi / 2)
    assert new.goal == Pose(5.0, 5.0, 0.0)
    assert new.gains.K_ps == 0.8 and new.gains.K_ptheta == run.gains.K_ptheta
    assert new.limits.torque_max_nm == 5.0 and new.params.m == 30.0 and new.t_max_s == 60.0
    assert with_overrides(run) == run
    with pytest.raises(ConfigError, match=r"start\.x_m"):
        with_overrides(run, Overrides(start=(math.nan, 0.0, 0.0)))
    with pytest.raises(ConfigError, match=r"gains\.K_x"):
        with_overrides(run, Overrides(gains={"K_x": 1.0}))
    with pytest.raises(ConfigError, match="control_period_s"):
        with_overrides(run, Overrides(period_s=-1.0))


def test_one_override_object_takes_poses_presets_and_typed_fields() -> None:
    """``Overrides`` (issue 29: one object where with_overrides took 14 keywords): a Pose is
    kept in rad, never read as degrees; a pose of non-numbers is a one-line error naming the
    field; a sensor preset, then fields as a user typed them, go over the run's sensors in
    that order (the step resolve_run did after with_overrides before).  Seen failing with
    ``_sensors`` applying ``sensor`` before the preset, and with a Pose sent through
    ``_pose`` (degrees)."""
    from dataclasses import replace

    from wmr.core.sensing import preset

    (run,) = parse_scenario(BASE).runs
    assert with_overrides(run, Overrides(goal=Pose(1.0, 2.0, 0.5))).goal == Pose(1.0, 2.0, 0.5)
    for bad in (("a", 0.0, 0.0), 3.0):
        with pytest.raises(ConfigError) as err:
            Overrides(start=bad)  # type: ignore[arg-type]
        assert err.value.field == "start"
    gps = with_overrides(run, Overrides(sensors="gps", sensor={"gps_sigma_m": "0.5"}))
    assert gps.sensors == replace(preset("gps"), gps_sigma_m=0.5)
    assert with_overrides(gps, Overrides(sensors="off")).sensors is None
    typed = with_overrides(run, Overrides(sensors={"seed": 3}))
    assert typed.sensors is not None and typed.sensors.seed == 3


def test_runspec_is_frozen_and_validated() -> None:
    spec = RunSpec("x", Pose(0, 0, 0), Pose(1, 1, 0))
    with pytest.raises(AttributeError):
        spec.name = "y"  # type: ignore[misc]
    with pytest.raises(ConfigError, match="control_period_s"):
        RunSpec("x", Pose(0, 0, 0), Pose(1, 1, 0), period_s=0.0)


def test_shipped_files_are_plain_toml() -> None:
    for name in ("fig9", "fig10", "fig11"):
        with resolve_scenario_path(name).open("rb") as fh:
            assert "name" in tomllib.load(fh)


class _CountingName(str):
    """A run name that counts the comparisons made with it."""

    compared = 0

    def __eq__(self, other: object) -> bool:
        _CountingName.compared += 1
        return str.__eq__(self, other)

    __hash__ = str.__hash__


def test_the_duplicate_name_check_is_linear_in_the_runs() -> None:
    # issue 28 item 6: each run's name was compared with every earlier run's (200,000 runs
    # took over 120 s); a lookup compares a name only with an equal-hashed one
    n = 3000
    runs = [{"name": _CountingName(f"r{i}"), "goal": [1.0 + i * 1e-3, 0.0, 0.0]}
            for i in range(n)]
    _CountingName.compared = 0
    scenario = parse_scenario({**BASE, "runs": runs})
    assert [r.name for r in scenario.runs] == [f"r{i}" for i in range(n)]
    assert _CountingName.compared < 10 * n  # the scan made n (n - 1) / 2, 4.5 million
    runs.append({"name": _CountingName("r1234"), "goal": [9.0, 0.0, 0.0]})
    with pytest.raises(ConfigError, match=r"runs\[3000\]\.name: 'r1234' is already the name "
                                          r"of runs\[1234\]"):
        parse_scenario({**BASE, "runs": runs})


def test_a_scenario_of_many_runs_loads_and_still_finds_a_duplicate(tmp_path: Path) -> None:
    n = 20_000
    path = tmp_path / "many.toml"
    text = 'name = "many"\nstart = [0.0, 0.0, 0.0]\ngoal = [1.0, 0.0, 0.0]\n'
    path.write_text(text + "".join(f'[[runs]]\nname = "r{i}"\n' for i in range(n)))
    assert len(load_scenario(path).runs) == n
    with path.open("a") as f:
        f.write('[[runs]]\nname = "r0"\n')
    with pytest.raises(ConfigError, match=rf"runs\[{n}\]\.name: 'r0' is already the name of "
                                          r"runs\[0\]"):
        load_scenario(path)
