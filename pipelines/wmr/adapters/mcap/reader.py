"""Read the MCAP log of a run back into arrays, tolerating cut files."""

from __future__ import annotations

import io
import math
import os
import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import IO, Any, NamedTuple

import numpy as np
from google.protobuf.message import DecodeError
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    DataEnd,
    Footer,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from mcap_protobuf.decoder import DecoderFactory
from numpy.typing import NDArray

from wmr.adapters.mcap.schemas import (
    GOAL_SCHEMA,
    GOAL_TOPIC,
    OPEN_LOOP_TOPICS,
    STEP_TOPICS,
    TORQUE_TOPIC,
    TopicLayout,
    decode_bodies,
    file_descriptor_set,
    message_class,
)
from wmr.adapters.mcap.writer import MAGIC
from wmr.core.signals import SIGNALS
from wmr.infra.errors import LogError


class Pose2D(NamedTuple):
    """A planar pose: position in m, heading in rad."""

    x_m: float
    y_m: float
    theta_rad: float


@dataclass
class RunData:
    """What a run log holds.

    Attributes
    ----------
    path
        The file read.
    t_ns
        Simulation time of each row, ns from run start, int64, shape ``(n,)``.
    signals
        Every column of :data:`wmr.core.signals.SIGNALS`, float64 arrays of shape ``(n,)``,
        bit-identical to what was written (NaN where a topic is missing from the file).
    metadata
        Metadata records by name (``run``, ``result``), values are strings.
    attachments
        Attachment name -> bytes.
    media_types
        Attachment name -> media type.
    goal
        The ``/goal`` pose (heading from the quaternion), or None when absent.
    truncated
        True when the file ends before its footer (cut, or a killed writer) or is damaged (a
        CRC mismatch, data after the end): the data is then what could be checked, and
        ``warnings`` says what is missing.
    warnings
        Human-readable notes on anything missing or skipped.
    """

    path: str
    t_ns: NDArray[np.int64]
    signals: dict[str, NDArray[np.float64]]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    media_types: dict[str, str] = field(default_factory=dict)
    goal: Pose2D | None = None
    truncated: bool = False
    warnings: list[str] = field(default_factory=list)

    @property
    def t_s(self) -> NDArray[np.float64]:
        """Simulation time of each row, s."""
        return self.t_ns.astype(np.float64) * 1e-9

    @property
    def n_steps(self) -> int:
        """Number of rows."""
        return int(self.t_ns.shape[0])

    def block(self) -> NDArray[np.float64]:
        """The signals as one ``(n, len(SIGNALS))`` array, columns as in ``SIGNALS``."""
        return np.column_stack([self.signals[name] for name in SIGNALS]).reshape(
            self.n_steps, len(SIGNALS)
        )


class _Scan:
    """Everything collected while walking the records of a file."""

    def __init__(self) -> None:
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.messages: dict[int, list[tuple[int, bytes]]] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self.attachments: dict[str, bytes] = {}
        self.media_types: dict[str, str] = {}
        self.complete = False
        self.damaged = False
        self.in_summary = False
        self.bad_chunks = 0
        self.warnings: list[str] = []
        #: The uncompressed records of every chunk that passed its checks (for recovery).
        self.chunks: list[bytes] = []
        #: Message records outside chunks, whole (for recovery).
        self.loose: list[Message] = []

    def damage(self, what: str) -> None:
        self.damaged = True
        self.warnings.append(what)

    def add_message(self, channel_id: int, log_time: int, data: bytes) -> None:
        self.messages.setdefault(channel_id, []).append((log_time, data))


try:
    from zstandard import ZstdError
except ImportError:  # pragma: no cover - zstandard comes with mcap

    class ZstdError(Exception):  # type: ignore[no-redef]
        """Placeholder when zstandard is absent."""


#: What a cut or damaged file raises inside mcap (lz4 raises RuntimeError).
_DAMAGE = (McapError, ZstdError, struct.error, ValueError, EOFError, RuntimeError, MemoryError)


def _records(stream: IO[bytes], size: int) -> Iterator[Any]:
    reader = StreamReader(stream, emit_chunks=True, record_size_limit=max(size, 1024))
    yield from reader.records


def _chunk_messages(chunk: Chunk, scan: _Scan) -> list[tuple[int, int, bytes]]:
    """The Message records of a chunk as ``(channel id, log time, data)``.

    Faster than :func:`mcap.stream_reader.breakup_chunk` (no record objects per message); the
    uncompressed CRC is checked; Schema and Channel records inside the chunk are kept in
    ``scan``.  Raises on any inconsistency, so that a damaged chunk is dropped whole.
    """
    if chunk.compression == "":
        buf = bytes(chunk.data)
    else:
        stream, _ = get_chunk_data_stream(chunk, validate_crc=False)
        buf = stream.read(chunk.uncompressed_size)
    if len(buf) != chunk.uncompressed_size:
        raise McapError(f"chunk size {len(buf)} != {chunk.uncompressed_size}")
    if chunk.uncompressed_crc and zlib.crc32(buf) != chunk.uncompressed_crc:
        raise McapError("chunk crc validation failed")
    out: list[tuple[int, int, bytes]] = []
    pos, end = 0, len(buf)
    unpack_head, unpack_msg = struct.Struct("<BQ").unpack_from, struct.Struct("<HIQ").unpack_from
    while pos < end:
        opcode, length = unpack_head(buf, pos)
        start, pos = pos + 9, pos + 9 + length
        if pos > end:
            raise McapError("record runs past the end of its chunk")
        if opcode == Opcode.MESSAGE:
            cid, _, log_time = unpack_msg(buf, start)
            out.append((cid, log_time, buf[start + 22 : pos]))
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            rec = ReadDataStream(io.BytesIO(buf[start:pos]))
            if opcode == Opcode.SCHEMA:
                schema = Schema.read(rec)
                scan.schemas[schema.id] = schema
            else:
                channel = Channel.read(rec)
                scan.channels[channel.id] = channel
    scan.chunks.append(buf)
    return out


def _check_footer(buf: bytes, footer: Footer, start: int, scan: _Scan) -> None:
    """Check the summary CRC (summary start to the footer's ``summary_offset_start``)."""
    if footer.summary_crc == 0 or footer.summary_start == 0:
        return
    covered = buf[footer.summary_start:start + 9 + 16]
    if footer.summary_start > start or zlib.crc32(covered) != footer.summary_crc:
        scan.damage("the summary section is damaged (summary CRC mismatch): "
                    "read from the data section's records instead")


def _scan(stream: IO[bytes], size: int) -> _Scan:
    """Walk every record, checking each CRC the file offers.

    Records of the summary section never override those of the data section (a damaged
    summary must not hide an intact Schema); attachment, data section and summary CRCs are
    checked, and bytes after the closing magic are reported.
    """
    scan = _Scan()
    buf = stream.read()
    bio = io.BytesIO(buf)
    start = 0
    try:
        for record in _records(bio, size):
            end = bio.tell()
            if isinstance(record, Chunk):
                # Decode the whole chunk before using any of it: a damaged chunk is dropped,
                # and the chunks after it are still read (their framing is intact).
                try:
                    messages = _chunk_messages(record, scan)
                except _DAMAGE as exc:
                    scan.damage(f"the chunk at byte {start} is damaged ({exc or type(exc)}): "
                                f"its messages from t = {record.message_start_time * 1e-9:g} s "
                                f"to {record.message_end_time * 1e-9:g} s are left out")
                    messages = []
                    scan.bad_chunks += 1
                for cid, log_time, data in messages:
                    scan.add_message(cid, log_time, data)
            elif isinstance(record, Message):
                scan.add_message(record.channel_id, record.log_time, record.data)
                scan.loose.append(record)
            elif isinstance(record, Schema):
                if not scan.in_summary or record.id not in scan.schemas:
                    scan.schemas[record.id] = record
            elif isinstance(record, Channel):
                if not scan.in_summary or record.id not in scan.channels:
                    scan.channels[record.id] = record
            elif isinstance(record, Metadata):
                scan.metadata[record.name] = dict(record.metadata)
            elif isinstance(record, Attachment):
                crc = int.from_bytes(buf[end - 4:end], "little")
                if crc and zlib.crc32(buf[start + 9:end - 4]) != crc:
                    scan.damage(f"attachment {record.name!r} is damaged (CRC mismatch): "
                                "left out")
                else:
                    scan.attachments[record.name] = bytes(record.data)
                    scan.media_types[record.name] = record.media_type
            elif isinstance(record, DataEnd):
                scan.in_summary = True
                if record.data_section_crc and zlib.crc32(buf[:start]) != \
                        record.data_section_crc:
                    scan.damage("the data section is damaged (data section CRC mismatch)"
                                + ("" if scan.bad_chunks else ": a record outside the chunks "
                                   "(metadata, attachment, schema, channel or index) may be "
                                   "wrong"))
            elif isinstance(record, Footer):
                scan.complete = True
                _check_footer(buf, record, start, scan)
            start = end
        if scan.complete and bio.tell() < size:
            scan.damage(f"{size - bio.tell()} bytes of unknown data after the closing magic "
                        "(another write appended to this file?)")
    except _DAMAGE as exc:
        detail = str(exc) or type(exc).__name__
        if scan.complete:  # only the closing magic is missing or wrong
            scan.warnings.append(f"the file is cut or damaged after its footer ({detail})")
            scan.complete = False
        else:
            scan.warnings.append(f"stopped at a cut or damaged record ({detail})")
            scan.warnings.append(
                "the file has no footer (cut, or the writer was killed): "
                "data read up to the last complete chunk"
            )
    else:
        if not scan.complete:
            scan.warnings.append("the file has no footer: data read up to the last chunk")
    return scan


def _generic_decoder(schema: Schema | None, channel: Channel) -> Callable[[bytes], Any] | None:
    try:
        return DecoderFactory().decoder_for(channel.message_encoding, schema)
    except Exception:  # a foreign or broken schema: the caller reports the topic as missing
        return None


def _decode_topic(
    layout: TopicLayout, channel: Channel, schema: Schema | None, msgs: list[tuple[int, bytes]]
) -> NDArray[np.float64] | None:
    """Signal columns of one topic: the vectorised inverse, else the file's protobuf schema."""
    datas = [data for _, data in msgs]
    ours = (
        schema is not None
        and schema.name == layout.schema_name
        and schema.data == file_descriptor_set(layout.schema_name)
    )
    if ours:
        fast = decode_bodies(layout, datas)
        if fast is not None:
            return fast
    decode = _generic_decoder(schema, channel)
    if decode is None:
        return None
    out = np.full((len(datas), len(layout.signals)), np.nan)
    try:
        for i, data in enumerate(datas):
            msg = decode(data)
            for j, name in enumerate(layout.signals):
                out[i, j] = getattr(msg, name, math.nan)
    except Exception:  # a damaged or foreign schema (a field of another type): not ours
        return None
    return out


def _goal(scan: _Scan, by_topic: dict[str, Channel]) -> Pose2D | None:
    channel = by_topic.get(GOAL_TOPIC)
    if channel is None or not scan.messages.get(channel.id):
        return None
    msg = message_class(GOAL_SCHEMA)()
    try:
        msg.ParseFromString(scan.messages[channel.id][0][1])
    except DecodeError:
        return None
    p, q = msg.pose.position, msg.pose.orientation
    return Pose2D(p.x, p.y, 2.0 * math.atan2(q.z, q.w))


def scan_file(name: str) -> _Scan:
    """Every readable record of the MCAP file ``name``, checked.

    Raises
    ------
    LogError
        The file is missing, empty, or not MCAP at all.
    """
    try:
        stream = open(name, "rb")
    except OSError as exc:
        raise LogError(f"{name}: cannot open the log: {exc.strerror}") from exc
    with stream:
        size = os.fstat(stream.fileno()).st_size
        head = stream.read(len(MAGIC))
        if not head:
            raise LogError(f"{name}: empty file, not an MCAP log")
        if head != MAGIC[: len(head)]:
            raise LogError(f"{name}: not an MCAP file (bad magic bytes)")
        stream.seek(0)
        return _scan(stream, size)


def read_run(path: str | os.PathLike[str]) -> RunData:
    """Read a run log; a cut or damaged file gives its readable prefix, marked truncated.

    Parameters
    ----------
    path
        An MCAP file written by :class:`wmr.adapters.mcap.RunLogWriter`.

    Returns
    -------
    RunData
        Times, signals, metadata, attachments and goal of the run.

    Raises
    ------
    LogError
        The file is missing, empty, or not MCAP at all.
    """
    name = os.fspath(path)
    scan = scan_file(name)
    by_topic = {c.topic: c for c in scan.channels.values()}
    columns: dict[str, NDArray[np.float64]] = {}
    counts: list[int] = []
    t_ns: NDArray[np.int64] | None = None
    warnings = list(scan.warnings)
    open_loop = TORQUE_TOPIC.topic in by_topic
    expected = {t.topic for t in (OPEN_LOOP_TOPICS if open_loop else STEP_TOPICS)}
    for layout in (*STEP_TOPICS, TORQUE_TOPIC):
        if not layout.signals:
            continue
        channel = by_topic.get(layout.topic)
        if channel is None:
            if layout.topic in expected:
                warnings.append(f"topic {layout.topic} is missing: its signals are NaN")
            continue
        msgs = scan.messages.get(channel.id, [])
        values = _decode_topic(layout, channel, scan.schemas.get(channel.schema_id), msgs)
        if values is None:
            warnings.append(f"topic {layout.topic} cannot be decoded: its signals are NaN")
            continue
        if t_ns is None:
            t_ns = np.array([log_time for log_time, _ in msgs], np.int64)
        counts.append(len(msgs))
        for j, sig in enumerate(layout.signals):
            columns[sig] = values[:, j]
    n = min(counts) if counts else 0
    if counts and max(counts) != n:
        warnings.append(f"signal topics differ in length {sorted(set(counts))}: trimmed to {n}")
    times = (t_ns if t_ns is not None else np.zeros(0, np.int64))[:n].copy()
    signals = {
        sig: np.ascontiguousarray(columns[sig][:n]) if sig in columns else np.full(n, np.nan)
        for sig in SIGNALS
    }
    for rec in ("run", "result"):
        if rec not in scan.metadata:
            warnings.append(f"no {rec!r} metadata record")
    return RunData(
        path=name,
        t_ns=times,
        signals=signals,
        metadata=scan.metadata,
        attachments=scan.attachments,
        media_types=scan.media_types,
        goal=_goal(scan, by_topic),
        truncated=not scan.complete or scan.damaged,
        warnings=warnings,
    )


__all__ = ["Pose2D", "RunData", "read_run"]
