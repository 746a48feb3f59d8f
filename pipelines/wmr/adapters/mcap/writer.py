"""Write the MCAP log of a closed-loop run, fast and reproducibly.

The MCAP container is written here rather than through :class:`mcap.writer.Writer`, whose
``add_message`` costs about 7 us per message in pure Python (45 us per control step for six
topics).  The Message records of a chunk are built by the C stepper (``wmr_encode_rows``, the
bytes of :class:`wmr.adapters.mcap.schemas.RowEncoder`, numpy's encoder, when the stepper is
not there) from the log's staging buffers, where each block of rows is copied once; the other
records are packed with :mod:`struct` exactly as :mod:`mcap.records` packs them
(``tests/test_mcaplog.py`` reads a whole log back with the ``mcap`` library and writes every
record again with its record classes: the same bytes), the Schema and Channel records by
:mod:`mcap.records` once per process (every log of a batch has the same).  Every CRC (each
chunk's, each attachment's, the data section's and the summary's) is zlib's CRC-32 computed by
zlib-ng, which folds with the CPU's carry-less multiply: the same values at about 30 times the
speed of the system zlib's.

Layout of a file: magic, Header, Schema and Channel records, the ``run`` Metadata record, the
Attachments, a chunk holding the ``/goal`` message, then one chunk per second of simulation
time (each followed by its Message Index records and flushed to the OS, so a killed run loses at
most the chunk in progress); at the close, one chunk of the scene's topics and the note
(:mod:`wmr.adapters.mcap.scene`, :mod:`wmr.adapters.mcap.readme`), the last rows' chunk, the
``result`` Metadata record, Data End, the summary (schemas, channels, statistics, chunk,
attachment and metadata indexes, summary offsets), Footer, magic.  Every chunk is flushed
to the OS as it is written, the close's too: a write refused by a full disk fails on its own
chunk, which is then cut back (:meth:`McapFile.rollback`) before the error is reported; a
buffer holding several chunks would fail the cut back as well.
Nothing in the file depends on the wall clock or on the host: the same inputs give the same
bytes.
"""

from __future__ import annotations

import ctypes
import functools
import json
import math
import os
import struct
import sys
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from types import TracebackType
from typing import Any, Final, Literal, NamedTuple, Protocol, cast

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, Schema
from numpy.typing import ArrayLike, NDArray
from zlib_ng.zlib_ng import crc32

from wmr.adapters.mcap.readme import write_readme
from wmr.adapters.mcap.scene import SceneRecorder
from wmr.adapters.mcap.schemas import (
    GOAL_SCHEMA,
    GOAL_TOPIC,
    MAGIC,
    N_SOURCES,
    SRC_QW,
    SRC_QZ,
    STEP_TOPICS,
    WORLD_FRAME,
    RowEncoder,
    TopicLayout,
    file_descriptor_set,
    message_class,
)
from wmr.adapters.stepper import Layout, load_stepper
from wmr.core.runlog import LogHeader, failed_result
from wmr.core.sensing import SensingRecord
from wmr.core.signals import COLUMN, SIGNALS
from wmr.infra.durable import AtomicFile, stop_signals_held
from wmr.infra.errors import LogError
from wmr.infra.version import __version__

_OP_MESSAGE: Final = int(Opcode.MESSAGE)
#: A Message record up to its data: opcode, record length, channel id, sequence, log and
#: publish time.
_MESSAGE_HEAD: Final = struct.Struct("<BQHIQQ")
#: Rows a log's staging buffers hold at first (grown when a chunk needs more): a chunk of
#: 1 s at 10 ms and the block after it, twice over.
_STAGE_ROWS: Final = 512
#: A Chunk record up to its compression string: opcode, record length, message start and end
#: times, uncompressed size and CRC, the string's length; and a Message Index record's head:
#: opcode, record length, channel id, length of the entries.
_CHUNK_HEAD: Final = struct.Struct("<BQQQQII")
_CHUNK_FIXED: Final = 8 + 8 + 8 + 4 + 4 + 8  # the Chunk record's length minus its strings
_INDEX_HEAD: Final = struct.Struct("<BQHI")
#: A Chunk Index record, as :meth:`mcap.records.ChunkIndex.write` packs it: opcode, record
#: length, message start and end times, chunk start and length, the byte length of the map
#: of Message Index offsets; the map (channel id, offset); the Message Indexes' length and the
#: compression string's; the string; the compressed and uncompressed sizes.
_CHUNK_INDEX_HEAD: Final = struct.Struct("<BQQQQQI")
_INDEX_OFFSET: Final = struct.Struct("<HQ")
_CHUNK_INDEX_TAIL: Final = struct.Struct("<QI")
_CHUNK_INDEX_SIZES: Final = struct.Struct("<QQ")
_CHUNK_INDEX_FIXED: Final = 8 * 4 + 4 + 8 + 4 + 8 * 2  # the length minus the map and string
Compression = Literal["zstd", "lz4", ""]
#: The chunks' compression by default: lz4, the fastest that both Rerun's and Foxglove's
#: readers take; on these records it takes half the CPU time of zstd level 1 (which was the
#: logs' compression before, and is still written on request) for about a quarter more bytes
#: (``benchmarks/log_cost.py``, docs/formats.md).
DEFAULT_COMPRESSION: Final[Compression] = "lz4"
#: lz4's level: negative levels are LZ4F's fast mode, acceleration ``1 - level`` (python-lz4
#: hands the level to LZ4F as it is).  On the rows' chunks (69 kB of records each, Monte Carlo
#: runs of Fig. 10 and Fig. 11's logs) -3 (acceleration 4) takes 77 to 84 % of -1's time and
#: about 65 % of level 0's for 0.6 % more bytes than -1; -2 and -4 give 5 to 7 % more bytes (where
#: the accelerated search skips falls across the rows' records), -16 17 % more for 61 % of the
#: time; a larger block or a checksum changes neither (docs/batch.md, issue 31, round 3).
LZ4_LEVEL: Final = -3
ZSTD_LEVEL: Final = 1

try:
    _MCAP_VERSION = version("mcap")
except PackageNotFoundError:  # pragma: no cover - installed from source
    _MCAP_VERSION = "unknown"
#: Header ``library`` field: software versions only, no host, no time.
LIBRARY: Final = f"wmr-cosim/{__version__} mcap-python/{_MCAP_VERSION}"


def _compressor(kind: Compression, level: int | None = None) -> Any:
    """The chunk compressor of ``kind`` at ``level`` (default :data:`LZ4_LEVEL` or
    :data:`ZSTD_LEVEL`); None for ``""``."""
    if kind == "zstd":
        return _zstd(ZSTD_LEVEL if level is None else level)
    if kind == "lz4":
        import lz4.frame

        return functools.partial(lz4.frame.compress,
                                 compression_level=LZ4_LEVEL if level is None else level)
    if kind == "":
        return None
    raise LogError(f"unknown MCAP chunk compression {kind!r} (use 'zstd', 'lz4' or '')")


@functools.lru_cache(maxsize=8)
def _zstd(level: int) -> Any:
    """zstd's one-shot compression at ``level``, a compressor per thread (one is not to be
    used by two threads at once, and a Dask worker may write logs in several)."""
    import zstandard

    local = threading.local()

    def compress(data: bytes | memoryview) -> bytes:
        c = getattr(local, "c", None)
        if c is None:
            c = local.c = zstandard.ZstdCompressor(level=level)
        return bytes(c.compress(data))

    return compress


class Sink(Protocol):
    """What :class:`McapFile` writes to: a binary file, or a
    :class:`wmr.infra.durable.AtomicFile`."""

    def write(self, data: bytes, /) -> object: ...
    def flush(self) -> None: ...
    def close(self) -> None: ...
    def seek(self, offset: int, /) -> object: ...
    def truncate(self) -> object: ...


#: What :meth:`McapFile.mark` saves: the position, the data section CRC, the chunks written.
_Mark = tuple[int, int, int]
#: A chunk written, as :meth:`McapFile.finish` indexes it: its first and last message times,
#: start and length, ``index_of`` (channel id, offset in its Message Index records and count
#: of each channel), the byte length of the Message Index records, of its data and of its
#: records uncompressed.
_Chunk = tuple[int, int, int, int, Sequence[tuple[int, int, int]], int, int, int]


class McapFile:
    """Minimal chunked MCAP writer with a vectorised message path.

    Parameters
    ----------
    stream
        Binary stream opened for writing, positioned at 0; closed by :meth:`finish`.
    compression
        Chunk compression: ``"lz4"`` (default, :data:`DEFAULT_COMPRESSION`), ``"zstd"`` or
        ``""``.
    library
        Header ``library`` field.
    level
        The compressor's level (default :data:`LZ4_LEVEL`, :data:`ZSTD_LEVEL`).
    """

    def __init__(
        self, stream: Sink, compression: Compression = DEFAULT_COMPRESSION,
        library: str = LIBRARY,
        level: int | None = None,
    ) -> None:
        self._stream = stream
        self._compression = compression
        self._compress = _compressor(compression, level)
        self._compression_bytes = compression.encode()
        #: a Chunk record up to its data: the fields, the compression string, the data length
        self._chunk_head = struct.Struct(f"{_CHUNK_HEAD.format}{len(self._compression_bytes)}sQ")
        self._pos = 0
        self._schemas: list[bytes] = []  # the records, written again in the summary
        self._channels: list[bytes] = []
        # what each chunk's Chunk Index record and the statistics need of it, packed by
        # finish(): one append per chunk (_Chunk)
        self._chunks: list[_Chunk] = []
        self._attachment_indexes: list[bytes] = []  # the records
        self._metadata_indexes: list[bytes] = []
        self._channel_ids: list[int] = []
        self._crc = 0  # of the data section: every byte before Data End, magic included
        self._broken = ""  # why the file cannot be finished (a rollback that failed)
        self._write(MAGIC + _record(Opcode.HEADER, _prefixed("") + _prefixed(library)))

    def _write(self, data: bytes) -> None:
        self._stream.write(data)
        self._pos += len(data)
        self._crc = crc32(data, self._crc)

    def add_schema(self, name: str, data: bytes, encoding: str = "protobuf") -> int:
        """Write a Schema record (protobuf by default); return its id (1, 2, ...)."""
        schema_id = len(self._schemas) + 1
        self._schemas.append(_schema_record(schema_id, name, encoding, data))
        self._write(self._schemas[-1])
        return schema_id

    def add_channel(self, topic: str, schema_id: int, message_encoding: str = "protobuf",
                    metadata: Mapping[str, str] | None = None) -> int:
        """Write a Channel record (protobuf by default); return its id (1, 2, ...)."""
        channel_id = len(self._channels) + 1
        self._channels.append(_channel_record(channel_id, topic, message_encoding, schema_id,
                                              tuple((metadata or {}).items())))
        self._channel_ids.append(channel_id)
        self._write(self._channels[-1])
        return channel_id

    def add_opening_records(self, schemas: Sequence[bytes], channels: Sequence[bytes]) -> None:
        """Write Schema and Channel records already packed (:func:`_opening_records`), ids
        1, 2, ... in order, in one write: the first of the file.

        Raises
        ------
        LogError
            The file has schemas or channels already (the records' ids would clash).
        """
        if self._schemas or self._channels:
            raise LogError("the opening Schema and Channel records come before any other")
        self._schemas += schemas
        self._channels += channels
        self._channel_ids += range(1, len(channels) + 1)
        self._write(b"".join((*schemas, *channels)))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a Metadata record (and remember its index)."""
        offset = self._pos
        record = metadata_record(name, data)
        self._write(record)
        self._metadata_indexes.append(_record(
            Opcode.METADATA_INDEX, _U64X2.pack(offset, len(record)) + _prefixed(name)))

    def add_attachment(self, name: str, media_type: str, data: bytes) -> None:
        """Write an Attachment record, log and create time 0 (packed here as
        :meth:`mcap.records.Attachment.write` packs it, its CRC by zlib-ng)."""
        offset = self._pos
        names = _prefixed(name) + _prefixed(media_type)
        body = b"".join((_U64X2.pack(0, 0), names, _U64.pack(len(data)), data))
        record = _record(Opcode.ATTACHMENT, body + _U32.pack(crc32(body)))
        self._write(record)
        self._attachment_indexes.append(_record(
            Opcode.ATTACHMENT_INDEX,
            _ATTACHMENT_INDEX.pack(offset, len(record), 0, 0, len(data)) + names))

    def add_chunk(
        self,
        records: bytes | memoryview,
        index: Mapping[int, tuple[NDArray[np.int64], NDArray[np.int64]]],
        uncompressed_crc: int | None = None,
    ) -> None:
        """Write a chunk of already serialised Message records, then its Message Indexes.

        Parameters
        ----------
        records
            Concatenated Message records, in log-time order (bytes, or a view of uint8).
        index
            Channel id -> (log times in ns, byte offsets of the records in ``records``).
        uncompressed_crc
            ``crc32(records)``, if the caller has it (computed here otherwise).
        """
        entries = [(cid, t, o) for cid, (t, o) in index.items() if len(t)]
        if not entries:
            return
        t_first = min(int(t[0]) for _, t, _ in entries)
        t_last = max(int(t[-1]) for _, t, _ in entries)
        parts: list[bytes] = []
        index_of: list[tuple[int, int, int]] = []
        at = 0
        for cid, t, o in entries:
            pairs = np.empty((len(t), 2), "<u8")
            pairs[:, 0], pairs[:, 1] = t, o
            index_of.append((cid, at, len(t)))
            parts += [_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 6 + pairs.nbytes, cid, pairs.nbytes),
                      pairs.tobytes()]
            at += _INDEX_HEAD.size + pairs.nbytes
        self.add_indexed_chunk(records, t_first, t_last, b"".join(parts), index_of,
                               uncompressed_crc)

    def add_messages(self, messages: Sequence[tuple[int, int, int, bytes]]) -> None:
        """One chunk of the messages of one channel or several: (log time in ns, channel id,
        sequence, data) each, written in log-time order (equal times in the order given),
        then a Message Index record per channel, in channel id order; nothing when
        ``messages`` is empty."""
        if not messages:
            return
        ordered = sorted(messages, key=_log_time)  # stable
        head = _MESSAGE_HEAD
        parts: list[bytes] = []
        pairs: dict[int, list[int]] = {}  # channel id: its (log time, offset) pairs
        pos = 0
        for t, cid, seq, data in ordered:
            pairs.setdefault(cid, []).extend((t, pos))
            parts += [head.pack(_OP_MESSAGE, 2 + 4 + 8 + 8 + len(data), cid, seq, t, t), data]
            pos += head.size + len(data)
        indexes: list[bytes] = []
        index_of: list[tuple[int, int, int]] = []
        at = 0
        for cid in sorted(pairs):
            # int64's bytes are uint64's (a negative time wrapped)
            entries = np.array(pairs[cid], "<i8").tobytes()
            indexes += [_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 6 + len(entries), cid,
                                         len(entries)), entries]
            index_of.append((cid, at, len(entries) // 16))
            at += _INDEX_HEAD.size + len(entries)
        self.add_indexed_chunk(b"".join(parts), ordered[0][0], ordered[-1][0], b"".join(indexes),
                               index_of)

    def add_row_chunk(self, records: bytes | memoryview, t_ns: NDArray[np.int64],
                      offsets: NDArray[np.int64], channel_ids: tuple[int, ...]) -> None:
        """:meth:`add_chunk` of rows: one message per channel and row, all channels at the
        row's time; ``offsets`` shape ``(rows, channels)``.  The Message Index records of
        every channel are one numpy array of packed records (:func:`_index_records`)."""
        n = len(t_ns)
        index = np.empty(len(channel_ids), _index_records(n))
        index["opcode"] = Opcode.MESSAGE_INDEX
        index["length"] = 6 + 16 * n
        index["channel"] = channel_ids
        index["entries_length"] = 16 * n
        index["entries"][:, :, 0] = t_ns
        index["entries"][:, :, 1] = offsets.T
        size = index.dtype.itemsize
        self.add_indexed_chunk(records, int(t_ns[0]), int(t_ns[-1]), index.tobytes(),
                               [(cid, k * size, n) for k, cid in enumerate(channel_ids)])

    def add_indexed_chunk(self, records: bytes | memoryview, t_first: int, t_last: int,
                          indexes: bytes | memoryview, index_of: Sequence[tuple[int, int, int]],
                          uncompressed_crc: int | None = None) -> None:
        """The Chunk record and its Message Index records (``indexes``: channel id, offset in
        ``indexes`` and message count of each in ``index_of``), packed here as
        :meth:`mcap.records.Chunk.write` and ``MessageIndex.write`` pack them (checked
        against them by ``tests/test_mcaplog.py``) without their copies through a
        ``BytesIO``: a chunk's head, its data and its indexes are written as they are, then
        handed to the OS at once; the Chunk Index record is one ``struct`` call."""
        size = len(records)  # bytes, or a view of uint8
        data = records if self._compress is None else self._compress(records)
        data_len = len(data)
        chunk_start = self._pos
        comp = self._compression_bytes
        head = self._chunk_head.pack(
            Opcode.CHUNK, _CHUNK_FIXED + len(comp) + data_len, t_first, t_last, size,
            crc32(records) if uncompressed_crc is None else uncompressed_crc, len(comp), comp,
            data_len)
        # the sinks' write takes any buffer (a BufferedWriter's does): views are not copied
        write = cast(Callable[[bytes | memoryview], object], self._stream.write)
        write(head)
        write(data)
        write(indexes)
        chunk_length = len(head) + data_len
        # the position and CRC only once every part is written: rollback() restores them
        self._crc = crc32(indexes, crc32(data, crc32(head, self._crc)))
        self._pos = chunk_start + chunk_length + len(indexes)
        self._chunks.append((t_first, t_last, chunk_start, chunk_length, index_of,
                             len(indexes), data_len, size))
        self._stream.flush()

    def mark(self) -> _Mark:
        """Where the file is, for :meth:`rollback` (taken before a chunk is added)."""
        return self._pos, self._crc, len(self._chunks)

    def rollback(self, mark: _Mark) -> None:
        """Undo what was written since ``mark`` (a chunk cut anywhere, or whole): the file
        is cut back to the marked position and the summary forgets it.  A stream that cannot
        be cut back (a full disk refusing the buffered bytes) is given up: the file stays as
        it is, readable up to its last whole chunk, and :meth:`finish` refuses to end it."""
        pos, crc, chunks = mark
        del self._chunks[chunks:]
        self._pos, self._crc = pos, crc
        try:
            self._stream.seek(pos)
            self._stream.truncate()
        except Exception as exc:  # the caller's own exception is the one to report
            self._broken = f"could not cut the log back after a failed write: {exc}"

    def abort(self) -> None:
        """Close the stream without a summary (the file stays readable up to its last chunk)."""
        self._stream.close()

    def finish(self) -> None:
        """Write Data End, the summary section and the Footer; close the stream.

        A stream with a ``commit`` method (:class:`wmr.infra.durable.AtomicFile`) is committed
        instead of closed: the finished file then replaces the one at its final path.

        Raises
        ------
        LogError
            A chunk could not be cut back after a failed write (:meth:`rollback`).
        """
        if self._broken:
            raise LogError(self._broken)
        self._write(_record(Opcode.DATA_END, _U32.pack(self._crc)))
        summary_start = self._pos
        parts: list[bytes] = []
        offsets: list[bytes] = []  # the Summary Offset records
        group_at = summary_start

        def group(opcode: Opcode, records: list[bytes]) -> None:
            nonlocal group_at
            if not records:
                return
            length = sum(len(r) for r in records)
            parts.extend(records)
            offsets.append(_record(Opcode.SUMMARY_OFFSET,
                                   _SUMMARY_OFFSET.pack(opcode, group_at, length)))
            group_at += length

        counts = dict.fromkeys(self._channel_ids, 0)
        chunk_indexes = []
        comp = self._compression_bytes
        t_first, t_last, n_messages = 0, 0, 0
        for start, end, chunk_start, chunk_length, index_of, indexes_length, data_len, size \
                in self._chunks:
            index_start = chunk_start + chunk_length
            entries: list[int] = []
            for cid, at, count in index_of:
                if count and n_messages == 0:
                    t_first, t_last = start, end
                counts[cid] += count
                n_messages += count
                entries += (cid, index_start + at)
            if n_messages:
                t_first, t_last = min(t_first, start), max(t_last, end)
            chunk_indexes.append(_chunk_index_struct(len(index_of), len(comp)).pack(
                Opcode.CHUNK_INDEX, _CHUNK_INDEX_FIXED + _INDEX_OFFSET.size * len(index_of)
                + len(comp), start, end, chunk_start, chunk_length,
                _INDEX_OFFSET.size * len(index_of), *entries, indexes_length, len(comp), comp,
                data_len, size))
        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        group(Opcode.STATISTICS, [_record(Opcode.STATISTICS, b"".join((
            _STATISTICS.pack(n_messages, len(self._schemas), len(self._channels),
                             len(self._attachment_indexes), len(self._metadata_indexes),
                             len(chunk_indexes), t_first, t_last, _COUNT.size * len(counts)),
            *(_COUNT.pack(cid, count) for cid, count in counts.items()))))])
        group(Opcode.CHUNK_INDEX, chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, self._attachment_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = group_at
        summary = b"".join(parts + offsets)
        footer = _FOOTER_HEAD.pack(Opcode.FOOTER, 20, summary_start, summary_offset_start)
        self._write(b"".join((summary, footer, _U32.pack(crc32(footer, crc32(summary))),
                              MAGIC)))
        commit = getattr(self._stream, "commit", None)
        if commit is not None:
            commit()
        else:
            self._stream.close()


_U32: Final = struct.Struct("<I")
_U64: Final = struct.Struct("<Q")
_U64X2: Final = struct.Struct("<QQ")
#: A record's opcode and length; the bodies of the records :class:`McapFile` packs itself, as
#: :mod:`mcap.records` packs them (checked against them by ``tests/test_mcaplog.py``):
#: Attachment Index (offset, length, log and create time, data size, then the name and media
#: type), Statistics (then a channel id and message count per channel), Summary Offset, and
#: the Footer up to its CRC.
_RECORD_HEAD: Final = struct.Struct("<BQ")
_ATTACHMENT_INDEX: Final = struct.Struct("<QQQQQ")
_STATISTICS: Final = struct.Struct("<QHIIIIQQI")
_COUNT: Final = struct.Struct("<HQ")
_SUMMARY_OFFSET: Final = struct.Struct("<BQQ")
_FOOTER_HEAD: Final = struct.Struct("<BQQQ")


def _log_time(message: tuple[int, int, int, bytes]) -> int:
    """The sort key of :meth:`McapFile.add_messages`' messages: their log time."""
    return message[0]


def _record(opcode: int, body: bytes) -> bytes:
    """A record: its opcode, its body's length, its body."""
    return _RECORD_HEAD.pack(opcode, len(body)) + body


def _prefixed(text: str) -> bytes:
    data = text.encode()
    return _U32.pack(len(data)) + data


def metadata_record(name: str, data: Mapping[str, str]) -> bytes:
    """A Metadata record's bytes as :meth:`mcap.records.Metadata.write` makes them (its name,
    then the map's byte length and each key and value, length-prefixed UTF-8, in the map's
    order), packed at once rather than through a ``RecordBuilder`` call per string: a log's
    ``run`` record has some 20 of them (checked against ``mcap``'s by ``tests/test_mcaplog.py``)."""
    entries = b"".join([_prefixed(k) + _prefixed(v) for k, v in data.items()])
    body = b"".join((_prefixed(name), _U32.pack(len(entries)), entries))
    return struct.pack("<BQ", Opcode.METADATA, len(body)) + body


@functools.lru_cache(maxsize=64)
def _row_index_of(channel_ids: tuple[int, ...], n: int) -> tuple[tuple[int, int, int], ...]:
    """``index_of`` of :meth:`McapFile.add_indexed_chunk` for a chunk of ``n`` rows of the
    per-step topics: channel id, offset and count of each channel's Message Index record
    (``15 + 16 n`` bytes each, in channel order)."""
    return tuple((cid, k * (15 + 16 * n), n) for k, cid in enumerate(channel_ids))


@functools.lru_cache(maxsize=64)
def _chunk_index_struct(n_indexes: int, n_compression: int) -> struct.Struct:
    """A Chunk Index record with ``n_indexes`` Message Index offsets and a compression string
    of ``n_compression`` bytes, as one ``struct`` (the layout of :data:`_CHUNK_INDEX_HEAD`)."""
    return struct.Struct(f"{_CHUNK_INDEX_HEAD.format}{_INDEX_OFFSET.format[1:] * n_indexes}"
                         f"{_CHUNK_INDEX_TAIL.format[1:]}{n_compression}s"
                         f"{_CHUNK_INDEX_SIZES.format[1:]}")


@functools.lru_cache(maxsize=64)
def _index_records(n: int) -> np.dtype[np.void]:
    """A Message Index record of ``n`` entries as a packed numpy record: opcode, record
    length, channel id, byte length of the entries, then (log time, offset) pairs."""
    return np.dtype([("opcode", "u1"), ("length", "<u8"), ("channel", "<u2"),
                     ("entries_length", "<u4"), ("entries", "<u8", (n, 2))])


@functools.lru_cache(maxsize=64)
def _schema_record(schema_id: int, name: str, encoding: str, data: bytes) -> bytes:
    """A Schema record's bytes, serialised once per process (every log of a batch has the
    same)."""
    rb = RecordBuilder()
    Schema(id=schema_id, name=name, encoding=encoding, data=data).write(rb)
    return rb.end()


@functools.lru_cache(maxsize=16)
def _opening_records(topics: tuple[TopicLayout, ...]
                     ) -> tuple[tuple[bytes, ...], tuple[bytes, ...]]:
    """The Schema and Channel records that open every log of ``topics``, packed once per
    process: the schemas of ``/goal`` and of the topics, each once, ids 1, 2, ... in that
    order; the topics' channels, ids 1 to n, then ``/goal``'s, n + 1 (what
    :meth:`McapFile.add_schema` and :meth:`McapFile.add_channel` would write a record at a
    time)."""
    names = list(dict.fromkeys([GOAL_SCHEMA, *(t.schema_name for t in topics)]))
    schema_ids = {name: k + 1 for k, name in enumerate(names)}
    schemas = tuple(_schema_record(schema_ids[name], name, "protobuf", file_descriptor_set(name))
                    for name in names)
    topic_schemas = [(t.topic, schema_ids[t.schema_name]) for t in topics]
    topic_schemas.append((GOAL_TOPIC, schema_ids[GOAL_SCHEMA]))
    channels = tuple(_channel_record(k + 1, topic, "protobuf", schema_id, ())
                     for k, (topic, schema_id) in enumerate(topic_schemas))
    return schemas, channels


@functools.lru_cache(maxsize=256)
def _channel_record(channel_id: int, topic: str, message_encoding: str, schema_id: int,
                    metadata: tuple[tuple[str, str], ...]) -> bytes:
    """A Channel record's bytes, serialised once per process."""
    rb = RecordBuilder()
    Channel(id=channel_id, topic=topic, message_encoding=message_encoding,
            schema_id=schema_id, metadata=dict(metadata)).write(rb)
    return rb.end()


def _address(a: NDArray[Any]) -> int:
    """The address of a C-contiguous array's data, for a ctypes call: a quarter of the cost of
    ``a.ctypes.data`` (which makes a helper object), where the array lends its buffer."""
    try:
        return ctypes.addressof(ctypes.c_char.from_buffer(a.data))
    except (TypeError, ValueError, BufferError):  # read-only, empty, or not contiguous
        return int(a.ctypes.data)


class _Scratch:
    """A thread's buffers for :meth:`_CRowEncoder.encode_chunk`: ``rows`` rows' records, their
    Message Index records, the quaternion's two columns and half-angles, and the addresses the
    C call takes."""

    def __init__(self, rows: int, row_max: int, n_topics: int) -> None:
        self.rows = rows
        self.out = np.empty(rows * row_max, np.uint8)
        self.index = np.empty(n_topics * (15 + 16 * rows), np.uint8)
        self.extra = np.empty(2 * rows, np.float64)
        self.half = np.empty(rows, np.float64)
        self.out_at, self.index_at, self.extra_at = (int(a.ctypes.data)
                                                     for a in (self.out, self.index, self.extra))


class _CRowEncoder:
    """:class:`RowEncoder`'s bytes, written by the C stepper (``wmr_encode_rows``) one row
    after another instead of by numpy gathers of whole columns.

    The derived source columns (the heading quaternion) are computed by numpy exactly as
    :class:`RowEncoder` computes them; the C code only places bytes.
    """

    def __init__(self, lib: Any, channel_ids: tuple[int, ...],
                 layouts: tuple[TopicLayout, ...]) -> None:
        self._fun = lib.wmr_encode_rows
        self._n_topics = len(layouts)
        i32 = np.int32
        self._channel = np.asarray(channel_ids, i32)
        self._body_len = np.asarray([len(t.body) for t in layouts], i32)
        self._bodies = np.frombuffer(b"".join(t.body for t in layouts), np.uint8).copy()
        self._n_slots = np.asarray([len(t.slots) for t in layouts], i32)
        self._slot_off = np.asarray([o for t in layouts for o, _ in t.slots] or [0], i32)
        self._slot_src = np.asarray([c for t in layouts for _, c in t.slots] or [0], i32)
        #: longest records of one row: header 33, timestamp 12, bodies
        self._row_max = int(self._body_len.sum()) + (33 + 12) * self._n_topics
        self._args = [a.ctypes.data for a in (self._channel, self._body_len, self._bodies,
                                              self._n_slots, self._slot_off, self._slot_src)]
        self._chunk_fun = lib.wmr_encode_chunk
        self._layout = Layout(len(SIGNALS), 2, self._n_topics, *self._args)
        self._layout_ref = ctypes.byref(self._layout)
        self._theta = COLUMN["theta_rad"]
        # a chunk's buffers, kept per thread (the encoder is shared by every log of a process,
        # and a Dask worker may run logs in several threads): new ones per chunk cost their
        # allocation and page faults each time
        self._buffers = threading.local()

    def encode_chunk(self, t_ns: NDArray[np.int64], block: NDArray[np.float64],
                     at: tuple[int, int] | None = None) -> tuple[memoryview, memoryview]:
        """A chunk's records (as :meth:`encode`) and its Message Index records, one per
        topic in topic order, as :mod:`mcap.records` packs them, in one C call.

        ``at``: the addresses of the data of ``t_ns`` and ``block`` when the caller knows
        them (C-contiguous int64 and float64: the log's staging buffers).  Both results are
        views of this thread's buffers: valid until its next call."""
        n = t_ns.shape[0]
        buf = self._scratch(n)
        # the heading quaternion as RowEncoder computes it (0.5 * theta, numpy's sin and
        # cos of a contiguous array), written in place: z then w, a column each
        half = np.multiply(block[:, self._theta], 0.5, out=buf.half[:n])
        np.sin(half, out=buf.extra[:n])
        np.cos(half, out=buf.extra[n:2 * n])
        if at is None:
            at = (_address(np.ascontiguousarray(t_ns, np.int64)),
                  _address(np.ascontiguousarray(block, np.float64)))
        size = self._chunk_fun(self._layout_ref, n, at[0], at[1], buf.extra_at, buf.out_at,
                               buf.index_at)
        if size < 0:  # more topics than the C encoder holds: never for STEP_TOPICS
            raise LogError(f"{self._n_topics} per-step topics: the C encoder takes at most 32")
        return buf.out[:size].data, buf.index[:self._n_topics * (15 + 16 * n)].data

    def _scratch(self, n: int) -> Any:
        """This thread's buffers for a chunk of ``n`` rows (and their addresses)."""
        buf = getattr(self._buffers, "chunk", None)
        if buf is None or buf.rows < n:
            buf = _Scratch(max(n, 2 * buf.rows if buf is not None else 128), self._row_max,
                           self._n_topics)
            self._buffers.chunk = buf
        return buf

    def encode(self, t_ns: NDArray[np.int64],
               block: NDArray[np.float64]) -> tuple[memoryview, NDArray[np.int64]]:
        """As :meth:`RowEncoder.encode`, the records in a view of the encoder's buffer
        rather than copied to bytes."""
        n = t_ns.shape[0]
        src = np.empty((n, N_SOURCES), np.float64)
        src[:, : len(SIGNALS)] = block
        half = 0.5 * block[:, COLUMN["theta_rad"]]
        src[:, SRC_QZ] = np.sin(half)
        src[:, SRC_QW] = np.cos(half)
        t = np.ascontiguousarray(t_ns, np.int64)
        out = np.empty(n * self._row_max, np.uint8)
        offsets = np.empty((n, self._n_topics), np.int64)
        size = self._fun(n, t.ctypes.data, src.ctypes.data, N_SOURCES, self._n_topics,
                         *self._args, out.ctypes.data, offsets.ctypes.data)
        return out[:size].data, offsets


def _row_encoder(channel_ids: tuple[int, ...],
                 layouts: tuple[TopicLayout, ...]) -> RowEncoder | _CRowEncoder:
    """The C row encoder when the stepper is there (and doubles are little-endian, as
    protobuf writes them), else numpy's: the same bytes.  The choice is made at each log's
    open, not once per process: a log opened before the stepper was built (a cold cache's
    first run) must not leave numpy's encoder to every later log of the process."""
    if sys.byteorder == "little":
        lib = load_stepper(build=False)
        if lib is not None:
            return _c_row_encoder(lib, channel_ids, layouts)
    return _numpy_row_encoder(channel_ids, layouts)


@functools.lru_cache(maxsize=16)  # an encoder holds no state of a log: one per layout
def _c_row_encoder(lib: Any, channel_ids: tuple[int, ...],
                   layouts: tuple[TopicLayout, ...]) -> _CRowEncoder:
    return _CRowEncoder(lib, channel_ids, layouts)


@functools.lru_cache(maxsize=16)
def _numpy_row_encoder(channel_ids: tuple[int, ...],
                       layouts: tuple[TopicLayout, ...]) -> RowEncoder:
    return RowEncoder(channel_ids, layouts)


#: ``json.dumps(value, sort_keys=True, allow_nan=True)`` without making an encoder a call (a
#: ``run`` record has some 20 values to encode)
_JSON: Final = json.JSONEncoder(sort_keys=True, allow_nan=True)
_JSON_FLOATS: Final = {math.inf: "Infinity", -math.inf: "-Infinity"}


def _as_str(value: object) -> str:
    """Metadata values are strings: keep strings, JSON-encode anything else (a float or an
    int as :mod:`json` writes it, without its encoder's passes)."""
    if isinstance(value, str):
        return value
    kind = type(value)
    if kind is float:
        number = cast(float, value)
        return (float.__repr__(number) if number - number == 0.0
                else "NaN" if number != number else _JSON_FLOATS[number])
    if kind is int:
        return int.__repr__(cast(int, value))
    try:
        return _JSON.encode(value)
    except (TypeError, ValueError) as exc:
        raise LogError(f"metadata value {value!r} is not JSON-serialisable: {exc}") from exc


def _str_dict(name: str, data: Mapping[str, object]) -> dict[str, str]:
    out: dict[str, str] = {}
    for key, value in data.items():
        if not isinstance(key, str):
            raise LogError(f"metadata record {name!r}: key {key!r} is not a string")
        out[key] = _as_str(value)
    return out


def yaw_quaternion(theta_rad: float) -> tuple[float, float, float, float]:
    """Unit quaternion ``(x, y, z, w)`` of a rotation by ``theta_rad`` about z."""
    return (0.0, 0.0, math.sin(0.5 * theta_rad), math.cos(0.5 * theta_rad))


def goal_message(x_m: float, y_m: float, theta_rad: float, t_ns: int = 0) -> bytes:
    """The ``/goal`` message: ``foxglove.PoseInFrame`` in frame ``world``.

    Parameters
    ----------
    x_m, y_m
        Goal position in the world frame, m.
    theta_rad
        Desired heading, rad.
    t_ns
        Timestamp, ns from run start.
    """
    msg = message_class(GOAL_SCHEMA)(frame_id=WORLD_FRAME)
    msg.timestamp.seconds, msg.timestamp.nanos = divmod(t_ns, 1_000_000_000)
    msg.pose.position.x = x_m
    msg.pose.position.y = y_m
    qx, qy, qz, qw = yaw_quaternion(theta_rad)
    q = msg.pose.orientation
    q.x, q.y, q.z, q.w = qx, qy, qz, qw
    return bytes(msg.SerializeToString(deterministic=True))


class _Topic(NamedTuple):
    """A topic of :meth:`RunLogWriter.write_messages`' arguments."""

    topic: str
    schema_name: str
    schema_data: bytes
    t_ns: ArrayLike
    messages: Sequence[bytes]
    schema_encoding: str
    message_encoding: str


class _Gathered:
    """A :class:`~wmr.adapters.mcap.schemas.MessageLog` that keeps the topics it is given,
    for the log writer to write them all as one chunk (the scene's and the note)."""

    def __init__(self) -> None:
        self.topics: list[_Topic] = []

    def write_messages(self, topic: str, schema_name: str, schema_data: bytes,
                       t_ns: ArrayLike, messages: Sequence[bytes], *,
                       schema_encoding: str = "protobuf",
                       message_encoding: str = "protobuf") -> None:
        self.topics.append(_Topic(topic, schema_name, schema_data, t_ns, messages,
                                  schema_encoding, message_encoding))


class RunLogWriter:
    """The MCAP log of one closed-loop run; a context manager.

    Topics, schemas and layout are described in :mod:`wmr.adapters.mcap`.  Rows given to
    :meth:`write_block` are buffered and written as one chunk per ``chunk_period_ns`` of
    simulation time (chunk boundaries at multiples of the period, so the bytes do not depend on
    how the caller batches rows).  Leaving the ``with`` block by an exception writes a
    ``result`` record with status ``failed`` and the error, and finishes the file.

    Parameters
    ----------
    path
        Output file.  Written as ``path + ".partial"`` (locked: a second writer to the same
        path is refused) and renamed over ``path`` once finished and fsynced, so that a killed
        run leaves the previous log at ``path`` whole and its own prefix in the ``.partial``
        file (readable; ``wmr log recover`` makes it a finished log).
    run
        The ``run`` metadata record: scenario, start, goal, params, gains, FMU hash, FMI version,
        software version, ...; string values are kept, others are JSON-encoded.
    goal
        ``(x_m, y_m, theta_rad)`` of the goal, logged once on ``/goal`` at t = 0.
    attachments
        Name -> ``(media_type, data)``, e.g. ``{"scenario.toml": ("application/toml", b"...")}``
        and ``{"modelDescription.xml": ("application/xml", b"...")}``.
    compression
        Chunk compression, ``"lz4"`` (default: half the CPU time of zstd), ``"zstd"`` (level
        1: a fifth fewer bytes; the logs' compression before) or ``""``.
    chunk_period_ns
        Simulation time per chunk, ns (default 1 s).
    topics
        The per-step topics: ``STEP_TOPICS`` (default) or ``OPEN_LOOP_TOPICS`` (no controller).
    durable
        fsync the finished log before its rename (default); off, a power loss (not a kill)
        may damage a finished log.
    scene
        Also write, when closed, the topics Rerun and Foxglove draw by themselves
        (:mod:`wmr.adapters.mcap.scene`; ``wmr run`` and ``wmr batch`` turn it on).
    scene_values
        ``(half_track_m, wheel_radius_m, stop_radius_m)`` the scene draws, typed (a
        :class:`~wmr.core.runlog.LogHeader`'s: :meth:`from_header`); ``None``: parsed from
        ``run``'s ``params`` and ``stop_radius_m``
        (:meth:`~wmr.adapters.mcap.scene.SceneRecorder.from_run_record`).
    location
        Where the log is kept once finished (:attr:`location`, the ``mcap`` field of the
        run's result record), when not ``path``: a log written under a name of its own and
        moved there after (a Dask worker's: two tries of a run never share a file).

    Raises
    ------
    LogError
        The file cannot be created or is being written by another process, or the metadata
        is not string-convertible.
    DiskFullError
        No space left on the device (from any method that writes).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        run: Mapping[str, object],
        goal: tuple[float, float, float],
        attachments: Mapping[str, tuple[str, bytes]] | None = None,
        compression: Compression = DEFAULT_COMPRESSION,
        chunk_period_ns: int = 1_000_000_000,
        topics: tuple[TopicLayout, ...] = STEP_TOPICS,
        durable: bool = True,
        scene: bool = False,
        scene_values: tuple[float, float, float | None] | None = None,
        location: str | os.PathLike[str] | None = None,
    ) -> None:
        self.path = os.fspath(path)
        self._location = self.path if location is None else os.fspath(location)
        if chunk_period_ns <= 0:
            raise LogError(f"chunk_period_ns must be positive, got {chunk_period_ns}")
        run_record = _str_dict("run", run)
        # committed by McapFile.finish, or abandoned
        stream = AtomicFile(self.path, "log", durable=durable)
        self._period = int(chunk_period_ns)
        # the rows given and not yet in a chunk: rows lo:hi (_span) of the staging buffers,
        # copied there from the caller's blocks.  What is pending changes only by one
        # assignment of _span (with what goes with it, on the same line: see _write_chunk), so
        # that no exception can leave a row in a chunk and pending both, nor a time without
        # its row
        self._t_buf = np.empty(_STAGE_ROWS, np.int64)
        self._x_buf = np.empty((_STAGE_ROWS, len(SIGNALS)), np.float64)
        self._spare: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None
        self._at = (int(self._t_buf.ctypes.data), int(self._x_buf.ctypes.data))  # their data
        self._span = (0, 0)
        self._last_t = -1
        self._boundary = self._period
        self._rows = 0
        self._closed = False
        # the schemas written by write_messages: (name, encoding, data) -> id
        self._schema_ids: dict[tuple[str, str, bytes], int] = {}
        try:
            self._file = McapFile(stream, compression)
            # the per-step topics' channels 1..n, then /goal's
            self._file.add_opening_records(*_opening_records(topics))
            channel_ids = tuple(range(1, len(topics) + 1))
            goal_channel = len(topics) + 1
            self._file.add_metadata("run", run_record)
            for name, (media_type, data) in (attachments or {}).items():
                self._file.add_attachment(name, media_type, bytes(data))
            self._encoder = _row_encoder(channel_ids, topics)
            self._in_c = isinstance(self._encoder, _CRowEncoder)
            controlled = topics == STEP_TOPICS
            self._scene = (None if not scene
                           else SceneRecorder.from_run_record(run, goal,
                                                              controlled=controlled)
                           if scene_values is None
                           else SceneRecorder(goal, half_track_m=scene_values[0],
                                              wheel_radius_m=scene_values[1],
                                              stop_radius_m=scene_values[2],
                                              controlled=controlled))
            self._channel_ids = channel_ids
            self._write_goal(goal_channel, goal)
        except BaseException:
            stream.close()
            raise

    @classmethod
    def from_header(cls, path: str | os.PathLike[str], header: LogHeader, *,
                    compression: Compression = DEFAULT_COMPRESSION,
                    chunk_period_ns: int = 1_000_000_000,
                    topics: tuple[TopicLayout, ...] = STEP_TOPICS, durable: bool = True,
                    scene: bool = True,
                    location: str | os.PathLike[str] | None = None) -> RunLogWriter:
        """The log of the run ``header`` describes, at ``path`` (the other parameters as
        the constructor's): its metadata, goal and attachments, and the scene's typed
        values."""
        return cls(path, run=header.run, goal=header.goal,
                   attachments=header.attachment_map(), compression=compression,
                   chunk_period_ns=chunk_period_ns, topics=topics, durable=durable,
                   scene=scene, scene_values=(header.half_track_m, header.wheel_radius_m,
                                              header.stop_radius_m), location=location)

    @property
    def location(self) -> str:
        """The log's final path (a :class:`~wmr.core.runlog.RunLog`'s location): ``path``,
        or the ``location`` it is moved to once finished."""
        return self._location

    # -- context manager ---------------------------------------------------------------------
    def __enter__(self) -> RunLogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._closed:
            return
        if exc is None:
            self.close(failed_result(None))
            return
        try:
            self.close(failed_result(exc))
        except Exception:  # never hide the run's own exception behind a logging one
            self._file.abort()

    # -- writing -----------------------------------------------------------------------------
    def _write_goal(self, channel: int, goal: tuple[float, float, float]) -> None:
        x, y, theta = (float(v) for v in goal)
        data = goal_message(x, y, theta)
        record = _MESSAGE_HEAD.pack(_OP_MESSAGE, 2 + 4 + 8 + 8 + len(data), channel, 0, 0, 0)
        zero = np.zeros(1, np.int64)
        self._file.add_chunk(record + data, {channel: (zero, zero)})

    @property
    def rows_written(self) -> int:
        """Rows given to :meth:`write_block` so far (buffered or on disk)."""
        lo, hi = self._span
        return self._rows + hi - lo

    def write_block(self, t_ns: ArrayLike, block: ArrayLike) -> None:
        """Log rows of the run: every per-step topic, one message per row.

        Parameters
        ----------
        t_ns
            Simulation time of each row, ns from run start, integer, shape ``(n,)``,
            non-negative and non-decreasing across calls.
        block
            Signal values, shape ``(n, len(SIGNALS))``, columns as in
            :data:`wmr.core.signals.SIGNALS`.  Copied: the caller may reuse its buffer.

        Raises
        ------
        LogError
            Wrong shape or dtype, time going backwards or negative, or the writer is closed.
        """
        if self._closed:
            raise LogError(f"{self.path}: write_block after close")
        t = np.asarray(t_ns)
        if t.ndim != 1 or t.dtype.kind not in "iu":
            raise LogError(f"t_ns must be a 1-D integer array of ns, got {t.dtype} {t.shape}")
        n = t.shape[0]
        x = np.asarray(block, dtype=np.float64)
        if x.shape != (n, len(SIGNALS)):
            raise LogError(f"block must have shape ({n}, {len(SIGNALS)}), got {x.shape}")
        if n == 0:
            return
        lo, hi = self._span
        if hi + n > self._t_buf.shape[0]:
            lo, hi = self._compact(n)
        # checked as stored (int64: a time past 2^63 - 1 is negative); taken only by the
        # assignment of the span below
        t = self._t_buf[hi:hi + n]
        t[:] = t_ns
        if t[0] < self._last_t or t[0] < 0 or (n > 1 and bool((t[1:] < t[:-1]).any())):
            raise LogError(
                f"t_ns must be non-negative and non-decreasing (got {t[0]} after {self._last_t})"
            )
        self._x_buf[hi:hi + n] = x
        self._span, self._last_t = (lo, hi + n), int(t[-1])
        if self._scene is not None:
            self._scene.add(t, x)
        if self._last_t >= self._boundary:
            self._flush_chunks(final=False)

    def _compact(self, n: int) -> tuple[int, int]:
        """Copy the pending rows to the front of the spare staging buffers (grown, when they
        cannot take ``n`` more rows, to half as much again as they then hold: a chunk of many
        blocks is copied a bounded number of times, one huge block costs half its size more)
        and make those the ones in use, in one assignment; return the new span."""
        lo, hi = self._span
        rows = hi - lo
        spare = self._spare
        if spare is None or spare[0].shape[0] < rows + n:
            size = max(self._t_buf.shape[0], rows + n + max(_STAGE_ROWS, (rows + n) // 2))
            spare = (np.empty(size, np.int64), np.empty((size, len(SIGNALS)), np.float64))
        spare[0][:rows] = self._t_buf[lo:hi]
        spare[1][:rows] = self._x_buf[lo:hi]
        self._t_buf, self._x_buf, self._spare, self._span, self._at = (
            spare[0], spare[1], (self._t_buf, self._x_buf), (0, rows),
            (int(spare[0].ctypes.data), int(spare[1].ctypes.data)))
        return 0, rows

    def write_messages(self, topic: str, schema_name: str, schema_data: bytes,
                       t_ns: ArrayLike, messages: Sequence[bytes], *,
                       schema_encoding: str = "protobuf",
                       message_encoding: str = "protobuf") -> None:
        """Log serialised protobuf ``messages`` on a topic of their own, as one chunk.

        For topics that are not one message per control step (sensor fixes, estimates: see
        :mod:`wmr.adapters.mcap.sensing`).  Call before :meth:`close`.

        Parameters
        ----------
        topic
            The new channel's topic (one call per topic).
        schema_name, schema_data
            Protobuf message name and its serialised ``FileDescriptorSet`` (a schema the log
            has already, by name, encoding and data, is not written again).
        t_ns
            Log time of each message, ns, non-decreasing, shape ``(len(messages),)``.
        messages
            The message bodies.
        schema_encoding, message_encoding
            The MCAP encodings of the schema and the messages (protobuf; the log's note to
            a viewer, :mod:`wmr.adapters.mcap.readme`, is ROS 2's ``ros2msg`` and ``cdr``).
        """
        if self._closed:
            raise LogError(f"{self.path}: write_messages after close")
        self._write_topics([_Topic(topic, schema_name, schema_data, t_ns, messages,
                                   schema_encoding, message_encoding)])

    def _write_topics(self, topics: Sequence[_Topic]) -> None:
        """Each of ``topics`` on a channel of its own (and its schema, unless the log has it),
        their messages all in one chunk (:meth:`McapFile.add_messages`); every topic's times
        are checked before anything is written."""
        times: list[list[int]] = []
        for topic in topics:
            t = np.asarray(topic.t_ns, dtype=np.int64)
            if t.shape != (len(topic.messages),) or (len(t) > 1 and bool(np.any(t[1:] < t[:-1]))):
                raise LogError(f"{topic.topic}: t_ns must be non-decreasing, one per message")
            times.append(t.tolist())
        messages: list[tuple[int, int, int, bytes]] = []
        for topic, t_list in zip(topics, times, strict=True):
            key = (topic.schema_name, topic.schema_encoding, topic.schema_data)
            schema_id = self._schema_ids.get(key)
            if schema_id is None:
                schema_id = self._schema_ids[key] = self._file.add_schema(
                    topic.schema_name, topic.schema_data, topic.schema_encoding)
            cid = self._file.add_channel(topic.topic, schema_id, topic.message_encoding)
            messages += [(t, cid, seq, data) for seq, (t, data)
                         in enumerate(zip(t_list, topic.messages, strict=True))]
        self._file.add_messages(messages)

    def write_sensing(self, record: SensingRecord) -> None:
        """Log the run's sensor fixes and estimates (:mod:`wmr.adapters.mcap.sensing`);
        call before :meth:`close`."""
        from wmr.adapters.mcap.sensing import write_sensing

        write_sensing(self, record)

    def _flush_chunks(self, final: bool) -> None:
        """Write the pending rows before the chunk boundary as chunks (and, ``final``, the
        last rows too), each from the staging buffers as they are (a view: no copy)."""
        while True:
            lo, hi = self._span
            if lo == hi:
                return
            t = self._t_buf[lo:hi]
            if t[-1] < self._boundary:
                if not final:
                    return  # the rows before the boundary may not all be here yet
                cut = hi
            else:
                cut = lo + int(t.searchsorted(self._boundary, side="left"))
            if cut > lo:
                self._write_chunk(lo, cut, hi)
            if cut < hi:
                self._boundary = (int(self._t_buf[cut]) // self._period + 1) * self._period

    def _write_chunk(self, lo: int, cut: int, hi: int) -> None:
        """Write the pending rows ``lo:cut`` as a chunk and leave ``cut:hi`` pending, as one
        step: an exception anywhere in it (a signal's ``KeyboardInterrupt`` between two
        bytecodes, a full disk) puts the rows back and cuts the file back to where the chunk
        began, so the rows are on disk once or pending, never both (``close`` would write
        them again) and never lost."""
        t, x = self._t_buf[lo:cut], self._x_buf[lo:cut]
        if self._in_c:
            t_at, x_at = self._at
            records, indexes = self._encoder.encode_chunk(  # type: ignore[union-attr]
                t, x, (t_at + 8 * lo, x_at + 8 * len(SIGNALS) * lo))
        else:
            records_, offsets = self._encoder.encode(t, x)
        before = self._span, self._rows
        mark = self._file.mark()
        try:
            # forgotten first, in the same try: whichever line an exception stops, the
            # handler below sees the whole step to undo
            self._span, self._rows = (cut, hi), self._rows + (cut - lo)
            if self._in_c:
                self._file.add_indexed_chunk(records, int(t[0]), int(t[-1]), indexes,
                                             _row_index_of(self._channel_ids, cut - lo))
            else:
                self._file.add_row_chunk(records_, t, offsets, self._channel_ids)
        except BaseException:
            self._span, self._rows = before
            self._file.rollback(mark)
            raise

    def close(self, result: Mapping[str, object]) -> None:
        """Write the buffered rows, the ``result`` metadata record, and finish the file.

        Parameters
        ----------
        result
            The fields of ``wmr run --json`` (``status``, ``final_position_error_m``, ...);
            string values are kept, others are JSON-encoded.
        """
        if self._closed:
            raise LogError(f"{self.path}: closed twice")
        # a stop signal now would leave the log of an ended run unfinished: it waits
        with stop_signals_held():
            drawn = _Gathered()
            if self._scene is not None:
                self._scene.write(drawn)  # the drawable topics (wmr.adapters.mcap.scene)
                # what to run to see the log as wmr's dashboard: Rerun shows it as a document
                write_readme(drawn)
            self._closed = True
            try:
                # the scene's topics and the note in one chunk: a chunk each cost a compression,
                # its CRCs, a write to the OS and its summary entries (five a log)
                self._write_topics(drawn.topics)
                self._flush_chunks(final=True)
                self._file.add_metadata("result", _str_dict("result", result))
                self._file.finish()
            except BaseException:
                self._file.abort()
                raise

    def discard(self, result: Mapping[str, object]) -> None:
        """Close the log and remove it: the run's log is not kept (a ``failed`` policy's
        run that converged after its rows were spilled to the file)."""
        self.close(result)
        os.unlink(self.path)


@dataclass(frozen=True)
class McapOpener:
    """The :data:`~wmr.core.runlog.LogOpener` of a run's MCAP log at ``path``: the one way
    ``wmr run``, ``wmr batch``, ``wmr benchmark``, ``wmr optimal`` and ``wmr ssp run`` open
    their logs (:meth:`RunLogWriter.from_header`).

    Attributes
    ----------
    path
        The log's final path (its folder is made when the log is opened).
    durable, scene, topics, compression
        As :class:`RunLogWriter`'s (``scene`` on by default: every run log draws).
    on_open
        Called with ``path`` once the log's ``.partial`` file is open (a supervising parent
        finishes it if the run's process dies: :mod:`wmr.apps.supervise`).
    location
        As :class:`RunLogWriter`'s: where the log is moved once finished, if not ``path``.
    """

    path: Path
    durable: bool = True
    scene: bool = True
    topics: tuple[TopicLayout, ...] = STEP_TOPICS
    compression: Compression = DEFAULT_COMPRESSION
    on_open: Callable[[Path], None] | None = None
    location: Path | None = None

    def __call__(self, header: LogHeader) -> RunLogWriter:
        path = Path(self.path)
        if not path.parent.is_dir():  # one stat, where mkdir's refusal raises and stats
            path.parent.mkdir(parents=True, exist_ok=True)
        log = RunLogWriter.from_header(path, header, compression=self.compression,
                                       topics=self.topics, durable=self.durable,
                                       scene=self.scene, location=self.location)
        if self.on_open is not None:
            self.on_open(path)
        return log


__all__ = ["LIBRARY", "McapFile", "McapOpener", "RunLogWriter", "goal_message",
           "metadata_record", "yaw_quaternion"]
