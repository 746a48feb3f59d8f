"""Protobuf schemas of the run log and their fixed wire layout.

Two kinds of message are logged:

* Foxglove's ``foxglove.PoseInFrame`` (``/robot/pose``, ``/goal``) and
  ``foxglove.FrameTransform`` (``/tf``), so that Foxglove and Rerun draw the robot;
* messages of our own in package ``wmr`` (file ``wmr/signals.proto``), one double field per
  column of :data:`wmr.core.signals.SIGNALS`, named exactly like the column (the name carries the
  unit), after a ``google.protobuf.Timestamp timestamp = 1`` field like Foxglove's.

Our descriptors are built with :mod:`google.protobuf.descriptor_pb2` at import time, no protoc.

Every per-step message has a FIXED layout: all fields are written, in field-number order,
including zero-valued doubles (legal protobuf; parsers accept it), so that a message is
``0x0A, len(ts), ts`` followed by a constant-length body whose double slots sit at known
offsets.  Only the Timestamp (two varints, zero fields omitted as in canonical proto3) changes
length from row to row.  :class:`RowEncoder` exploits this to serialise a whole block of rows
(and the MCAP Message records around them) with a few numpy operations instead of one
protobuf object per message.
"""

from __future__ import annotations

import functools
import itertools
import struct
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final, Protocol

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2
from google.protobuf.descriptor import FileDescriptor
from numpy.typing import ArrayLike, NDArray

from wmr.core.signals import COLUMN, CONTROL_SIGNALS, PLANT_SIGNALS, SIGNALS

WORLD_FRAME: Final = "world"
BASE_FRAME: Final = "base_link"
#: The MCAP magic, at the start and the end of every file (MCAP spec, "Magic").
MAGIC: Final = bytes([137, 77, 67, 65, 80, 48, 13, 10])

# Extra source columns derived from the block: the heading as a quaternion about z.
SRC_QZ: Final = len(SIGNALS)
SRC_QW: Final = len(SIGNALS) + 1
N_SOURCES: Final = len(SIGNALS) + 2

#: Our messages: name -> the signal columns they carry, in field order (numbers 2, 3, ...).
WMR_MESSAGES: Final[dict[str, tuple[str, ...]]] = {
    "wmr.RobotState": PLANT_SIGNALS,
    "wmr.ControllerErrors": CONTROL_SIGNALS[0:6],
    "wmr.Commands": CONTROL_SIGNALS[6:16],
    "wmr.ControlPoints": CONTROL_SIGNALS[16:20],
    # the torques alone: the input of an open-loop run (an optimal manoeuvre replayed on the
    # FMU), which has no controller and so none of the controller topics
    "wmr.Torques": ("tau_r_nm", "tau_l_nm"),
}
WMR_PROTO_FILE: Final = "wmr/signals.proto"


class MessageLog(Protocol):
    """What the scene and the sensing topics need of a log writer
    (:class:`wmr.adapters.mcap.RunLogWriter`)."""

    def write_messages(self, topic: str, schema_name: str, schema_data: bytes,
                       t_ns: ArrayLike, messages: Sequence[bytes]) -> None:
        """Log serialised messages on a topic of their own."""
        ...


def _wmr_file_proto() -> descriptor_pb2.FileDescriptorProto:
    fdp = descriptor_pb2.FileDescriptorProto(
        name=WMR_PROTO_FILE,
        package="wmr",
        syntax="proto3",
        dependency=["google/protobuf/timestamp.proto"],
    )
    fdt = descriptor_pb2.FieldDescriptorProto
    for full_name, fields in WMR_MESSAGES.items():
        msg = fdp.message_type.add(name=full_name.split(".", 1)[1])
        msg.field.add(
            name="timestamp",
            number=1,
            type=fdt.TYPE_MESSAGE,
            label=fdt.LABEL_OPTIONAL,
            type_name=".google.protobuf.Timestamp",
        )
        for i, name in enumerate(fields):
            msg.field.add(name=name, number=i + 2, type=fdt.TYPE_DOUBLE, label=fdt.LABEL_OPTIONAL)
    return fdp


_POOL: Final = descriptor_pool.DescriptorPool()
_POOL.AddSerializedFile(timestamp_pb2.DESCRIPTOR.serialized_pb)
_POOL.Add(_wmr_file_proto())


def message_class(schema_name: str) -> Any:
    """The generated protobuf class of a schema of the log.

    Parameters
    ----------
    schema_name
        Full protobuf name, e.g. ``"wmr.Commands"`` or ``"foxglove.PoseInFrame"``.

    Returns
    -------
    type
        The message class (instantiate it, ``ParseFromString`` into it).
    """
    if schema_name == "foxglove.PoseInFrame":
        return PoseInFrame
    if schema_name == "foxglove.FrameTransform":
        return FrameTransform
    return message_factory.GetMessageClass(_POOL.FindMessageTypeByName(schema_name))


@functools.lru_cache(maxsize=64)
def file_descriptor_set(schema_name: str) -> bytes:
    """Serialised ``FileDescriptorSet`` of a schema and its dependencies (the MCAP schema data).

    Parameters
    ----------
    schema_name
        Full protobuf name of the message.

    Returns
    -------
    bytes
        Deterministic serialisation, dependencies first.
    """
    return descriptor_set(message_class(schema_name).DESCRIPTOR.file)


def descriptor_set(file: FileDescriptor) -> bytes:
    """Serialised ``FileDescriptorSet`` of a proto file and its dependencies, dependencies
    first (deterministic): the MCAP schema data of any of its messages."""
    fds = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: FileDescriptor) -> None:
        for dep in fd.dependencies:
            if dep.name not in seen:
                seen.add(dep.name)
                add(dep)
        fd.CopyToProto(fds.file.add())

    add(file)
    return fds.SerializeToString(deterministic=True)


def timestamped_doubles(schema_name: str, proto_file: str,
                        fields: tuple[str, ...]) -> tuple[Any, bytes]:
    """A proto3 message ``schema_name`` (``package.Name``) of a ``timestamp`` (field 1) and
    ``fields`` as doubles (2, 3, ...), in a file of its own: the message class and the MCAP
    schema data (the ``FileDescriptorSet``, ``google/protobuf/timestamp.proto`` first).

    The logs' own small topics (the EKF covariance, the control phase) are such messages."""
    package, name = schema_name.split(".", 1)
    fdt = descriptor_pb2.FieldDescriptorProto
    fdp = descriptor_pb2.FileDescriptorProto(
        name=proto_file, package=package, syntax="proto3",
        dependency=["google/protobuf/timestamp.proto"])
    msg = fdp.message_type.add(name=name)
    msg.field.add(name="timestamp", number=1, type=fdt.TYPE_MESSAGE, label=fdt.LABEL_OPTIONAL,
                  type_name=".google.protobuf.Timestamp")
    for i, field in enumerate(fields):
        msg.field.add(name=field, number=i + 2, type=fdt.TYPE_DOUBLE, label=fdt.LABEL_OPTIONAL)
    pool = descriptor_pool.DescriptorPool()
    pool.AddSerializedFile(timestamp_pb2.DESCRIPTOR.serialized_pb)
    pool.Add(fdp)
    fds = descriptor_pb2.FileDescriptorSet()
    timestamp_pb2.DESCRIPTOR.CopyToProto(fds.file.add())
    fds.file.add().CopyFrom(fdp)
    return (message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name)),
            fds.SerializeToString(deterministic=True))


# --------------------------------------------------------------------------------------------
# Fixed wire layout of a message body (everything after the timestamp field)
# --------------------------------------------------------------------------------------------

#: A piece of a body: its constant bytes and its double slots as (offset, source column).
_Piece = tuple[bytes, list[tuple[int, int]]]


def _f64(field: int, source: int | float) -> _Piece:
    tag = bytes([field << 3 | 1])
    if isinstance(source, float):
        return tag + struct.pack("<d", source), []
    return tag + bytes(8), [(1, source)]


def _string(field: int, text: str) -> _Piece:
    raw = text.encode()
    assert len(raw) < 128
    return bytes([field << 3 | 2, len(raw)]) + raw, []


def _concat(*pieces: _Piece) -> _Piece:
    data = b""
    slots: list[tuple[int, int]] = []
    for raw, sl in pieces:
        slots += [(off + len(data), src) for off, src in sl]
        data += raw
    return data, slots


def _sub(field: int, *pieces: _Piece) -> _Piece:
    raw, slots = _concat(*pieces)
    assert len(raw) < 128
    return bytes([field << 3 | 2, len(raw)]) + raw, [(off + 2, src) for off, src in slots]


def _vector3(field: int, x: int, y: int) -> _Piece:
    return _sub(field, _f64(1, x), _f64(2, y), _f64(3, 0.0))


def _yaw_quaternion(field: int) -> _Piece:
    return _sub(field, _f64(1, 0.0), _f64(2, 0.0), _f64(3, SRC_QZ), _f64(4, SRC_QW))


_X: Final = COLUMN["x_m"]
_Y: Final = COLUMN["y_m"]


@dataclass(frozen=True)
class TopicLayout:
    """One per-step topic: its schema and the fixed layout of its message body.

    Attributes
    ----------
    topic
        MCAP channel topic.
    schema_name
        Full protobuf message name.
    body
        Constant bytes of the body (fields 2.. of the message), double slots zeroed.
    slots
        ``(offset in body, source column)`` of each variable double; source columns index
        :data:`wmr.core.signals.SIGNALS`, then :data:`SRC_QZ`, :data:`SRC_QW`.
    signals
        Signal names the message carries 1:1 (field name == signal name); empty for poses.
    """

    topic: str
    schema_name: str
    body: bytes
    slots: tuple[tuple[int, int], ...]
    signals: tuple[str, ...]


def _layout(topic: str, schema_name: str, piece: _Piece, signals: tuple[str, ...]) -> TopicLayout:
    raw, slots = piece
    return TopicLayout(topic, schema_name, raw, tuple(slots), signals)


def _wmr_layout(topic: str, schema_name: str) -> TopicLayout:
    names = WMR_MESSAGES[schema_name]
    piece = _concat(*(_f64(i + 2, COLUMN[n]) for i, n in enumerate(names)))
    return _layout(topic, schema_name, piece, names)


#: The per-step topics, in the order their messages appear for each row.
STEP_TOPICS: Final[tuple[TopicLayout, ...]] = (
    _layout(
        "/robot/pose",
        "foxglove.PoseInFrame",
        _concat(_string(2, WORLD_FRAME), _sub(3, _vector3(1, _X, _Y), _yaw_quaternion(2))),
        (),
    ),
    _layout(
        "/tf",
        "foxglove.FrameTransform",
        _concat(
            _string(2, WORLD_FRAME),
            _string(3, BASE_FRAME),
            _vector3(4, _X, _Y),
            _yaw_quaternion(5),
        ),
        (),
    ),
    _wmr_layout("/robot/state", "wmr.RobotState"),
    _wmr_layout("/controller/errors", "wmr.ControllerErrors"),
    _wmr_layout("/controller/commands", "wmr.Commands"),
    _wmr_layout("/controller/points", "wmr.ControlPoints"),
)
#: The torque topic of an open-loop log (``/robot/torques``, :data:`OPEN_LOOP_TOPICS`).
TORQUE_TOPIC: Final = _wmr_layout("/robot/torques", "wmr.Torques")
#: The per-step topics of an open-loop log: the robot's, and the torques applied; no
#: controller topics, so that no field is NaN for want of a controller.
OPEN_LOOP_TOPICS: Final[tuple[TopicLayout, ...]] = (*STEP_TOPICS[:3], TORQUE_TOPIC)
#: The controller's phase (approach, align), only where it changes (:mod:`.scene`).
PHASE_TOPIC: Final = "/controller/phase"
GOAL_TOPIC: Final = "/goal"
GOAL_SCHEMA: Final = "foxglove.PoseInFrame"

# --------------------------------------------------------------------------------------------
# Vectorised encoding of MCAP Message records
# --------------------------------------------------------------------------------------------

_TS_SLOTS: Final = 12  # seconds: tag + 5 varint bytes; nanos: tag + 5 varint bytes
_SEG_HEAD: Final = 33  # opcode 1, length 8, channel 2, sequence 4, log 8, publish 8, 0x0A, len
_SHIFTS: Final = np.arange(0, 35, 7, dtype=np.uint64)  # 5 varint groups of 7 bits
_MAX_T_NS: Final = 2**63 - 1
_OP_MESSAGE: Final = 0x05


_TS_TAGS: Final = np.array([0x08, 0x10], np.uint8)  # Timestamp.seconds = 1, .nanos = 2


def encode_timestamps(
    t_ns: NDArray[np.int64],
) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """Serialise ``google.protobuf.Timestamp`` messages of many times at once.

    Parameters
    ----------
    t_ns
        Times in ns, ``0 <= t_ns < 2**63``, shape ``(n,)``.

    Returns
    -------
    padded : ndarray of uint8, shape (n, 12)
        Seconds field (tag, 5 varint bytes) in bytes 0..5, nanos field in bytes 6..11.
    nbytes : ndarray of int64, shape (n, 2)
        Varint length of seconds and of nanos; 0 when the value is 0 and the field is omitted,
        as protobuf does.  The message is ``padded[:, :1 + nbytes[:, 0]]`` if the seconds are
        non-zero, followed by ``padded[:, 6:7 + nbytes[:, 1]]`` if the nanos are non-zero.

    Notes
    -----
    Byte ``j`` of the varint of ``v`` exists iff ``v >> 7j != 0`` (for ``j = 0``: iff the
    field is present), and carries the continuation bit iff byte ``j + 1`` exists.  Seconds of
    an int64 ns time are below 2**34 and nanos below 2**30: 5 varint bytes suffice.
    """
    n = t_ns.shape[0]
    sec, nanos = np.divmod(t_ns.astype(np.uint64), np.uint64(1_000_000_000))
    shifted = np.stack([sec, nanos], axis=1)[:, :, None] >> _SHIFTS  # (n, 2, 5)
    nonzero = shifted != 0
    out = np.empty((n, 2, 6), np.uint8)
    out[:, :, 0] = _TS_TAGS
    body = out[:, :, 1:]
    np.bitwise_and(shifted, np.uint64(0x7F), out=body, casting="unsafe")
    body[:, :, :4] |= nonzero[:, :, 1:].view(np.uint8) << 7
    return out.reshape(n, _TS_SLOTS), nonzero.sum(axis=2, dtype=np.int64)


class RowEncoder:
    """Serialise rows of a run block as MCAP Message records, all per-step topics, vectorised.

    The records of row ``i`` are, topic after topic in :data:`STEP_TOPICS` order, an MCAP
    Message record (opcode, length, channel id, sequence 0, log time = publish time = t_ns)
    whose data is the protobuf message of that row.

    Each row is first written into a "source" uint8 row (constant bytes, time, lengths,
    timestamp bytes, doubles); the records are then one gather of source columns.  Which columns
    depends only on the varint lengths of the row's timestamp; rows come in runs of equal
    lengths (time increases), so a chunk is a handful of 2-D gathers with cached column maps.

    Parameters
    ----------
    channel_ids
        MCAP channel id of each topic of ``layouts``, same order.
    layouts
        The topics written for each row: :data:`STEP_TOPICS` (a closed-loop run, default) or
        :data:`OPEN_LOOP_TOPICS`.
    """

    def __init__(self, channel_ids: tuple[int, ...],
                 layouts: tuple[TopicLayout, ...] = STEP_TOPICS) -> None:
        if len(channel_ids) != len(layouts):
            raise ValueError("one channel id per step topic")
        n_topics = len(layouts)
        # The padded segment of topic k, in symbols (kind, index), mapped to source columns.
        sym: list[tuple[str, int]] = []
        ts_pos: list[int] = []  # where each topic's 12 padded timestamp bytes start
        seg_const: list[int] = []  # segment length without the timestamp bytes
        for k, (layout, cid) in enumerate(zip(layouts, channel_ids, strict=True)):
            head = struct.pack("<BQHI", _OP_MESSAGE, 0, cid, 0)
            sym += [("len", 8 * k + j - 1) if 1 <= j <= 8 else ("c", b) for j, b in enumerate(head)]
            sym += [("t", j) for j in range(8)] * 2  # log time, publish time
            sym += [("c", 0x0A), ("tslen", 0)]
            ts_pos.append(len(sym))
            sym += [("ts", j) for j in range(_TS_SLOTS)]
            body: list[tuple[str, int]] = [("c", b) for b in layout.body]
            for off, src in layout.slots:
                body[off : off + 8] = [("d", 8 * src + j) for j in range(8)]
            sym += body
            seg_const.append(_SEG_HEAD + len(layout.body))
        consts = sorted({v for kind, v in sym if kind == "c"})
        n_const = len(consts)
        base = {"c": 0, "t": n_const, "tslen": n_const + 8, "len": n_const + 9}
        base["ts"] = base["len"] + 8 * n_topics
        base["d"] = base["ts"] + _TS_SLOTS
        col_of_const = {v: i for i, v in enumerate(consts)}
        self._col_map = np.asarray(
            [col_of_const[v] if kind == "c" else base[kind] + v for kind, v in sym], np.intp
        )
        self._base = base
        self._ts_pos = ts_pos
        self._n_src = base["d"] + 8 * N_SOURCES
        self._consts = np.asarray(consts, np.uint8)
        self._seg_const = np.asarray(seg_const, np.int64)
        self._seg_start = np.concatenate([[0], np.cumsum(self._seg_const)[:-1]])
        self._n_topics = n_topics
        self._cols_by_key: dict[int, NDArray[np.intp]] = {}
        # the source rows' scratch buffer, one per thread: the writer shares one encoder
        # between every log of a process, and a Dask worker writes logs in several threads
        # (one buffer for all wrote a thread's rows into another's log)
        self._scratch = threading.local()

    def _cols(self, key: int) -> NDArray[np.intp]:
        """Source columns of a row whose timestamp varints have lengths ``divmod(key, 8)``."""
        cols = self._cols_by_key.get(key)
        if cols is None:
            n_sec, n_nanos = divmod(key, 8)
            keep = np.ones(self._col_map.shape[0], np.bool_)
            used = [n_sec > 0] + [j < n_sec for j in range(5)]
            used += [n_nanos > 0] + [j < n_nanos for j in range(5)]
            for pos in self._ts_pos:
                keep[pos : pos + _TS_SLOTS] = used
            cols = self._cols_by_key[key] = self._col_map[keep]
        return cols

    def _source_rows(self, n: int) -> NDArray[np.uint8]:
        """This thread's ``n`` source rows (their constant columns filled)."""
        buf: NDArray[np.uint8] | None = getattr(self._scratch, "src", None)
        if buf is None or buf.shape[0] < n:
            buf = np.empty((n, self._n_src), np.uint8)
            buf[:, : self._consts.shape[0]] = self._consts
            self._scratch.src = buf
        return buf[:n]

    def encode(
        self, t_ns: NDArray[np.int64], block: NDArray[np.float64]
    ) -> tuple[bytes, NDArray[np.int64]]:
        """Serialise rows as concatenated MCAP Message records.

        Parameters
        ----------
        t_ns
            Simulation time of each row in ns, int64, shape ``(n,)``, non-negative.
        block
            Signals, float64, shape ``(n, len(SIGNALS))``.

        Returns
        -------
        records : bytes
            The Message records, row after row, topic after topic.
        offsets : ndarray of int64, shape (n, len(STEP_TOPICS))
            Byte offset of each record in ``records``.
        """
        n = t_ns.shape[0]
        if n == 0:
            return b"", np.zeros((0, self._n_topics), np.int64)
        ts, nbytes = encode_timestamps(t_ns)
        tslen = nbytes.sum(axis=1) + np.count_nonzero(nbytes, axis=1)
        src = self._source_rows(n)
        b = self._base
        src[:, b["t"] : b["t"] + 8] = t_ns.astype("<u8").view(np.uint8).reshape(n, 8)
        src[:, b["tslen"]] = tslen
        rec_len = (self._seg_const - 9 + tslen[:, None]).astype("<u8")
        src[:, b["len"] : b["ts"]] = rec_len.view(np.uint8).reshape(n, 8 * self._n_topics)
        src[:, b["ts"] : b["d"]] = ts
        d = src[:, b["d"] :].view("<f8")
        d[:, : len(SIGNALS)] = block
        half = 0.5 * block[:, COLUMN["theta_rad"]]
        d[:, SRC_QZ] = np.sin(half)
        d[:, SRC_QW] = np.cos(half)
        key = nbytes[:, 0] * 8 + nbytes[:, 1]
        starts = [0, *(np.flatnonzero(key[1:] != key[:-1]) + 1).tolist(), n]
        records = b"".join(
            src[i:j][:, self._cols(int(key[i]))].tobytes() for i, j in itertools.pairwise(starts)
        )
        seg_len = self._seg_const + tslen[:, None]  # (n, K)
        row_start = np.concatenate([[0], np.cumsum(seg_len.sum(axis=1))[:-1]])
        offsets = row_start[:, None] + self._seg_start + np.arange(self._n_topics) * tslen[:, None]
        return records, offsets


def decode_bodies(layout: TopicLayout, datas: list[bytes]) -> NDArray[np.float64] | None:
    """Inverse of the fixed layout: the signal columns of many messages of one topic.

    Parameters
    ----------
    layout
        The topic's layout (must carry signals).
    datas
        Serialised messages.

    Returns
    -------
    ndarray of float64, shape (len(datas), len(layout.signals)), or None
        ``None`` when any message does not have the fixed layout (then parse with protobuf).
    """
    sizes = np.fromiter(map(len, datas), np.int64, len(datas))
    ends = np.cumsum(sizes)
    rows = decode_spans(layout, np.frombuffer(b"".join(datas), np.uint8), ends - sizes, ends)
    return None if rows is None else rows.T


def at_every_byte(data: NDArray[np.uint8], dtype: str) -> NDArray[Any]:
    """The value of ``dtype`` that starts at each byte of ``data`` (a view, no copy, unaligned):
    ``at_every_byte(data, "<u8")[p]`` is the little-endian uint64 in ``data[p:p + 8]``, so
    that one fancy index reads a field of many records at once."""
    size = np.dtype(dtype).itemsize
    return np.ndarray((max(data.size - size + 1, 0),), dtype, buffer=data, strides=(1,))


@functools.lru_cache(maxsize=64)
def _body_checks(layout: TopicLayout, signals: tuple[str, ...]) -> tuple[
        NDArray[np.int64], NDArray[np.uint64], NDArray[np.uint64], NDArray[np.int64]]:
    """How to check a body and read it 8 bytes at a time: where its words start (every 8
    bytes, the last one ending at the body's end), which of their bytes are constant (a
    mask) and what those hold, and where the double of each of ``signals`` starts."""
    blen = len(layout.body)
    assert blen >= 8, "a body with a double slot has 9 bytes at least"
    const = np.full(blen, 0xFF, np.uint8)
    for off, _ in layout.slots:
        const[off : off + 8] = 0
    words = np.minimum(np.arange(0, blen, 8), blen - 8)
    at = words[:, None] + np.arange(8)
    body = np.frombuffer(layout.body, np.uint8)
    slot_of = {src: off for off, src in layout.slots}
    doubles = np.array([slot_of[COLUMN[name]] for name in signals], np.int64)
    return (words.astype(np.int64), const[at].copy().view("<u8")[:, 0],
            (body & const)[at].copy().view("<u8")[:, 0], doubles)


def decode_spans(layout: TopicLayout, data: NDArray[np.uint8], starts: NDArray[np.int64],
                 ends: NDArray[np.int64],
                 signals: Sequence[str] | None = None) -> NDArray[np.float64] | None:
    """Inverse of the fixed layout, in place: the signals of the messages ``data[starts[i]:
    ends[i]]`` (an inflated chunk, or messages end to end), without a ``bytes`` per message.

    Every message is checked as a whole: the timestamp field first (tag ``0x0A``, a length of
    at most 12), the body right after it to the message's end, and every constant byte of the
    body (tags, frame names, zero slots) equal to the layout's.

    Parameters
    ----------
    layout
        The topic's layout (must carry signals).
    data
        The bytes the messages are in.
    starts, ends
        Where each message starts and ends in ``data`` (int64, shape ``(m,)``).
    signals
        The signals to decode (default: all of ``layout.signals``), each one of them.

    Returns
    -------
    ndarray of float64, shape (len(signals), m), or None
        One row per signal (each contiguous), one column per message; ``None`` when any
        message does not have the fixed layout (then parse with protobuf).
    """
    names = layout.signals if signals is None else tuple(signals)
    words, mask, const, doubles = _body_checks(layout, names)
    m, blen = starts.shape[0], len(layout.body)
    if m == 0:
        return np.empty((len(names), 0), np.float64)
    size = ends - starts
    if int(size.min()) < 2 + blen:
        return None
    head = at_every_byte(data, "<u2")[starts]  # the timestamp field's tag, then its length
    ts_len = head >> 8
    if not (bool(((head & 0xFF) == 0x0A).all()) and int(ts_len.max()) <= _TS_SLOTS
            and bool((size == 2 + blen + ts_len).all())):
        return None
    body = ends - blen
    seen = at_every_byte(data, "<u8")[body[:, None] + words]
    seen &= mask
    if bool((seen != const).any()):
        return None
    return at_every_byte(data, "<f8")[doubles[:, None] + body]  # (signals, m)
