"""The drawable topics of a run log (wmr.adapters.mcap.scene): the phase is the stabiliser's,
the point clouds decode as Foxglove's schema says, and a failing scene never costs the log."""

from __future__ import annotations

import math
import warnings
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader

from wmr.adapters.mcap import RunLogWriter, read_run
from wmr.adapters.mcap import scene as scene_mod
from wmr.adapters.mcap.scene import (
    GOAL_TOPIC,
    PATH_TOPIC,
    PHASE_COLORS,
    PHASE_TOPIC,
    ROBOT_PERIOD_NS,
    ROBOT_TOPIC,
    ControlPhase,
    control_phases,
    phase_changes,
    read_cloud,
    robot_outline,
)
from wmr.core.control.registry import BUILTIN_NAMES, make_controller
from wmr.core.plant import Pose
from wmr.core.runspec import RunSpec
from wmr.core.signals import COLUMN, SIGNALS
from wmr.infra.errors import DiskFullError

EPS_M = 0.05


def _distances() -> np.ndarray:
    """A distance history that crosses every threshold of the hysteresis both ways: in to
    the alignment, out but not beyond 2 eps (stays aligned), beyond it (back to approach),
    and in again."""
    return np.concatenate([np.linspace(1.0, 0.03, 40), [0.025, 0.02, 0.06, 0.09, 0.1, 0.1001,
                                                         0.08, 0.03, 0.0249, 0.0]])


@pytest.mark.parametrize("name", BUILTIN_NAMES)
def test_phases_are_the_stabilisers(name: str) -> None:
    """Replayed on the distance it logged, the hysteresis gives the controller's own phase at
    every step (for the PI and its peers)."""
    ctrl = make_controller(RunSpec(name=name, start=Pose(-1.0, 0.0, 0.0), goal=Pose(0.0, 0.0, 0.0),
                                   period_s=0.01, stop_radius_m=EPS_M, controller=name))
    stab: Any = ctrl.stabiliser  # the PI's Stabiliser or a peer's: each has .phase
    seen, dr = [], []
    for k, d in enumerate(_distances()):
        a = 0.3 * k  # from all sides
        x, y = -d * math.cos(a), -d * math.sin(a)
        out = stab.update(x, y, 0.1 * k)
        dr.append(out[0])
        seen.append(stab.phase)
    assert set(seen) == {0, 1} and seen.count(1) > 2
    np.testing.assert_array_equal(control_phases(np.array(dr), EPS_M), seen)


def test_phase_topic_is_a_step_at_each_change() -> None:
    t = np.arange(10, dtype=np.int64) * 10
    phase = np.array([0, 0, 0, 1, 1, 0, 0, 0, 1, 1], np.int8)
    pt, pv = phase_changes(t, phase)
    np.testing.assert_array_equal(pt, [0, 20, 30, 40, 50, 70, 80, 90])
    np.testing.assert_array_equal(pv, [0, 0, 1, 1, 0, 0, 1, 1])


@given(st.lists(st.integers(0, 1), min_size=1, max_size=60))
def test_phase_changes_are_the_first_last_and_both_sides_of_each_change(
        phases: list[int]) -> None:
    """Against the definition, with Python sets: every row once, in time order, also when
    changes are adjacent (rows shared by two changes) or the run is one row long."""
    phase = np.array(phases, np.int8)
    t = np.arange(len(phases), dtype=np.int64) * 7 + 3
    want = {0, len(phases) - 1}
    for i in range(1, len(phases)):
        if phases[i] != phases[i - 1]:
            want |= {i - 1, i}
    pt, pv = phase_changes(t, phase)
    assert pt.tolist() == [int(t[i]) for i in sorted(want)]
    assert pv.tolist() == [phases[i] for i in sorted(want)]


def _log(path: Path, n: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """A made-up closed-loop log: a straight approach to the goal at (3, 0), then a turn in
    place inside the stop radius."""
    t = np.arange(n, dtype=np.int64) * 10_000_000
    block = np.zeros((n, len(SIGNALS)))
    x = np.minimum(np.linspace(0.0, 3.2, n), 3.0)
    block[:, COLUMN["x_m"]] = x
    block[:, COLUMN["theta_rad"]] = np.where(x >= 3.0, np.linspace(0, 1, n), 0.0)
    block[:, COLUMN["dr_m"]] = np.abs(3.0 - x)
    run = {"stop_radius_m": EPS_M, "params": {"L": 0.3, "r": 0.15}}
    with RunLogWriter(path, run=run, goal=(3.0, 0.0, 1.0), scene=True) as log:
        log.write_block(t, block)
        log.close({"status": "converged"})
    return t, block


def _messages(path: Path, topic: str) -> list[tuple[int, bytes]]:
    with open(path, "rb") as f:
        return [(m.log_time, m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]


def test_scene_clouds_decode_through_their_own_fields(tmp_path: Path) -> None:
    """Read the way Foxglove's reader does (fields, offsets, stride from the message): the
    robot is its outline placed at the logged pose every 50 ms, coloured by phase; the path
    passes through the logged positions; the goal arrow starts at the goal."""
    path = tmp_path / "run.mcap"
    t, block = _log(path)
    robot = _messages(path, ROBOT_TOPIC)
    first = np.flatnonzero(np.diff(t // ROBOT_PERIOD_NS, prepend=-1) != 0)
    assert [lt for lt, _ in robot] == t[first].tolist()
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

    body = robot_outline(0.3, 0.15)
    phase = control_phases(block[:, COLUMN["dr_m"]], EPS_M)
    assert phase[0] == 0 and phase[-1] == 1
    for (_, data), row in zip(robot, first, strict=True):
        pos, rgba = read_cloud(data)
        np.testing.assert_allclose(pos[:, :2], body, atol=1e-6)  # the body, in its own frame
        msg = PointCloud.FromString(data)
        assert msg.frame_id == "world"
        assert msg.pose.position.x == pytest.approx(block[row, COLUMN["x_m"]])
        theta = 2 * math.atan2(msg.pose.orientation.z, msg.pose.orientation.w)
        assert theta == pytest.approx(block[row, COLUMN["theta_rad"]])
        assert tuple(rgba[0, :3]) == PHASE_COLORS[phase[row]]
    [(t0, data)] = _messages(path, PATH_TOPIC)
    pos, _ = read_cloud(data)
    assert t0 == 0 and len(pos) > 10
    assert np.allclose(pos[:, 1], 0.0) and pos[0, 0] == 0.0 and pos[-1, 0] == pytest.approx(3.0)
    [(_, data)] = _messages(path, GOAL_TOPIC)
    pos, _ = read_cloud(data)
    np.testing.assert_allclose(pos[0, :2], [3.0, 0.0], atol=1e-6)
    phases = [ControlPhase.FromString(d).phase for _, d in _messages(path, PHASE_TOPIC)]
    assert phases[0] == 0.0 and phases[-1] == 1.0
    # the signal topics are those of a log without a scene: read back bit for bit
    back = read_run(path)
    np.testing.assert_array_equal(back.block(), block)


def test_a_failing_scene_keeps_the_log(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*args: object) -> bytes:
        raise ValueError("no scene today")

    monkeypatch.setattr(scene_mod, "cloud_message", broken)
    path = tmp_path / "run.mcap"
    with pytest.warns(RuntimeWarning, match="scene topics were not written"):
        _, block = _log(path)
    back = read_run(path)
    assert back.metadata["result"]["status"] == "converged"
    np.testing.assert_array_equal(back.block(), block)


def _cloud_cases() -> list[tuple[float, float, float, int]]:
    """Poses ``(x, y, theta)`` and times: random ones, and every zero, -0.0 and sign case of x,
    y and the heading."""
    import random

    rng = random.Random(11)
    specials = [0.0, -0.0, 1e-300, -7.5, 12.0]
    cases = [(x, y, th, t) for x in specials for y in specials
             for th in (0.0, -0.0, math.pi, -math.pi, 2 * math.pi, 1.0)
             for t in (0, 1, 999_999_999, 1_000_000_000, 12_345_678_901)]
    cases += [(rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-10, 10),
               rng.randrange(0, 10**12)) for _ in range(3000)]
    return cases


def _whole_cloud(pts: Any, x: float, y: float, th: float, t: int) -> bytes:
    """A placed cloud serialised whole by protobuf."""
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

    from wmr.adapters.mcap.scene import _FIELDS

    whole = PointCloud(frame_id="world", point_stride=16, fields=_FIELDS, data=pts.tobytes())
    whole.timestamp.FromNanoseconds(t)
    whole.pose.position.x, whole.pose.position.y = x, y
    whole.pose.orientation.z = math.sin(0.5 * th)
    whole.pose.orientation.w = math.cos(0.5 * th)
    return bytes(whole.SerializeToString(deterministic=True))


def test_cloud_messages_are_protobuf_s_own_bytes() -> None:
    """The concatenated parts (cached timestamps, directly packed poses) against one
    PointCloud serialised whole by protobuf."""
    from wmr.adapters.mcap.scene import cloud_message, cloud_points

    pts = cloud_points([[0.0, 0.0], [1.0, -2.5], [3.25, 0.5]], (10, 20, 30))
    for x, y, th, t in _cloud_cases():
        assert cloud_message(t, pts, (x, y, th)) == _whole_cloud(pts, x, y, th, t), (x, y, th, t)


def test_placed_clouds_records_are_mcap_s_of_protobuf_s_bytes() -> None:
    """The C stepper's records of the robot's outlines (``PlacedClouds.records``, one call for
    all) against the ``mcap`` library's Message records of each cloud serialised whole by
    protobuf, in two variants (the phases' colours), in order, sequence numbers 0, 1, ...;
    the sequence's own items are the same messages; their CRC is zlib's."""
    from mcap.data_stream import RecordBuilder
    from mcap.records import Message

    from wmr.adapters.mcap.scene import PlacedClouds, cloud_points, cloud_tail

    shapes = tuple(cloud_points([[0.0, 0.0], [1.0, -2.5], [3.25, 0.5], [k, 1.0]], (10, 20, k))
                   for k in (1, 2))
    cases = _cloud_cases()
    t = np.array([c[3] for c in cases], np.int64)
    poses = np.array([c[:3] for c in cases], np.float64)
    variants = (np.arange(len(cases)) % 3 == 0).astype(np.int8)
    clouds = PlacedClouds(t, poses, variants, (shapes, tuple(cloud_tail(s) for s in shapes)))
    built = clouds.records(channel=513)
    assert built is not None, "the C stepper is not there"
    records, offsets, crc = built
    expected = RecordBuilder()
    starts = []
    for i, ((x, y, th, ti), v) in enumerate(zip(cases, variants.tolist(), strict=True)):
        starts.append(expected.count)
        data = _whole_cloud(shapes[v], x, y, th, ti)
        assert clouds[i] == data, (x, y, th, ti)
        Message(channel_id=513, sequence=i, log_time=ti, publish_time=ti, data=data
                ).write(expected)
    assert bytes(records) == expected.end()
    assert offsets.tolist() == starts
    assert crc == zlib.crc32(records)  # made from the tails' own CRCs


def test_a_long_run_has_at_most_max_outlines_robot_clouds(tmp_path: Path) -> None:
    """Closing the log of a long run stays quick: at most MAX_OUTLINES outlines, evenly spaced
    at a whole multiple of the period; a run of 200 s or less keeps one per period."""
    from wmr.adapters.mcap.scene import MAX_OUTLINES, ROBOT_PERIOD_NS, robot_period_ns

    assert robot_period_ns(0) == ROBOT_PERIOD_NS
    assert robot_period_ns(MAX_OUTLINES * ROBOT_PERIOD_NS - 1) == ROBOT_PERIOD_NS
    assert robot_period_ns(MAX_OUTLINES * ROBOT_PERIOD_NS) == 2 * ROBOT_PERIOD_NS
    for last_s in (1.0, 199.99, 200.0, 1234.5, 3000.0):
        last = round(last_s * 1e9)
        period = robot_period_ns(last)
        assert period % ROBOT_PERIOD_NS == 0
        assert last // period + 1 <= MAX_OUTLINES, last_s
    n = 300_001  # 3000 s at 100 Hz
    t = np.arange(n, dtype=np.int64) * 10_000_000
    rows = np.zeros((n, 4))
    rows[:, 0] = np.linspace(0.0, 1.0, n)
    rows[:, 3] = 5.0
    rec = scene_mod.SceneRecorder({"stop_radius_m": "0.05"}, (0.0, 0.0, 0.0), controlled=True)
    rec._t, rec._rows = [t], [rows]

    class Log:
        def __init__(self) -> None:
            self.topics: dict[str, int] = {}

        def write_messages(self, topic: str, schema_name: str, schema_data: bytes,
                           t_ns: Any, messages: list[bytes]) -> None:
            self.topics[topic] = len(messages)

    log = Log()
    rec._write(log)
    # every 0.8 s (16 periods: 15 would give 4001), 0 to 3000 s
    assert log.topics[scene_mod.ROBOT_TOPIC] == 3751 <= MAX_OUTLINES


@pytest.mark.parametrize("error", [DiskFullError("no space left on /x while writing y"),
                                   OSError(5, "Input/output error"), ValueError("a drawing")])
def test_a_full_disk_is_the_log_s_failure_a_drawing_s_only_warns(error: Exception) -> None:
    """The scene's failures warn and leave the signal topics as they are, but a file that
    cannot be written (a full disk, an I/O error) is raised as itself, not a warning."""
    rec = scene_mod.SceneRecorder({"stop_radius_m": "0.05"}, (0.0, 0.0, 0.0), controlled=True)

    class Log:
        def write_messages(self, *args: Any) -> None:
            raise error

    if isinstance(error, OSError | DiskFullError):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(type(error)):
                rec.write(Log())
    else:
        with pytest.warns(RuntimeWarning, match="scene topics were not written: ValueError"):
            rec.write(Log())


@pytest.mark.parametrize("name", ["layout.json", "layout-gps-zoom.json"])
def test_the_lichtblick_layouts_name_only_what_our_logs_write(name: str) -> None:
    """The layouts of docs/replay.md's Lichtblick check (``tools/lichtblick/``) show topics,
    frames and plotted fields our logs hold: a topic or field renamed in the code would leave
    a panel silently empty in the viewer. Seen failing with ``/robot/state.x_m`` misspelt in a
    plot path."""
    import json

    from wmr.adapters.mcap.schemas import BASE_FRAME, GOAL_TOPIC, STEP_TOPICS, WORLD_FRAME
    from wmr.adapters.mcap.sensing import ESTIMATE_TOPIC, GPS_TOPIC
    from wmr.infra.paths import _REPO_ROOT

    layout = json.loads((_REPO_ROOT / "tools" / "lichtblick" / name).read_text(encoding="utf-8"))
    panels = layout["configById"]
    scene_topics = {ROBOT_TOPIC, PATH_TOPIC, GOAL_TOPIC, scene_mod.GOAL_TOPIC,
                    scene_mod.GPS_SCENE_TOPIC, scene_mod.ESTIMATE_SCENE_TOPIC, GPS_TOPIC,
                    ESTIMATE_TOPIC}
    three_d = panels["3D!wmr"]
    assert three_d["followTf"] == WORLD_FRAME
    assert set(three_d["topics"]) <= scene_topics
    assert {k.removeprefix("frame:") for k in three_d["transforms"]} <= {WORLD_FRAME, BASE_FRAME}
    fields = {f"{t.topic}.{s}" for t in STEP_TOPICS for s in t.signals}
    paths = [p["value"] for p in panels["Plot!wmr"]["paths"]]
    assert paths and set(paths) <= fields, set(paths) - fields
    # the layout tree names exactly the panels configured
    tree = layout["layout"]
    assert {tree["first"], tree["second"]} == set(panels)
