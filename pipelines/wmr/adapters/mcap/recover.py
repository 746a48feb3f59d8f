"""Rewrite a killed or damaged log as a finished, indexed MCAP file (``wmr log recover``).

A run killed before its log was finished leaves ``NAME.mcap.partial``: records up to its last
flushed chunk, no summary, no footer.  Our reader reads such a file, but other MCAP tools (the
``mcap`` library's seeking reader, Foxglove, Rerun) need the summary and the footer.  Recovery
reads every record that passes its checks (:func:`wmr.adapters.mcap.reader.scan_log`: chunk,
attachment, data section and summary CRCs) and writes them again with
:class:`wmr.adapters.mcap.writer.McapFile`: Schema, Channel, Metadata and Attachment records, each
intact chunk's Message records byte for byte (channel ids renumbered if needed), then the
summary.  A ``recovery`` Metadata record says what was read and what was lost.  The output is
written like every log (``.partial``, fsync, rename): recovery never damages a file either.

A killed run's log has no scene topics (``/scene/*``, ``/controller/phase``: the
:class:`~wmr.adapters.mcap.scene.SceneRecorder` writes them when the log is closed), so Rerun
and Foxglove would draw nothing of it.  For a log without a ``result`` record (the run did not
finish), recovery makes them from the rows the recovered log holds (:func:`_add_scene`), each
missing topic on a channel of its own, their messages in one chunk after the copied chunks
(as the log writer writes them at a close); the copied messages stay byte
for byte, and the ``recovery`` record lists the topics it made (``scene_added``).
"""

from __future__ import annotations

import fcntl
import itertools
import json
import os
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from wmr.adapters.mcap.reader import (
    MAX_LOG_TIME_NS,
    LogScan,
    ReadLimits,
    _LogFile,
    default_limits,
    open_log,
    read_chunk_at,
    scan_log,
)
from wmr.adapters.mcap.readme import README_TOPIC, write_readme
from wmr.adapters.mcap.scene import (
    GOAL_TOPIC,
    PATH_TOPIC,
    PHASE_TOPIC,
    ROBOT_TOPIC,
    SceneRecorder,
)
from wmr.adapters.mcap.schemas import TORQUE_TOPIC
from wmr.adapters.mcap.writer import McapFile, _str_dict
from wmr.infra.durable import PARTIAL_SUFFIX, AtomicFile, partial_path
from wmr.infra.errors import LogError

#: Name of the Metadata record that a recovered log carries.
RECOVERY_RECORD: Final = "recovery"
_MESSAGE: Final = 0x05
_HEAD = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQ")
#: The topics of :class:`wmr.adapters.mcap.scene.SceneRecorder` and the log's note
#: (:mod:`wmr.adapters.mcap.readme`), all written when a log is closed (made by recovery if
#: missing).
SCENE_TOPICS: Final = (GOAL_TOPIC, PATH_TOPIC, ROBOT_TOPIC, PHASE_TOPIC, README_TOPIC)
#: Smallest chunk recovery writes when the source's chunks are smaller (mcap's default size).
_CHUNK_BYTES: Final = 1 << 20


@dataclass
class Recovery:
    """What :func:`recover_log` did.

    Attributes
    ----------
    source, output
        The file read and the file written.
    messages
        Messages written.
    chunks
        Chunks written.
    dropped_messages
        Messages left out because their channel or schema was lost.
    lost
        What could not be kept, one line each (the reader's warnings and the drops).
    scene_added
        The scene topics made from the recovered rows (those the source lacked).
    """

    source: Path
    output: Path
    messages: int = 0
    chunks: int = 0
    dropped_messages: int = 0
    lost: list[str] = field(default_factory=list)
    scene_added: list[str] = field(default_factory=list)


def default_output(source: str | os.PathLike[str]) -> Path:
    """``X.mcap`` and ``X.mcap.partial`` recover to ``X.recovered.mcap``."""
    name = Path(source).name
    if name.endswith(PARTIAL_SUFFIX):
        name = name[: -len(PARTIAL_SUFFIX)]
    stem = name[: -len(".mcap")] if name.endswith(".mcap") else name
    return Path(source).with_name(f"{stem}.recovered.mcap")


def _messages(buf: bytes) -> list[tuple[int, int, bytes]]:
    """``(channel id, log time, whole record)`` of the Message records of a checked chunk."""
    out: list[tuple[int, int, bytes]] = []
    pos, end = 0, len(buf)
    while pos < end:
        opcode, length = _HEAD.unpack_from(buf, pos)
        nxt = pos + 9 + length
        if opcode == _MESSAGE:
            cid, _, log_time = _MSG.unpack_from(buf, pos + 9)
            out.append((cid, log_time, buf[pos:nxt]))
        pos = nxt
    return out


def recover_log(source: str | os.PathLike[str], output: str | os.PathLike[str] | None = None,
                *, overwrite: bool = False, limits: ReadLimits | None = None,
                scene: bool = True, result: Mapping[str, object] | None = None) -> Recovery:
    """Write what is intact in ``source`` as a finished MCAP log at ``output``.

    Parameters
    ----------
    source
        A log, finished or not, damaged or not (``X.mcap``, ``X.mcap.partial``).
    output
        Where to write (default :func:`default_output`); never ``source`` itself.
    overwrite
        Replace ``output`` if it exists.
    limits
        How much the source may make the reader hold (see
        :class:`wmr.adapters.mcap.reader.ReadLimits`; default
        :func:`wmr.adapters.mcap.reader.default_limits`).
    scene
        Make the scene topics an unfinished source (no ``result`` record: a killed run)
        lacks from the rows it holds; off, the output holds exactly the source's intact
        messages.
    result
        The ``result`` record to give a source that has none (a run whose process died:
        :mod:`wmr.apps.supervise`), written as the log writer writes it.

    Returns
    -------
    Recovery
        Counts and what was lost.

    Raises
    ------
    LogError
        ``source`` is missing (naming ``X.mcap.partial`` when a killed run left one), not a
        regular file (a FIFO, a device, a folder), not MCAP, or locked by the run still
        writing it; ``output`` exists (without ``overwrite``) or is the source, or cannot be
        written.
    """
    src = Path(source)
    dst = Path(output) if output is not None else default_output(src)
    limits = default_limits() if limits is None else limits
    with open_log(str(src)) as log:
        # a live run holds an exclusive lock on its X.mcap.partial (wmr.infra.durable): its
        # log is still growing, and renaming it would strand the run's own commit
        try:
            fcntl.flock(log.fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            raise LogError(f"{src}: a run is still writing this log (the file is locked); "
                           "wait for it to finish, or stop it first") from None
        if dst.exists() and os.path.samefile(src, dst):
            raise LogError(f"{dst}: the recovered log cannot replace its source; give another "
                           "output file")
        if dst.exists() and not overwrite:
            raise LogError(f"{dst}: exists; give another output file or allow overwriting "
                           "(--force)")
        if partial_path(dst).exists() and os.path.samefile(src, partial_path(dst)):
            # X.mcap.partial -> X.mcap: the writer of X.mcap would empty its own source first;
            # the source is kept, renamed (still locked by us: no run can take it meanwhile)
            aside = src.with_name(src.name + ".recovering")
            os.replace(src, aside)
            src = aside
        scan = scan_log(log, limits, keep_chunks=True)
        rec = Recovery(source=src, output=dst)
        _write(scan, log, src, rec, limits if scene else None, result)
    return rec


class _SceneSink:
    """The log writer's ``write_messages`` (what :class:`SceneRecorder` needs) on the recovered
    file, for the topics in ``missing`` only: their messages in one chunk at :meth:`finish`."""

    def __init__(self, file: McapFile, missing: set[str], rec: Recovery) -> None:
        self._file = file
        self._missing = missing
        self._rec = rec
        self._schemas: dict[tuple[str, bytes], int] = {}  # the clouds share one schema
        self._messages: list[tuple[int, int, int, bytes]] = []  # until finish()

    def write_messages(self, topic: str, schema_name: str, schema_data: bytes,
                       t_ns: npt.ArrayLike, messages: Sequence[bytes], *,
                       schema_encoding: str = "protobuf",
                       message_encoding: str = "protobuf") -> None:
        if topic not in self._missing or not messages:
            return
        key = (schema_name, schema_data)
        if key not in self._schemas:
            self._schemas[key] = self._file.add_schema(schema_name, schema_data,
                                                       schema_encoding)
        cid = self._file.add_channel(topic, self._schemas[key], message_encoding)
        self._messages += [(t, cid, seq, data) for seq, (t, data)
                           in enumerate(zip(np.asarray(t_ns, np.int64).tolist(), messages,
                                            strict=True))]
        self._rec.scene_added.append(topic)

    def finish(self) -> None:
        """Write the topics' messages, all in one chunk (as the log writer writes them)."""
        if self._messages:
            self._file.add_messages(self._messages)
            self._rec.chunks += 1
            self._rec.messages += len(self._messages)
            self._messages = []


def _add_scene(file: McapFile, src: Path, scan: LogScan, limits: ReadLimits,
               rec: Recovery) -> None:
    """Write the scene topics ``scan`` lacks, made from the rows of ``src`` that recovery kept
    (read again by :func:`wmr.adapters.mcap.reader.read_run`: the same checks, so the same
    rows), when the run did not finish (no ``result`` record); nothing without rows or a
    ``run`` record."""
    from wmr.adapters.mcap.reader import read_run

    topics = {c.topic for c in scan.channels.values()}
    missing = set(SCENE_TOPICS) - topics
    # a finished log without them was written without a scene on purpose
    # (RunLogWriter(scene=False)); a killed run never reached the close that writes them
    if not missing or "result" in scan.metadata or "run" not in scan.metadata:
        return
    run = read_run(src, limits)
    if not run.n_steps:
        return
    if run.goal is None:  # no goal to draw: the path and the robot all the same
        missing.discard(GOAL_TOPIC)
    goal = run.goal or (0.0, 0.0, 0.0)
    # the file has only the run record's strings: parsed in the scene's one place
    recorder = SceneRecorder.from_run_record(run.metadata["run"], (goal[0], goal[1], goal[2]),
                                             controlled=TORQUE_TOPIC.topic not in topics)
    recorder.add(run.t_ns, run.block())
    sink = _SceneSink(file, missing, rec)
    recorder.write(sink)
    write_readme(sink)
    sink.finish()


def _write(scan: LogScan, log: _LogFile, src: Path, rec: Recovery,
           scene_limits: ReadLimits | None, result: Mapping[str, object] | None = None
           ) -> None:
    """Write what ``scan`` kept of ``log`` to ``rec.output`` as a finished log (its good
    chunks read again one at a time); on failure nothing stays."""
    src_bytes = log.size
    rec.lost = list(scan.warnings)
    if "result" not in scan.metadata:
        rec.lost.append("no 'result' metadata record: the run did not finish")
    late = sum(scan.bad_times.values())
    sink = AtomicFile(rec.output, "log")
    file = McapFile(sink)
    try:
        schema_ids = {0: 0}
        for old in sorted(scan.schemas):
            s = scan.schemas[old]
            schema_ids[old] = file.add_schema(s.name, s.data, s.encoding)
        channel_ids: dict[int, int] = {}
        for old in sorted(scan.channels):
            c = scan.channels[old]
            if c.schema_id not in schema_ids:
                rec.lost.append(f"channel {c.topic!r}: its schema {c.schema_id} is lost; "
                                "its messages are left out")
                continue
            channel_ids[old] = file.add_channel(c.topic, schema_ids[c.schema_id],
                                                c.message_encoding, c.metadata)
        for name, data in scan.metadata.items():
            file.add_metadata(name, data)
        for name, blob in scan.attachments.items():
            file.add_attachment(name, scan.media_types[name], blob)

        loose = [(m.channel_id, m.log_time, _loose_record(m)) for m in scan.loose]
        # consecutive small chunks are merged up to _CHUNK_BYTES: a source of a million tiny
        # chunks gives a file of a few, not a million chunk records and indexes
        pending: list[tuple[int, int, bytes]] = []
        pending_bytes = 0
        chunks = (_messages(read_chunk_at(log, offset, length, scan.limits))
                  for offset, length in scan.chunks)
        for messages in itertools.chain(chunks, [loose, None]):
            if messages is None or (pending and pending_bytes >= _CHUNK_BYTES):
                if pending:
                    _write_chunk(file, pending)
                    rec.chunks += 1
                    rec.messages += len(pending)
                pending, pending_bytes = [], 0
                if messages is None:
                    break
            kept = [(channel_ids[c], t, r) for c, t, r in messages
                    if c in channel_ids and t <= MAX_LOG_TIME_NS]
            late += sum(1 for _, t, _ in messages if t > MAX_LOG_TIME_NS)
            rec.dropped_messages += sum(1 for c, t, _ in messages
                                        if c not in channel_ids and t <= MAX_LOG_TIME_NS)
            pending += kept
            pending_bytes += sum(len(r) for _, _, r in kept)
        if scene_limits is not None:
            _add_scene(file, src, scan, scene_limits, rec)
        if result is not None and "result" not in scan.metadata:
            file.add_metadata("result", _str_dict("result", result))
        if rec.dropped_messages:
            rec.lost.append(f"{rec.dropped_messages} messages of lost channels left out")
        if late:
            rec.lost.append(f"{late} messages with log times beyond 2^63-1 ns (after the year "
                            "2262) left out")
        file.add_metadata(RECOVERY_RECORD, {
            "source": src.name,
            "source_bytes": str(src_bytes),
            "source_finished": json.dumps(scan.complete and not scan.damaged),
            "messages": str(rec.messages),
            "chunks": str(rec.chunks),
            "lost": json.dumps(rec.lost),
            "scene_added": json.dumps(rec.scene_added),
        })
        file.finish()
    except BaseException:
        # a half-written recovery is worth nothing: remove it while still holding its lock
        sink.partial.unlink(missing_ok=True)
        file.abort()
        raise


def _loose_record(message: object) -> bytes:
    from mcap.data_stream import RecordBuilder

    rb = RecordBuilder()
    message.write(rb)  # type: ignore[attr-defined]
    return bytes(rb.end())


def _write_chunk(file: McapFile, messages: list[tuple[int, int, bytes]]) -> None:
    """One chunk of whole Message records, sorted by log time, with their indexes."""
    messages.sort(key=lambda m: m[1])  # stable: keeps the order of equal times
    parts: list[bytes] = []
    index: dict[int, tuple[list[int], list[int]]] = {}
    pos = 0
    for cid, log_time, record in messages:
        if record[9:11] != struct.pack("<H", cid):  # renumbered channel
            record = record[:9] + struct.pack("<H", cid) + record[11:]
        times, offsets = index.setdefault(cid, ([], []))
        times.append(log_time)
        offsets.append(pos)
        parts.append(record)
        pos += len(record)
    file.add_chunk(b"".join(parts), {cid: (np.array(t, np.int64), np.array(o, np.int64))
                                     for cid, (t, o) in index.items()})


__all__ = ["RECOVERY_RECORD", "SCENE_TOPICS", "Recovery", "default_output", "recover_log"]
