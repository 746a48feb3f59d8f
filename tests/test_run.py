"""``wmr run`` end to end on the FMU: results, logs, reproducibility, failures, bad input."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import read_run
from wmr.apps.request import Overrides, RunRequest
from wmr.apps.run import run_to_log
from wmr.build.fmus import BuildResult
from wmr.cli import main
from wmr.config.scenario import load_scenario
from wmr.core.plant import Pose, RobotParams
from wmr.infra.errors import ConfigError, FmuError

RESULT_FIELDS = {"status", "final_position_error_m", "final_heading_error_rad",
                 "time_to_goal_s", "path_length_m", "mcap"}



def _run_json(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict[str, object]]:
    code = main(["run", *args, "--json"])
    last = capsys.readouterr().out.strip().splitlines()[-1]
    return code, json.loads(last)


def test_default_run_is_the_fig11_case_and_converges(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "fig11.mcap"
    code, record = _run_json(capsys, "--out", str(out))
    assert code == 0
    assert RESULT_FIELDS <= set(record)
    assert record["status"] == "converged"
    assert float(record["final_position_error_m"]) < 0.05  # type: ignore[arg-type]
    assert float(record["final_heading_error_rad"]) < math.radians(2)  # type: ignore[arg-type]
    assert Path(str(record["mcap"])) == out
    log = read_run(out)
    assert not log.truncated
    assert log.metadata["result"]["status"] == "converged"
    run = log.metadata["run"]
    assert run["fmi_version"] == "3.0" and len(run["fmu_sha256"]) == 64
    assert json.loads(run["goal"]) == {"x_m": 20.0, "y_m": 10.0, "heading_rad": 0.0}
    assert {"modelDescription.xml", "fig11.toml"} <= set(log.attachments)
    assert log.n_steps == int(log.metadata["result"]["steps"])
    assert log.signals["x_m"][-1] == pytest.approx(20.0, abs=0.05)


def test_the_same_run_gives_the_same_bytes(tmp_path: Path, built: BuildResult) -> None:
    spec = load_scenario("fig11").runs[0]
    path = tmp_path / "run.mcap"  # the same path: the result record names it, the CRCs cover it
    with FmuPlant(built.fmus[3]) as plant:
        run_to_log(spec, path, plant)
        a = path.read_bytes()
        run_to_log(spec, path, plant)
    b = path.read_bytes()
    assert len(a) > 100_000
    assert a == b


def test_fmi2_and_fmi3_runs_log_the_same_signals(tmp_path: Path, built: BuildResult) -> None:
    spec = load_scenario("fig11").runs[0]
    blocks = []
    for version in (2, 3):
        with FmuPlant(built.fmus[version]) as plant:
            run_to_log(spec, tmp_path / f"v{version}.mcap", plant)
        blocks.append(read_run(tmp_path / f"v{version}.mcap").block())
    np.testing.assert_array_equal(blocks[0], blocks[1])


@pytest.mark.parametrize("args, field", [
    (["--goal", "nan", "10", "0"], "goal.x_m"),
    (["--start", "0", "inf", "0"], "start.y_m"),
    (["--period", "-0.01"], "control_period_s"),
    (["--gain", "K_ps=nan"], "K_ps"),
    (["--param", "m=-3"], "m"),
    (["no_such_scenario"], "scenario"),
])
def test_bad_input_is_one_line_naming_the_field_and_writes_no_log(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], field: str) -> None:
    out = tmp_path / "bad.mcap"
    code = main(["run", *args, "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0
    assert len(err) == 1 and err[0].startswith("wmr: error:") and field in err[0]
    assert not out.exists()


def test_a_hostile_fmu_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "evil.fmu").write_bytes(b"PK\x03\x04 definitely not a zip")
    code = main(["run", "--fmu", str(tmp_path / "evil.fmu"), "--out", str(tmp_path / "x.mcap")])
    err = capsys.readouterr().err
    assert code == 1 and "not an FMU" in err
    assert not (tmp_path / "x.mcap").exists()


class _FailingPlant:
    """The FMU, failing at step ``fail_at`` the way a diverging model would."""

    def __init__(self, inner: FmuPlant, fail_at: int) -> None:
        self.inner, self.fail_at, self.n = inner, fail_at, 0
        self.sha256, self.fmu_path, self.fmi_version = inner.sha256, inner.fmu_path, "3.0"
        self.model_description_xml = inner.model_description_xml

    def reset(self, params: RobotParams, start: Pose, v0_mps: float = 0.0,
              omega0_radps: float = 0.0) -> np.ndarray:
        self.n = 0
        return self.inner.reset(params, start, v0_mps, omega0_radps)

    def step(self, tau_r_nm: float, tau_l_nm: float, h_s: float) -> np.ndarray:
        self.n += 1
        if self.n == self.fail_at:
            raise FmuError("fmi3DoStep returned fmi3Error")
        return self.inner.step(tau_r_nm, tau_l_nm, h_s)

    def close(self) -> None:
        self.inner.close()


def test_a_failed_run_is_recorded_as_failed_with_its_log_readable(tmp_path: Path,
                                                                  built: BuildResult) -> None:
    spec = load_scenario("fig11").runs[0]
    with FmuPlant(built.fmus[3]) as inner:
        record = run_to_log(spec, tmp_path / "f.mcap", _FailingPlant(inner, 700))  # type: ignore[arg-type]
    assert record["status"] == "failed"
    assert "fmi3DoStep" in str(record["message"])
    log = read_run(tmp_path / "f.mcap")
    assert not log.truncated
    assert log.metadata["result"]["status"] == "failed"
    assert log.n_steps == 700  # every step before the failure is in the log


def test_timeout_is_a_status_not_a_hang(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, record = _run_json(capsys, "--max-time", "3", "--out", str(tmp_path / "t.mcap"))
    assert code == 3
    assert record["status"] == "timeout"
    assert "max_time_s" in str(record["message"])


def test_a_killed_run_leaves_a_log_readable_up_to_its_last_chunk(tmp_path: Path,
                                                                 built: BuildResult) -> None:
    out = tmp_path / "killed.mcap"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    code = ("import sys, wmr.cli; sys.exit(wmr.cli.main(['run', '--goal', '300', '300', '0',"
            f" '--max-time', '2000', '--out', {str(out)!r}]))")
    proc = subprocess.Popen([sys.executable, "-c", code], env=env)
    deadline = time.monotonic() + 60
    partial = out.with_name(out.name + ".partial")
    while time.monotonic() < deadline and (not partial.exists()
                                           or partial.stat().st_size < 300_000):
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not out.exists(), "an unfinished log never takes the final name"
    log = read_run(partial)
    assert log.truncated
    assert log.n_steps >= 100 and "result" not in log.metadata
    assert np.all(np.diff(log.t_ns) == 10_000_000)


@pytest.mark.parametrize("scenario", ["fig9", "fig10"])
def test_every_paper_run_converges_on_the_fmu(scenario: str, built: BuildResult) -> None:
    from wmr.core.closedloop import run_closed_loop
    from wmr.core.control.from_spec import SpecController

    failures = []
    with FmuPlant(built.fmus[3]) as plant:
        for spec in load_scenario(scenario).runs:
            res = run_closed_loop(spec, plant, controller=SpecController())
            if not (res.status == "converged" and res.final_position_error_m < 0.05
                    and res.final_heading_error_rad < math.radians(2)):
                failures.append((spec.name, res.status, res.final_position_error_m,
                                 math.degrees(res.final_heading_error_rad)))
    assert failures == []


def test_view_writes_a_live_recording_beside_the_log(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    import rerun.chunk as rrc

    from wmr.adapters.rerun.replay import TIMELINE

    out = tmp_path / "live.mcap"
    code, record = _run_json(capsys, "--view", "--out", str(out))
    assert code == 0 and record["status"] == "converged"
    steps = int(record["steps"])  # type: ignore[call-overload]
    rows: dict[str, int] = {}
    for chunk in rrc.RrdReader(out.with_suffix(".rrd")).stream():
        if TIMELINE in chunk.to_record_batch().schema.names:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    assert rows and max(rows.values()) == steps  # every step reached the live view
    assert read_run(out).n_steps == steps  # and the log is unchanged by the view


def test_a_typed_in_goal_names_the_run_and_its_default_log(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    code, record = _run_json(capsys, "--goal", "3", "-1", "90")
    assert code == 0
    assert record["name"] == "fig11-to_3_-1_90deg"
    assert Path(str(record["mcap"])) == Path("runs/fig11-to_3_-1_90deg.mcap")
    log = read_run(tmp_path / str(record["mcap"]))
    assert log.metadata["run"]["name"] == "fig11-to_3_-1_90deg"
    assert not (tmp_path / "runs" / "fig11.mcap").exists()


def test_a_record_holds_json_numbers_only() -> None:
    """``core.record.record``: NaN and the infinities become ``null`` (a strict JSON reader
    refuses ``NaN``), finite figures stay as they are, the keys are docs/results.md's.
    Seen failing with ``jsonable`` returning its value unchanged."""

    from wmr.core.record import RunFigures, jsonable, record

    assert jsonable(math.nan) is None and jsonable(math.inf) is None and jsonable(None) is None
    assert jsonable(2.5) == 2.5
    rec = record(RunFigures(
        name="r", status="timeout", message="m", final_position_error_m=1.5,
        final_heading_error_rad=math.nan, time_to_goal_s=None, path_length_m=2.0,
        energy_net_j=-math.inf, energy_positive_j=1.0, energy_abs_j=1.0,
        torque_sq_integral_n2m2s=0.5, peak_torque_nm=8.0, steps=3))
    assert json.loads(json.dumps(rec, allow_nan=False)) == rec
    assert rec["final_heading_error_rad"] is None and rec["energy_net_j"] is None
    assert rec["final_position_error_m"] == 1.5 and rec["steps"] == 3
    doc = (Path(__file__).resolve().parents[1] / "docs" / "results.md").read_text()
    assert all(f"`{key}`" in doc for key in rec)


@pytest.mark.parametrize(("make", "field"), [
    (lambda: RunRequest(overrides=Overrides(goal=(1.0, 2.0))), "goal"),  # type: ignore[arg-type]
    (lambda: RunRequest(overrides=Overrides(start="0 0 0")), "start"),  # type: ignore[arg-type]
    (lambda: RunRequest(overrides=Overrides(period_s=math.nan)), "period_s"),
    (lambda: RunRequest(overrides=Overrides(max_time_s="10")), "max_time_s"),  # type: ignore[arg-type]
    (lambda: RunRequest(overrides=Overrides(params=[("m", 1.0)])), "params"),  # type: ignore[arg-type]
    (lambda: RunRequest(fmi=4), "fmi"),
])
def test_a_run_request_is_checked_when_made(make: Any, field: str) -> None:
    """``apps.request``: a request that cannot be run is refused when it is made, naming the
    field by its keyword (the CLI names it by its option), before any scenario is loaded.
    Seen failing with ``Overrides.__post_init__`` and ``RunRequest.__post_init__`` removed
    (nothing raised when the request was made)."""
    with pytest.raises(ConfigError) as err:
        make()
    assert err.value.field == field


def test_a_run_request_keeps_what_it_was_given() -> None:
    request = RunRequest("fig9", run="r1", overrides=Overrides(goal=[5, 5, 30], gains={"K_ps": 1}))
    assert request.overrides.goal == (5.0, 5.0, 30.0) and request.overrides.gains == {"K_ps": 1}
    assert (request.scenario, request.run, request.fmi, request.log) == ("fig9", "r1", 3, None)
