"""Issue 33, items 12-14: logs of real robots (poses only), the control phase in
``wmr.read_log``, and a spawned viewer that keeps none of the caller's pipes."""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap_protobuf.writer import Writer as ProtobufWriter
from numpy.typing import NDArray

import wmr
from test_replay import read_rrd, run_cli
from wmr.adapters.mcap import read_run
from wmr.adapters.mcap.reader import ReadLimits
from wmr.adapters.mcap.scene import ALIGN, APPROACH, control_phases
from wmr.adapters.rerun.replay import VIEWER_PORT, _listening
from wmr.infra.errors import LogError

# -- item 14: the spawned viewer and the caller's pipe -------------------------------------------

_FAKE_VIEWER = """#!/bin/sh
# a viewer that never exits (nor listens), chatty like Rerun's INFO/WARN lines
echo $$ > "{pid_file}"
i=0
while [ $i -lt 50 ]; do
  echo "INFO fake viewer line $i"; echo "WARN fake viewer $i" >&2; i=$((i+1))
done
exec sleep 600
"""


def test_a_spawned_viewer_keeps_neither_our_pipe_nor_our_terminal(
        fig11_log: Path, tmp_path: Path) -> None:
    """Before: ``wmr replay LOG 2>&1 | tail`` waited as long as the viewer ran (rr.spawn let it
    inherit our stdout/stderr) and its lines came out on ours.  Now it gets neither: our pipe
    closes when wmr ends; its lines are in its own log in the cache."""
    if _listening(VIEWER_PORT):
        pytest.skip(f"a viewer already listens on port {VIEWER_PORT}: nothing would be spawned")
    fake_bin = tmp_path / "bin"
    fake_bin.mkdir()
    pid_file = tmp_path / "viewer.pid"
    fake = fake_bin / "rerun"
    fake.write_text(_FAKE_VIEWER.format(pid_file=pid_file))
    fake.chmod(0o755)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), DISPLAY=":77",
               PATH=f"{fake_bin}{os.pathsep}{os.environ.get('PATH', '')}",
               WMR_CACHE_DIR=str(tmp_path / "cache"))
    log = tmp_path / "fig11.mcap"
    log.write_bytes(fig11_log.read_bytes())
    proc = subprocess.Popen([sys.executable, "-m", "wmr.cli", "replay", str(log)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    start = time.monotonic()
    try:
        out, _ = proc.communicate(timeout=90)  # to EOF of the pipe: every writer has closed it
        took_s = time.monotonic() - start
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise
    finally:
        if pid_file.exists():
            os.kill(int(pid_file.read_text()), signal.SIGKILL)
    text = out.decode()
    assert pid_file.exists(), "the fake viewer was not started"
    assert took_s < 60
    assert "fake viewer" not in text
    # it never listened: the recording went to a file, said in one line
    assert "not listening on port" in text and log.with_suffix(".rrd").is_file(), text
    assert "INFO fake viewer line 49" in (tmp_path / "cache" / "viewer.log").read_text()


# -- item 13: the control phase in wmr.read_log ---------------------------------------------------


def test_read_log_gives_the_logged_control_phase_at_each_row(fig11_log: Path) -> None:
    """Before: ``/controller/phase`` was logged but ``wmr.read_log`` had no phase.  Now
    ``Log.phase`` is a column on the rows' index: the logged step plot, forward-filled, which
    is the stabiliser's hysteresis on the logged distance to the goal."""
    log = wmr.read_log(fig11_log)
    phase = log.phase
    assert phase is not None and phase.name == "phase"
    assert phase.index.equals(log.signals.index)
    expected = control_phases(log.signals["dr_m"].to_numpy(),
                              float(log.metadata["run"]["stop_radius_m"]))
    np.testing.assert_array_equal(phase.to_numpy(), expected.astype(np.float64))
    # fig11 approaches, then aligns inside the stop radius until it converges
    assert phase.iloc[0] == APPROACH and phase.iloc[-1] == ALIGN
    assert set(np.unique(phase.to_numpy())) == {APPROACH, ALIGN}


def test_a_log_without_the_phase_topic_has_no_phase(fig11_log: Path, tmp_path: Path) -> None:
    """A log without ``/controller/phase`` (a killed run's) says so: ``phase`` is None."""
    cut = tmp_path / "cut.mcap"
    data = fig11_log.read_bytes()
    cut.write_bytes(data[: len(data) // 2])  # the scene topics are written at close
    log = wmr.read_log(cut)
    assert log.truncated and len(log.signals) > 0
    assert log.phase is None


# -- item 12: logs of real robots (poses only) ----------------------------------------------------

#: The real robot's log: wall-clock log times (ns since 1970), 20 Hz.
_T0_NS = 1_764_000_000_000_000_000
_HZ = 20
#: It stands still for this long (its pose jitters by a few mm), then drives an arc.
_STILL_S = 2.0
_RADIUS_M, _OMEGA_RADPS, _DRIVE_S = 2.0, 0.5, 10.0


def _robot_truth() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Times (s from the first pose) and the poses (x_m, y_m, yaw_rad) a real robot logs."""
    t = np.arange(int((_STILL_S + _DRIVE_S) * _HZ)) / _HZ
    rng = np.random.default_rng(33)
    drive = np.clip(t - _STILL_S, 0.0, None)
    yaw = _OMEGA_RADPS * drive
    x = _RADIUS_M * np.sin(yaw) + rng.uniform(-0.002, 0.002, t.size) * (drive == 0)
    y = _RADIUS_M * (1.0 - np.cos(yaw))
    return t, np.column_stack([x, y, yaw])


def write_robot_log(path: Path, schema: str = "PoseInFrame",
                    topics: tuple[str, ...] = ("/robot/pose",)) -> Path:
    """A real robot's log as Foxglove's own tools write it: ``mcap-protobuf-support``'s
    Writer (schemas from the messages' own descriptors), ``foxglove_schemas_protobuf``
    messages, wall-clock times, no metadata of ours."""
    cls = PoseInFrame if schema == "PoseInFrame" else FrameTransform
    t, poses = _robot_truth()
    with path.open("wb") as f:
        w = ProtobufWriter(f)
        for ti, (x, y, yaw) in zip(t, poses, strict=True):
            ns = _T0_NS + round(ti * 1e9)
            m = cls()
            m.timestamp.FromNanoseconds(ns)
            pos, q = (m.pose.position, m.pose.orientation) if schema == "PoseInFrame" else (
                m.translation, m.rotation)
            if schema == "PoseInFrame":
                m.frame_id = "odom"
            else:
                m.parent_frame_id, m.child_frame_id = "odom", "base_link"
            pos.x, pos.y = x, y
            q.z, q.w = math.sin(yaw / 2), math.cos(yaw / 2)
            for topic in topics:
                w.write_message(topic, m, log_time=ns, publish_time=ns)
        w.finish()
    return path


@pytest.mark.parametrize("schema", ["PoseInFrame", "FrameTransform"])
def test_read_log_reads_a_real_robots_pose_only_log(tmp_path: Path, schema: str) -> None:
    """Before: ``wmr.read_log`` of a log holding only Foxglove poses gave 0 rows without a
    word.  Now: a row per pose, x_m, y_m and the quaternion's yaw (unwrapped), from the first
    pose, the other signals NaN, and one warning saying it is a pose-only log."""
    path = write_robot_log(tmp_path / "robot.mcap", schema)
    t, truth = _robot_truth()
    log = wmr.read_log(path)
    assert len(log.signals) == t.size
    np.testing.assert_allclose(log.signals.index.to_numpy(), t, atol=1e-9)
    np.testing.assert_allclose(log.signals[["x_m", "y_m"]].to_numpy(), truth[:, :2], atol=1e-12)
    # 5 rad at the end: the heading unwrapped past pi, as ours
    np.testing.assert_allclose(log.signals["theta_rad"].to_numpy(), truth[:, 2], atol=1e-9)
    assert log.signals["theta_rad"].iloc[-1] > math.pi
    assert log.signals.drop(columns=["x_m", "y_m", "theta_rad"]).isna().all().all()
    pose_lines = [w for w in log.warnings if "pose-only log" in w]
    assert pose_lines == [f"a pose-only log (foxglove.{schema} on /robot/pose): x_m, y_m, "
                          "theta_rad from its poses, the other signals NaN"]
    assert not log.truncated and log.phase is None


def test_a_pose_log_on_several_topics_is_refused_until_one_is_named(tmp_path: Path) -> None:
    path = write_robot_log(tmp_path / "robot.mcap", topics=("/odom/pose", "/robot/pose"))
    with pytest.raises(LogError, match=r"on 2 topics \(/odom/pose, /robot/pose\): name the "
                                       r"robot's with --pose-topic TOPIC"):
        wmr.read_log(path)
    assert len(wmr.read_log(path, pose_topic="/odom/pose").signals) == _robot_truth()[0].size
    with pytest.raises(LogError, match=r"no foxglove\.PoseInFrame or foxglove\.FrameTransform "
                                       r"topic '/nope'"):
        wmr.read_log(path, pose_topic="/nope")


def test_a_pose_log_is_read_within_the_read_budget(tmp_path: Path) -> None:
    """A stranger's file goes through the same bounded reader as ours: past the budget, the
    poses that fit, marked truncated, with the limit named."""
    path = write_robot_log(tmp_path / "robot.mcap")
    data = read_run(path, ReadLimits(total_bytes=128 << 10))
    assert data.pose_topic == "/robot/pose"
    assert data.truncated and 0 < data.n_steps < _robot_truth()[0].size
    assert any("ReadLimits.total_bytes" in w for w in data.warnings)


def test_wmr_replay_replays_a_real_robots_pose_only_log(tmp_path: Path) -> None:
    """Before: ``wmr replay robot.mcap`` refused it ("no readable control step ... topic
    /robot/state is missing").  Now its path and pose are replayed, with the one line saying
    it is a pose-only log."""
    path = write_robot_log(tmp_path / "robot.mcap")
    out = tmp_path / "robot.rrd"
    rc, stdout, stderr = run_cli("replay", str(path), "--rrd", str(out))
    assert stdout.strip() == str(out)
    assert rc == 0, stderr
    assert "a pose-only log (foxglove.PoseInFrame on /robot/pose)" in stderr
    ents, _ = read_rrd(out)
    [strip] = ents["/runs/robot/world/path"].column("LineStrips2D:strips")
    np.testing.assert_allclose(np.array(strip)[0], _robot_truth()[1][:, :2], atol=1e-6)
