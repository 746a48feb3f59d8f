"""The drawable topics of a run log: what Rerun's and Foxglove's own MCAP loaders draw.

Poses (``foxglove.PoseInFrame``) and transforms (``foxglove.FrameTransform``) carry no
geometry: opened in Rerun (``rerun run.mcap``) or in Foxglove's 3-D panel, a log holding only
them shows an empty view.  The one primitive both tools draw from a protobuf MCAP log is
``foxglove.PointCloud`` (Rerun: ``Points3D`` with the ``red``/``green``/``blue``/``alpha``
fields as colours; Foxglove: its point-cloud renderer); ``SceneUpdate`` is Foxglove's only,
``LocationFix`` is geodetic (a map, not our plane), and a URDF needs a ROS 2 ``std_msgs/String``
topic.  So every drawable topic here is a point cloud in frame ``world`` (z = 0):

==========================  =============================================================
topic                       content
==========================  =============================================================
``/scene/robot``            the robot's outline (chassis, wheels, a 1 m heading arrow),
                            every :data:`ROBOT_PERIOD_NS` of simulation time (at most
                            :data:`MAX_OUTLINES` a log: :func:`robot_period_ns`); coloured
                            by the control phase (:data:`PHASE_COLORS`)
``/scene/path``             the whole path, a point every :data:`PATH_SPACING_M`, coloured
                            by phase, once at t = 0
``/scene/goal``             the goal: a 1 m arrow along theta_d and a ring of the stop
                            radius, once at t = 0
``/scene/gps``              all the position fixes (runs with sensors), once at t = 0
                            (``/sensors/gps`` has each at its time, also a point cloud)
``/scene/estimate``         the estimated path (runs with sensors), once at t = 0
``/controller/phase``       ``wmr.ControlPhase``: ``phase`` 0 = approach, 1 = align (the
                            stabiliser's final alignment inside the stop radius), a
                            message at the first and last step and on both sides of each
                            change (a step plot in any plotting tool)
==========================  =============================================================

They are made from the rows the log already holds (no new column in
:data:`wmr.core.signals.SIGNALS`) by :class:`SceneRecorder`, which the log writer feeds each
block and asks to write its topics when the log is closed (one chunk per topic): a run killed
before its end has no scene topics (``wmr log recover`` makes them from the rows it holds,
:mod:`wmr.adapters.mcap.recover`), and its signal topics are unchanged.  The phase is the
stabiliser's hysteresis (:func:`control_phases`) replayed on the logged distance ``dr_m``.
"""

from __future__ import annotations

import ctypes
import functools
import math
import struct
import warnings
from collections.abc import Mapping, Sequence
from typing import Any, Final, overload

import numpy as np
import numpy.typing as npt
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

from wmr.adapters.mcap.schemas import (
    PHASE_TOPIC,
    WORLD_FRAME,
    MessageLog,
    descriptor_set,
    timestamped_doubles,
)
from wmr.core.signals import COLUMN
from wmr.infra.errors import DiskFullError, LogError

ROBOT_TOPIC: Final = "/scene/robot"
PATH_TOPIC: Final = "/scene/path"
GOAL_TOPIC: Final = "/scene/goal"
GPS_SCENE_TOPIC: Final = "/scene/gps"
ESTIMATE_SCENE_TOPIC: Final = "/scene/estimate"
CLOUD_SCHEMA: Final = "foxglove.PointCloud"
PHASE_SCHEMA: Final = "wmr.ControlPhase"

#: The stabiliser's phases (``wmr.core.control.stabiliser.APPROACH`` / ``ALIGN``).
APPROACH: Final = 0
ALIGN: Final = 1
PHASE_NAMES: Final = ("approach", "align")
#: The stabiliser enters the alignment at this fraction of the stop radius and leaves it
#: beyond the other (``Stabiliser.align_radius``, ``exit_radius``; checked by the tests).
ALIGN_RADIUS_FRACTION: Final = 0.5
EXIT_RADIUS_FRACTION: Final = 2.0

Rgb = tuple[int, int, int]
#: Colours of the phases, on the path and the robot, here and in ``wmr replay``.
PHASE_COLORS: Final[tuple[Rgb, Rgb]] = ((31, 119, 180), (255, 127, 14))
GOAL_COLOR: Final[Rgb] = (214, 39, 40)
GPS_COLOR: Final[Rgb] = (90, 90, 90)
ESTIMATE_COLOR: Final[Rgb] = (204, 0, 153)

#: One robot outline per this much simulation time (20 Hz: smooth playback, small log).
ROBOT_PERIOD_NS: Final = 50_000_000
#: Most robot outlines in one log: a run longer than ``MAX_OUTLINES`` periods (200 s) gets
#: them at a longer period (:func:`robot_period_ns`), so that closing the log of a long run
#: stays quick (a 3000 s run had 60,000 outlines, 240 MB to compress, seconds at its close:
#: past a run's wall-clock limit the batch kills a worker that takes that long).
MAX_OUTLINES: Final = 4000


def robot_period_ns(last_t_ns: int) -> int:
    """The period of the robot's outlines in a log whose last row is at ``last_t_ns``:
    :data:`ROBOT_PERIOD_NS`, or a whole multiple of it that keeps at most
    :data:`MAX_OUTLINES` outlines."""
    k = max(1, -(-(max(last_t_ns, 0) + 1) // (ROBOT_PERIOD_NS * MAX_OUTLINES)))
    return ROBOT_PERIOD_NS * k


#: Spacing of the path's points, m.
PATH_SPACING_M: Final = 0.05
#: Spacing of the points along the outlines, m.
OUTLINE_SPACING_M: Final = 0.025
#: Length of the heading arrows of the robot and the goal, m.
ARROW_M: Final = 1.0
#: Robot geometry when a log has no ``params`` (the paper's robot, Section 5).
DEFAULT_HALF_TRACK_M: Final = 0.3
DEFAULT_WHEEL_RADIUS_M: Final = 0.15

#: x, y, z float32 and red, green, blue, alpha uint8: 16 bytes a point.
_POINT: Final = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"),
                          ("green", "u1"), ("blue", "u1"), ("alpha", "u1")])


# --------------------------------------------------------------------------- geometry


def robot_geometry(run: Mapping[str, str]) -> tuple[float, float]:
    """Half track ``L`` and wheel radius ``r`` (m) from a log's ``run`` record (or the paper's).

    Parameters
    ----------
    run
        The ``run`` metadata record; its ``params`` is a JSON object with ``L`` and ``r``.
    """
    return _geometry(run.get("params", "{}"))


@functools.lru_cache(maxsize=256)  # every log of a batch of one robot has the same params
def _geometry(params_json: str) -> tuple[float, float]:
    # here, not at the top: the reader imports the writer, which imports this module
    from wmr.adapters.mcap.reader import metadata_json

    try:  # bounded: a stranger's log may hold a value nested too deep for json.loads
        params = metadata_json(params_json)
        half_track = float(params.get("L", DEFAULT_HALF_TRACK_M))
        radius = float(params.get("r", DEFAULT_WHEEL_RADIUS_M))
    except (ValueError, TypeError, AttributeError, LogError):
        return DEFAULT_HALF_TRACK_M, DEFAULT_WHEEL_RADIUS_M
    if not (half_track > 0 and radius > 0 and math.isfinite(half_track + radius)):
        return DEFAULT_HALF_TRACK_M, DEFAULT_WHEEL_RADIUS_M
    return half_track, radius


def _segment(a: Sequence[float], b: Sequence[float], spacing_m: float) -> npt.NDArray[np.float64]:
    n = max(2, math.ceil(math.dist(a, b) / spacing_m) + 1)
    return np.linspace(a, b, n)


def _rectangle(cx: float, cy: float, hx: float, hy: float) -> npt.NDArray[np.float64]:
    c = [(cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy), (cx - hx, cy + hy)]
    return np.concatenate([_segment(c[i], c[(i + 1) % 4], OUTLINE_SPACING_M)
                           for i in range(4)])


def _arrow(length_m: float) -> npt.NDArray[np.float64]:
    """An arrow along +x from the origin: shaft and two barbs."""
    head = 0.25 * length_m
    tip = (length_m, 0.0)
    return np.concatenate([
        _segment((0.0, 0.0), tip, OUTLINE_SPACING_M),
        _segment(tip, (length_m - head, 0.5 * head), OUTLINE_SPACING_M),
        _segment(tip, (length_m - head, -0.5 * head), OUTLINE_SPACING_M)])


def robot_outline(half_track_m: float, wheel_radius_m: float) -> npt.NDArray[np.float64]:
    """The robot in its own frame (B at the origin, x forward), as points, shape ``(m, 2)``.

    The chassis and wheels as ``wmr replay`` draws them, and the 1 m heading arrow.
    """
    return _robot_outline(half_track_m, wheel_radius_m).copy()


@functools.lru_cache(maxsize=64)
def _robot_outline(half_track_m: float, wheel_radius_m: float) -> npt.NDArray[np.float64]:
    chassis_len = 2.0 * half_track_m + 0.2
    return np.concatenate([
        _rectangle(0.5 * chassis_len - 0.3, 0.0, 0.5 * chassis_len, 0.8 * half_track_m),
        _rectangle(0.0, half_track_m, wheel_radius_m, 0.05),
        _rectangle(0.0, -half_track_m, wheel_radius_m, 0.05),
        _arrow(ARROW_M)])


def goal_outline(x_m: float, y_m: float, theta_rad: float,
                 stop_radius_m: float | None) -> npt.NDArray[np.float64]:
    """The goal as points in the world: the heading arrow and the stop-radius ring."""
    pts = _goal_shape(stop_radius_m if stop_radius_m and stop_radius_m > 0 else None)
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    return np.column_stack([x_m + c * pts[:, 0] - s * pts[:, 1],
                            y_m + s * pts[:, 0] + c * pts[:, 1]])


@functools.lru_cache(maxsize=64)
def _goal_shape(stop_radius_m: float | None) -> npt.NDArray[np.float64]:
    """The goal's points in its own frame (read-only: shared by every call)."""
    pts = _arrow(ARROW_M)
    if stop_radius_m is not None:
        k = max(12, int(2 * math.pi * stop_radius_m / 0.01))
        a = np.linspace(0.0, 2 * math.pi, k, endpoint=False)
        pts = np.concatenate([pts, stop_radius_m * np.column_stack([np.cos(a), np.sin(a)])])
    pts.flags.writeable = False
    return pts


def resample_path(xy: npt.NDArray[np.float64], spacing_m: float = PATH_SPACING_M
                  ) -> npt.NDArray[np.intp]:
    """Indices of the rows of a path kept for drawing: the first, then each one at least
    ``spacing_m`` along the path from the last kept, and the last (non-finite rows skipped)."""
    ok = np.flatnonzero(np.isfinite(xy).all(axis=1))
    if ok.size == 0:
        return ok
    step = np.linalg.norm(np.diff(xy[ok], axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(step)])
    bins = np.floor(s / spacing_m).astype(np.int64)
    keep = np.concatenate([[True], bins[1:] != bins[:-1]])
    keep[-1] = True
    return ok[keep]


# --------------------------------------------------------------------------- phase


def control_phases(dr_m: npt.ArrayLike, stop_radius_m: float,
                   start_phase: int = APPROACH) -> npt.NDArray[np.int8]:
    """The stabiliser's phase at each step, from the distance to the goal it saw.

    The stabiliser (``wmr.core.control.stabiliser``, and its peers) starts in the approach,
    enters the alignment when ``dr <= 0.5 * stop_radius`` and goes back to the approach only
    when ``dr > 2 * stop_radius``; ``dr_m`` is the logged column (the distance the controller
    computed, from the estimate in runs with sensors), so this is its phase exactly.

    Parameters
    ----------
    dr_m
        The ``dr_m`` column, shape ``(n,)``; NaN (no controller) stays in the approach.
    stop_radius_m
        The run's stop radius epsilon.
    start_phase
        The phase before the first row (the last of the previous block, for a run seen
        block by block); a run starts in the approach.

    Returns
    -------
    numpy.ndarray
        :data:`APPROACH` (0) or :data:`ALIGN` (1) per step, int8.
    """
    dr = np.asarray(dr_m, dtype=np.float64)
    enter = dr <= ALIGN_RADIUS_FRACTION * stop_radius_m
    leave = dr > EXIT_RADIUS_FRACTION * stop_radius_m
    # a two-state hysteresis: the state is that of the last step that was a switch point
    switch = np.where(enter, ALIGN, np.where(leave, APPROACH, -1))
    idx = np.where(switch >= 0, np.arange(dr.size), -1)
    last = np.maximum.accumulate(idx) if dr.size else idx
    out = np.where(last >= 0, switch[np.maximum(last, 0)], start_phase)
    return out.astype(np.int8)


def phase_changes(t_ns: npt.NDArray[np.int64], phase: npt.NDArray[np.int8]
                  ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int8]]:
    """The rows of a step plot of ``phase``: the first and last step and both sides of each
    change, in time order."""
    if phase.size == 0:
        return t_ns[:0], phase[:0]
    change = np.flatnonzero(phase[1:] != phase[:-1]) + 1
    rows = np.sort(np.concatenate([[0, phase.size - 1], change - 1, change]))
    # without duplicates (np.unique: the same, at ten times the cost for these few rows)
    rows = rows[np.concatenate([[True], rows[1:] != rows[:-1]])]
    return t_ns[rows], phase[rows]


#: The control phase's message (a double, like every other plotted field: 0 approach, 1 align)
#: and its MCAP schema data.
ControlPhase, _PHASE_SCHEMA_DATA = timestamped_doubles(PHASE_SCHEMA, "wmr/phase.proto", ("phase",))


# --------------------------------------------------------------------------- point clouds


_FIELDS: Final = [PackedElementField(name=name, offset=offset,
                                     type=PackedElementField.FLOAT32 if name in "xyz"
                                     else PackedElementField.UINT8)
                  for name, offset in (("x", 0), ("y", 4), ("z", 8), ("red", 12),
                                       ("green", 13), ("blue", 14), ("alpha", 15))]


def cloud_points(xy: npt.ArrayLike, colors: npt.ArrayLike) -> npt.NDArray[np.void]:
    """Points for :func:`cloud_message`: ``xy`` shape ``(m, 2)`` at z = 0, ``colors`` one
    RGB for all or one per point."""
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    c = np.broadcast_to(np.asarray(colors, dtype=np.uint8).reshape(-1, 3), (len(p), 3))
    out = np.zeros(len(p), _POINT)
    out["x"], out["y"] = p[:, 0], p[:, 1]
    out["red"], out["green"], out["blue"] = c[:, 0], c[:, 1], c[:, 2]
    out["alpha"] = 255
    return out


def cloud_message(t_ns: int, points: npt.NDArray[np.void],
                  pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
                  tail: bytes | None = None) -> bytes:
    """A ``foxglove.PointCloud`` of ``points`` in frame ``world``, placed at ``pose``.

    Parameters
    ----------
    t_ns
        Its timestamp, ns.
    points
        From :func:`cloud_points`, in the cloud's own frame.
    pose
        ``(x_m, y_m, theta_rad)`` of the cloud's frame in the world (Rerun draws it as the
        entity's ``InstancePoses3D``, Foxglove as the cloud's origin): the robot's outline is
        the same bytes at every step, so its topic compresses to almost nothing.
    tail
        :func:`cloud_tail` of ``points``, when the caller sends the same points many times.

    Protobuf writes the fields of a message one after another in field-number order
    (timestamp 1, frame_id 2, pose 3, point_stride 4, fields 5, data 6), so the message is the
    concatenation of its parts' serialisations: the parts that do not change (the frame, and
    the points of a cloud sent at every step) are serialised once, the timestamps of a run
    (multiples of the robot's period, the same in every run) once per process, and a pose
    whose four numbers are all non-zero is packed directly (:func:`_pose_bytes`).
    """
    return (_stamp_bytes(int(t_ns)) + _FRAME + _pose_bytes(*pose)
            + (cloud_tail(points) if tail is None else tail))


@functools.lru_cache(maxsize=8192)
def _stamp_bytes(t_ns: int) -> bytes:
    """The serialised ``timestamp`` field of a cloud at ``t_ns``."""
    head = PointCloud()
    head.timestamp.FromNanoseconds(t_ns)
    return head.SerializeToString(deterministic=True)


#: The serialised ``pose`` field when x, y and the quaternion's z and w are all non-zero: tag
#: 3 and length 40, then ``position`` (tag 1, length 18: x as field 1, y as field 2; z = 0 is
#: left out) and ``orientation`` (tag 2, length 18: z as field 3, w as field 4; x = y = 0 are
#: left out), each double after its tag byte, little-endian.
_POSE: Final = struct.Struct("<BBBBBdBdBBBdBd")


def _pose_bytes(x: float, y: float, theta: float) -> bytes:
    """The serialised ``pose`` field of a cloud placed at ``(x, y, theta)``: the bytes protobuf
    writes (checked on random and zero poses by ``tests/test_scene.py``)."""
    qz, qw = math.sin(0.5 * theta), math.cos(0.5 * theta)
    if x != 0.0 and y != 0.0 and qz != 0.0 and qw != 0.0:
        return _POSE.pack(0x1A, 40, 0x0A, 18, 0x09, x, 0x11, y, 0x12, 18, 0x19, qz, 0x21, qw)
    # a zero (or -0.0, which protobuf runtimes treat alike or not) is left to protobuf
    placed = PointCloud()
    placed.pose.position.x, placed.pose.position.y = x, y
    placed.pose.orientation.z = qz
    placed.pose.orientation.w = qw
    return placed.SerializeToString(deterministic=True)


def cloud_tail(points: npt.NDArray[np.void]) -> bytes:
    """The serialised ``point_stride``, ``fields`` and ``data`` of a cloud of ``points``."""
    return bytes(PointCloud(point_stride=_POINT.itemsize, fields=_FIELDS,
                            data=points.tobytes()).SerializeToString(deterministic=True))


_FRAME: Final = PointCloud(frame_id=WORLD_FRAME).SerializeToString(deterministic=True)


#: The ``FileDescriptorSet`` of ``foxglove.PointCloud``, dependencies first.
CLOUD_SCHEMA_DATA: Final = descriptor_set(PointCloud.DESCRIPTOR.file)


def _write_cloud(log: MessageLog, topic: str, points: npt.NDArray[np.void]) -> None:
    """One unplaced cloud of ``points`` on ``topic`` at t = 0 (the goal, the path, the fixes,
    the estimate; the robot's outlines, one per period, are :meth:`SceneRecorder._write`'s)."""
    log.write_messages(topic, CLOUD_SCHEMA, CLOUD_SCHEMA_DATA, [0], [cloud_message(0, points)])


def write_sensing_scene(log: MessageLog, gps_xy_m: npt.ArrayLike,
                        est_xy_m: npt.ArrayLike) -> None:
    """The fixes and the estimated path as point clouds at t = 0 (runs with sensors)."""
    gps = np.asarray(gps_xy_m, dtype=np.float64).reshape(-1, 2)
    est = np.asarray(est_xy_m, dtype=np.float64).reshape(-1, 2)
    if len(gps):
        _write_cloud(log, GPS_SCENE_TOPIC, cloud_points(gps, GPS_COLOR))
    if len(est):
        keep = resample_path(est)
        _write_cloud(log, ESTIMATE_SCENE_TOPIC, cloud_points(est[keep], ESTIMATE_COLOR))


@functools.lru_cache(maxsize=64)
def _robot_clouds(half_track_m: float, wheel_radius_m: float
                  ) -> tuple[tuple[npt.NDArray[np.void], ...], tuple[bytes, ...]]:
    """The robot's outline as a cloud in each phase's colour, and their :func:`cloud_tail`."""
    body = _robot_outline(half_track_m, wheel_radius_m)
    shapes = tuple(cloud_points(body, c) for c in PHASE_COLORS)
    return shapes, tuple(cloud_tail(c) for c in shapes)


class PlacedClouds(Sequence[bytes]):
    """Serialised clouds, one per row: the robot's outline in the row's variant (the phase's
    colour) placed at the row's pose; a sequence of :func:`cloud_message` bytes.

    A log writer may instead ask :meth:`records` for all their MCAP Message records at once,
    written by the C stepper (``wmr_cloud_records``: the same bytes, checked by
    ``tests/test_scene.py``), which costs a tenth of the messages made one by one.

    Parameters
    ----------
    t_ns
        Timestamps, ns, shape ``(n,)``.
    poses
        ``(x_m, y_m, theta_rad)`` per row, shape ``(n, 3)``.
    variants
        Index into ``shapes`` per row, shape ``(n,)``.
    shapes
        The clouds' points (:func:`cloud_points`) and their :func:`cloud_tail` bytes.
    """

    def __init__(self, t_ns: npt.NDArray[np.int64], poses: npt.NDArray[np.float64],
                 variants: npt.NDArray[np.int8],
                 shapes: tuple[tuple[npt.NDArray[np.void], ...], tuple[bytes, ...]]) -> None:
        self._t_ns = np.ascontiguousarray(t_ns, np.int64)
        self._pose = np.ascontiguousarray(poses, np.float64)
        self._variant = np.ascontiguousarray(variants, np.uint8)
        self._shapes, self._tails = shapes

    def __len__(self) -> int:
        return len(self._t_ns)

    @overload
    def __getitem__(self, i: int) -> bytes: ...

    @overload
    def __getitem__(self, i: slice) -> list[bytes]: ...

    def __getitem__(self, i: int | slice) -> bytes | list[bytes]:
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        v = int(self._variant[i])
        x, y, theta = self._pose[i].tolist()
        return cloud_message(int(self._t_ns[i]), self._shapes[v], (x, y, theta), self._tails[v])

    def records(self, channel: int) -> tuple[memoryview, npt.NDArray[np.int64], int] | None:
        """The Message records of every cloud on ``channel`` (sequence numbers 0, 1, ...),
        their offsets and their CRC-32 (``zlib.crc32`` of the records, made from the tails'
        own CRCs), or None without the C stepper."""
        from wmr.adapters.fmi.robot import load_stepper

        lib = load_stepper()
        n = len(self._t_ns)
        if lib is None or n == 0:
            return None
        tails = [np.frombuffer(tail, np.uint8) for tail in self._tails]
        tail_ptrs = (ctypes.c_void_p * len(tails))(*(a.ctypes.data for a in tails))
        tail_len = np.asarray([len(tail) for tail in self._tails], np.int32)
        frame = np.frombuffer(_FRAME, np.uint8)
        # a record: head 31, timestamp 14, pose 42, the frame and the tail
        out = np.empty(n * (31 + 14 + 42 + len(_FRAME) + int(tail_len.max())), np.uint8)
        offsets = np.empty(n, np.int64)
        crc = ctypes.c_uint(0)
        size = lib.wmr_cloud_records(n, self._t_ns.ctypes.data, self._pose.ctypes.data,
                                     self._variant.ctypes.data,
                                     channel, frame.ctypes.data, len(_FRAME), tail_ptrs,
                                     tail_len.ctypes.data, len(tails), out.ctypes.data,
                                     offsets.ctypes.data, ctypes.byref(crc))
        if size < 0:  # a variant without a tail, or too many tails: left to the Python path
            return None
        return out[:size].data, offsets, crc.value


# --------------------------------------------------------------------------- the recorder


_X, _Y, _TH, _DR = COLUMN["x_m"], COLUMN["y_m"], COLUMN["theta_rad"], COLUMN["dr_m"]


class SceneRecorder:
    """Keeps what the scene topics need of each block, and writes them when the log closes.

    Parameters
    ----------
    run
        The log's ``run`` record (strings): ``params`` (robot geometry) and ``stop_radius_m``
        (the phase and the goal ring; without it, no phase topic).
    goal
        ``(x_m, y_m, theta_rad)`` of the goal.
    controlled
        Whether the rows come from the closed loop (``dr_m`` is the controller's): the phase
        topic is written only then.
    """

    def __init__(self, run: Mapping[str, str], goal: tuple[float, float, float], *,
                 controlled: bool) -> None:
        self._goal = goal
        self._half_track, self._wheel_radius = robot_geometry(run)
        try:
            eps = float(run.get("stop_radius_m", "nan"))
        except ValueError:
            eps = math.nan
        self._stop_radius = eps if math.isfinite(eps) and eps > 0 else None
        self._controlled = controlled
        self._t: list[npt.NDArray[np.int64]] = []
        self._rows: list[npt.NDArray[np.float64]] = []

    def add(self, t_ns: npt.NDArray[np.int64], block: npt.NDArray[np.float64]) -> None:
        """Keep the pose and ``dr_m`` of the rows (the caller's arrays are not kept)."""
        self._t.append(np.array(t_ns, dtype=np.int64))
        self._rows.append(block[:, [_X, _Y, _TH, _DR]].copy())

    def write(self, log: MessageLog) -> None:
        """Write the scene topics to ``log``; a failure here warns and leaves the log as is,
        except a failure to write the file (a full disk, an I/O error), which is the log's."""
        try:
            self._write(log)
        except (DiskFullError, OSError):
            raise  # not a drawing's failure: the log's close would meet it next anyway
        except Exception as exc:  # the signal topics matter more than their drawing
            warnings.warn(f"the scene topics were not written: {type(exc).__name__}: {exc}",
                          RuntimeWarning, stacklevel=2)

    def _write(self, log: MessageLog) -> None:
        gx, gy, gth = self._goal
        _write_cloud(log, GOAL_TOPIC,
                     cloud_points(goal_outline(gx, gy, gth, self._stop_radius), GOAL_COLOR))
        if not self._t:
            return
        t = np.concatenate(self._t)
        rows = np.concatenate(self._rows)
        xy = rows[:, :2]
        phase = (control_phases(rows[:, 3], self._stop_radius)
                 if self._controlled and self._stop_radius is not None
                 else np.zeros(len(t), np.int8))
        colors = np.asarray(PHASE_COLORS, np.uint8)[phase]
        keep = resample_path(xy)
        _write_cloud(log, PATH_TOPIC, cloud_points(xy[keep], colors[keep]))
        # one outline per robot_period_ns(t[-1]): the first row of each period
        slot = t // robot_period_ns(int(t[-1]))
        first = np.flatnonzero(np.concatenate([[True], slot[1:] != slot[:-1]]))
        first = first[np.isfinite(rows[first, :3]).all(axis=1)]
        log.write_messages(ROBOT_TOPIC, CLOUD_SCHEMA, CLOUD_SCHEMA_DATA, t[first], PlacedClouds(
            t[first], rows[first, :3], phase[first],
            _robot_clouds(self._half_track, self._wheel_radius)))
        if self._controlled and self._stop_radius is not None:
            pt, pv = phase_changes(t, phase)
            msgs = []
            for ti, v in zip(pt.tolist(), pv.tolist(), strict=True):
                m = ControlPhase(phase=float(v))
                m.timestamp.FromNanoseconds(ti)
                msgs.append(m.SerializeToString(deterministic=True))
            log.write_messages(PHASE_TOPIC, PHASE_SCHEMA, _PHASE_SCHEMA_DATA, pt, msgs)


#: The numpy type of each packed field type the clouds here use (``foxglove.PackedElementField``).
_PACKED_TYPES: Final = {PackedElementField.UINT8: "u1", PackedElementField.FLOAT32: "<f4",
                        PackedElementField.FLOAT64: "<f8"}


def cloud_field(msg: PointCloud, name: str) -> npt.NDArray[Any] | None:
    """The field ``name`` of every point of the cloud ``msg``, read through its ``fields``
    and ``point_stride`` as Foxglove's reader does.

    Returns
    -------
    numpy.ndarray or None
        One value per point, of the field's own type; ``None`` when the cloud has no such
        field, a type other than ``UINT8``, ``FLOAT32`` or ``FLOAT64``, or a layout that does
        not fit its data (a damaged or foreign message: the caller leaves it out).
    """
    field = next((f for f in msg.fields if f.name == name), None)
    if field is None or field.type not in _PACKED_TYPES:
        return None
    dt = np.dtype(_PACKED_TYPES[field.type])
    stride = msg.point_stride
    if stride <= 0 or len(msg.data) % stride or field.offset + dt.itemsize > stride:
        return None
    raw = np.frombuffer(msg.data, np.uint8).reshape(-1, stride)
    return raw[:, field.offset:field.offset + dt.itemsize].copy().view(dt).ravel()


def read_cloud(data: bytes) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """Positions ``(m, 3)`` and colours ``(m, 4)`` of a ``foxglove.PointCloud`` message, read
    through its own ``fields`` and ``point_stride`` as Foxglove's reader does (for tests)."""
    msg = PointCloud.FromString(data)

    def col(name: str) -> npt.NDArray[Any]:
        values = cloud_field(msg, name)
        if values is None:
            raise ValueError(f"the cloud has no readable field {name!r}")
        return values

    pos = np.column_stack([col(n) for n in "xyz"]).astype(np.float32)
    rgba = np.column_stack([col(n) for n in ("red", "green", "blue", "alpha")])
    return pos, rgba.astype(np.uint8)


__all__ = ["ALIGN", "APPROACH", "CLOUD_SCHEMA", "CLOUD_SCHEMA_DATA", "ESTIMATE_SCENE_TOPIC",
           "GOAL_TOPIC", "GPS_SCENE_TOPIC", "PATH_TOPIC", "PHASE_COLORS", "PHASE_NAMES",
           "PHASE_TOPIC", "ROBOT_TOPIC", "ControlPhase", "PlacedClouds", "SceneRecorder",
           "cloud_field", "cloud_message", "cloud_points", "control_phases", "phase_changes",
           "read_cloud", "resample_path", "robot_geometry", "robot_outline", "write_sensing_scene"]
