"""The drawable topics of a run log (wmr.adapters.mcap.scene): the phase is the stabiliser's,
the point clouds decode as Foxglove's schema says, the robot is drawn once per phase in its own
frame (the log's ``/tf`` moves it), and a failing scene never costs the log."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from wmr.adapters.mcap import RunLogWriter, read_run
from wmr.adapters.mcap import scene as scene_mod
from wmr.adapters.mcap.scene import (
    GOAL_TOPIC,
    PATH_TOPIC,
    PHASE_COLORS,
    PHASE_TOPIC,
    ROBOT_TOPIC,
    ControlPhase,
    control_phases,
    phase_changes,
    read_cloud,
    resample_path,
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


@given(st.lists(st.sampled_from([0.0, 0.02, 0.025, 0.03, 0.1, 0.11, 5.0, math.nan]),
                max_size=60), st.sampled_from([0, 1]))
def test_phases_are_the_hysteresis_step_by_step(dr: list[float], start: int) -> None:
    """Against the definition, one step at a time: into the alignment at ``dr <= eps / 2``,
    back to the approach only at ``dr > 2 eps``, the phase kept in between and on NaN, from
    ``start``; runs of kept steps at the start, the end, and between switches."""
    want, phase = [], start
    for d in dr:
        if d <= 0.5 * EPS_M:
            phase = 1
        elif d > 2 * EPS_M:
            phase = 0
        want.append(phase)
    got = control_phases(np.array(dr, np.float64), EPS_M, start_phase=start)
    assert got.dtype == np.int8 and got.tolist() == want


@pytest.mark.parametrize("params", [
    {"L": 0.3, "r": 0.15}, {"L": 0.25}, {}, {"L": -1.0, "r": 0.1}, {"L": math.nan, "r": 0.1},
    {"L": "0.4", "r": True}, {"L": "wide", "r": 0.1}, {"L": [0.3], "r": 0.1},
    {"L": math.inf, "r": 0.1}, {"L": 1e308, "r": 1e308}])
def test_the_robot_s_geometry_is_the_same_from_the_run_mapping_and_from_its_json(
        params: dict[str, Any]) -> None:
    """The writer hands the scene the run's own mapping (no JSON round trip per log); a log's
    record is JSON text: the same geometry from both, the paper's where a value is unusable."""
    import json

    from wmr.adapters.mcap.scene import robot_geometry

    assert robot_geometry({"params": params}) == robot_geometry(
        {"params": json.dumps(params, allow_nan=True)})


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


@given(st.lists(st.tuples(st.floats(-5, 5) | st.just(math.nan), st.floats(-5, 5)),
                min_size=1, max_size=80),
       st.sampled_from([0.01, 0.3, 1.0]))
def test_the_path_keeps_a_row_per_spacing_of_its_arc_length(
        xy: list[tuple[float, float]], spacing_m: float) -> None:
    """Against the definition, step by step: the finite rows, their arc length summed from
    ``np.linalg.norm`` of each step, the first row, each row entering a new multiple of the
    spacing, and the last."""
    pts = np.array(xy, np.float64).reshape(-1, 2)
    ok = [i for i, (x, y) in enumerate(xy) if math.isfinite(x) and math.isfinite(y)]
    want: list[int] = []
    s, last_bin = 0.0, 0
    for k, i in enumerate(ok):
        if k:
            dx, dy = np.diff(pts[[ok[k - 1], i]], axis=0)[0]
            s += float(np.linalg.norm([dx, dy]))
        b = math.floor(s / spacing_m)
        if k == 0 or b != last_bin or k == len(ok) - 1:
            want.append(i)
        last_bin = b
    assert resample_path(pts, spacing_m).tolist() == want


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
    robot is its outline in frame ``base_link``, the child frame of ``/tf``, at the identity
    pose, once at the first row and again where the phase changes, in the new phase's colour;
    ``/tf`` places ``base_link`` at the logged pose of every row; the path passes through
    the logged positions; the goal arrow starts at the goal."""
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

    path = tmp_path / "run.mcap"
    t, block = _log(path)
    robot = _messages(path, ROBOT_TOPIC)
    phase = control_phases(block[:, COLUMN["dr_m"]], EPS_M)
    assert phase[0] == 0 and phase[-1] == 1
    changes = [0, *[i for i in range(1, len(phase)) if phase[i] != phase[i - 1]]]
    assert len(changes) == 2
    assert [lt for lt, _ in robot] == t[changes].tolist()
    body = robot_outline(0.3, 0.15)
    for (_, data), row in zip(robot, changes, strict=True):
        pos, rgba = read_cloud(data)
        np.testing.assert_allclose(pos[:, :2], body, atol=1e-6)  # the body, in its own frame
        msg = PointCloud.FromString(data)
        assert msg.frame_id == "base_link"
        assert (msg.pose.position.x, msg.pose.position.y, msg.pose.orientation.z,
                msg.pose.orientation.w) == (0.0, 0.0, 0.0, 1.0)
        assert {tuple(c) for c in rgba[:, :3].tolist()} == {PHASE_COLORS[phase[row]]}
    tfs = [FrameTransform.FromString(d) for _, d in _messages(path, "/tf")]
    assert len(tfs) == len(t)
    for tf, row in zip(tfs, block, strict=True):
        assert (tf.parent_frame_id, tf.child_frame_id) == ("world", "base_link")
        assert tf.translation.x == row[COLUMN["x_m"]]
        assert 2 * math.atan2(tf.rotation.z, tf.rotation.w) == pytest.approx(
            row[COLUMN["theta_rad"]])
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


def test_a_long_run_draws_its_robot_once_per_phase(tmp_path: Path) -> None:
    """The robot's messages do not grow with the run: a 600 s run (the old layout drew 12,000
    outlines) has one in the approach and one from the row where it turns to the alignment
    (the log's transforms move it)."""
    n = 60_001  # 600 s at 100 Hz
    t = np.arange(n, dtype=np.int64) * 10_000_000
    rows = np.zeros((n, len(SIGNALS)))
    rows[:, COLUMN["x_m"]] = np.linspace(0.0, 1.0, n)
    rows[:, COLUMN["dr_m"]] = 5.0
    rows[-1000:, COLUMN["dr_m"]] = 0.01  # aligned for the last 10 s
    rec = scene_mod.SceneRecorder((0.0, 0.0, 0.0), half_track_m=0.3, wheel_radius_m=0.15,
                                  stop_radius_m=0.05, controlled=True)
    rec.add(t, rows)

    class Log:
        def __init__(self) -> None:
            self.topics: dict[str, list[int]] = {}

        def write_messages(self, topic: str, schema_name: str, schema_data: bytes,
                           t_ns: Any, messages: list[bytes]) -> None:
            assert len(t_ns) == len(messages)
            self.topics[topic] = [int(v) for v in t_ns]

    log = Log()
    rec._write(log)
    assert log.topics[scene_mod.ROBOT_TOPIC] == [0, int(t[-1000])]


@pytest.mark.parametrize("error", [DiskFullError("no space left on /x while writing y"),
                                   OSError(5, "Input/output error"), ValueError("a drawing")])
def test_a_full_disk_is_the_log_s_failure_a_drawing_s_only_warns(error: Exception) -> None:
    """The scene's failures warn and leave the signal topics as they are, but a file that
    cannot be written (a full disk, an I/O error) is raised as itself, not a warning."""
    rec = scene_mod.SceneRecorder((0.0, 0.0, 0.0), half_track_m=0.3, wheel_radius_m=0.15,
                                  stop_radius_m=0.05, controlled=True)

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


class _Topics:
    """The messages a recorder writes, by topic (a log's ``write_messages``)."""

    def __init__(self) -> None:
        self.topics: dict[str, tuple[list[int], list[bytes]]] = {}

    def write_messages(self, topic: str, schema_name: str, schema_data: bytes,
                       t_ns: Any, messages: list[bytes]) -> None:
        self.topics[topic] = ([int(v) for v in t_ns], list(messages))


def _drawn(rec: scene_mod.SceneRecorder) -> dict[str, tuple[list[int], list[bytes]]]:
    t = np.arange(300, dtype=np.int64) * 10_000_000
    rows = np.zeros((len(t), len(SIGNALS)))
    rows[:, COLUMN["x_m"]] = np.linspace(0.0, 2.0, len(t))
    rows[:, COLUMN["dr_m"]] = np.linspace(2.0, 0.0, len(t))
    rec.add(t, rows)
    log = _Topics()
    rec._write(log)
    return log.topics


@pytest.mark.parametrize(("run", "typed"), [
    # what a log's run record holds (JSON strings) and the typed values it stands for
    ({"params": '{"L": 0.4, "r": 0.1}', "stop_radius_m": "0.2"}, (0.4, 0.1, 0.2)),
    ({"params": '{"L": 0.4}'}, (0.4, scene_mod.DEFAULT_WHEEL_RADIUS_M, None)),
    # a stranger's values: the paper's robot, no ring, no phase
    ({"params": '{"L": -1, "r": 0.1}', "stop_radius_m": "null"},
     (scene_mod.DEFAULT_HALF_TRACK_M, scene_mod.DEFAULT_WHEEL_RADIUS_M, None)),
    ({"params": "[not json", "stop_radius_m": "NaN"},
     (scene_mod.DEFAULT_HALF_TRACK_M, scene_mod.DEFAULT_WHEEL_RADIUS_M, None)),
])
def test_a_run_record_s_strings_draw_as_their_typed_values(
        run: dict[str, str], typed: tuple[float, float, float | None]) -> None:
    """Recovery has only the log's strings: :meth:`SceneRecorder.from_run_record` parses
    them into the typed values the writer is given, and the two draw the same bytes (and
    not those of another robot: the outline depends on the values)."""
    goal = (2.0, 0.0, 0.0)
    parsed = _drawn(scene_mod.SceneRecorder.from_run_record(run, goal, controlled=True))
    half_track, radius, stop = typed
    given_typed = _drawn(scene_mod.SceneRecorder(goal, half_track_m=half_track,
                                                 wheel_radius_m=radius, stop_radius_m=stop,
                                                 controlled=True))
    assert parsed == given_typed
    assert (PHASE_TOPIC in parsed) == (stop is not None)
    other = _drawn(scene_mod.SceneRecorder(goal, half_track_m=half_track + 0.1,
                                           wheel_radius_m=radius, stop_radius_m=stop,
                                           controlled=True))
    assert other[ROBOT_TOPIC] != parsed[ROBOT_TOPIC]


@settings(max_examples=50, deadline=None)  # a loaded machine is no failure of the bytes
@given(t_ns=st.integers(0, 2**63 - 1), n=st.integers(0, 40),
       frame=st.sampled_from(["world", "base_link"]), seed=st.integers(0, 2**32 - 1))
def test_a_cloud_message_is_the_one_message_s_serialisation(t_ns: int, n: int, frame: str,
                                                            seed: int) -> None:
    """cloud_message joins three serialisations (the stamp, the fields a frame's clouds share,
    the points): the bytes of the one foxglove.PointCloud they make, serialised by protobuf."""
    rng = np.random.default_rng(seed)
    points = scene_mod.cloud_points(rng.normal(size=(n, 2)), rng.integers(0, 256, (n, 3)))
    msg = PointCloud(frame_id=frame, point_stride=16, data=points.tobytes(), fields=[
        PackedElementField(name=name, offset=offset, type=PackedElementField.FLOAT32
                           if name in "xyz" else PackedElementField.UINT8)
        for name, offset in (("x", 0), ("y", 4), ("z", 8), ("red", 12), ("green", 13),
                             ("blue", 14), ("alpha", 15))])
    msg.timestamp.FromNanoseconds(t_ns)
    msg.pose.orientation.w = 1.0
    assert scene_mod.cloud_message(t_ns, points, frame) == msg.SerializeToString(
        deterministic=True)


def _chunks_of(path: Path) -> tuple[dict[int, tuple[str, int]], dict[int, str],
                                    list[tuple[list[tuple[int, int, int]], list[Any]]]]:
    """A log's channels (id: topic, schema id), schemas (id: name) and chunks: each chunk's
    Message records as (offset, channel id, log time), parsed from its inflated bytes, and the
    Message Index records that follow it."""
    import struct

    from mcap.records import Channel, Chunk, MessageIndex, Schema
    from mcap.stream_reader import StreamReader, get_chunk_data_stream

    channels: dict[int, tuple[str, int]] = {}
    schemas: dict[int, str] = {}
    chunks: list[tuple[list[tuple[int, int, int]], list[Any]]] = []
    with open(path, "rb") as f:
        for r in StreamReader(f, emit_chunks=True).records:
            if isinstance(r, Channel):
                channels[r.id] = (r.topic, r.schema_id)
            elif isinstance(r, Schema):
                schemas[r.id] = r.name
            elif isinstance(r, Chunk):
                stream, size = get_chunk_data_stream(r, validate_crc=True)
                data = stream.read(size)
                records, at = [], 0
                while at < len(data):
                    opcode, length = struct.unpack_from("<BQ", data, at)
                    assert opcode == 0x05  # Message
                    cid, _, log_time = struct.unpack_from("<HIQ", data, at + 9)
                    records.append((at, cid, log_time))
                    at += 9 + length
                chunks.append((records, []))
            elif isinstance(r, MessageIndex):
                chunks[-1][1].append(r)
    return channels, schemas, chunks


def _assert_scene_in_one_chunk(path: Path) -> None:
    """The scene's topics and the note are one chunk's, alone, in log-time order; each
    channel's Message Index lists its records' times and offsets; the clouds share a schema."""
    from wmr.adapters.mcap.recover import SCENE_TOPICS

    channels, schemas, chunks = _chunks_of(path)
    scene = {cid for cid, (topic, _) in channels.items() if topic in SCENE_TOPICS}
    assert {channels[cid][0] for cid in scene} == set(SCENE_TOPICS)
    holding = [c for c in chunks if scene & {cid for _, cid, _ in c[0]}]
    assert len(holding) == 1
    records, indexes = holding[0]
    assert {cid for _, cid, _ in records} == scene
    times = [t for _, _, t in records]
    assert times == sorted(times) and times[-1] > 0  # the robot's second outline, the phase
    assert [i.channel_id for i in indexes] == sorted(scene)
    for index in indexes:
        assert index.records == [(t, at) for at, cid, t in records if cid == index.channel_id]
    clouds = {channels[cid][1] for cid in scene
              if channels[cid][0] in (GOAL_TOPIC, PATH_TOPIC, ROBOT_TOPIC)}
    assert len(clouds) == 1 and list(schemas.values()).count("foxglove.PointCloud") == 1


def test_the_scene_and_the_note_are_one_chunk_and_recovery_writes_them_so(
        tmp_path: Path) -> None:
    """The close writes the scene's topics and the note in one chunk (it was a chunk each:
    five compressions, writes to the OS and summary entries a log), their records in log-time
    order with every channel's Message Index pointing at its records, the clouds on one
    schema; recovery of a killed run's log makes them the same way.  The mcap reader finds
    each topic's messages through the summary's index."""
    from wmr.adapters.mcap.recover import SCENE_TOPICS, recover_log

    path = tmp_path / "run.mcap"
    t, block = _log(path)
    _assert_scene_in_one_chunk(path)
    with open(path, "rb") as f:
        reader = make_reader(f)
        kept = {topic: [(m.log_time, m.data) for _, _, m in reader.iter_messages(topics=[topic])]
                for topic in SCENE_TOPICS}
    assert [len(kept[topic]) for topic in SCENE_TOPICS] == [1, 1, 2, 4, 1]
    # a killed run: the .partial as it stands before the close (its first 2 s of rows)
    cut = tmp_path / "cut.mcap"
    run = {"stop_radius_m": EPS_M, "params": {"L": 0.3, "r": 0.15}}
    with RunLogWriter(tmp_path / "live.mcap", run=run, goal=(3.0, 0.0, 1.0), scene=True) as log:
        log.write_block(t, block)
        cut.with_name("cut.mcap.partial").write_bytes(
            (tmp_path / "live.mcap.partial").read_bytes())
        log.close({"status": "converged"})
    rec = recover_log(cut.with_name("cut.mcap.partial"), cut)
    assert sorted(rec.scene_added) == sorted(SCENE_TOPICS)
    _assert_scene_in_one_chunk(cut)


@pytest.mark.parametrize("stop_radius_m", [0.05, 0.2, None])
def test_the_goal_cloud_kept_for_a_batch_is_the_one_drawn_afresh(stop_radius_m: float | None
                                                                ) -> None:
    """The ``/scene/goal`` message is kept per goal and stop radius (the runs of a batch
    share them): after the other goals and radii, it is the cloud drawn afresh for its own."""
    from wmr.adapters.mcap.scene import (
        GOAL_COLOR,
        SceneRecorder,
        cloud_message,
        cloud_points,
        goal_outline,
    )

    class Log:
        def __init__(self) -> None:
            self.goal: list[bytes] = []

        def write_messages(self, topic: str, schema_name: str, schema_data: bytes,
                           t_ns: Any, messages: list[bytes]) -> None:
            if topic == GOAL_TOPIC:
                self.goal = list(messages)

    for goal in ((3.0, 0.0, 1.0), (3.0, 0.0, 1.0), (-1.0, 2.0, 0.0)):
        for radius in (0.05, 0.2, None, stop_radius_m):
            log = Log()
            SceneRecorder(goal, half_track_m=0.3, wheel_radius_m=0.15, stop_radius_m=radius,
                          controlled=True).write(log)
            assert log.goal == [cloud_message(0, cloud_points(goal_outline(*goal, radius),
                                                              GOAL_COLOR))]
