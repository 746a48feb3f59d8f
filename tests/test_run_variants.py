"""Issue 11, defects 1 and 2: a variant run gets its own name and log, and its log attaches
the effective scenario that repeats it exactly."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from wmr.adapters.mcap import read_run
from wmr.cli import main
from wmr.config.naming import MAX_NAME_CHARS, fmu_tokens, run_name
from wmr.config.scenario import Overrides, load_scenario, with_overrides
from wmr.config.scenario_file import run_spec_toml


def _run_json(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict[str, object]]:
    code = main(["run", *args, "--json"])
    last = capsys.readouterr().out.strip().splitlines()[-1]
    return code, json.loads(last)


@pytest.mark.parametrize(("override", "token"), [
    ({"params": {"m": 40.0}}, "m=40"),
    ({"gains": {"K_ps": 0.3}}, "K_ps=0.3"),
    ({"limits": {"torque_max_nm": 6.0}}, "torque_max_nm=6"),
    ({"period_s": 0.02}, "period=0.02"),
    ({"stop_radius_m": 0.1}, "stop=0.1"),
    ({"max_time_s": 60.0}, "tmax=60"),
    ({"heading_tolerance_deg": 1.0}, "htol=1deg"),
    ({"start": (1.0, 2.0, 45.0)}, "from_1_2_45deg"),
    ({"goal": (5.0, 5.0, 30.0)}, "to_5_5_30deg"),
    ({"controller": "astolfi"}, "astolfi"),
])
def test_every_override_names_the_run(override: dict[str, object], token: str) -> None:
    base = load_scenario("fig11").runs[0]
    spec = with_overrides(base, Overrides(**override))  # type: ignore[arg-type]
    assert run_name(base, spec) == f"fig11-{token}"


def test_an_unchanged_run_keeps_its_name_and_long_names_stay_apart() -> None:
    base = load_scenario("fig11").runs[0]
    assert run_name(base, with_overrides(base, Overrides(goal=(20.0, 10.0, 0.0)))) == "fig11"
    assert run_name(base, base, fmu_tokens(2, None)) == "fig11-fmi2"  # (wmr run: file only)
    assert run_name(base, base, fmu_tokens(3, "other/plant.fmu")) == "fig11-fmu_plant"
    a = with_overrides(base,
                       Overrides(gains={k: 0.123456789 for k in base.gains.as_dict()},
                                 limits={"torque_max_nm": 5.0}, params={"m": 30.0}))
    b = with_overrides(a, Overrides(params={"m": 31.0}))
    na, nb = run_name(base, a), run_name(base, b)
    assert len(na) <= MAX_NAME_CHARS and len(nb) <= MAX_NAME_CHARS and na != nb


def test_a_variant_run_does_not_overwrite_the_baseline_log(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    _, base = _run_json(capsys, "--max-time", "1")
    _, variant = _run_json(capsys, "--max-time", "1", "--param", "m=40", "--fmi", "2")
    assert base["mcap"] == str(Path("runs/fig11-tmax=1.mcap"))
    assert variant["mcap"] == str(Path("runs/fig11-m=40-tmax=1-fmi2.mcap"))
    assert variant["name"] == "fig11-m=40-tmax=1"  # the FMI version names the file, not the run
    assert json.loads(read_run(str(base["mcap"])).metadata["run"]["params"])["m"] == 25.0
    assert json.loads(read_run(str(variant["mcap"])).metadata["run"]["params"])["m"] == 40.0


def test_the_log_attaches_the_effective_scenario_that_repeats_the_run_bit_for_bit(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    first = tmp_path / "o.mcap"
    code, rec = _run_json(capsys, "--param", "m=40", "--gain", "K_ps=0.3", "--goal", "5", "5",
                          "30", "--limit", "torque_max_nm=7", "--period", "0.02",
                          "--out", str(first))
    assert code == 0
    log = read_run(first)
    toml = log.attachments[f"{rec['name']}.toml"]
    assert "fig11.toml" not in log.attachments
    (tmp_path / "effective.toml").write_bytes(toml)
    again = tmp_path / "again.mcap"
    code2, rec2 = _run_json(capsys, str(tmp_path / "effective.toml"), "--out", str(again))
    assert code2 == 0 and rec2["name"] == rec["name"]
    log2 = read_run(again)
    assert np.array_equal(log.t_ns, log2.t_ns)
    assert log.block().tobytes() == log2.block().tobytes()  # bit for bit, NaNs included
    run, run2 = log.metadata["run"], log2.metadata["run"]
    for key in ("params", "gains", "limits", "goal", "start", "control_period_s", "name"):
        assert run[key] == run2[key]
    assert json.loads(run["params"])["m"] == 40.0 and json.loads(run["gains"])["K_ps"] == 0.3
    assert log2.attachments[f"{rec['name']}.toml"] == toml


def test_the_effective_scenario_reads_back_into_the_same_run_for_every_shipped_run() -> None:
    import tomllib

    from wmr.apps.batch import load_batch
    from wmr.config.scenario import parse_scenario

    specs = [s for name in ("fig9", "fig10", "fig11") for s in load_scenario(name).runs]
    specs += [r.spec for r in load_batch("sensing_fig10").runs[:4]]  # runs with [sensors]
    assert any(s.sensors is not None for s in specs)
    for spec in specs:
        peer = replace(with_overrides(spec, Overrides(controller="graceful",
                                                      heading_tolerance_deg=0.3)),
                       name=spec.name + " \"q\"")
        for s in (spec, peer):
            back = parse_scenario(tomllib.loads(run_spec_toml(s))).runs
            assert back == (s,)


def test_a_heading_of_minus_zero_is_written_as_minus_zero_after_a_heading_of_zero() -> None:
    """The effective scenario's degrees are remembered by value (a batch's runs share their
    angles): -0.0 equals 0.0, yet its file must say -0.0, whichever was written first (the
    run read back must be the run, bit for bit)."""
    import math
    import tomllib

    from wmr.config.scenario import parse_scenario
    from wmr.core.plant import Pose

    spec = load_scenario("fig11").runs[0]
    for first, then in ((0.0, -0.0), (-0.0, 0.0)):
        for heading in (first, then):
            s = replace(spec, start=Pose(0.5, 0.5, heading))
            text = run_spec_toml(s)
            back = parse_scenario(tomllib.loads(text)).runs[0]
            assert math.copysign(1.0, back.start.heading_rad) == math.copysign(1.0, heading)
