"""Promises of ``wmr batch`` checked against independent facts (issue 23, gaps 1 and 7).

* Resume compares the FMU: the same command with another FMU (same runs, same inputs) redoes
  every run, and the journal then names the new FMU (docs/batch.md, "Resume").
* A worker killed **while writing its log** leaves a partial log that the batch recovers into
  ``runs/<id>.mcap``: the test kills the worker from outside, by the process holding the
  partial log open, once that log holds data (the executor's own fault hooks kill before the
  log is opened).
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import threading
import zipfile
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from wmr.adapters.mcap import read_run
from wmr.apps.batch import BatchOptions, BatchSpec, load_batch, run_batch
from wmr.apps.batch.journal import log_complete, run_digest
from wmr.apps.batch.runner import BatchOutcome

TWO_RUNS = """
name = "two"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 15.0
[[list]]
name = "a"
[[list]]
name = "b"
gains = { K_ps = 0.8 }
"""


def _journal(out: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in (out / "journal.jsonl").read_text().splitlines()
            if line.strip()]


def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _other_fmu(fmu: Path, dest: Path) -> Path:
    """The same FMU with one more documentation file: other bytes, same model."""
    other = dest / fmu.name
    other.write_bytes(fmu.read_bytes())
    with zipfile.ZipFile(other, "a") as zf:
        zf.writestr("documentation/rebuilt.txt", "another build of the same model\n")
    assert file_sha256(other) != file_sha256(fmu)
    return other


def test_resume_redoes_every_run_when_the_fmu_changed(fmu3: Path, tmp_path: Path) -> None:
    spec = tmp_path / "two.toml"
    spec.write_text(TWO_RUNS)
    batch = load_batch(spec)
    out = tmp_path / "out"
    first = run_batch(batch, out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert len(first.executed) == 2
    again = run_batch(batch, out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.executed == [] and again.skipped == 2  # same FMU: nothing to do
    other = _other_fmu(fmu3, tmp_path)
    changed = run_batch(batch, out, BatchOptions(workers=1, fmu_path=other), progress=False)
    assert changed.skipped == 0
    assert sorted(changed.executed) == sorted(first.executed)
    last = {str(line["run_id"]): line["digest"] for line in _journal(out)}
    assert last == {run.run_id: run_digest(run.digest, file_sha256(other)) for run in batch.runs}
    # and back to the first FMU: its old lines were superseded, so every run is redone again
    back = run_batch(batch, out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert back.skipped == 0 and len(back.executed) == 2


SLOW_RUN = """
name = "slow"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
limits = { torque_max_nm = 0.01 }   # cannot arrive: it runs to max_time_s
max_time_s = 3000.0                 # 300 000 steps, seconds of wall clock
"""


def _holders(path: Path) -> list[int]:
    """The processes with ``path`` open (Linux /proc)."""
    pids = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            for fd in os.listdir(f"/proc/{pid}/fd"):
                if os.readlink(f"/proc/{pid}/fd/{fd}") == str(path):
                    pids.append(int(pid))
                    break
        except OSError:  # gone, or not ours
            continue
    return pids


class _KillMidLog(threading.Thread):
    """SIGKILL whichever process writes ``partial`` once it holds ``min_bytes``, ``times`` times
    (the pool retries a run whose worker died once)."""

    def __init__(self, partial: Path, min_bytes: int, times: int) -> None:
        super().__init__(daemon=True)
        self.partial, self.min_bytes, self.times = partial, min_bytes, times
        self.sizes: list[int] = []
        self.done = threading.Event()

    def run(self) -> None:
        killed: set[int] = set()
        while len(self.sizes) < self.times and not self.done.wait(0.002):
            # the writer first, then the size: a retry truncates the last attempt's partial log
            pids = [pid for pid in _holders(self.partial.resolve()) if pid not in killed]
            try:
                size = self.partial.stat().st_size
            except FileNotFoundError:
                continue
            if not pids or size < self.min_bytes:
                continue
            for pid in pids:
                os.kill(pid, signal.SIGKILL)
            killed.update(pids)
            self.sizes.append(size)


def _batch_killed_mid_log(batch: BatchSpec, out: Path, fmu: Path) -> tuple[BatchOutcome, Path]:
    """``batch`` (one run) with its worker SIGKILLed mid-log on both attempts; its log."""
    log = out / "runs" / f"{batch.runs[0].run_id}.mcap"
    killer = _KillMidLog(log.with_name(log.name + ".partial"), 200_000, times=2)
    killer.start()
    try:
        result = run_batch(batch, out, BatchOptions(workers=1, run_timeout_s=600.0, fmu_path=fmu),
                           progress=False)
    finally:
        killer.done.set()
        killer.join()
    assert len(killer.sizes) == 2, "the worker was not caught writing its log"
    return result, log


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs Linux /proc")
def test_a_worker_killed_mid_log_leaves_its_run_recovered(fmu3: Path, tmp_path: Path) -> None:
    spec = tmp_path / "slow.toml"
    spec.write_text(SLOW_RUN)
    batch = load_batch(spec)
    out = tmp_path / "out"
    result, log = _batch_killed_mid_log(batch, out, fmu3)
    assert result.counts["failed"] == 1
    (line,) = _journal(out)
    assert line["killed"] is True
    # the partial log of the second attempt, recovered into a finished log
    assert log.exists(), ({p.name: p.stat().st_size for p in log.parent.iterdir()}, line)
    with open(log, "rb") as f:  # any MCAP reader opens it, every CRC checks
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_summary() is not None
        n_messages = sum(1 for _ in reader.iter_messages())
    assert n_messages > 0
    assert not log_complete(log)  # no result record: the run never finished
    data = read_run(log)
    assert not data.truncated, data.warnings
    assert data.n_steps > 100
    np.testing.assert_array_equal(data.t_ns, np.arange(data.n_steps) * 10_000_000)
    assert data.signals["x_m"][0] == 1.0  # the run's own start
    assert not list(log.parent.glob("*.partial")) and not list(log.parent.glob("*.killed"))
    # killed runs are final: the same command redoes nothing
    again = run_batch(batch, out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.executed == []


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs Linux /proc")
def test_a_killed_run_done_again_is_recovered_over_its_earlier_log(fmu3: Path,
                                                                   tmp_path: Path) -> None:
    """docs/batch.md: a killed run's partial log "is recovered into its log's place", also
    when an earlier batch left a log there (the run redone for another FMU, killed again):
    the earlier log is replaced, and nothing is left beside it."""
    spec = tmp_path / "slow.toml"
    spec.write_text(SLOW_RUN)
    batch = load_batch(spec)
    out = tmp_path / "out"
    _, log = _batch_killed_mid_log(batch, out, fmu3)
    earlier = log.stat().st_ino
    other = _other_fmu(fmu3, tmp_path)
    result, _ = _batch_killed_mid_log(batch, out, other)
    assert result.executed == [batch.runs[0].run_id] and result.counts["failed"] == 1
    assert _journal(out)[-1]["digest"] == run_digest(batch.runs[0].digest, file_sha256(other))
    assert sorted(p.name for p in log.parent.iterdir()) == [log.name], "left beside the log"
    assert log.stat().st_ino != earlier, "the earlier run's log was kept"
    data = read_run(log)
    assert not data.truncated and data.n_steps > 100
