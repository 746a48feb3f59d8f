"""Issue 33, item 12: a simulation and a real robot's log of the same manoeuvre, overlaid.

The "real" log is the simulated run itself, as a robot's localisation would log it: written by
``mcap-protobuf-support``'s own Writer (``foxglove.PoseInFrame``, wall-clock times, 20 Hz,
not on the simulation's samples), standing still for a known time before it moves, and
displaced by a known offset.  The overlay must undo the time offset and measure the path
offset."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap_protobuf.writer import Writer as ProtobufWriter

import wmr
from test_replay import read_rrd, run_cli
from wmr.adapters.mcap import read_run
from wmr.adapters.rerun.overlay import DEVIATION_ENTITY
from wmr.core.compare import (
    MOTION_THRESHOLD_M,
    MOTION_THRESHOLD_RAD,
    motion_start_s,
    path_deviation_m,
)

#: The robot's logger starts this long before it moves (s), on the wall clock (ns).
STILL_S = 2.3456
T0_NS = 1_764_000_000_123_456_789
#: Its localisation's frame is off by this much (m).
OFFSET_M = (0.10, -0.05)
HZ = 20.0


# -- the definition ------------------------------------------------------------------------------


def test_start_of_motion_is_the_interpolated_threshold_crossing() -> None:
    """A robot at rest until 1 s, then at 0.5 m/s: 2 cm from its start at 1.04 s, found
    between 10 Hz samples (the distance is linear there: the interpolation is exact)."""
    t = np.arange(0, 3, 0.1)
    x = np.where(t > 1.0, 0.5 * (t - 1.0), 0.0)
    start = motion_start_s(t, x + 3.0, np.full_like(t, -2.0), np.zeros_like(t))
    assert start == pytest.approx(1.0 + MOTION_THRESHOLD_M / 0.5, abs=1e-12)
    # a turn in place is motion: 0.2 rad/s from 0.5 s
    th = np.where(t > 0.5, 0.2 * (t - 0.5), 0.0)
    assert motion_start_s(t, np.zeros_like(t), np.zeros_like(t), th) == pytest.approx(
        0.5 + MOTION_THRESHOLD_RAD / 0.2, abs=1e-12)
    # jitter below the thresholds is not motion
    rng = np.random.default_rng(1)
    assert motion_start_s(t, rng.uniform(-0.005, 0.005, t.size),
                          rng.uniform(-0.005, 0.005, t.size),
                          rng.uniform(-0.01, 0.01, t.size)) is None


def test_path_deviation_interpolates_the_reference_at_the_same_time() -> None:
    t_ref = np.array([0.0, 1.0, 2.0])
    ref = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    t, d = path_deviation_m(t_ref, ref, np.array([-0.5, 0.5, 1.5, 2.5]),
                            np.array([[9, 9], [0.5, 0.3], [1.4, 0.5], [9, 9]]))
    np.testing.assert_array_equal(t, [0.5, 1.5])  # outside the reference's span: none
    np.testing.assert_allclose(d, [0.3, 0.4])


# -- the overlay ---------------------------------------------------------------------------------


def write_real_log(path: Path, sim_log: Path, topics: tuple[str, ...] = ("/robot/pose",),
                   shift_s: float = 0.0) -> Path:
    """The simulated run as a real robot logs it (see the module's docstring): its pose at
    ``t - STILL_S`` (the first pose before), plus :data:`OFFSET_M`, at 20 Hz.  ``shift_s``
    moves the motion in the log by that much more (a misalignment the test plants)."""
    sim = read_run(sim_log)
    ts = sim.t_s
    tau = np.arange(0.0, STILL_S + ts[-1] + 1.0, 1.0 / HZ)
    at = np.clip(tau - STILL_S - shift_s, 0.0, ts[-1])
    x = np.interp(at, ts, sim.signals["x_m"]) + OFFSET_M[0]
    y = np.interp(at, ts, sim.signals["y_m"]) + OFFSET_M[1]
    yaw = np.interp(at, ts, sim.signals["theta_rad"])
    with path.open("wb") as f:
        w = ProtobufWriter(f)
        for ti, xi, yi, th in zip(tau, x, y, yaw, strict=True):
            ns = T0_NS + round(ti * 1e9)
            m = PoseInFrame(frame_id="odom")
            m.timestamp.FromNanoseconds(ns)
            m.pose.position.x, m.pose.position.y = xi, yi
            m.pose.orientation.z, m.pose.orientation.w = math.sin(th / 2), math.cos(th / 2)
            for topic in topics:
                w.write_message(topic, m, log_time=ns, publish_time=ns)
        w.finish()
    return path


def _deviation(rrd: Path) -> tuple[np.ndarray, np.ndarray]:
    ents, _ = read_rrd(rrd)
    ent = ents[f"/runs/robot/{DEVIATION_ENTITY}"]
    values = np.concatenate([np.concatenate(c.to_pylist()) for c in
                             ent.columns["Scalars:scalars"]])
    times = np.concatenate([np.asarray(c.to_numpy(), "timedelta64[ns]").astype(np.int64)
                            for c in ent.times]) * 1e-9
    return times, values


@pytest.mark.parametrize("planted_s", [0.0, 0.25])
def test_a_real_robots_log_is_aligned_at_the_start_of_motion_and_its_deviation_plotted(
        fig11_log: Path, tmp_path: Path, planted_s: float) -> None:
    """``wmr replay SIM REAL``: REAL's times shifted by -STILL_S (its motion starts with the
    simulation's), and the deviation panel is the known offset all along.  With the motion
    planted a quarter second later in REAL than the offset says (``planted_s``), the
    shift follows it, so the deviation still equals the offset: the alignment is by the
    motion, not by the log's start."""
    real = write_real_log(tmp_path / "robot.mcap", fig11_log, shift_s=planted_s)
    out = tmp_path / "overlay.rrd"
    rc, stdout, stderr = run_cli("replay", str(fig11_log), str(real), "--rrd", str(out))
    assert rc == 0, stderr
    assert stdout.strip() == str(out)
    [line] = [x for x in stderr.splitlines() if "aligned to" in x]
    shift = float(line.split("shifted by ")[1].split(" s")[0])
    assert shift == pytest.approx(-(STILL_S + planted_s), abs=0.005), line
    t, dev = _deviation(out)
    sim = read_run(fig11_log)
    # every 20 Hz sample of the robot inside the simulated run's span
    assert t.size == pytest.approx(sim.t_s[-1] * HZ, abs=2) and t[0] >= 0
    np.testing.assert_allclose(dev, math.hypot(*OFFSET_M), atol=0.004)
    ents, _ = read_rrd(out)
    # the robot's path, drawn as logged (the offset kept), and its pose on the shared axis
    robot_t = np.concatenate([np.asarray(c.to_numpy(), "timedelta64[ns]").astype(np.int64)
                              for c in ents["/runs/robot/world/robot"].times]) * 1e-9
    assert robot_t[0] == pytest.approx(shift, abs=5e-4)  # shift: printed to the ms
    [[summary]] = ents["/summary"].columns["TextDocument:text"][0].to_pylist()
    assert line.removeprefix("wmr: ") in summary
    [robot_row] = [r for r in summary.splitlines() if r.endswith("| `robot` |")]
    assert "| poses only |" in robot_row


def test_a_misaligned_overlay_would_show_in_the_deviation(fig11_log: Path,
                                                          tmp_path: Path) -> None:
    """The independent check that the deviation can see a misalignment: the same logs put
    on their own times (each from its first sample: no alignment) are metres apart."""
    real = read_run(write_real_log(tmp_path / "robot.mcap", fig11_log))
    sim = read_run(fig11_log)
    _, dev = path_deviation_m(sim.t_s, np.column_stack([sim.signals["x_m"], sim.signals["y_m"]]),
                              real.t_s, np.column_stack([real.signals["x_m"],
                                                         real.signals["y_m"]]))
    assert dev.max() > 1.0


def test_pose_topic_names_the_robots_topic_in_the_overlay(fig11_log: Path,
                                                          tmp_path: Path) -> None:
    """A robot's log with poses on two topics: refused until ``--pose-topic`` names one,
    which applies to it, not to our log (which has ``/robot/pose`` too); the API's
    ``pose_topic`` is the same."""
    real = write_real_log(tmp_path / "robot.mcap", fig11_log,
                          topics=("/odom/pose", "/robot/pose"))
    out = tmp_path / "overlay.rrd"
    rc, _, stderr = run_cli("replay", str(fig11_log), str(real), "--rrd", str(out))
    assert rc == 4 and "name the robot's with --pose-topic TOPIC" in stderr, stderr
    rc, _, stderr = run_cli("replay", str(fig11_log), str(real), "--rrd", str(out),
                            "--pose-topic", "/odom/pose")
    assert rc == 0, stderr
    assert "a pose-only log (foxglove.PoseInFrame on /odom/pose)" in stderr
    assert "robot aligned to fig11" in stderr
    result = wmr.replay([fig11_log, real], rrd=tmp_path / "api.rrd", pose_topic="/odom/pose")
    assert not isinstance(result, Path | list)
    [line] = result.aligned
    assert line.startswith("robot aligned to fig11 at the start of motion")


def test_a_strangers_times_at_the_int64_edge_are_not_wrapped_around() -> None:
    """A hostile log whose last pose is a few ms short of 2^63 ns: shifted by the alignment
    it would wrap around to negative times; it is replayed unaligned, with one line."""
    from wmr.adapters.mcap import RunData
    from wmr.adapters.rerun.overlay import align_runs

    def run(t_ns: np.ndarray, pose_topic: str | None) -> RunData:
        t = t_ns.astype(np.float64) * 1e-9
        x = np.clip(t - 1.0, 0.0, 1.0)  # moves from 1 s on (0.02 m at 1.02 s)
        zeros = np.zeros_like(t)
        return RunData(path="x", t_ns=t_ns, signals={"x_m": x, "y_m": zeros,
                                                     "theta_rad": zeros},
                       pose_topic=pose_topic)

    sim = run(np.arange(0, 3_000_000_000, 10_000_000, dtype=np.int64), None)
    # the robot moves at once: it is shifted later by about a second
    edge = np.array([0, 100_000_000, 200_000_000, 2**63 - 1_000_000], np.int64)
    robot = run(edge, "/robot/pose")
    robot.signals["x_m"][:] = [0.0, 0.5, 1.0, 1.0]
    runs, alignments, warnings = align_runs(["sim", "robot"], [sim, robot])
    assert alignments == [] and runs[1] is robot
    [line] = warnings
    assert "robot is not aligned to sim" in line and "int64" in line


def test_a_pose_only_log_varies_no_input_of_the_runs_beside_it() -> None:
    """The multi-run table lists the inputs that differ between runs; a real robot's log has
    no run record, so beside one simulation it makes no column (before: every input of the
    simulation was a column, '?' for the robot)."""
    from wmr.adapters.rerun.replay import varied_inputs

    sim = _FakeRun({"run": {"params": '{"m": 25.0}', "controller": "pi"}})
    other = _FakeRun({"run": {"params": '{"m": 30.0}', "controller": "pi"}})
    robot = _FakeRun({})
    assert varied_inputs([sim, robot]) == []  # type: ignore[list-item]
    assert varied_inputs([sim, other, robot]) == ["params.m"]  # type: ignore[list-item]


class _FakeRun:
    def __init__(self, metadata: dict[str, dict[str, str]]) -> None:
        self.metadata = metadata
