"""The sensing topics of a run log, and their replay.

Only runs with sensors have them:

===================================== ======================== =================================
topic                                 schema                   content
===================================== ======================== =================================
``/sensors/gps``                      ``foxglove.PoseInFrame`` each position fix: log time = its
                                                               arrival, ``timestamp`` = its
                                                               measurement time, identity
                                                               orientation (a fix has none)
``/robot/pose_estimate``              ``foxglove.PoseInFrame`` what the stabiliser was given,
                                                               every control step
``/robot/pose_estimate/covariance``   ``wmr.PoseCovariance``   the EKF's ``xx_m2``, ``xy_m2``,
                                                               ``yy_m2``, ``theta_theta_rad2``
                                                               (estimator ``ekf`` only)
===================================== ======================== =================================

Foxglove's schemas (``foxglove-schemas-protobuf`` 0.4) have no pose with covariance (only the
geodetic ``LocationFix`` carries one), hence the covariance on a topic of its own.  The true
pose stays on ``/robot/pose``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

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
COVARIANCE_SCHEMA: Final = "wmr.PoseCovariance"
COVARIANCE_FIELDS: Final = ("xx_m2", "xy_m2", "yy_m2", "theta_theta_rad2")


#: The EKF's covariance message and its MCAP schema data.
PoseCovariance, _COVARIANCE_SCHEMA_DATA = timestamped_doubles(
    COVARIANCE_SCHEMA, "wmr/sensing.proto", COVARIANCE_FIELDS)


def _pose_bytes(t_ns: int, x: float, y: float, theta: float | None) -> bytes:
    msg = PoseInFrame(frame_id=WORLD_FRAME)
    msg.timestamp.FromNanoseconds(t_ns)
    msg.pose.position.x = x
    msg.pose.position.y = y
    if theta is None:
        msg.pose.orientation.w = 1.0
    else:
        msg.pose.orientation.z = math.sin(0.5 * theta)
        msg.pose.orientation.w = math.cos(0.5 * theta)
    return msg.SerializeToString()


def write_sensing(log: MessageLog, rec: SensingRecord) -> None:
    """Write the fixes and estimates of ``rec`` to ``log`` (a :class:`RunLogWriter`)."""
    pose_schema = file_descriptor_set(POSE_SCHEMA)
    log.write_messages(GPS_TOPIC, POSE_SCHEMA, pose_schema, rec.gps_arrival_ns,
                       [_pose_bytes(int(t), float(x), float(y), None)
                        for t, (x, y) in zip(rec.gps_t_ns, rec.gps_xy_m, strict=True)])
    log.write_messages(ESTIMATE_TOPIC, POSE_SCHEMA, pose_schema, rec.est_t_ns,
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
    from wmr.adapters.mcap.scene import write_sensing_scene  # what Rerun and Foxglove draw

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
    A message that does not parse as a ``foxglove.PoseInFrame`` is left out.
    """
    from google.protobuf.message import DecodeError

    from wmr.adapters.mcap.reader import scan_file

    scan = scan_file(os.fspath(path), topics=(GPS_TOPIC, ESTIMATE_TOPIC))
    gps: list[tuple[int, int, float, float]] = []
    est: list[tuple[int, int, float, float, float]] = []
    for cid, channel in scan.channels.items():
        if channel.topic not in (GPS_TOPIC, ESTIMATE_TOPIC):
            continue
        for log_time, data in scan.messages.get(cid, []):
            try:
                msg = PoseInFrame.FromString(data)
            except DecodeError:
                continue
            t = msg.timestamp.ToNanoseconds()
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


__all__ = ["COVARIANCE_TOPIC", "ESTIMATE_TOPIC", "GPS_TOPIC", "PoseCovariance", "SensingTrace",
           "read_sensing", "write_sensing"]
