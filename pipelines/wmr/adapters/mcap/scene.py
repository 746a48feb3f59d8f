"""The drawable topics of a run log: what Rerun's and Foxglove's own MCAP loaders draw.

Poses (``foxglove.PoseInFrame``) and transforms (``foxglove.FrameTransform``) carry no
geometry: opened in Rerun (``rerun run.mcap``) or in Foxglove's 3-D panel, a log holding only
them shows an empty view.  The one primitive both tools draw from a protobuf MCAP log is
``foxglove.PointCloud`` (Rerun: ``Points3D`` with the ``red``/``green``/``blue``/``alpha``
fields as colours; Foxglove: its point-cloud renderer); ``SceneUpdate`` is Foxglove's only,
``LocationFix`` is geodetic (a map, not our plane), and a URDF needs a ROS 2 ``std_msgs/String``
topic.  So every drawable topic here is a point cloud (z = 0), in frame ``world`` but for the
robot, which is drawn in its own frame ``base_link`` and moved by the viewers along the
``/tf`` transforms (``world`` to ``base_link``) that the log holds at every logged step:

==========================  =============================================================
topic                       content
==========================  =============================================================
``/scene/robot``            the robot's outline (chassis, wheels, a 1 m heading arrow) in
                            frame ``base_link``, at the first row and at each change of
                            the control phase, coloured by the phase
                            (:data:`PHASE_COLORS`): a few messages a run
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

Logs written before this layout drew the outline in frame ``world``, placed by its ``pose``,
every 50 ms of simulation time (4 kB a message: more bytes than the six per-step topics
together); the readers take both (only the signal topics are read back).

They are made from the rows the log already holds (no new column in
:data:`wmr.core.signals.SIGNALS`) by :class:`SceneRecorder`, which the log writer feeds each
block and asks to write its topics when the log is closed (all of them and the log's note in
one chunk, the clouds on one schema): a run killed
before its end has no scene topics (``wmr log recover`` makes them from the rows it holds,
:mod:`wmr.adapters.mcap.recover`), and its signal topics are unchanged.  The phase is the
stabiliser's hysteresis (:func:`control_phases`) replayed on the logged distance ``dr_m``.
"""

from __future__ import annotations

import functools
import math
import struct
import warnings
from collections.abc import Mapping, Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

from wmr.adapters.mcap.schemas import (
    BASE_FRAME,
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


def robot_geometry(run: Mapping[str, object]) -> tuple[float, float]:
    """Half track ``L`` and wheel radius ``r`` (m) from a log's ``run`` record (or the paper's).

    Parameters
    ----------
    run
        The ``run`` metadata record; its ``params`` is a JSON object with ``L`` and ``r`` (as
        a log holds it), or a mapping (as the writer is given it: read without the JSON).
    """
    params = run.get("params", "{}")
    if isinstance(params, Mapping):
        return _checked_geometry(params)
    return _geometry(str(params))


@functools.lru_cache(maxsize=256)  # every log of a batch of one robot has the same params
def _geometry(params_json: str) -> tuple[float, float]:
    # here, not at the top: the reader imports the writer, which imports this module
    from wmr.adapters.mcap.reader import metadata_json

    try:  # bounded: a stranger's log may hold a value nested too deep for json.loads
        params = metadata_json(params_json)
    except (ValueError, TypeError, AttributeError, LogError):
        return DEFAULT_HALF_TRACK_M, DEFAULT_WHEEL_RADIUS_M
    return _checked_geometry(params)


def _checked_geometry(params: object) -> tuple[float, float]:
    """``L`` and ``r`` of ``params`` if both are positive and finite, else the paper's."""
    try:
        half_track = float(params.get("L", DEFAULT_HALF_TRACK_M))  # type: ignore[attr-defined]
        radius = float(params.get("r", DEFAULT_WHEEL_RADIUS_M))  # type: ignore[attr-defined]
    except (ValueError, TypeError, AttributeError):
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
    finite = np.isfinite(xy[:, 0]) & np.isfinite(xy[:, 1])
    ok = None if finite.all() else np.flatnonzero(finite)
    p = xy if ok is None else xy[ok]
    n = len(p)
    if n == 0:
        return np.flatnonzero(finite)
    # np.linalg.norm(np.diff(p, axis=0), axis=1)'s bits (the sum of the two squares, then its
    # root), then the arc length and its bins, in place: a long run's temporaries are big
    # enough for each new one to cost its page faults
    step = np.diff(p[:, 0])
    dy = np.diff(p[:, 1])
    np.multiply(step, step, out=step)
    np.multiply(dy, dy, out=dy)
    np.add(step, dy, out=step)
    np.sqrt(step, out=step)
    s = np.empty(n)
    s[0] = 0.0
    np.cumsum(step, out=s[1:])
    np.floor(np.divide(s, spacing_m, out=s), out=s)  # the bin of each row's arc length
    keep = np.empty(n, bool)
    keep[0] = True
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    keep[-1] = True
    kept = np.flatnonzero(keep)
    return kept if ok is None else ok[kept]


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
    # a two-state hysteresis: a step that is a switch point is in the phase it switches to
    # (ALIGN is 1, APPROACH 0), any other step in that of the last switch point before it.
    # The others come in runs (the band between the two radii, NaN), few: each run takes
    # the phase of the step before it, without a pass over the whole run for them
    out = enter.astype(np.int8)
    held = np.flatnonzero(~(enter | leave))
    if held.size:
        first = np.flatnonzero(np.diff(held, prepend=-2) != 1)  # where each run starts
        before = held[first] - 1
        phase = np.where(before >= 0, out[np.maximum(before, 0)], start_phase)
        out[held] = np.repeat(phase, np.diff(first, append=held.size))
    return out


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


def cloud_message(t_ns: int, points: npt.NDArray[np.void], frame: str = WORLD_FRAME) -> bytes:
    """A ``foxglove.PointCloud`` of ``points`` in ``frame``, at the frame's origin.

    Parameters
    ----------
    t_ns
        Its timestamp, ns.
    points
        From :func:`cloud_points`, in ``frame``.
    frame
        ``world`` (default), or ``base_link``: the robot's own frame, which the viewers place
        by the ``/tf`` transforms of the log (the robot's outline).
    """
    # the message's fields in their numbers' order, as its deterministic serialisation
    # writes them: the timestamp (1), what every cloud in ``frame`` shares (2 to 5: packed
    # once), the points (6); the same bytes as one message's, without copying the seven
    # field descriptions into a new message each time
    stamp = PointCloud()
    stamp.timestamp.FromNanoseconds(int(t_ns))
    return b"".join((stamp.SerializeToString(deterministic=True), _cloud_head(frame),
                     PointCloud(data=points.tobytes()).SerializeToString(deterministic=True)))


@functools.lru_cache(maxsize=8)
def _cloud_head(frame: str) -> bytes:
    """The fields 2 to 5 of every ``foxglove.PointCloud`` in ``frame`` (its frame, its pose at
    the frame's origin, the points' stride and fields), serialised."""
    msg = PointCloud(frame_id=frame, point_stride=_POINT.itemsize, fields=_FIELDS)
    msg.pose.orientation.w = 1.0  # the identity: an all-zero quaternion is no rotation
    return bytes(msg.SerializeToString(deterministic=True))


#: The ``FileDescriptorSet`` of ``foxglove.PointCloud``, dependencies first.
CLOUD_SCHEMA_DATA: Final = descriptor_set(PointCloud.DESCRIPTOR.file)


#: The goal and the stop radius a ``/scene/goal`` cloud is drawn from, packed: the key of
#: :func:`_goal_cloud` (by their bits: -0.0 and 0.0 draw other float32 bytes, and NaN is
#: equal to itself there).
_GOAL_KEY: Final = struct.Struct("<4d")


@functools.lru_cache(maxsize=64)  # the runs of a batch mostly share their goal
def _goal_cloud(key: bytes) -> bytes:
    """The ``/scene/goal`` message at t = 0 of the goal and stop radius packed in ``key``
    (:data:`_GOAL_KEY`; a radius of 0: no ring)."""
    gx, gy, gth, radius = _GOAL_KEY.unpack(key)
    return cloud_message(0, cloud_points(goal_outline(gx, gy, gth, radius or None), GOAL_COLOR))


def _write_cloud(log: MessageLog, topic: str, points: npt.NDArray[np.void]) -> None:
    """One cloud of ``points`` in the world on ``topic`` at t = 0 (the goal, the path, the
    fixes, the estimate)."""
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
def _robot_clouds(half_track_m: float, wheel_radius_m: float) -> tuple[npt.NDArray[np.void], ...]:
    """The robot's outline as a cloud in each phase's colour (read-only: shared)."""
    body = _robot_outline(half_track_m, wheel_radius_m)
    shapes = tuple(cloud_points(body, c) for c in PHASE_COLORS)
    for shape in shapes:
        shape.flags.writeable = False
    return shapes


def robot_clouds(t_ns: npt.NDArray[np.int64], phase: npt.NDArray[np.int8],
                 half_track_m: float, wheel_radius_m: float
                 ) -> tuple[npt.NDArray[np.int64], list[bytes]]:
    """The ``/scene/robot`` messages of a run: its outline in frame ``base_link`` at the first
    row and at each change of phase, in the new phase's colour.

    Parameters
    ----------
    t_ns
        The rows' times, ns, shape ``(n,)``.
    phase
        The control phase of each row (:func:`control_phases`), shape ``(n,)``.
    half_track_m, wheel_radius_m
        The robot's geometry.

    Returns
    -------
    tuple
        The messages' times, ns, and the serialised clouds.
    """
    if len(t_ns) == 0:
        return t_ns[:0], []
    first = np.flatnonzero(np.concatenate([[True], phase[1:] != phase[:-1]]))
    shapes = _robot_clouds(half_track_m, wheel_radius_m)
    return t_ns[first], [cloud_message(int(t_ns[i]), shapes[int(phase[i])], BASE_FRAME)
                         for i in first.tolist()]


# --------------------------------------------------------------------------- the recorder


_X, _Y, _DR = COLUMN["x_m"], COLUMN["y_m"], COLUMN["dr_m"]
#: Rows a recorder holds at first: 10 s at 10 ms (then twice as many each time it fills).
_SCENE_ROWS: Final = 1024


class SceneRecorder:
    """Keeps what the scene topics need of each block, and writes them when the log closes.

    Parameters
    ----------
    goal
        ``(x_m, y_m, theta_rad)`` of the goal.
    half_track_m, wheel_radius_m
        The robot's half track ``L`` and wheel radius ``r``, m (its outline); either not
        positive and finite: the paper's robot (:data:`DEFAULT_HALF_TRACK_M`,
        :data:`DEFAULT_WHEEL_RADIUS_M`).
    stop_radius_m
        The run's stop radius, m (the phase and the goal ring); ``None``, not positive or not
        finite: no ring, no phase topic.
    controlled
        Whether the rows come from the closed loop (``dr_m`` is the controller's): the phase
        topic is written only then.
    """

    def __init__(self, goal: tuple[float, float, float], *, half_track_m: float,
                 wheel_radius_m: float, stop_radius_m: float | None,
                 controlled: bool) -> None:
        self._goal = goal
        half_track, radius = float(half_track_m), float(wheel_radius_m)
        self._half_track, self._wheel_radius = (
            (half_track, radius)
            if half_track > 0 and radius > 0 and math.isfinite(half_track + radius)
            else (DEFAULT_HALF_TRACK_M, DEFAULT_WHEEL_RADIUS_M))
        eps = math.nan if stop_radius_m is None else float(stop_radius_m)
        self._stop_radius = eps if math.isfinite(eps) and eps > 0 else None
        self._controlled = controlled
        # the rows' times, and x, y and dr a column each (what the drawing reads column by
        # column), rows 0:_n of them; grown by doubling
        self._n = 0
        self._t = np.empty(_SCENE_ROWS, np.int64)
        self._cols = np.empty((3, _SCENE_ROWS), np.float64)

    @classmethod
    def from_run_record(cls, run: Mapping[str, object], goal: tuple[float, float, float], *,
                        controlled: bool) -> SceneRecorder:
        """The recorder of a log known only by its ``run`` record: its strings (a log read
        back: recovery) or the mapping a writer was given without typed values (its
        ``params`` read without the JSON, :func:`robot_geometry`); ``params`` (``L`` and
        ``r``) and ``stop_radius_m`` are read here, the one place they are."""
        half_track_m, wheel_radius_m = robot_geometry(run)
        try:
            stop_radius_m = float(run.get("stop_radius_m", "nan"))  # type: ignore[arg-type]
        except (ValueError, TypeError):
            stop_radius_m = math.nan
        return cls(goal, half_track_m=half_track_m, wheel_radius_m=wheel_radius_m,
                   stop_radius_m=stop_radius_m, controlled=controlled)

    def add(self, t_ns: npt.NDArray[np.int64], block: npt.NDArray[np.float64]) -> None:
        """Keep the times, position and ``dr_m`` of the rows (copied: the caller's arrays are
        not kept)."""
        k = self._n
        n = k + len(t_ns)
        if n > self._t.shape[0]:
            size = max(n, 2 * self._t.shape[0])
            t, cols = np.empty(size, np.int64), np.empty((3, size), np.float64)
            t[:k], cols[:, :k] = self._t[:k], self._cols[:, :k]
            self._t, self._cols = t, cols
        self._t[k:n] = t_ns
        cols = self._cols
        cols[0, k:n] = block[:, _X]
        cols[1, k:n] = block[:, _Y]
        cols[2, k:n] = block[:, _DR]
        self._n = n

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
        log.write_messages(GOAL_TOPIC, CLOUD_SCHEMA, CLOUD_SCHEMA_DATA, [0],
                           [_goal_cloud(_GOAL_KEY.pack(*self._goal, self._stop_radius or 0.0))])
        if not self._n:
            return
        t = self._t[:self._n]
        xy = self._cols[:2, :self._n].T  # (n, 2): each column contiguous
        phase = (control_phases(self._cols[2, :self._n], self._stop_radius)
                 if self._controlled and self._stop_radius is not None
                 else np.zeros(len(t), np.int8))
        keep = resample_path(xy)
        _write_cloud(log, PATH_TOPIC, cloud_points(
            xy[keep], np.asarray(PHASE_COLORS, np.uint8)[phase[keep]]))
        robot_t, robot = robot_clouds(t, phase, self._half_track, self._wheel_radius)
        log.write_messages(ROBOT_TOPIC, CLOUD_SCHEMA, CLOUD_SCHEMA_DATA, robot_t, robot)
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
           "PHASE_TOPIC", "ROBOT_TOPIC", "ControlPhase", "SceneRecorder", "cloud_field",
           "cloud_message", "cloud_points", "control_phases", "phase_changes", "read_cloud",
           "resample_path", "robot_clouds", "robot_geometry", "robot_outline",
           "write_sensing_scene"]
