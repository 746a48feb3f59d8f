"""Read the MCAP log of a run back into arrays, tolerating cut files."""

from __future__ import annotations

import io
import itertools
import json
import math
import os
import re
import stat
import struct
import threading
import zlib
from collections.abc import Callable, Collection, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Final, NamedTuple

import numpy as np
from google.protobuf.message import DecodeError
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    Channel,
    Message,
    Metadata,
    Schema,
)
from mcap_protobuf.decoder import DecoderFactory
from numpy.typing import NDArray

from wmr.adapters.mcap.schemas import (
    GOAL_SCHEMA,
    GOAL_TOPIC,
    MAGIC,
    OPEN_LOOP_TOPICS,
    PHASE_TOPIC,
    STEP_TOPICS,
    TORQUE_TOPIC,
    TopicLayout,
    at_every_byte,
    decode_spans,
    file_descriptor_set,
    message_class,
)
from wmr.core.signals import SIGNALS
from wmr.infra.durable import partial_path
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
    phase
        The control phase at each row, from ``/controller/phase`` (0 approach, 1 align:
        :data:`wmr.adapters.mcap.scene.PHASE_NAMES`; the topic holds the changes only, each
        row takes the last one at or before its time; NaN before the first), None when the
        log has no such topic (a killed run's, an open-loop run's, another program's).
    pose_topic
        Set for a pose-only log (a real robot's: :func:`read_run`'s ``pose_topic``): the
        topic its ``x_m``, ``y_m``, ``theta_rad`` come from; every other signal is NaN and
        ``t_ns`` counts from its first pose.
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
    phase: NDArray[np.float64] | None = None
    pose_topic: str | None = None

    @property
    def t_s(self) -> NDArray[np.float64]:
        """Simulation time of each row, s."""
        t_s = self.t_ns.astype(np.float64)
        t_s *= 1e-9  # in place: one array of the rows' length, not two
        return t_s

    @property
    def n_steps(self) -> int:
        """Number of rows."""
        return int(self.t_ns.shape[0])

    def block(self) -> NDArray[np.float64]:
        """The signals as one ``(n, len(SIGNALS))`` array, columns as in ``SIGNALS``."""
        return np.column_stack([self.signals[name] for name in SIGNALS]).reshape(
            self.n_steps, len(SIGNALS)
        )


try:
    from zstandard import ZstdError
except ImportError:  # pragma: no cover - zstandard comes with mcap

    class ZstdError(Exception):  # type: ignore[no-redef]
        """Placeholder when zstandard is absent."""


#: What a damaged record raises inside mcap (lz4 raises RuntimeError).
_DAMAGE = (McapError, ZstdError, struct.error, ValueError, EOFError, RuntimeError, MemoryError)


@dataclass(frozen=True)
class ReadLimits:
    """How much a log may make the reader hold or do: a file from anyone stays bounded.

    A log beyond a limit is still read up to it, with a warning naming the limit; raise a
    limit (``read_run(path, limits=ReadLimits(total_bytes=...))``, or ``total_bytes`` for
    every reader at once: ``WMR_READ_LIMIT_MIB`` or ``wmr replay --read-limit MIB``,
    :func:`default_limits`) to read a larger log.

    Attributes
    ----------
    chunk_bytes
        Largest chunk, uncompressed (its declared ``uncompressed_size``, and the bytes
        inflated, counted while decompressing), bytes.  Our chunks hold 1 s of a run
        (about 100 kB); ``mcap``'s own writer makes 1 MiB ones.
    record_bytes
        Largest record outside a chunk (an attachment, a metadata record), bytes.
    total_bytes
        The memory the read may take, bytes: everything kept (each message's data and 16
        bytes for its time and place, attachments, metadata) and the rows made of it (8
        bytes per signal, :data:`ROW_COPIES` times: the columns and what the caller makes of
        them, a DataFrame or Rerun's columns).  A 10,000 s run at 100 Hz (wmr's own 390 MB
        log of 10^6 rows) needs about 1 GiB; read with the default it peaks at about
        1.3 GB.  The inflated chunk being read (at most ``chunk_bytes``) comes on top.
    records
        Records outside chunks other than messages (chunks, indexes, schemas, unknown
        opcodes): a file of a million tiny chunks takes about a minute.
    json_bytes, json_depth
        Largest metadata value decoded as JSON (characters), and its deepest nesting.
    """

    chunk_bytes: int = 64 << 20
    record_bytes: int = 64 << 20
    total_bytes: int = 1536 << 20
    records: int = 1_000_000
    json_bytes: int = 1 << 20
    json_depth: int = 64


#: Signals per topic: the float64 columns a message of that topic is decoded into.
_SIGNALS_OF: Final = {t.topic: len(t.signals) for t in (*STEP_TOPICS, TORQUE_TOPIC)}
#: The limits used when none are given (and ``WMR_READ_LIMIT_MIB`` is not set).
DEFAULT_LIMITS: Final = ReadLimits()
#: The environment variable that sets ``total_bytes`` of :func:`default_limits`, in MiB.
READ_LIMIT_ENV: Final = "WMR_READ_LIMIT_MIB"
#: How to raise ``total_bytes``, for the warning that says it was reached.
RAISE_HINT: Final = (f"raise it (wmr replay/wmr log recover --read-limit MIB, or "
                     f"{READ_LIMIT_ENV}=MIB) to read it all")
#: Bytes one kept message costs besides its data: its log time and its end offset (int64).
_MESSAGE_OVERHEAD: Final = 16
#: Bytes one batch of messages (a chunk's messages of one channel) costs: its three objects.
_BATCH_OVERHEAD: Final = 400
#: Copies of the rows' float64 signals that a read leads to, counted against ``total_bytes``:
#: the decoded topics and the columns of :class:`RunData`, then the caller's own (a DataFrame
#: in :func:`wmr.read_log`, the block and Rerun's columns in ``wmr replay``).
ROW_COPIES: Final = 3


def default_limits(total_mib: float | None = None) -> ReadLimits:
    """The read limits with ``total_bytes`` from ``total_mib``, else ``WMR_READ_LIMIT_MIB``,
    else :data:`DEFAULT_LIMITS`.

    Raises
    ------
    ConfigError
        ``WMR_READ_LIMIT_MIB`` (or ``total_mib``) is not a positive number of MiB.
    """
    from wmr.infra.errors import ConfigError

    name = "read_limit"
    text: str | None = str(total_mib)
    if total_mib is None:
        name, text = READ_LIMIT_ENV, os.environ.get(READ_LIMIT_ENV)
        if not text:
            return DEFAULT_LIMITS
    try:
        mib = float(text or "")
    except ValueError:
        mib = math.nan
    if not (math.isfinite(mib) and 1 <= mib <= 1 << 24):
        raise ConfigError(name, f"{text!r} is not a size in MiB from 1 to {1 << 24}",
                          "give the read limit in MiB, e.g. 4096")
    return ReadLimits(total_bytes=int(mib * (1 << 20)))
@contextmanager
def read_limit(mib: float | None) -> Iterator[None]:
    """Every read inside the block takes ``mib`` MiB as its limit (``WMR_READ_LIMIT_MIB`` set
    for the block, then as it was): ``wmr replay``/``wmr log recover --read-limit`` and
    ``wmr.replay(read_limit_mib=...)``.  ``None`` leaves the limit as it is.

    Raises
    ------
    ConfigError
        ``read_limit_mib``: not a size in MiB from 1 to 2**24 (checked before the block runs).
    """
    if mib is None:
        yield
        return
    from wmr.infra.errors import ConfigError

    try:
        default_limits(mib)
    except ConfigError as exc:
        raise ConfigError("read_limit_mib", exc.problem, exc.fix) from None
    old = os.environ.get(READ_LIMIT_ENV)
    os.environ[READ_LIMIT_ENV] = repr(float(mib))
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(READ_LIMIT_ENV, None)
        else:
            os.environ[READ_LIMIT_ENV] = old


#: Largest log time that fits the int64 ns of :class:`RunData` (year 2262).
MAX_LOG_TIME_NS: Final = (1 << 63) - 1
_HEAD: Final = struct.Struct("<BQ")
_MSG_HEAD: Final = struct.Struct("<HIQ")
#: Chunk fields: start and end time, uncompressed size and CRC, length of the compression name.
_CHUNK_HEAD: Final = struct.Struct("<QQQII")


def _mib(n: int) -> str:
    """A limit for a message: in MiB when it is a whole number of them, else in bytes (a
    limit under 1 MiB printed as "0 MiB" said nothing)."""
    return f"{n >> 20} MiB" if n >= 1 << 20 and not n % (1 << 20) else f"{n} B"


class _OverLimit(McapError):
    """A chunk declares more than the chunk limit (its message follows "the chunk at ...")."""


class _Stop(Exception):
    """The records cannot be followed past this point (cut file, broken framing)."""


class _Batch(NamedTuple):
    """One chunk's messages of one channel kept as data: where they sit among the channel's
    messages (``slot``: the first one's index) and their data end to end (``blob``, each
    message ending at its ``ends`` offset)."""

    slot: int
    ends: NDArray[np.int64]
    blob: NDArray[np.uint8]


class ChannelMessages:
    """The messages of one channel, kept compact: their log times in one int64 array, the data
    of each batch (one chunk's messages of the channel) end to end in one array with their
    end offsets: 16 bytes a message besides its data, not the ~130 of a tuple of an int and a
    ``bytes`` (a log of 10^6 rows holds 6 * 10^6 messages).  A batch of one of our signal
    topics that :class:`LogScan` was asked to decode (``decode=``; :func:`read_run`) keeps its
    signals instead of its data, in one float64 array of a row per signal: its messages are
    then no longer iterable as bytes.

    The times and the signals grow in place (their capacity doubles): no array per batch, and
    the signals of a whole run are read without a copy of them all at the end."""

    __slots__ = ("_batches", "_rows", "_times", "count", "nbytes", "raw_count")

    def __init__(self) -> None:
        self._batches: list[_Batch] = []
        self._times = np.zeros(0, np.int64)
        self._rows: NDArray[np.float64] | None = None
        self.count = 0
        #: Bytes kept (what :meth:`LogScan.add_messages` charged, less the decoded rows).
        self.nbytes = 0
        #: Messages kept as data (not decoded yet).
        self.raw_count = 0

    def _append(self, times: NDArray[np.int64], rows: NDArray[np.float64] | None) -> int:
        """Put ``times`` (and ``rows``) after the messages kept; the first one's index."""
        slot, m = self.count, len(times)
        if slot + m > self._times.size:  # grow: twice the capacity, the kept part copied
            cap = max(2 * self._times.size, slot + m, 1024)
            grown = np.empty(cap, np.int64)
            grown[:slot] = self._times[:slot]
            self._times = grown
            if self._rows is not None:
                rows_grown = np.empty((self._rows.shape[0], cap))
                rows_grown[:, :slot] = self._rows[:, :slot]
                self._rows = rows_grown
        if rows is not None and self._rows is None:  # the first decoded batch
            self._rows = np.empty((rows.shape[0], self._times.size))
        self._times[slot : slot + m] = times
        if rows is not None and self._rows is not None:
            self._rows[:, slot : slot + m] = rows
        self.count += m
        return slot

    def add(self, times: NDArray[np.int64], ends: NDArray[np.int64],
            blob: NDArray[np.uint8]) -> None:
        """Keep one batch of messages as data (``blob.nbytes + 16 * len(times)`` bytes)."""
        slot = self._append(times, None)
        self._batches.append(_Batch(slot, ends, blob))
        self.raw_count += len(times)
        self.nbytes += _batch_bytes(int(blob.nbytes), len(times), 0)

    def add_rows(self, times: NDArray[np.int64], rows: NDArray[np.float64]) -> None:
        """Keep one batch of messages decoded (``rows``: one row per signal)."""
        self._append(times, rows)
        self.nbytes += _batch_bytes(0, len(times), rows.shape[0])

    def parts(self) -> Iterator[_Batch]:
        """The batches kept as data, in file order."""
        yield from self._batches

    def rows(self) -> NDArray[np.float64] | None:
        """The decoded signals, one row per signal and a column per message (a view: those
        of messages kept as data are not set), or None when no batch was decoded."""
        return None if self._rows is None else self._rows[:, : self.count]

    def batches(self) -> Iterator[tuple[NDArray[np.int64], list[bytes]]]:
        """``(log times, datas)`` batch by batch (a list of ``bytes`` for one batch only).

        Raises
        ------
        ValueError
            A batch was decoded as it was read (its data is gone).
        """
        if self._rows is not None:
            raise ValueError("these messages were decoded as they were read "
                             "(LogScan decode=): their data is not kept")
        for batch in self._batches:
            raw = batch.blob.tobytes()
            bounds = np.r_[0, batch.ends].tolist()
            yield (self._times[batch.slot : batch.slot + len(batch.ends)],
                   [raw[a:b] for a, b in itertools.pairwise(bounds)])

    def times(self) -> NDArray[np.int64]:
        """Every log time, in file order (a view)."""
        return self._times[: self.count]

    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        for times, datas in self.batches():
            yield from zip(times.tolist(), datas, strict=True)

    def __len__(self) -> int:
        return self.count

    def __eq__(self, other: object) -> bool:
        """Equal to the same messages as a list of ``(log time, data)`` (what the scan kept
        before) or as another :class:`ChannelMessages`."""
        if isinstance(other, ChannelMessages | list):
            return list(self) == list(other)
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]  # mutable, like the list it stands for

def _batch_bytes(data_bytes: int, n_messages: int, n_signals: int) -> int:
    """Bytes a batch holds: its data (or its decoded rows, 8 bytes a signal), 16 bytes a
    message for its time and place, and the batch's own objects."""
    return data_bytes + (_MESSAGE_OVERHEAD + 8 * n_signals) * n_messages + _BATCH_OVERHEAD


#: How :class:`LogScan` keeps a channel's messages: whether at all, the layout and signals
#: to decode them into as they are read (None: kept as data), and the signals per message
#: charged for the rows they become.
class _Plan(NamedTuple):
    wanted: bool
    layout: TopicLayout | None
    signals: tuple[str, ...]
    n_signals: int


def _gather(data: NDArray[np.uint8], starts: NDArray[np.int64],
            ends: NDArray[np.int64]) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """The spans ``data[starts[i]:ends[i]]`` end to end, and where each ends, with numpy."""
    sizes = ends - starts
    out_ends = np.cumsum(sizes)
    if sizes.size and bool(np.all(sizes == sizes[0])):  # one size: a 2-D gather
        idx = (starts[:, None] + np.arange(int(sizes[0]), dtype=np.int64)).ravel()
    else:
        idx = (np.repeat(starts - (out_ends - sizes), sizes)
               + np.arange(int(out_ends[-1]) if sizes.size else 0, dtype=np.int64))
    return data[idx], out_ends


class LogScan:
    """Everything collected while walking the records of a file.

    ``topics`` (None: all) are the topics whose messages are kept; the messages of a channel
    on another topic are read for their CRC and dropped (a channel not yet seen keeps its
    messages: its record may come later).  ``decode`` maps a topic of ours to its layout
    and the signals to decode its messages into as each chunk is read, when the channel's
    schema is ours and the messages have its fixed layout (else they are kept as data).
    """

    def __init__(self, limits: ReadLimits, keep_chunks: bool,
                 topics: Collection[str] | None = None,
                 decode: Mapping[str, tuple[TopicLayout, tuple[str, ...]]] | None = None
                 ) -> None:
        self.limits = limits
        self.keep_chunks = keep_chunks
        self.topics = None if topics is None else frozenset(topics)
        self.decode = decode
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.messages: dict[int, ChannelMessages] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self.attachments: dict[str, bytes] = {}
        self.media_types: dict[str, str] = {}
        self.complete = False
        self.damaged = False
        self.in_summary = False
        self.bad_chunks = 0
        self.warnings: list[str] = []
        #: ``(offset, length)`` of every Chunk record that passed its checks (for recovery,
        #: which reads them again one at a time: :func:`read_chunk_at`).
        self.chunks: list[tuple[int, int]] = []
        #: Message records outside chunks, whole (for recovery).
        self.loose: list[Message] = []
        #: Bytes kept so far, counted against ``limits.total_bytes``.
        self.kept_bytes = 0
        self.over_budget = False
        self.records = 0
        #: Messages left out because their log time does not fit int64 ns, by channel id.
        self.bad_times: dict[int, int] = {}
        #: Where the summary section starts (after Data End), 0 before.
        self.summary_start = 0
        #: Channel id -> (its Channel and Schema records, what to do with its messages).
        self._plans: dict[int, tuple[Channel | None, Schema | None, _Plan]] = {}

    def damage(self, what: str) -> None:
        self.damaged = True
        self.warnings.append(what)

    def fits(self, n_bytes: int) -> bool:
        """Whether ``n_bytes`` more stay within the budget."""
        return self.kept_bytes + n_bytes <= self.limits.total_bytes

    def over(self, what: str) -> None:
        """Say (once) that the budget is spent and the read stops at ``what``."""
        if not self.over_budget:
            self.over_budget = True
            self.damage(f"reading the log takes more than {_mib(self.limits.total_bytes)} of "
                        f"memory (ReadLimits.total_bytes): read stops at {what}; "
                        f"{RAISE_HINT}")

    def charge(self, n_bytes: int, what: str) -> bool:
        """Count ``n_bytes`` against the budget; False (and one warning) once it is spent."""
        if not self.fits(n_bytes):
            self.over(what)
            return False
        self.kept_bytes += n_bytes
        return True

    def add_message_time(self, channel_id: int, log_time: int) -> bool:
        """False (counted in ``bad_times``) for a log time that does not fit int64 ns."""
        if log_time > MAX_LOG_TIME_NS:
            self.bad_times[channel_id] = self.bad_times.get(channel_id, 0) + 1
            return False
        return True

    def wanted(self, channel_id: int) -> bool:
        """Whether the messages of this channel are kept."""
        return self._plan(channel_id).wanted

    def _plan(self, channel_id: int) -> _Plan:
        """What to do with the messages of a channel, as its records stand now."""
        channel = self.channels.get(channel_id)
        schema = None if channel is None else self.schemas.get(channel.schema_id)
        cached = self._plans.get(channel_id)
        if cached is not None and cached[0] is channel and cached[1] is schema:
            return cached[2]
        if channel is None:  # its record may come later: keep, decode nothing
            plan = _Plan(True, None, (), 0)
        elif self.topics is not None and channel.topic not in self.topics:
            plan = _Plan(False, None, (), 0)
        elif self.decode is None:
            plan = _Plan(True, None, (), _SIGNALS_OF.get(channel.topic, 0))
        elif channel.topic not in self.decode:
            plan = _Plan(True, None, (), 0)
        else:
            layout, signals = self.decode[channel.topic]
            plan = _Plan(True, layout if _ours(layout, schema) else None, signals,
                         len(signals))
        self._plans[channel_id] = (channel, schema, plan)
        return plan

    def add_messages(self, data: NDArray[np.uint8], heads: NDArray[np.int64],
                     ends: NDArray[np.int64], what: str) -> bool:
        """Keep the messages whose records are in ``data`` (each from its channel id at
        ``heads[i]`` to its end at ``ends[i]``), by channel, if they fit the budget (else none
        of them, and False).  Whole channels are kept or dropped, and our signal topics
        decoded (``decode``), with numpy: no Python object per message."""
        if not heads.size:
            return True
        cids = at_every_byte(data, "<u2")[heads]
        kept: list[tuple[int, NDArray[np.intp], _Plan, NDArray[np.float64] | None,
                         NDArray[np.uint64]]] = []
        n_bytes = 0
        for cid in np.flatnonzero(np.bincount(cids)).tolist():
            plan = self._plan(cid)
            if not plan.wanted:
                continue
            at = np.flatnonzero(cids == cid)
            times = at_every_byte(data, "<u8")[heads[at] + 6]  # after the sequence number
            if times.max() > MAX_LOG_TIME_NS:
                late = times > MAX_LOG_TIME_NS
                self.bad_times[cid] = self.bad_times.get(cid, 0) + int(late.sum())
                at, times = at[~late], times[~late]
                if not at.size:
                    continue
            rows = (None if plan.layout is None else
                    decode_spans(plan.layout, data, heads[at] + 22, ends[at], plan.signals))
            # what read_run decodes it into (a message of a few bytes can make many floats),
            # twice: the batches' arrays and their concatenation
            n_data = 0 if rows is not None else int((ends[at] - heads[at] - 22).sum())
            n_bytes += n_data + (_MESSAGE_OVERHEAD + 16 * plan.n_signals) * at.size
            kept.append((cid, at, plan, rows, times))
        if not self.charge(n_bytes + _BATCH_OVERHEAD * len(kept), what):
            return False
        for cid, at, _, rows, times in kept:
            msgs = self.messages.setdefault(cid, ChannelMessages())
            t = times.view(np.int64)  # all below 2^63
            if rows is not None:
                msgs.add_rows(t, rows)
            else:
                blob, blob_ends = _gather(data, heads[at] + 22, ends[at])
                msgs.add(t, blob_ends, blob)
        return True


class _LogFile:
    """A log opened for reading: sequential reads with a running CRC, bounded by its size."""

    def __init__(self, name: str, fd: int, size: int) -> None:
        self.name = name
        self.fd = fd
        self.size = size
        self.pos = 0
        self.crc = 0
        #: False once bytes were skipped unread (the running CRC then proves nothing).
        self.crc_whole = True
        self._f = open(fd, "rb", buffering=1 << 16, closefd=False)

    def read(self, n: int) -> bytes:
        data = self._f.read(n)
        if len(data) != n:  # the file shrank under us, or ends inside a record
            raise _Stop(f"the file ends inside the record at byte {self.pos}")
        self.crc = zlib.crc32(data, self.crc)
        self.pos += n
        return data

    def skip(self, n: int) -> None:
        """Seek past ``n`` bytes without reading them (a damaged or oversized record)."""
        self._f.seek(n, io.SEEK_CUR)
        self.pos += n
        self.crc_whole = False

    def close(self) -> None:
        self._f.close()
        os.close(self.fd)

    def __enter__(self) -> _LogFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_KINDS: Final = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a named pipe (FIFO)"),
                 (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                 (stat.S_ISSOCK, "a socket"))


def _not_regular(name: str, mode: int) -> LogError:
    kind = next((k for test, k in _KINDS if test(mode)), "not a regular file")
    return LogError(f"{name}: is {kind}, not a log file; give an .mcap file")


def open_log(name: str) -> _LogFile:
    """Open the log ``name`` for reading, refusing what is not a regular MCAP file.

    A FIFO or a device is refused before it is opened (opening a FIFO waits for a writer),
    and checked again once open.

    Raises
    ------
    LogError
        Missing (naming ``NAME.partial`` when a killed run left one), not a regular file,
        unreadable, empty, or not MCAP.
    """
    try:
        mode = os.stat(name).st_mode
    except OSError as exc:
        hint = ""
        if isinstance(exc, FileNotFoundError) and partial_path(name).is_file():
            part = partial_path(name)
            hint = (f"; the run writing it was killed or is still running: its data is in "
                    f"{part} (wmr log recover {part})")
        raise LogError(f"{name}: cannot open the log: {exc.strerror}{hint}") from exc
    if not stat.S_ISREG(mode):
        raise _not_regular(name, mode)
    try:
        fd = os.open(name, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise LogError(f"{name}: cannot open the log: {exc.strerror}") from exc
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):  # replaced between the stat and the open
        os.close(fd)
        raise _not_regular(name, st.st_mode)
    log = _LogFile(name, fd, st.st_size)
    try:
        head = os.pread(fd, len(MAGIC), 0)
        if not head:
            raise LogError(f"{name}: empty file, not an MCAP log")
        if head != MAGIC[: len(head)]:
            raise LogError(f"{name}: not an MCAP file (bad magic bytes)")
    except BaseException:
        log.close()
        raise
    return log


#: One zstd decompressor per thread (one must not be used by two threads at once).
_ZSTD: Final = threading.local()


def _inflate(compression: str, data: bytes, size: int) -> bytes:
    """``data`` decompressed, never more than ``size + 1`` bytes (a bomb stops there)."""
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        dctx = getattr(_ZSTD, "dctx", None)
        if dctx is None:
            dctx = _ZSTD.dctx = zstandard.ZstdDecompressor()
        try:
            declared = zstandard.frame_content_size(data[:18])  # from the frame header
        except zstandard.ZstdError:
            declared = -1
        if declared == size:
            # one frame declaring exactly the chunk's size (zstd checks what it inflates to
            # against it) and nothing after it: inflated at once into ``size`` bytes
            try:
                return bytes(dctx.decompress(data, allow_extra_data=False))
            except zstandard.ZstdError:
                pass  # several frames, or damage: streamed below, which says which
        reader = dctx.stream_reader(io.BytesIO(data), read_across_frames=True)
        parts, got = [], 0
        while got <= size:
            part = reader.read(size + 1 - got)
            if not part:
                break
            parts.append(part)
            got += len(part)
        return b"".join(parts)
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1))
    raise McapError(f"unknown compression {compression!r}")


def _chunk_messages(buf: bytes, scan: LogScan) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The Message records of an inflated, checked chunk, walked record by record: where each
    one's fields start (its channel id, after the opcode and length) and where it ends.

    The way for a chunk that :func:`_message_starts` cannot read at once; Schema and Channel
    records inside the chunk are kept in ``scan``.  Raises on any inconsistency, and on any
    other record (MCAP chunks hold only these three), so that a damaged chunk is dropped
    whole.
    """
    heads: list[int] = []
    ends: list[int] = []
    pos, end = 0, len(buf)
    unpack_head = _HEAD.unpack_from
    while pos < end:
        opcode, length = unpack_head(buf, pos)
        start, pos = pos + 9, pos + 9 + length
        if pos > end:
            raise McapError("record runs past the end of its chunk")
        if opcode == Opcode.MESSAGE:
            if length < 22:
                raise McapError("message record too short")
            heads.append(start)
            ends.append(pos)
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            rec = ReadDataStream(io.BytesIO(buf[start:pos]))
            if opcode == Opcode.SCHEMA:
                schema = Schema.read(rec)
                scan.schemas[schema.id] = schema
            else:
                channel = Channel.read(rec)
                scan.channels[channel.id] = channel
        else:  # a chunk holds only these three (zeros would be walked 9 bytes at a time)
            raise McapError(f"a record of opcode 0x{opcode:02x} inside the chunk")
    return np.array(heads, np.int64), np.array(ends, np.int64)


#: Rounds of :func:`_message_starts` dropping look-alike headers before it gives up.
_PRUNE_ROUNDS: Final = 8
#: The smallest Message record: opcode, length, and 22 bytes of fields.
_MIN_MESSAGE: Final = 9 + 22
#: Bytes of a chunk searched for record headers at once.
_BLOCK: Final = 1 << 20
#: The Message opcode as a plain int (an IntEnum makes numpy compare 40 times slower).
_OP_MESSAGE: Final = int(Opcode.MESSAGE)


def _message_starts(data: NDArray[np.uint8]) -> tuple[NDArray[np.int64],
                                                      NDArray[np.int64]] | None:
    """Where each record of an inflated chunk starts and ends, found with numpy, when every
    record is a Message (our writer's chunks, and most of any writer's); None otherwise.

    The candidates are the bytes 0x05 whose length field keeps a Message record (22 bytes of
    fields at least) inside the chunk.  A byte inside a record may look like such a header:
    a candidate that no other candidate points to (its start plus 9 plus its length) is
    dropped, over a few rounds.  The records left must tile the chunk exactly from byte 0,
    each ending where the next starts and the last at the chunk's end: that is the one way to
    walk the chunk, as :func:`_chunk_messages` would walk it record by record.  When they do
    not (another record, damage, or look-alikes that survive), None: the chunk is then walked
    record by record, which names what is wrong.
    """
    n = data.size
    if n < _MIN_MESSAGE:
        return None
    last = n - _MIN_MESSAGE + 1
    # a block at a time: no byte mask of a whole large chunk (the robot's outlines: 16 MB)
    parts = [np.flatnonzero(data[i : min(i + _BLOCK, last)] == _OP_MESSAGE) + i
             for i in range(0, last, _BLOCK)]
    cand = parts[0] if len(parts) == 1 else np.concatenate(parts)
    if not cand.size or cand[0]:
        return None
    length = at_every_byte(data, "<u8")[cand + 1]
    fits = (length >= 22) & (length <= (n - 9 - cand).astype(np.uint64))
    starts = cand[fits]
    ends = starts + 9 + length[fits].astype(np.int64)
    for _ in range(_PRUNE_ROUNDS):
        if not starts.size or starts[0]:
            return None
        if ends[-1] == n and bool((ends[:-1] == starts[1:]).all()):
            return starts + 9, ends
        at = np.searchsorted(starts, ends)
        hit = at < starts.size
        at = at[hit]
        pointed = np.zeros(starts.size, np.bool_)
        pointed[0] = True
        pointed[at[starts[at] == ends[hit]]] = True
        if pointed.all():  # nothing to drop, and yet no tiling
            return None
        starts, ends = starts[pointed], ends[pointed]
    return None


def _inflate_chunk(body: bytes, limits: ReadLimits) -> bytes:
    """The records of a Chunk record's body, inflated no further than its declared size (at
    most ``limits.chunk_bytes``) and checked against its size and CRC; raises on damage."""
    _, _, usize, ucrc, clen = _CHUNK_HEAD.unpack_from(body, 0)
    if usize > limits.chunk_bytes:
        raise _OverLimit(f"declares {usize} bytes uncompressed, above the "
                        f"{_mib(limits.chunk_bytes)} chunk limit (ReadLimits.chunk_bytes; a "
                        "decompression bomb?)")
    compression = body[32 : 32 + clen].decode()
    (rlen,) = struct.unpack_from("<Q", body, 32 + clen)
    data_at = 40 + clen
    if data_at + rlen > len(body):
        raise McapError("its data runs past the end of the record")
    buf = _inflate(compression, body[data_at : data_at + rlen], usize)
    if len(buf) != usize:
        raise McapError(f"it inflates to {'more than ' if len(buf) > usize else ''}"
                        f"{len(buf)} bytes, not the {usize} it declares")
    if ucrc and zlib.crc32(buf) != ucrc:
        raise McapError("chunk crc validation failed")
    return buf


def read_chunk_at(log: _LogFile, offset: int, length: int, limits: ReadLimits) -> bytes:
    """The records of the Chunk record at ``offset`` (of ``length`` bytes after its opcode and
    length), read again from the file: recovery keeps where the good chunks are, not their
    inflated records (a 10^6-row log holds over 1 GB of them).

    Raises
    ------
    LogError
        The chunk no longer reads as it did (the file changed under the lock).
    """
    body = os.pread(log.fd, length, offset + _HEAD.size)
    try:
        if len(body) != length:
            raise McapError("the file is shorter than it was")
        return _inflate_chunk(body, limits)
    except _DAMAGE as exc:
        raise LogError(f"{log.name}: the chunk at byte {offset} changed while it was read "
                       f"({str(exc) or type(exc).__name__})") from None


def _read_chunk(log: _LogFile, start: int, length: int, scan: LogScan) -> None:
    """Check a Chunk record's sizes against the limits, inflate it bounded, keep its messages.

    A chunk over a limit is skipped unread; a damaged one is left out whole; the records
    after either are still read (the chunk's own length frames them).
    """
    limits = scan.limits
    where = f"the chunk at byte {start}"
    # compressed data never exceeds its uncompressed size by more than the frame overhead
    if length > limits.chunk_bytes + (1 << 20) or scan.over_budget:
        log.skip(length)
        if not scan.over_budget:
            scan.damage(f"{where} is {length} bytes, above the {_mib(limits.chunk_bytes)} "
                        "chunk limit (ReadLimits.chunk_bytes): left out")
        scan.bad_chunks += 1
        return
    body = log.read(length)
    try:
        t0, t1, _, _, _ = _CHUNK_HEAD.unpack_from(body, 0)
    except struct.error:
        scan.damage(f"{where} is damaged (its header is cut): left out")
        scan.bad_chunks += 1
        return
    span = f"its messages from t = {t0 * 1e-9:g} s to {t1 * 1e-9:g} s are left out"
    try:
        buf = _inflate_chunk(body, limits)
        del body
        data = np.frombuffer(buf, np.uint8)
        spans = _message_starts(data)
        heads, ends = _chunk_messages(buf, scan) if spans is None else spans
    except _OverLimit as exc:
        scan.damage(f"{where} {exc}: {span}")
        scan.bad_chunks += 1
        return
    except _DAMAGE as exc:
        scan.damage(f"{where} is damaged ({str(exc) or type(exc).__name__}): {span}")
        scan.bad_chunks += 1
        return
    if scan.keep_chunks:
        # recovery reads the chunk again when it writes it: only its place is kept
        if scan.charge(_MESSAGE_OVERHEAD, f"the chunk at t = {t0 * 1e-9:g} s"):
            scan.chunks.append((start, length))
            return
    elif scan.add_messages(data, heads, ends, f"the chunk at t = {t0 * 1e-9:g} s"):
        return
    scan.bad_chunks += 1


def _check_crc(scan: LogScan, log: _LogFile, crc: int, expected: int, what: str,
               consequence: str) -> None:
    if not expected:
        return
    if not log.crc_whole:  # only records over a limit are skipped unread
        scan.warnings.append(f"the {what} CRC was not checked: records over a read limit "
                             "were skipped unread")
    elif crc != expected:
        scan.damage(f"the {what} is damaged ({what} CRC mismatch){consequence}")


#: Records read only for their CRC: indexes, statistics, summary offsets, header, unknown.
_SKIPPED: Final = frozenset({Opcode.HEADER, Opcode.MESSAGE_INDEX, Opcode.CHUNK_INDEX,
                             Opcode.ATTACHMENT_INDEX, Opcode.METADATA_INDEX,
                             Opcode.STATISTICS, Opcode.SUMMARY_OFFSET}) | frozenset(
    range(0x80, 0x100))


def _parse_record(log: _LogFile, opcode: int, start: int, body: bytes, scan: LogScan,
                  crc_before: int, crc_head: int) -> None:
    """Keep what a record outside a chunk holds; raises on a damaged record."""
    rec = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.MESSAGE:
        message = Message.read(rec, len(body))
        if scan.keep_chunks:
            if (scan.charge(len(body) + _MESSAGE_OVERHEAD, f"the message at byte {start}")
                    and scan.add_message_time(message.channel_id, message.log_time)):
                scan.loose.append(message)
        else:
            scan.add_messages(np.frombuffer(body, np.uint8), np.zeros(1, np.int64),
                              np.full(1, len(body), np.int64), f"the message at byte {start}")
    elif opcode == Opcode.SCHEMA:
        schema = Schema.read(rec)
        if not scan.in_summary or schema.id not in scan.schemas:
            scan.schemas[schema.id] = schema
    elif opcode == Opcode.CHANNEL:
        channel = Channel.read(rec)
        if not scan.in_summary or channel.id not in scan.channels:
            scan.channels[channel.id] = channel
    elif opcode == Opcode.METADATA:
        metadata = Metadata.read(rec)
        if scan.charge(len(body), f"the metadata record {metadata.name!r}"):
            scan.metadata[metadata.name] = dict(metadata.metadata)
    elif opcode == Opcode.ATTACHMENT:
        attachment = Attachment.read(rec)
        crc = int.from_bytes(body[-4:], "little")
        if crc and zlib.crc32(body[:-4]) != crc:
            scan.damage(f"attachment {attachment.name!r} is damaged (CRC mismatch): left out")
        elif scan.charge(len(body), f"the attachment {attachment.name!r}"):
            scan.attachments[attachment.name] = bytes(attachment.data)
            scan.media_types[attachment.name] = attachment.media_type
    elif opcode == Opcode.DATA_END:
        (data_crc,) = struct.unpack_from("<I", body, 0)
        scan.in_summary = True
        _check_crc(scan, log, crc_before, data_crc, "data section",
                   "" if scan.bad_chunks else ": a record outside the chunks (metadata, "
                   "attachment, schema, channel or index) may be wrong")
        log.crc, log.crc_whole = 0, True  # the summary's CRC starts here
        scan.summary_start = log.pos
    elif opcode == Opcode.FOOTER:
        summary_start, _, summary_crc = struct.unpack_from("<QQI", body, 0)
        scan.complete = True
        if summary_start:
            # covers the summary and the Footer up to its own summary_crc field
            crc = zlib.crc32(body[:16], crc_head)
            if summary_start != scan.summary_start:
                crc ^= 0xFFFFFFFF  # the footer points elsewhere: it cannot be trusted
            _check_crc(scan, log, crc, summary_crc, "summary",
                       ": read from the data section's records instead")
    # any other opcode was skipped by the caller


def _walk(log: _LogFile, scan: LogScan) -> None:
    """Follow the records of ``log`` to the closing magic; raise :class:`_Stop` where the
    framing breaks (a record's length is checked against the file before anything is read)."""
    log.read(len(MAGIC))
    while not scan.complete:
        start, crc_before = log.pos, log.crc
        if start == log.size:
            return
        if log.size - start < _HEAD.size:
            raise _Stop(f"the file ends inside the record at byte {start}")
        opcode, length = _HEAD.unpack(log.read(_HEAD.size))
        if not (0 < opcode < 0x10 or opcode >= 0x80):
            raise _Stop(f"no MCAP record at byte {start} (opcode 0x{opcode:02x}: zeroed or "
                        "damaged bytes)")
        if length > log.size - log.pos:
            raise _Stop(f"the record at byte {start} claims {length} bytes, past the end of "
                        f"the file ({log.size} bytes)")
        if opcode != Opcode.MESSAGE:  # messages count against total_bytes instead
            scan.records += 1
            if scan.records > scan.limits.records:
                raise _Stop(f"more than {scan.limits.records} records outside chunks "
                            "(ReadLimits.records)")
        if opcode == Opcode.CHUNK:
            _read_chunk(log, start, length, scan)
            continue
        if length > scan.limits.record_bytes:
            log.skip(length)
            if opcode not in _SKIPPED:
                scan.damage(f"the record at byte {start} (opcode 0x{opcode:02x}) is {length} "
                            f"bytes, above the {_mib(scan.limits.record_bytes)} limit "
                            "(ReadLimits.record_bytes): left out")
            continue
        crc_head = log.crc
        body = log.read(length)
        if opcode in _SKIPPED:
            continue
        try:
            _parse_record(log, opcode, start, body, scan, crc_before, crc_head)
        except _DAMAGE as exc:
            scan.damage(f"the record at byte {start} (opcode 0x{opcode:02x}) is damaged "
                        f"({str(exc) or type(exc).__name__}): left out")
    magic = log._f.read(len(MAGIC))
    if magic != MAGIC:
        scan.complete = False
        raise _Stop("the closing magic bytes are missing or wrong")
    if log.size > log.pos + len(MAGIC):
        scan.damage(f"{log.size - log.pos - len(MAGIC)} bytes of unknown data after the "
                    "closing magic (another write appended to this file?)")


def scan_log(log: _LogFile, limits: ReadLimits = DEFAULT_LIMITS,
             keep_chunks: bool = False, topics: Collection[str] | None = None,
             decode: Mapping[str, tuple[TopicLayout, tuple[str, ...]]] | None = None
             ) -> LogScan:
    """Walk every record of an open log, checking each CRC the file offers and each size
    against ``limits``.

    Records of the summary section never override those of the data section (a damaged
    summary must not hide an intact Schema); attachment, data section and summary CRCs are
    checked, and bytes after the closing magic are reported.  ``keep_chunks`` keeps the
    places of the good chunks and the loose Message records (for recovery) instead of the
    messages; ``topics`` (None: all) are the topics whose messages are kept, and ``decode``
    those decoded as they are read (:class:`LogScan`).
    """
    scan = LogScan(limits, keep_chunks, topics, decode)
    try:
        _walk(log, scan)
    except (_Stop, OSError) as exc:
        detail = str(exc) or type(exc).__name__
        if scan.complete:  # only the closing magic is missing or wrong
            scan.warnings.append(f"the file is cut or damaged after its footer ({detail})")
            scan.complete = False
        else:
            scan.warnings.append(f"stopped at a cut or damaged record ({detail})")
            scan.warnings.append("the file has no footer (cut, or the writer was killed): "
                                 "data read up to the last complete chunk")
    else:
        if not scan.complete:
            scan.warnings.append("the file has no footer: data read up to the last chunk")
    return scan


def scan_file(name: str, limits: ReadLimits | None = None,
              topics: Collection[str] | None = None,
              decode: Mapping[str, tuple[TopicLayout, tuple[str, ...]]] | None = None
              ) -> LogScan:
    """Every readable record of the MCAP file ``name``, checked (:func:`scan_log`), within
    ``limits`` (default :func:`default_limits`), keeping the messages of ``topics`` (all),
    those of ``decode``'s topics decoded as they are read.

    Raises
    ------
    LogError
        The file is missing, not a regular file, empty, or not MCAP at all.
    """
    with open_log(name) as log:
        return scan_log(log, default_limits() if limits is None else limits, topics=topics,
                        decode=decode)

def _generic_decoder(schema: Schema | None, channel: Channel) -> Callable[[bytes], Any] | None:
    try:
        return DecoderFactory().decoder_for(channel.message_encoding, schema)
    except Exception:  # a foreign or broken schema: the caller reports the topic as missing
        return None


def _ours(layout: TopicLayout, schema: Schema | None) -> bool:
    """Whether ``schema`` is the one our writer gives ``layout``'s topic (byte for byte)."""
    return (schema is not None and schema.name == layout.schema_name
            and schema.data == file_descriptor_set(layout.schema_name))


def _decode_topic(layout: TopicLayout, signals: tuple[str, ...], channel: Channel,
                  schema: Schema | None, msgs: ChannelMessages) -> NDArray[np.float64] | None:
    """``signals`` of one channel's messages, one row per signal: decoded as they were read,
    else (batch by batch) the vectorised inverse of the layout, else the file's protobuf
    schema; None when the channel cannot be decoded."""
    ours = _ours(layout, schema)
    out = msgs.rows()
    if out is None:
        if not msgs.count and not ours and _generic_decoder(schema, channel) is None:
            return None
        out = np.empty((len(signals), msgs.count))
    decode: Callable[[bytes], Any] | None = None
    for batch in msgs.parts():
        part = out[:, batch.slot : batch.slot + len(batch.ends)]
        fast = (decode_spans(layout, batch.blob, np.r_[0, batch.ends[:-1]], batch.ends,
                             signals) if ours else None)
        if fast is not None:
            part[:] = fast
            continue
        decode = decode or _generic_decoder(schema, channel)
        if decode is None:
            return None
        raw = batch.blob.tobytes()
        part[:] = np.nan
        try:
            for i, (a, b) in enumerate(itertools.pairwise(np.r_[0, batch.ends].tolist())):
                msg = decode(raw[a:b])
                for j, name in enumerate(signals):
                    part[j, i] = getattr(msg, name, math.nan)
        except Exception:  # a damaged or foreign schema (a field of another type): not ours
            return None
    return out


def _goal(scan: LogScan, by_topic: dict[str, list[Channel]]) -> Pose2D | None:
    msgs = [m for c in by_topic.get(GOAL_TOPIC, []) for m in scan.messages.get(c.id, ())]
    if not msgs:
        return None
    msg = message_class(GOAL_SCHEMA)()
    try:
        msg.ParseFromString(min(msgs, key=lambda m: m[0])[1])
    except DecodeError:
        return None
    p, q = msg.pose.position, msg.pose.orientation
    return Pose2D(p.x, p.y, 2.0 * math.atan2(q.z, q.w))


def _phase(scan: LogScan, channels: list[Channel], t_ns: NDArray[np.int64],
           warnings: list[str]) -> NDArray[np.float64] | None:
    """The control phase at each row time ``t_ns``: the last ``phase`` message at or before
    it (the topic is a step plot: its changes only), NaN before the first."""
    times: list[int] = []
    values: list[float] = []
    for channel in channels:
        msgs = scan.messages.pop(channel.id, ChannelMessages())
        decode = _generic_decoder(scan.schemas.get(channel.schema_id), channel)
        if decode is not None:
            try:
                for log_time, data in msgs:
                    values.append(float(decode(data).phase))
                    times.append(log_time)
            except Exception:  # not our ControlPhase (no double ``phase``), or damaged
                decode = None
        if decode is None:
            warnings.append(f"topic {PHASE_TOPIC} cannot be decoded: the phase is NaN")
            return np.full(t_ns.shape, np.nan)
    if not times:
        return None
    order = np.argsort(np.array(times, np.int64), kind="stable")
    t = np.array(times, np.int64)[order]
    v = np.array(values, np.float64)[order]
    # each change holds from its row to the next change's (the last of equal times wins)
    bounds = np.r_[np.searchsorted(t_ns, t, side="left"), t_ns.size]
    out = np.full(t_ns.shape, np.nan)
    out[bounds[0] :] = np.repeat(v, np.diff(bounds))
    return out


#: Schemas a pose-only log (a real robot's) may carry its poses in, found by schema name.
POSE_SCHEMAS: Final = ("foxglove.PoseInFrame", "foxglove.FrameTransform")
#: The signals a pose-only log gives (the others are NaN).
POSE_SIGNALS: Final = ("x_m", "y_m", "theta_rad")


def _yaw_rad(q: Any) -> float:
    """Heading of a quaternion: its rotation about z (ZYX Euler yaw), rad."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _pose_topic(name: str, scan: LogScan, by_topic: dict[str, list[Channel]],
                asked: str | None) -> str | None:
    """The topic of a pose-only log's poses: ``asked``, else the one topic of a
    :data:`POSE_SCHEMAS` message (our ``/goal`` aside); None when the file has none.

    Raises
    ------
    LogError
        ``asked`` is not a pose topic of the file, or several topics hold poses (one line
        naming them and ``--pose-topic``).
    """
    def schema_of(topic: str) -> str:
        schema = scan.schemas.get(by_topic[topic][0].schema_id)
        return schema.name if schema is not None else ""

    poses = sorted(t for t in by_topic if t != GOAL_TOPIC and schema_of(t) in POSE_SCHEMAS)
    if asked is not None:
        if asked not in by_topic or schema_of(asked) not in POSE_SCHEMAS:
            raise LogError(f"{name}: no {' or '.join(POSE_SCHEMAS)} topic {asked!r} in this "
                           f"log (its pose topics: {', '.join(poses) or 'none'}): give one "
                           "of them to --pose-topic (pose_topic=)")
        return asked
    if len(poses) > 1:
        raise LogError(f"{name}: a log of poses only, on {len(poses)} topics "
                       f"({', '.join(poses)}): name the robot's with --pose-topic TOPIC "
                       "(pose_topic=)")
    return poses[0] if poses else None


def _pose_series(topic: str, scan: LogScan, channels: list[Channel],
                 warnings: list[str]) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None:
    """Log times and ``x_m``, ``y_m``, ``theta_rad`` (unwrapped yaw; one row each) of a pose
    topic, in time order; a ``FrameTransform`` topic of several frame pairs gives its most
    frequent pair's."""
    layout = TopicLayout(topic, "", b"", (), POSE_SIGNALS)
    times: list[int] = []
    rows: list[tuple[float, float, float]] = []
    pairs: dict[tuple[str, str], int] = {}
    keys: list[tuple[str, str]] = []
    for channel in channels:
        schema = scan.schemas.get(channel.schema_id)
        msgs = scan.messages.pop(channel.id, ChannelMessages())
        scan.kept_bytes -= msgs.nbytes  # decoded below, the raw messages go
        decode = _generic_decoder(schema, channel)
        if decode is None or schema is None:
            continue
        transform = schema.name == "foxglove.FrameTransform"
        try:
            for log_time, data in msgs:
                msg = decode(data)
                if transform:
                    p, q = msg.translation, msg.rotation
                    key = (msg.parent_frame_id, msg.child_frame_id)
                    pairs[key] = pairs.get(key, 0) + 1
                    keys.append(key)
                else:
                    p, q = msg.pose.position, msg.pose.orientation
                rows.append((float(p.x), float(p.y), _yaw_rad(q)))
                times.append(log_time)
        except Exception:  # a damaged message, or a schema of that name but other fields
            warnings.append(f"topic {topic}: a message cannot be decoded as "
                            f"{schema.name}: its poses from there on are left out")
    if not times:
        return None
    t = np.array(times, np.int64)
    v = np.array(rows, np.float64).reshape(len(rows), len(layout.signals))
    if len(pairs) > 1:
        best = max(pairs, key=lambda k: pairs[k])
        keep = np.array([k == best for k in keys])
        warnings.append(f"topic {topic} holds {len(pairs)} frame pairs: the poses of "
                        f"{best[0]} -> {best[1]} ({pairs[best]} messages) are read")
        t, v = t[keep], v[keep]
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    first = np.r_[True, t[1:] != t[:-1]]
    t, v = t[first], v[first]
    v[:, 2] = np.unwrap(v[:, 2])
    return t, np.ascontiguousarray(v.T)  # one row per signal, as _topic_series gives


def _topic_series(layout: TopicLayout, signals: tuple[str, ...], channels: list[Channel],
                  scan: LogScan, warnings: list[str]
                  ) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None:
    """Log times and ``signals`` (one row per signal) of one topic, from every channel on
    it, in time order.

    Whatever is not one message per distinct log time in file order (several channels, times
    going backwards, repeated times, times beyond int64) is said in a warning naming the
    topic; None when no channel of the topic can be decoded.
    """
    topic = layout.topic
    times: list[NDArray[np.int64]] = []
    values: list[NDArray[np.float64]] = []
    for channel in channels:
        # decoded, the raw messages go: they and the decoded rows are not held at once
        msgs = scan.messages.pop(channel.id, ChannelMessages())
        decoded = _decode_topic(layout, signals, channel, scan.schemas.get(channel.schema_id),
                                msgs)
        # the raw messages and the batches' decoded arrays are gone: the rows stay
        scan.kept_bytes -= msgs.nbytes + 8 * len(signals) * msgs.raw_count
        if decoded is None:
            continue
        times.append(msgs.times())
        values.append(decoded)
    lost = sum(scan.bad_times.get(c.id, 0) for c in channels)
    if lost:
        warnings.append(f"topic {topic}: {lost} messages have log times beyond 2^63-1 ns "
                        "(after the year 2262): left out")
    if not times:
        return None
    if len(channels) > 1:
        warnings.append(f"topic {topic} has {len(channels)} channels (ids "
                        f"{', '.join(str(c.id) for c in channels)}): their messages are "
                        "merged by log time")
    t = np.concatenate(times) if len(times) > 1 else times[0]
    v = np.concatenate(values, axis=1) if len(values) > 1 else values[0]
    if t.size > 1 and bool(np.any(t[1:] < t[:-1])):
        if len(channels) == 1:
            warnings.append(f"topic {topic}: log times go backwards "
                            f"{int(np.count_nonzero(t[1:] < t[:-1]))} times in file order "
                            "(chunks out of order?): messages sorted by log time")
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[:, order]
    if t.size > 1 and bool(np.any(t[1:] == t[:-1])):
        first = np.r_[True, t[1:] != t[:-1]]
        warnings.append(f"topic {topic}: {t.size - int(first.sum())} messages repeat the log "
                        "time of another: the first at each time is kept")
        t, v = t[first], v[:, first]
    return t, v


def _join_by_time(series: dict[str, tuple[NDArray[np.int64], NDArray[np.float64]]],
                  warnings: list[str]) -> NDArray[np.int64]:
    """The row times: the log times of any signal topic (one row per distinct time)."""
    all_t = [t for t, _ in series.values()]
    if not all_t:
        return np.zeros(0, np.int64)
    first = all_t[0]
    if all(t is first or np.array_equal(t, first) for t in all_t):
        return first
    rows = np.unique(np.concatenate(all_t))
    for topic, (t, _) in series.items():
        if t.size != rows.size:
            warnings.append(f"topic {topic} has messages at {t.size} of the {rows.size} "
                            f"row times (topics disagree in log times): its signals are NaN "
                            f"at the other {rows.size - t.size}")
    return rows


def read_run(path: str | os.PathLike[str], limits: ReadLimits | None = None,
             pose_topic: str | None = None,
             signals: Collection[str] | None = None) -> RunData:
    """Read a run log; a cut or damaged file gives its readable prefix, marked truncated.

    Rows are joined by log time: row times are the log times of the signal topics read, and
    a topic without a message at a row's time is NaN there (with a warning naming it).

    Parameters
    ----------
    path
        An MCAP file written by :class:`wmr.adapters.mcap.RunLogWriter`.
    limits
        How much the file may make the reader hold (:class:`ReadLimits`; default
        :func:`default_limits`): past ``total_bytes``, the rows that fit, with a warning.
    pose_topic
        A file with none of our signal topics (a real robot's) is read as a pose-only log,
        its poses from its one ``foxglove.PoseInFrame`` or ``foxglove.FrameTransform``
        topic, or from this one when it has several (``RunData``'s ``pose_topic`` says
        which, and a warning line).  A log of ours is read as ours whatever this says (so
        that ``wmr replay SIM.mcap REAL.mcap --pose-topic T`` names REAL's topic).
    signals
        The signals to read (names of :data:`wmr.core.signals.SIGNALS`; default: all).
        Only the topics that carry them are kept and decoded (the path, ``x_m``, ``y_m``,
        ``theta_rad``, is ``/robot/state`` alone), and ``RunData.signals`` holds these.

    Returns
    -------
    RunData
        Times, signals, metadata, attachments and goal of the run.

    Raises
    ------
    LogError
        The file is missing, not a regular file, empty, or not MCAP at all.
    ConfigError
        ``signals`` names a signal that is not one of ``SIGNALS``.
    """
    name = os.fspath(path)
    asked = _asked(signals)
    # each signal topic read: the signals of it asked for, decoded as its chunks are read
    decode = {t.topic: (t, sigs) for t in _SIGNAL_TOPICS
              if (sigs := tuple(s for s in t.signals if s in asked))}
    scan = scan_file(name, limits, topics={GOAL_TOPIC, PHASE_TOPIC, *decode}, decode=decode)
    by_topic: dict[str, list[Channel]] = {}
    for channel in sorted(scan.channels.values(), key=lambda c: c.id):
        by_topic.setdefault(channel.topic, []).append(channel)
    foreign: str | None = None
    if not any(t.topic in by_topic for t in _SIGNAL_TOPICS):  # not ours: a robot's poses?
        foreign = _pose_topic(name, scan, by_topic, pose_topic)
    if foreign is not None:
        # a stranger's file, read again through the same bounded walk, keeping its poses
        scan = scan_file(name, limits, topics={foreign})
    warnings = list(scan.warnings)
    open_loop = TORQUE_TOPIC.topic in by_topic
    expected = {t.topic for t in (OPEN_LOOP_TOPICS if open_loop else STEP_TOPICS)}
    series: dict[str, tuple[NDArray[np.int64], NDArray[np.float64]]] = {}
    names: dict[str, tuple[str, ...]] = {}  # the signals of each series' rows
    if foreign is not None:
        schema = scan.schemas.get(by_topic[foreign][0].schema_id)
        warnings.append(f"a pose-only log ({schema.name if schema else '?'} on {foreign}): "
                        f"{', '.join(POSE_SIGNALS)} from its poses, the other signals NaN")
        got = _pose_series(foreign, scan, by_topic[foreign], warnings)
        if got is not None:
            t0 = got[0][0]
            series[foreign] = (got[0] - t0, got[1])  # from the first pose, like our logs
            names[foreign] = POSE_SIGNALS
    for topic, (layout, sigs) in decode.items() if foreign is None else ():
        channels = by_topic.get(topic)
        if channels is None:
            if topic in expected:
                warnings.append(f"topic {topic} is missing: its signals are NaN")
            continue
        got = _topic_series(layout, sigs, channels, scan, warnings)
        if got is None:
            warnings.append(f"topic {topic} cannot be decoded: its signals are NaN")
            continue
        series[topic] = got
        names[topic] = sigs
    times = _join_by_time(series, warnings)
    # the rows' columns, and what the caller makes of them, within what the budget has left
    row_bytes = 8 * (len(asked) + 1) * ROW_COPIES
    fit = max(0, scan.limits.total_bytes - scan.kept_bytes) // row_bytes
    if times.size > fit:
        scan.over(f"the row at t = {times[fit] * 1e-9:g} s ({fit} of {times.size} rows)")
        warnings.append(scan.warnings[-1])
        last = times[fit - 1] if fit else -1
        times = times[:fit]
        series = {topic: (t[t <= last], v[:, t <= last]) for topic, (t, v) in series.items()}
    n = times.size
    columns: dict[str, NDArray[np.float64]] = {}
    for topic, (t, values) in series.items():
        at = None if t is times or t.size == n else np.searchsorted(times, t)
        for j, sig in enumerate(names[topic]):
            if sig not in asked:
                continue
            if at is None:
                columns[sig] = np.ascontiguousarray(values[j])  # a row: no copy
            else:
                columns[sig] = np.full(n, np.nan)
                columns[sig][at] = values[j]
    for rec in ("run", "result") if foreign is None else ():
        if rec not in scan.metadata:
            warnings.append(f"no {rec!r} metadata record")
    return RunData(
        path=name,
        t_ns=times,
        signals={sig: columns[sig] if sig in columns else np.full(n, np.nan) for sig in asked},
        metadata=scan.metadata,
        attachments=scan.attachments,
        media_types=scan.media_types,
        goal=_goal(scan, by_topic),
        phase=_phase(scan, by_topic[PHASE_TOPIC], times, warnings)
        if PHASE_TOPIC in by_topic and foreign is None else None,
        pose_topic=foreign,
        truncated=not scan.complete or scan.damaged or bool(scan.bad_times)
        or scan.over_budget,
        warnings=warnings,
    )


def _asked(signals: Collection[str] | None) -> tuple[str, ...]:
    """The signals asked for, in the order of ``SIGNALS`` (all of them for None).

    Raises
    ------
    ConfigError
        A name that is not one of ``SIGNALS``.
    """
    if signals is None:
        return SIGNALS
    wanted = {signals} if isinstance(signals, str) else set(signals)
    unknown = sorted(wanted.difference(SIGNALS))
    if unknown:
        from wmr.infra.errors import ConfigError

        raise ConfigError("signals", f"no signal {', '.join(map(repr, unknown))} in a log",
                          f"choose among {', '.join(SIGNALS)}")
    return tuple(s for s in SIGNALS if s in wanted)


def metadata_json(value: str, limits: ReadLimits = DEFAULT_LIMITS) -> Any:
    """A metadata value decoded from JSON, bounded in size and nesting depth.

    Parameters
    ----------
    value
        The string stored in a Metadata record.
    limits
        ``json_bytes`` and ``json_depth`` bound what is decoded.

    Returns
    -------
    Any
        The decoded value.

    Raises
    ------
    ValueError
        ``value`` is not JSON (a plain string: keep it as it is).
    LogError
        ``value`` is longer than ``limits.json_bytes`` or nests deeper than
        ``limits.json_depth`` (checked before decoding: a deep value would exhaust the stack).
    """
    if len(value) > limits.json_bytes:
        raise LogError(f"{len(value)} characters, above the {limits.json_bytes}-character "
                       "JSON limit (ReadLimits.json_bytes)")
    if _json_depth(value) > limits.json_depth:
        raise LogError(f"nests deeper than {limits.json_depth} levels (ReadLimits.json_depth)")
    return json.loads(value)


#: Topics whose presence makes a file one of our logs (not a pose-only one).
_SIGNAL_TOPICS: Final = tuple(t for t in (*STEP_TOPICS, TORQUE_TOPIC) if t.signals)
_JSON_STRING: Final = re.compile(r'"(?:[^"\\]|\\.)*"')


def _json_depth(text: str) -> int:
    """Deepest nesting of ``[``/``{`` in ``text``, strings ignored (vectorised)."""
    if "[" not in text and "{" not in text:
        return 0
    bare = np.frombuffer(_JSON_STRING.sub("", text).encode(), np.uint8)
    step = (np.isin(bare, (ord("["), ord("{"))).astype(np.int64)
            - np.isin(bare, (ord("]"), ord("}"))))
    return int(np.cumsum(step).max(initial=0))


# --------------------------------------------------------------------------- finished logs


def log_stamp(path: str | os.PathLike[str]) -> dict[str, int] | None:
    """Size and modification time (ns) of the file at ``path`` (what a batch journals with
    its run's log), ``None`` if there is none."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns}


def log_finished(path: str | os.PathLike[str],
                 stamp: Mapping[str, Any] | None = None) -> bool:
    """Whether ``path`` is a finished MCAP log with a ``result`` metadata record.

    With the ``stamp`` taken when the log was finished (:func:`log_stamp`), a log of the same
    size and modification time that still ends with the MCAP magic is that log (a stat and an
    8-byte read, about 20 µs: a resume of a million runs checks in seconds).  Otherwise, or
    when those differ, the footer and the summary section are read (about 0.5 ms, not the
    messages).  A missing, cut or damaged file is not finished.
    """
    from mcap.reader import make_reader

    if stamp is not None and log_stamp(path) == stamp:
        try:
            with open(path, "rb") as stream:
                stream.seek(-len(MAGIC), os.SEEK_END)
                if stream.read() == MAGIC:
                    return True
        except OSError:
            return False
    try:
        with open(path, "rb") as stream:
            summary = make_reader(stream).get_summary()
    except Exception:  # missing, cut or damaged: not finished
        return False
    return summary is not None and any(m.name == "result" for m in summary.metadata_indexes)


def finished_result(path: str | os.PathLike[str]) -> dict[str, str] | None:
    """The ``result`` metadata record (its strings) of the finished log at ``path``;
    ``None`` if the log is missing, unfinished (its summary lists no ``result``) or
    damaged."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            summary = reader.get_summary()
            if summary is None or not any(m.name == "result" for m in summary.metadata_indexes):
                return None
            return next((dict(m.metadata) for m in reader.iter_metadata()
                         if m.name == "result"), None)
    except Exception:  # missing, cut or damaged: nothing to read the record from
        return None



__all__ = [
    "DEFAULT_LIMITS",
    "MAX_LOG_TIME_NS",
    "POSE_SCHEMAS",
    "POSE_SIGNALS",
    "READ_LIMIT_ENV",
    "ROW_COPIES",
    "ChannelMessages",
    "Pose2D",
    "ReadLimits",
    "RunData",
    "default_limits",
    "finished_result",
    "log_finished",
    "log_stamp",
    "metadata_json",
    "open_log",
    "read_chunk_at",
    "read_limit",
    "read_run",
    "scan_file",
    "scan_log",
]
