"""Log policies of ``wmr batch`` and ``wmr run`` (full, failed-only, none, every k-th step) and
the sharded ``runs/`` folder of large batches: what is kept, what the summary says, resume."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import wmr.apps.batch.runner as runner_module
import wmr.apps.batch.summary as summary_module
import wmr.apps.run as run_module
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import read_run
from wmr.adapters.rerun.replay import find_logs
from wmr.apps.batch import BatchOptions, load_batch, run_batch
from wmr.apps.batch.journal import log_complete
from wmr.apps.batch.report import write_report
from wmr.apps.batch.runner import _test_hooks
from wmr.apps.batch.summary import log_relpath
from wmr.apps.run import LogPolicy, run_to_log
from wmr.cli import main
from wmr.config.scenario import load_scenario
from wmr.core.runlog import MemoryLog
from wmr.core.signals import SIGNALS
from wmr.infra.errors import ConfigError

# 2 x N short runs: the "ok" ones converge (about 25 ms each), the "weak" ones time out after
# 2 s of simulated time (0.01 N m cannot move the robot): half the runs keep a log under
# the failed-only policy.
SPEC = """
name = "lp"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 15.0
[random]
seed = 3
n = {n}
[random.start]
r_m = {{ dist = "uniform", low = 0.5, high = 1.5 }}
bearing_deg = {{ dist = "uniform", low = -180.0, high = 180.0 }}
[random.goal]
heading_deg = {{ dist = "along_x" }}
[[list]]
name = "ok"
[[list]]
name = "weak"
limits = {{ torque_max_nm = 0.01 }}
max_time_s = 2.0
"""
POLICIES = {"full": LogPolicy("full"), "failed": LogPolicy("failed"),
            "none": LogPolicy("none"), "every-7": LogPolicy("full", 7)}


def _spec(folder: Path, n: int, log: str = "") -> Path:
    path = folder / f"lp{n}.toml"
    path.write_text(SPEC.format(n=n) + log, encoding="utf-8")
    return path


def _journal(out: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in (out / "journal.jsonl").read_text().splitlines()
            if line.strip()]


@pytest.fixture(scope="module")
def spec8(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _spec(tmp_path_factory.mktemp("spec"), 4)


@pytest.fixture(scope="module")
def batches(spec8: Path, fmu3: Path, tmp_path_factory: pytest.TempPathFactory
            ) -> dict[str, Path]:
    """The 8-run batch under each policy, one worker."""
    out = {}
    for name, policy in POLICIES.items():
        folder = tmp_path_factory.mktemp(name)
        result = run_batch(load_batch(spec8), folder,
                           BatchOptions(workers=1, fmu_path=fmu3, log=policy), progress=False)
        assert len(result.executed) == 8 and result.log == policy
        out[name] = folder
    return out


def _logs(out: Path) -> set[str]:
    return {p.relative_to(out).as_posix() for p in (out / "runs").rglob("*")
            if p.is_file()}


@pytest.mark.parametrize("name", list(POLICIES))
def test_each_policy_keeps_its_logs_and_the_summary_says_which(
        batches: dict[str, Path], name: str) -> None:
    out = batches[name]
    rows = pq.read_table(out / "summary.parquet").to_pylist()
    assert {r["status"] for r in rows} == {"converged", "timeout"}
    expected = {r["run_id"] for r in rows if POLICIES[name].keeps(r["status"])}
    assert len(expected) == {"full": 8, "failed": 4, "none": 0, "every-7": 8}[name]
    # the summary's mcap column names the logs kept, and nothing else is on disk
    assert {r["mcap"] for r in rows if r["mcap"] is not None} == _logs(out) \
        == {f"runs/{i}.mcap" for i in expected}
    assert all(r["mcap"] is None for r in rows if r["run_id"] not in expected)
    assert all(log_complete(out / r["mcap"]) for r in rows if r["mcap"])
    stated = json.loads((out / "batch.json").read_text())
    assert stated["log"] == POLICIES[name].as_dict() and stated["logs_kept"] == len(expected)
    assert f"{len(expected)} of 8 runs kept one" in write_report(out).read_text()


def test_the_results_do_not_depend_on_the_policy(batches: dict[str, Path]) -> None:
    """Every column but ``mcap`` is the full policy's, value for value; with full logs the
    summary's bytes are those of any other full batch."""
    full = pq.read_table(batches["full"] / "summary.parquet").drop(["mcap"])
    for name in ("failed", "none", "every-7"):
        assert pq.read_table(batches[name] / "summary.parquet").drop(["mcap"]).equals(full)


def test_a_failed_runs_log_is_the_full_policys(batches: dict[str, Path]) -> None:
    """The failed-only policy holds the rows in memory and writes them after the run: the
    same log as one written as the run went (the bytes too, but for the log's own path in its
    ``result`` record: see the spill test)."""
    kept = sorted(_logs(batches["failed"]))
    assert kept
    for rel in kept:
        held, full = read_run(batches["failed"] / rel), read_run(batches["full"] / rel)
        assert held.attachments == full.attachments
        assert held.metadata["run"] == full.metadata["run"]
        assert {k: v for k, v in held.metadata["result"].items() if k != "mcap"} == \
            {k: v for k, v in full.metadata["result"].items() if k != "mcap"}
        assert all(np.array_equal(held.signals[k], full.signals[k]) for k in full.signals)


def test_every_kth_step_and_the_last(batches: dict[str, Path]) -> None:
    for rel in sorted(_logs(batches["full"]))[:3]:
        full, thin = read_run(batches["full"] / rel), read_run(batches["every-7"] / rel)
        n = full.n_steps
        rows = sorted({*range(0, n, 7), n - 1})
        assert thin.n_steps == len(rows)
        assert np.array_equal(thin.t_s, full.t_s[rows])
        assert all(np.array_equal(thin.signals[k], full.signals[k][rows]) for k in full.signals)
        assert json.loads(thin.metadata["run"]["log_every_k_steps"]) == 7
        assert "log_every_k_steps" not in full.metadata["run"]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 12), max_size=12), st.integers(1, 9))
def test_decimation_does_not_depend_on_the_blocks(sizes: list[int], k: int) -> None:
    """Rows 0, k, 2k, ... of the whole run and its last row, however the loop cuts blocks."""
    sink = MemoryLog()
    thin = run_module._EveryK(sink, k)
    t = np.arange(sum(sizes), dtype=np.int64)
    start = 0
    for n in sizes:
        thin.write_block(t[start:start + n], np.zeros((n, len(SIGNALS))))
        start += n
    thin.end()
    total = len(t)
    assert sink.t_ns.tolist() == ([] if not total else sorted({*range(0, total, k), total - 1}))


def test_a_long_run_spills_its_held_rows_and_a_converged_one_leaves_nothing(
        fmu3: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Past HOLD_ROWS rows the failed-only policy writes the log as it goes (memory stays
    bounded): a run that then converges leaves no file, one that times out the full log."""
    run = load_scenario("fig11").runs[0]
    weak = load_batch(_spec(tmp_path, 1)).runs[1].spec
    log = tmp_path / "logs" / "t.mcap"  # the same path for both: the log records it
    with FmuPlant(fmu3) as plant:
        run_to_log(weak, log, plant)
        full = log.read_bytes()
        log.unlink()
        monkeypatch.setattr(run_module, "HOLD_ROWS", 50)
        converged = run_to_log(run, tmp_path / "logs" / "c.mcap", plant,
                               log=LogPolicy("failed"))
        timeout = run_to_log(weak, log, plant, log=LogPolicy("failed"))
    assert converged["status"] == "converged" and converged["mcap"] is None
    assert timeout["status"] == "timeout" and timeout["mcap"] == str(log)
    assert [p.name for p in log.parent.iterdir()] == ["t.mcap"]
    assert log.read_bytes() == full


def test_a_run_that_raises_keeps_its_log_with_the_error(fmu3: Path, tmp_path: Path) -> None:
    run = load_scenario("fig11").runs[0]

    def stop(t_s: float, t_max_s: float) -> None:
        if t_s > 1.0:
            raise KeyboardInterrupt

    with FmuPlant(fmu3) as plant, pytest.raises(KeyboardInterrupt):
        run_to_log(run, tmp_path / "r.mcap", plant, progress=stop, log=LogPolicy("failed"))
    log = read_run(tmp_path / "r.mcap")
    assert log.metadata["result"]["status"] == "failed" and log.n_steps > 100


# -- the sharded layout ----------------------------------------------------------------------

def test_log_paths_are_flat_up_to_1000_runs_and_sharded_beyond() -> None:
    assert log_relpath("0999-0123abcd", 1000) == "runs/0999-0123abcd.mcap"
    assert log_relpath("0999-0123abcd", 1001) == "runs/000/0999-0123abcd.mcap"
    assert log_relpath("1000-0123abcd", 1001) == "runs/001/1000-0123abcd.mcap"
    assert log_relpath("999999-0123abcd", 10**6) == "runs/999/999999-0123abcd.mcap"
    assert log_relpath("1999999-0123abcd", 2 * 10**6) == "runs/1999/1999999-0123abcd.mcap"


@pytest.fixture
def shards_of_3(monkeypatch: pytest.MonkeyPatch) -> None:
    """Batches of over 3 runs are sharded, in shards of 3 runs."""
    monkeypatch.setattr(summary_module, "SHARD_RUNS", 3)


def test_a_sharded_batch_resumes_replays_and_reports(
        spec8: Path, fmu3: Path, tmp_path: Path, batches: dict[str, Path],
        shards_of_3: None) -> None:
    batch = load_batch(spec8)
    with _test_hooks(stop_after=5):
        first = run_batch(batch, tmp_path,
                          BatchOptions(workers=2, fmu_path=fmu3, log=LogPolicy("full")),
                          progress=False)
    assert first.interrupted
    again = run_batch(batch, tmp_path,
                      BatchOptions(workers=2, fmu_path=fmu3, log=LogPolicy("full")), progress=False)
    assert again.skipped == 5 and len(again.executed) == 3
    shards = sorted(p.name for p in (tmp_path / "runs").iterdir())
    assert shards == ["000", "001", "002"]
    assert all(len(list((tmp_path / "runs" / s).iterdir())) <= 3 for s in shards)
    rows = pq.read_table(tmp_path / "summary.parquet").to_pylist()
    assert {r["mcap"] for r in rows} == _logs(tmp_path)
    assert all(r["mcap"].startswith(f"runs/{int(r['run_id'][:4]) // 3:03d}/") for r in rows)
    full = pq.read_table(batches["full"] / "summary.parquet").drop(["mcap"])
    assert pq.read_table(tmp_path / "summary.parquet").drop(["mcap"]).equals(full)
    assert len(find_logs([tmp_path])) == 8  # wmr replay DIR
    write_report(tmp_path)
    third = run_batch(batch, tmp_path, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert third.executed == [] and third.skipped == 8


def test_an_unsharded_batch_folder_of_before_still_resumes(
        batches: dict[str, Path], spec8: Path, fmu3: Path, tmp_path: Path,
        shards_of_3: None, journal_of_before: Callable[[Path, Any], None]) -> None:
    """Journal lines written before lines said where their log is (no ``path``) have it at
    ``runs/<run_id>.mcap``: a batch folder of that time, resumed by a batch that shards, keeps
    every run and its summary."""
    out = tmp_path / "old"
    shutil.copytree(batches["full"], out, copy_function=shutil.copy2)
    journal_of_before(out, load_batch(spec8).runs)  # lines that hold their records
    lines = _journal(out)
    for line in lines:
        del line["path"]
    (out / "journal.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    (out / "summary.csv").unlink()
    again = run_batch(load_batch(spec8), out, BatchOptions(workers=1, fmu_path=fmu3),
                      progress=False)
    assert again.executed == [] and again.skipped == 8
    assert (out / "summary.csv").read_bytes() == \
        (batches["full"] / "summary.csv").read_bytes()


def test_a_journal_path_outside_runs_is_not_followed(
        batches: dict[str, Path], spec8: Path, fmu3: Path, tmp_path: Path,
        journal_of_before: Callable[[Path, Any], None]) -> None:
    """A journal line of before names its log (``path``); a compact line leaves it to the
    summary row, which its seal covers."""
    out = tmp_path / "copy"
    shutil.copytree(batches["full"], out, copy_function=shutil.copy2)
    journal_of_before(out, load_batch(spec8).runs)
    lines = _journal(out)
    # a path out of the folder and back: it names the run's finished log, but is not followed
    lines[2]["path"] = f"runs/../../{out.name}/{lines[2]['path']}"
    lines[3]["path"] = f"../{out.name}/{lines[3]['path']}"
    (out / "journal.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
    again = run_batch(load_batch(spec8), out, BatchOptions(workers=1, fmu_path=fmu3),
                      progress=False)
    assert sorted(again.executed) == [lines[2]["run_id"], lines[3]["run_id"]]


# -- the policy in the spec, on the command line, and by default -----------------------------

def test_the_spec_log_table_and_the_command_line(spec8: Path, fmu3: Path, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    spec = _spec(tmp_path, 4, '[log]\nkeep = "none"\n')
    assert load_batch(spec).log == LogPolicy("none")
    assert main(["batch", str(spec), "--out", str(tmp_path / "a"), "--fmu", str(fmu3),
                 "--workers", "1", "--no-progress"]) == 0
    assert "no logs: 0 logs kept now" in capsys.readouterr().err
    assert _logs(tmp_path / "a") == set()
    # the command line wins over the spec, option by option
    assert main(["batch", str(spec), "--out", str(tmp_path / "b"), "--fmu", str(fmu3),
                 "--workers", "1", "--no-progress", "--log", "failed",
                 "--log-every", "5"]) == 0
    err = capsys.readouterr().err
    assert "logs of failed and timed-out runs only, every 5th control step: 4 logs kept" in err
    assert json.loads((tmp_path / "b" / "batch.json").read_text())["log"] == \
        {"keep": "failed", "every_k_steps": 5}


@pytest.mark.parametrize(("table", "field"), [
    ('keep = "some"', "log.keep"),
    ("every_k_steps = 0", "log.every_k_steps"),
    ("every_k_steps = 2.5", "log.every_k_steps"),
    ("keep_logs = true", "log.keep_logs"),
])
def test_bad_log_tables_are_named(tmp_path: Path, table: str, field: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_batch(_spec(tmp_path, 2, f"[log]\n{table}\n"))
    assert err.value.field == field


def test_bad_log_options_are_named(spec8: Path, tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["batch", str(spec8), "--out", str(tmp_path / "o"), "--log-every", "0"]) == 1
    assert "--log-every" in capsys.readouterr().err


def test_a_large_batch_keeps_the_logs_of_failed_runs_by_default(
        spec8: Path, fmu3: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(runner_module, "FULL_LOGS_MAX_RUNS", 7)
    result = run_batch(load_batch(spec8), tmp_path, BatchOptions(workers=1, fmu_path=fmu3),
                       progress=False)
    assert result.log == LogPolicy("failed") and result.logs_kept == 4


def test_wmr_run_log_policy(fmu3: Path, tmp_path: Path,
                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r.mcap"
    assert main(["run", "fig11", "--fmu", str(fmu3), "--out", str(out), "--log", "failed",
                 "--json"]) == 0
    record = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert record["status"] == "converged" and record["mcap"] is None and not out.exists()
    assert main(["run", "fig11", "--fmu", str(fmu3), "--out", str(out), "--log-every",
                 "10"]) == 0
    assert f"log {out}" in capsys.readouterr().out
    assert read_run(out).n_steps < 300


# -- resume after kill -9 under each policy --------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("name", list(POLICIES))
def test_resume_after_kill_9(name: str, fmu3: Path, tmp_path: Path) -> None:
    """``wmr batch`` killed with SIGKILL (parent and workers) mid-batch, then rerun: every run
    once in the journal, the summary that of an uninterrupted batch, and the logs those the
    policy keeps (no debris of the killed runs)."""
    policy = POLICIES[name]
    spec = _spec(tmp_path, 25)
    ref = tmp_path / "ref"
    run_batch(load_batch(spec), ref, BatchOptions(workers=1, fmu_path=fmu3, log=policy),
              progress=False)
    out = tmp_path / "o"
    options = ["--log", policy.keep, "--log-every", str(policy.every_k_steps)]
    cmd = [sys.executable, "-m", "wmr.cli", "batch", str(spec), "--out", str(out), "--fmu",
           str(fmu3), "--workers", "2", "--no-progress", *options]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)
    journal = out / "journal.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (
            not journal.exists() or len(journal.read_bytes().splitlines()) < 6):
        time.sleep(0.005)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    done = len(_journal(out))
    assert 6 <= done < 50
    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    ids = [line["run_id"] for line in _journal(out)]
    assert len(ids) == len(set(ids)) == 50
    assert (out / "summary.csv").read_bytes() == (ref / "summary.csv").read_bytes()
    assert _logs(out) == _logs(ref)
