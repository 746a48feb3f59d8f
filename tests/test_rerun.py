"""``wmr rerun``, ``BatchResult.log`` and ``wmr replay DIR --worst/--status``: every run of a
batch reachable, its log kept or not, in the first shard or a later one."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest

import wmr.apps.batch.summary as summary_module
from wmr.api import BatchResult, read_log
from wmr.apps.batch import BatchOptions, load_batch, run_batch
from wmr.apps.batch.rerun import pick_runs, rerun_run
from wmr.apps.batch.summary import RESULT_COLUMNS
from wmr.apps.run import LogPolicy
from wmr.cli import main
from wmr.infra.errors import ConfigError

# 2 x 3 short runs, in shards of 3 (the fixture below): the "ok" ones converge (about 25 ms
# each), the "weak" ones time out after 2 s of simulated time (0.01 N m cannot move the robot).
SPEC = """
name = "rr"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 15.0
[random]
seed = 3
n = 3
[random.start]
r_m = { dist = "uniform", low = 0.5, high = 1.5 }
bearing_deg = { dist = "uniform", low = -180.0, high = 180.0 }
[random.goal]
heading_deg = { dist = "along_x" }
[[list]]
name = "ok"
[[list]]
name = "weak"
limits = { torque_max_nm = 0.01 }
max_time_s = 2.0
"""
# 2 runs with sensors (noisy fixes, the EKF or none): the noise is seeded by the run's name
SENSORS = """
name = "rs"
start = [1.0, 0.5, 0.0]
goal = [0.0, 0.0, 0.0]
max_time_s = 15.0
[sensors]
gps_sigma_m = 0.05
[grid.sensors]
estimator = ["none", "ekf"]
"""
KEEPS = ("full", "failed", "none")
# the PI and Astolfi on the same 2 draws (common random numbers): runs 0-1 the PI, 2-3 Astolfi,
# Astolfi with a gain of its own so that its gains, not only its name, must reach the rerun
CONTROLLERS = """
name = "rc"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 15.0
[grid]
controller = ["pi", "astolfi"]
[[list]]
name = "a"
controller_gains = { astolfi = { k_rho = 2.5 } }
[random]
seed = 5
n = 2
[random.start]
r_m = { dist = "uniform", low = 0.5, high = 1.5 }
bearing_deg = { dist = "uniform", low = -180.0, high = 180.0 }
[random.goal]
heading_deg = { dist = "along_x" }
"""


@pytest.fixture(scope="module")
def batches(tmp_path_factory: pytest.TempPathFactory, fmu3: Path) -> dict[str, Path]:
    """The spec run under each log policy, its logs in shards of 3 runs (runs/000, runs/001),
    and the sensors spec with full logs."""
    root = tmp_path_factory.mktemp("rerun")
    spec = root / "rr.toml"
    spec.write_text(SPEC, encoding="utf-8")
    out: dict[str, Path] = {}
    with pytest.MonkeyPatch.context() as m:
        m.setattr(summary_module, "SHARD_RUNS", 3)
        for keep in KEEPS:
            out[keep] = root / keep
            run_batch(load_batch(spec), out[keep],
                      BatchOptions(workers=1, fmu_path=fmu3, log=LogPolicy(keep)), progress=False)
    sensors = root / "rs.toml"
    sensors.write_text(SENSORS, encoding="utf-8")
    out["sensors"] = root / "sensors"
    run_batch(load_batch(sensors), out["sensors"],
              BatchOptions(workers=1, fmu_path=fmu3, log=LogPolicy("full")), progress=False)
    controllers = root / "rc.toml"
    controllers.write_text(CONTROLLERS, encoding="utf-8")
    out["controllers"] = root / "controllers"
    run_batch(load_batch(controllers), out["controllers"],
              BatchOptions(workers=1, fmu_path=fmu3, log=LogPolicy("failed")), progress=False)
    return out


def _rows(out: Path) -> list[dict[str, Any]]:
    return pq.read_table(out / "summary.parquet").to_pylist()


def _same_result(record: dict[str, Any], row: dict[str, Any]) -> None:
    """Every result field of ``record`` equals the summary row's (the log's place apart)."""
    for column in RESULT_COLUMNS:
        if column == "mcap":
            continue
        value = record.get(column)
        if isinstance(value, float) and not math.isfinite(value):
            value = None
        assert value == row[column], (row["run_id"], column, value, row[column])


def _same_log(a: Path, b: Path) -> None:
    """Two logs of one run: the same signals, attachments and metadata, but where each is."""
    one, two = read_log(a), read_log(b)
    assert one.signals.equals(two.signals)
    assert one.attachments == two.attachments
    assert one.metadata["run"] == two.metadata["run"]
    assert {k: v for k, v in one.result.items() if k != "mcap"} \
        == {k: v for k, v in two.result.items() if k != "mcap"}


def test_the_batches_are_sharded_and_each_policy_keeps_what_it_says(
        batches: dict[str, Path]) -> None:
    assert sorted(p.name for p in (batches["full"] / "runs").iterdir()) == ["000", "001"]
    kept = {keep: [r["mcap"] for r in _rows(batches[keep])] for keep in KEEPS}
    assert all(kept["full"]) and not any(kept["none"])
    assert [bool(m) for m in kept["failed"]] == [r["status"] != "converged"
                                                for r in _rows(batches["failed"])]


@pytest.mark.parametrize("keep", KEEPS)
def test_rerun_reproduces_the_summary_row_in_the_first_and_a_later_shard(
        batches: dict[str, Path], keep: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = batches[keep]
    rows = _rows(out)
    for row in (rows[0], rows[4]):  # runs/000 (converged) and runs/001 (timeout)
        code = main(["rerun", str(out), row["run_id"], "--json"])
        assert code == {"converged": 0, "timeout": 3}[row["status"]]
        record = json.loads(capsys.readouterr().out.splitlines()[-1])
        _same_result(record, row)
        log = out / "rerun" / f"{row['run_id']}.mcap"
        assert record["mcap"] == str(log)
        _same_log(log, batches["full"] / _rows(batches["full"])[rows.index(row)]["mcap"])
    # the batch's own logs are untouched: no rerun writes among them
    assert not list((out / "runs").rglob("*rerun*"))


def test_rerun_reproduces_a_run_with_sensors(batches: dict[str, Path], tmp_path: Path) -> None:
    out = batches["sensors"]
    for row in _rows(out):
        record = rerun_run(out, row["run_id"], out=tmp_path / f"{row['run_id']}.mcap")
        _same_result(record, row)
        assert record["estimated_final_position_error_m"] is not None
        _same_log(Path(record["mcap"]), out / row["mcap"])


def test_rerun_reproduces_the_summary_row_under_each_controller(
        batches: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    """One run of each controller of a batch that varies it, made again from the batch
    folder alone (no log was kept of these converged runs): its record is its summary row,
    and its log is of its own controller, not the PI's."""
    out = batches["controllers"]
    rows = _rows(out)
    assert [r["controller"] for r in rows] == ["pi", "pi", "astolfi", "astolfi"]
    assert rows[1]["draw"] == rows[3]["draw"] == 1  # the same draw under each controller
    assert all(r["status"] == "converged" and r["mcap"] is None for r in rows)
    # same start and robot, another controller: another trip (a rerun on the PI would not be)
    assert rows[1]["time_to_goal_s"] != rows[3]["time_to_goal_s"]
    for row in (rows[1], rows[3]):
        assert main(["rerun", str(out), row["run_id"], "--json"]) == 0
        record = json.loads(capsys.readouterr().out.splitlines()[-1])
        _same_result(record, row)
        run = read_log(record["mcap"]).metadata["run"]
        assert run["controller"] == row["controller"]
        assert run["controller_gains"] == ({"k_rho": 2.5} if row["controller"] == "astolfi"
                                           else {})


def test_rerun_refuses_a_run_of_another_spec_and_a_folder_that_is_no_batch(
        batches: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run_id = _rows(batches["full"])[1]["run_id"]
    other = run_id[:5] + ("0" if run_id[5] != "0" else "1") + run_id[6:]
    assert main(["rerun", str(batches["full"]), other]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"is {run_id}, not {other}" in err
    assert main(["rerun", str(tmp_path), run_id, "--json"]) == 1
    captured = capsys.readouterr()
    assert "is not a batch folder (no batch.json)" in captured.err
    assert json.loads(captured.out)["field"] == "DIR"


def test_batch_result_log_finds_a_sharded_log_and_reruns_one_not_kept(
        batches: dict[str, Path]) -> None:
    full = BatchResult(batches["full"], pq.read_table(batches["full"] / "summary.parquet")
                       .to_pandas())
    run_id = full.summary["run_id"][4]
    log = full.log(run_id)  # runs/001/<run_id>.mcap
    assert log.path_to_file == batches["full"] / "runs" / "001" / f"{run_id}.mcap"
    none = BatchResult(batches["none"], pq.read_table(batches["none"] / "summary.parquet")
                       .to_pandas())
    with pytest.raises(ConfigError) as err:
        none.log(run_id)
    text = str(err.value)
    assert "log policy (no logs) kept no log" in text
    assert "rerun=True" in text and f"wmr rerun {batches['none']} {run_id}" in text
    again = none.log(run_id, rerun=True)
    assert again.path_to_file == batches["none"] / "rerun" / f"{run_id}.mcap"
    _same_log(again.path_to_file, log.path_to_file)
    with pytest.raises(ConfigError, match="no run 'nope'"):
        none.log("nope")


def test_worst_and_status_choose_the_right_runs(batches: dict[str, Path]) -> None:
    import pandas as pd

    out = batches["failed"]
    frame = pd.read_parquet(out / "summary.parquet")
    # the failed and timed-out runs first (those that ended furthest from the goal first),
    # then the slowest converged ones
    bad = frame[frame["status"] != "converged"].sort_values(
        ["final_position_error_m", "run_id"], ascending=[False, True])
    good = frame[frame["status"] == "converged"].sort_values(
        ["time_to_goal_s", "run_id"], ascending=[False, True])
    expected = [*bad["run_id"], *good["run_id"]]
    assert len(bad) == 3
    assert [r for r, _ in pick_runs(out, worst=4)] == expected[:4]
    assert [r for r, _ in pick_runs(out, worst=99)] == expected
    by_path = frame[frame["status"] == "converged"].sort_values("path_length_m",
                                                                ascending=False)
    assert [r for r, _ in pick_runs(out, worst=4, by="path_length_m")][3] \
        == by_path["run_id"].iloc[0]
    assert [r for r, _ in pick_runs(out, status="timeout")] == sorted(bad["run_id"])
    with pytest.raises(ConfigError, match="no failed run"):
        pick_runs(out, status="failed")
    with pytest.raises(ConfigError, match="'name' is not a numeric column"):
        pick_runs(out, worst=1, by="name")


def test_replay_worst_reruns_the_runs_not_kept_and_says_so(
        batches: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = batches["failed"]
    rrd = tmp_path / "worst.rrd"
    assert main(["replay", str(out), "--worst", "4", "--no-viewer", "--rrd", str(rrd)]) == 0
    err = capsys.readouterr().err
    slowest = pick_runs(out, worst=4)[3][0]
    assert f"run {slowest}: its log was not kept (logs of failed and timed-out runs only): " \
           f"made again with a full log into {out / 'rerun' / slowest}.mcap" in err
    assert "wrote 4 runs" in err and rrd.is_file()


def test_replay_of_a_batch_that_kept_no_log_names_its_policy(
        batches: dict[str, Path], capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    import shutil

    out = tmp_path / "none"  # a copy: another test reruns into the batch's rerun/ folder
    shutil.copytree(batches["none"], out, ignore=shutil.ignore_patterns("rerun"))
    assert main(["replay", str(out), "--no-viewer"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "log policy (no logs) kept no log" in err and "--worst N" in err \
        and "--status failed|timeout" in err and "no .mcap files" not in err
