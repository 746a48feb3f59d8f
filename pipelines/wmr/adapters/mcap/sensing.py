"""The sensing topics of a run log, and their replay.

Only runs with sensors have them:

===================================== ======================== =================================
topic                                 schema                   content
===================================== ======================== =================================
``/sensors/gps``                      ``foxglove.PointCloud``  each position fix, one point
                                                               (``x``, ``y``, ``z`` = 0 float64,
                                                               ``red``, ``green``, ``blue``,
                                                               ``alpha`` uint8) in frame
                                                               ``world``, no ``pose``: log time
                                                               = its arrival, ``timestamp`` =
                                                               its measurement time
``/robot/pose_estimate``              ``foxglove.PoseInFrame`` what the stabiliser was given,
                                                               every control step
``/robot/pose_estimate/covariance``   ``wmr.PoseCovariance``   the EKF's ``xx_m2``, ``xy_m2``,
                                                               ``yy_m2``, ``theta_theta_rad2``
                                                               (estimator ``ekf`` only)
===================================== ======================== =================================

A fix is a position without a heading.  Logs written before this version carry each fix as a
``foxglove.PoseInFrame`` with an identity orientation, which Foxglove's and Lichtblick's 3-D
panels draw as an arrow along +x: a heading nobody measured.  A point cloud of one point is
what both panels (and Rerun's MCAP loader: ``Points3D``) draw as a bare position, and its
coordinates are float64 so that a fix reads back as it was measured.  :func:`read_sensing`
reads both forms, by the channel's schema name.

Foxglove's schemas (``foxglove-schemas-protobuf`` 0.4) have no pose with covariance (only the
geodetic ``LocationFix`` carries one, and our plane has no geodetic origin), hence the
covariance on a topic of its own.  The true pose stays on ``/robot/pose``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from wmr.adapters.mcap.scene import (
    CLOUD_SCHEMA,
    CLOUD_SCHEMA_DATA,
    GPS_COLOR,
    cloud_field,
    write_sensing_scene,
)
from wmr.adapters.mcap.schemas import (
    WORLD_FRAME,
    MessageLog,
    file_descriptor_set,
    timestamped_doubles,
)
from wmr.core.sensing.estimator import SensingRecord

GPS_TOPIC: Final = "/sensors/gps"
ESTIMATE_TOPIC: Final = "/robot/pose_estimate"
COVARIANCE_TOPIC: Final = "/robot/pose_estimate/covariance"
POSE_SCHEMA: Final = "foxglove.PoseInFrame"
#: The schema of a fix: a point cloud of one point (before: ``POSE_SCHEMA``, still read).
GPS_SCHEMA: Final = CLOUD_SCHEMA
COVARIANCE_SCHEMA: Final = "wmr.PoseCovariance"
COVARIANCE_FIELDS: Final = ("xx_m2", "xy_m2", "yy_m2", "theta_theta_rad2")


#: The EKF's covariance message and its MCAP schema data.
PoseCovariance, _COVARIANCE_SCHEMA_DATA = timestamped_doubles(
    COVARIANCE_SCHEMA, "wmr/sensing.proto", COVARIANCE_FIELDS)


def _pose_bytes(t_ns: int, x: float, y: float, theta: float) -> bytes:
    msg = PoseInFrame(frame_id=WORLD_FRAME)
    msg.timestamp.FromNanoseconds(t_ns)
    msg.pose.position.x = x
    msg.pose.position.y = y
    msg.pose.orientation.z = math.sin(0.5 * theta)
    msg.pose.orientation.w = math.cos(0.5 * theta)
    return msg.SerializeToString()


#: A fix as a point: x, y, z float64 (a fix reads back as it was measured), then the colour.
_FIX_POINT: Final = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "u1"),
                              ("green", "u1"), ("blue", "u1"), ("alpha", "u1")])
_FIX_FIELDS: Final = [
    PackedElementField(name=name, offset=offset,
                       type=PackedElementField.FLOAT64 if name in "xyz"
                       else PackedElementField.UINT8)
    for name, offset in (("x", 0), ("y", 8), ("z", 16), ("red", 24), ("green", 25),
                         ("blue", 26), ("alpha", 27))]


def fix_message(t_ns: int, x_m: float, y_m: float) -> bytes:
    """A position fix as logged on ``/sensors/gps``: a ``foxglove.PointCloud`` of one point
    at ``(x_m, y_m, 0)`` in frame ``world`` with timestamp ``t_ns`` (its measurement time).

    It has no ``pose`` (the cloud's origin is the frame's) and nothing else that holds an
    orientation: a 3-D panel draws a point, not an arrow along a heading nobody measured.
    """
    point = np.zeros(1, _FIX_POINT)
    point["x"], point["y"] = x_m, y_m
    point["red"], point["green"], point["blue"] = GPS_COLOR
    point["alpha"] = 255
    msg = PointCloud(frame_id=WORLD_FRAME, point_stride=_FIX_POINT.itemsize,
                     fields=_FIX_FIELDS, data=point.tobytes())
    msg.timestamp.FromNanoseconds(t_ns)
    return msg.SerializeToString()


def write_sensing(log: MessageLog, rec: SensingRecord) -> None:
    """Write the fixes and estimates of ``rec`` to ``log`` (a :class:`RunLogWriter`)."""
    log.write_messages(GPS_TOPIC, GPS_SCHEMA, CLOUD_SCHEMA_DATA, rec.gps_arrival_ns,
                       [fix_message(int(t), float(x), float(y))
                        for t, (x, y) in zip(rec.gps_t_ns, rec.gps_xy_m, strict=True)])
    log.write_messages(ESTIMATE_TOPIC, POSE_SCHEMA, file_descriptor_set(POSE_SCHEMA),
                       rec.est_t_ns,
                       [_pose_bytes(int(t), float(p[0]), float(p[1]), float(p[2]))
                        for t, p in zip(rec.est_t_ns, rec.est_pose, strict=True)])
    if len(rec.est_cov) and np.isfinite(rec.est_cov).all():
        msgs = []
        for t, c in zip(rec.est_t_ns.tolist(), rec.est_cov.tolist(), strict=True):
            m = PoseCovariance(**dict(zip(COVARIANCE_FIELDS, c, strict=True)))
            m.timestamp.FromNanoseconds(t)
            msgs.append(m.SerializeToString())
        log.write_messages(COVARIANCE_TOPIC, COVARIANCE_SCHEMA, _COVARIANCE_SCHEMA_DATA,
                           rec.est_t_ns, msgs)
    write_sensing_scene(log, rec.gps_xy_m, rec.est_pose[:, :2])


@dataclass(frozen=True)
class SensingTrace:
    """The sensing topics of a log, as read back.

    Attributes
    ----------
    gps_t_ns, gps_xy_m
        Measurement time (ns) and position (m) of each fix, ``(k,)`` and ``(k, 2)``.
    est_t_ns, est_pose
        Time (ns) and ``(x_m, y_m, theta_rad)`` of each estimate.
    """

    gps_t_ns: npt.NDArray[np.int64]
    gps_xy_m: npt.NDArray[np.float64]
    est_t_ns: npt.NDArray[np.int64]
    est_pose: npt.NDArray[np.float64]


def read_sensing(path: str | os.PathLike[str]) -> SensingTrace | None:
    """The sensing topics of the log at ``path``; ``None`` when it has none.

    The log is read by the bounded scan of :func:`wmr.adapters.mcap.reader.scan_file` (record
    lengths checked against the file, inflation capped, a damaged region left out), never by
    a reader that trusts the file: a log from someone else cannot take the memory or hang here.
    The fixes are read in both forms, by their channel's schema: ``foxglove.PointCloud``
    (each point a fix) and, in logs written before it, ``foxglove.PoseInFrame`` (its
    position).  A message that does not parse as its schema, or a cloud without float ``x``
    and ``y`` fields that fit its data, is left out.
    """
    from google.protobuf.message import DecodeError

    from wmr.adapters.mcap.reader import scan_file

    scan = scan_file(os.fspath(path), topics=(GPS_TOPIC, ESTIMATE_TOPIC))
    gps: list[tuple[int, int, float, float]] = []
    est: list[tuple[int, int, float, float, float]] = []
    for cid, channel in scan.channels.items():
        if channel.topic not in (GPS_TOPIC, ESTIMATE_TOPIC):
            continue
        schema = scan.schemas.get(channel.schema_id)
        # a fix is a point cloud, or in an older log a pose; estimates are poses
        kind: type[PointCloud] | type[PoseInFrame] = (
            PointCloud if channel.topic == GPS_TOPIC and schema is not None
            and schema.name == GPS_SCHEMA else PoseInFrame)
        for log_time, data in scan.messages.get(cid, []):
            try:
                msg = kind.FromString(data)
            except DecodeError:
                continue
            t = msg.timestamp.ToNanoseconds()
            if isinstance(msg, PointCloud):
                xs, ys = cloud_field(msg, "x"), cloud_field(msg, "y")
                if xs is None or ys is None or xs.dtype.kind != "f" or ys.dtype.kind != "f":
                    continue
                gps.extend((log_time, t, x, y) for x, y in zip(xs.tolist(), ys.tolist(),
                                                              strict=True))
                continue
            p = msg.pose
            if channel.topic == GPS_TOPIC:
                gps.append((log_time, t, p.position.x, p.position.y))
            else:
                theta = 2.0 * math.atan2(p.orientation.z, p.orientation.w)
                est.append((log_time, t, p.position.x, p.position.y, theta))
    if not gps and not est:
        return None
    gps.sort(key=lambda r: r[0])  # in log-time order, as the run wrote them
    est.sort(key=lambda r: r[0])
    g = np.array([r[1:] for r in gps], dtype=np.float64).reshape(-1, 3)
    e = np.array([r[1:] for r in est], dtype=np.float64).reshape(-1, 4)
    return SensingTrace(gps_t_ns=np.array([r[1] for r in gps], np.int64), gps_xy_m=g[:, 1:3],
                        est_t_ns=np.array([r[1] for r in est], np.int64),
                        est_pose=e[:, 1:4])


__all__ = ["COVARIANCE_TOPIC", "ESTIMATE_TOPIC", "GPS_SCHEMA", "GPS_TOPIC", "PoseCovariance",
           "SensingTrace", "fix_message", "read_sensing", "write_sensing"]
