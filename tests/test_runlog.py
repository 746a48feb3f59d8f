"""The log protocol (wmr.core.runlog): the in-memory log keeps what a run wrote, and the MCAP
log and the in-memory one receive the same run bit for bit through ``run_to_log``, under every
log policy (full, failed-only, every k-th step)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from mcap.reader import make_reader

import wmr.apps.run as run_module
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import McapOpener, RunLogWriter, read_run
from wmr.adapters.mcap.sensing import read_sensing
from wmr.apps.run import LogPolicy, run_to_log
from wmr.config.scenario import load_scenario
from wmr.core.runlog import (
    NO_RESULT,
    LogHeader,
    MemoryLog,
    MemoryOpener,
    RunLog,
    failed_result,
)
from wmr.core.runspec import RunSpec
from wmr.core.sensing import SensorConfig
from wmr.core.signals import SIGNALS
from wmr.infra.errors import LogError

N = len(SIGNALS)


def _bits(a: npt.NDArray[np.float64]) -> npt.NDArray[np.uint64]:
    """The float64 array's bits: equality that tells NaNs, -0.0 and +0.0 apart exactly."""
    return np.ascontiguousarray(a).view(np.uint64)


def _fig11(t_max_s: float | None = None) -> RunSpec:
    spec = load_scenario("fig11").runs[0]
    return spec if t_max_s is None else replace(spec, t_max_s=t_max_s)


def _weak() -> RunSpec:
    """A run that times out: 0.01 N m cannot bring the robot to its goal in 2 s."""
    spec = _fig11(2.0)
    return replace(spec, name="weak", limits=replace(spec.limits, torque_max_nm=0.01))


# -- MemoryLog --------------------------------------------------------------------------------

def test_a_memory_log_keeps_copies_of_the_blocks_it_was_given() -> None:
    """The loop reuses its block buffer after each call: the log keeps what the rows were
    when written, concatenated in order."""
    log = MemoryLog()
    t = np.arange(3, dtype=np.int64)
    buf = np.arange(3 * N, dtype=np.float64).reshape(3, N)
    log.write_block(t, buf)
    first = buf.copy()
    t += 3
    buf += 1000.0  # the caller's next block, in the same arrays
    log.write_block(t, buf)
    t[:] = -1
    buf[:] = np.nan
    assert log.t_ns.tolist() == [0, 1, 2, 3, 4, 5]
    assert np.array_equal(log.block, np.vstack([first, first + 1000.0]))
    assert log.rows == 6 and log.block_sizes == (3, 3)
    assert isinstance(log, RunLog)


def test_a_closed_memory_log_takes_nothing_more() -> None:
    log = MemoryLog(LogHeader(run={"name": "r"}, goal=(1.0, 2.0, 0.5)))
    log.close({"status": "converged"})
    assert log.closed and log.result == {"status": "converged"} and not log.discarded
    with pytest.raises(LogError, match="write_block after close"):
        log.write_block(np.zeros(1, np.int64), np.zeros((1, N)))
    with pytest.raises(LogError, match="closed twice"):
        log.close({"status": "converged"})
    with pytest.raises(LogError, match="shape"):
        MemoryLog().write_block(np.zeros(2, np.int64), np.zeros((2, N - 1)))


@pytest.mark.parametrize("opened", ["memory", "mcap"])
def test_a_run_that_raises_closes_its_log_failed_with_its_error(
        opened: str, tmp_path: Path) -> None:
    """The ``with`` block of either log, left by an exception, closes the log with status
    ``failed`` and the error (:func:`failed_result`); left without a result, it says so."""
    header = LogHeader.of_spec(_fig11())
    logs: dict[str, RunLog] = {}

    def open_log(name: str) -> RunLog:
        log: RunLog = (MemoryLog(header) if opened == "memory"
                       else McapOpener(tmp_path / f"{name}.mcap")(header))
        logs[name] = log
        return log

    with pytest.raises(ZeroDivisionError), open_log("raised") as log:
        log.write_block(np.zeros(1, np.int64), np.zeros((1, N)))
        raise ZeroDivisionError("division by zero")
    with open_log("left"):
        pass
    expected = {"raised": failed_result(ZeroDivisionError("division by zero")),
                "left": {"status": "failed", "error": NO_RESULT}}
    assert expected["raised"]["error"] == "ZeroDivisionError: division by zero"
    for name, result in expected.items():
        log = logs[name]
        if isinstance(log, MemoryLog):
            assert log.closed and log.result == result
        else:
            assert read_run(tmp_path / f"{name}.mcap").metadata["result"] == result


# -- the same run through both -----------------------------------------------------------------

def test_the_mcap_log_and_the_memory_log_receive_the_same_run(
        fmu3: Path, tmp_path: Path) -> None:
    """One run logged to MCAP and to memory: the same rows bit for bit (the MCAP reader
    gives the written arrays back), the same result, header and attachments."""
    spec = _fig11(4.0)
    memory = MemoryOpener()
    with FmuPlant(fmu3) as plant:
        on_file = run_to_log(spec, tmp_path / "a.mcap", plant)
        in_memory = run_to_log(spec, memory, plant)
    log = memory.last
    assert in_memory["mcap"] is None and on_file["mcap"] == str(tmp_path / "a.mcap")
    assert {**in_memory, "mcap": on_file["mcap"]} == on_file
    assert log.closed and log.result == in_memory and log.sensing is None
    data = read_run(tmp_path / "a.mcap")
    assert data.n_steps == log.rows > 300
    assert np.array_equal(data.t_ns, log.t_ns)
    assert np.array_equal(_bits(data.block()), _bits(log.block))
    # the header: the run record (MCAP keeps non-strings as JSON), the goal, the attachments
    run = data.metadata["run"]
    assert run.keys() == log.header.run.keys()
    assert all(run[k] == (v if isinstance(v, str) else json.dumps(v, sort_keys=True))
               for k, v in log.header.run.items())
    assert log.header.goal == (spec.goal.x_m, spec.goal.y_m, spec.goal.heading_rad)
    assert (log.header.half_track_m, log.header.wheel_radius_m, log.header.stop_radius_m) == (
        spec.params.L, spec.params.r, spec.stop_radius_m)
    with open(tmp_path / "a.mcap", "rb") as f:
        attached = [(a.name, a.media_type, a.data) for a in make_reader(f).iter_attachments()]
    assert attached == list(log.header.attachments)


def test_the_log_attaches_the_model_description_of_the_fmu_the_run_ran(
        fmu3: Path, tmp_path: Path) -> None:
    """The attached ``modelDescription.xml`` is the one the plant extracted and runs, not
    the archive read again at log time: an FMU file replaced (or a batch thread's other FMU)
    after the plant opened does not change what the log says ran.  Seen failing when the
    archive was re-read by path (a replaced file made the run fail with BadZipFile)."""
    import shutil
    import zipfile

    fmu = tmp_path / "robot.fmu"
    shutil.copyfile(fmu3, fmu)
    with zipfile.ZipFile(fmu3) as zf:
        expected = zf.read("modelDescription.xml")
    memory = MemoryOpener()
    with FmuPlant(fmu) as plant:
        fmu.write_bytes(b"not an FMU any more")
        record = run_to_log(_fig11(1.0), memory, plant)
    assert record["status"] != "failed", record["message"]
    assert dict((a[0], a[2]) for a in memory.last.header.attachments)[
        "modelDescription.xml"] == expected


def test_a_run_with_sensors_writes_its_sensing_through_the_protocol(
        fmu3: Path, tmp_path: Path) -> None:
    """``write_sensing``: the in-memory log keeps the run's record, the MCAP log's sensing
    topics read back as it."""
    spec = replace(_fig11(2.0), sensors=SensorConfig(gps_rate_hz=10.0, gps_sigma_m=0.05))
    memory = MemoryOpener()
    with FmuPlant(fmu3) as plant:
        run_to_log(spec, memory, plant)
        run_to_log(spec, tmp_path / "s.mcap", plant)
    kept = memory.last.sensing
    trace = read_sensing(tmp_path / "s.mcap")
    assert kept is not None and trace is not None and len(kept.gps_t_ns) > 10
    assert np.array_equal(trace.gps_t_ns, kept.gps_t_ns)
    assert np.array_equal(trace.gps_xy_m, kept.gps_xy_m)
    assert np.array_equal(trace.est_pose[:, :2], kept.est_pose[:, :2])
    # the heading goes through a quaternion in the log
    assert np.allclose(trace.est_pose[:, 2], kept.est_pose[:, 2], rtol=0.0, atol=1e-12)


# -- log policies through the protocol ---------------------------------------------------------

def test_failed_only_opens_no_log_for_a_converged_run_and_the_whole_run_for_a_timeout(
        fmu3: Path) -> None:
    full, held = MemoryOpener(), MemoryOpener()
    with FmuPlant(fmu3) as plant:
        converged = run_to_log(_fig11(), held, plant, log=LogPolicy("failed"))
        assert converged["status"] == "converged" and converged["mcap"] is None
        assert held.logs == []  # nothing opened: no header made, no rows written
        run_to_log(_weak(), full, plant)
        timeout = run_to_log(_weak(), held, plant, log=LogPolicy("failed"))
    assert timeout["status"] == "timeout"
    (log,) = held.logs
    assert log.closed and log.result == timeout
    assert np.array_equal(log.t_ns, full.last.t_ns)
    assert np.array_equal(_bits(log.block), _bits(full.last.block))


def test_held_rows_spill_into_the_log_when_the_run_raises(fmu3: Path) -> None:
    """A run that raises under a failed-only policy is a failed run: its held rows are
    written to a log opened then, closed ``failed`` with the error."""
    held = MemoryOpener()

    def stop(t_s: float, t_max_s: float) -> None:
        if t_s > 1.0:
            raise KeyboardInterrupt

    with FmuPlant(fmu3) as plant, pytest.raises(KeyboardInterrupt):
        run_to_log(_fig11(), held, plant, progress=stop, log=LogPolicy("failed"))
    (log,) = held.logs
    assert log.result == {"status": "failed", "error": "KeyboardInterrupt: "}
    assert log.rows > 100 and log.t_ns[0] == 0


def test_a_spilled_run_that_converges_is_discarded(
        fmu3: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Past HOLD_ROWS the rows go to the log as the run goes; a run that then converges
    drops its log (``discard``), closed with its record."""
    monkeypatch.setattr(run_module, "HOLD_ROWS", 50)
    held = MemoryOpener()
    with FmuPlant(fmu3) as plant:
        record = run_to_log(_fig11(), held, plant, log=LogPolicy("failed"))
    (log,) = held.logs
    assert record["status"] == "converged" and record["mcap"] is None
    assert log.discarded and log.result == record and log.rows == record["steps"]


def test_every_kth_row_and_the_last_through_the_protocol(fmu3: Path) -> None:
    full, thin = MemoryOpener(), MemoryOpener()
    with FmuPlant(fmu3) as plant:
        run_to_log(_fig11(3.0), full, plant)
        run_to_log(_fig11(3.0), thin, plant, log=LogPolicy("full", every_k_steps=7))
    n = full.last.rows
    rows = sorted({*range(0, n, 7), n - 1})
    assert thin.last.t_ns.tolist() == full.last.t_ns[rows].tolist()
    assert np.array_equal(_bits(thin.last.block), _bits(full.last.block[rows]))
    assert thin.last.header.run["log_every_k_steps"] == 7
    assert "log_every_k_steps" not in full.last.header.run


def test_the_mcap_opener_is_the_writer_of_a_path(tmp_path: Path) -> None:
    """``McapOpener`` makes the log's folder, reports the open ``.partial`` file, and its
    log is the writer ``RunLogWriter(path, run=..., goal=..., attachments=...)`` makes: the
    same bytes."""
    header = LogHeader(run={"name": "r", "params": {"L": 0.3, "r": 0.15},
                            "stop_radius_m": 0.05},
                       goal=(1.0, 0.5, 0.25), attachments=(("a.txt", "text/plain", b"x"),),
                       half_track_m=0.3, wheel_radius_m=0.15, stop_radius_m=0.05)
    t = np.arange(250, dtype=np.int64) * 10_000_000
    block = np.linspace(0.0, 1.0, 250 * N).reshape(250, N)
    opened: list[bool] = []
    path = tmp_path / "new" / "o.mcap"
    with McapOpener(path, on_open=lambda p: opened.append(
            Path(str(p) + ".partial").exists()))(header) as log:
        assert isinstance(log, RunLog) and log.location == str(path)
        log.write_block(t, block)
        log.close({"status": "converged"})
    with RunLogWriter(tmp_path / "w.mcap", run=header.run, goal=header.goal,
                      attachments={"a.txt": ("text/plain", b"x")}, scene=True) as writer:
        writer.write_block(t, block)
        writer.close({"status": "converged"})
    assert opened == [True]
    assert path.read_bytes() == (tmp_path / "w.mcap").read_bytes()
