"""The journal of a batch (``OUT/journal.jsonl``) and the test of a finished log.

The parent process appends one JSON line per finished run to a file opened with ``O_APPEND``
(a short write is continued until every byte is written): a batch killed at any moment leaves
whole lines, plus at most one cut line, which the reader ignores.

A line (:func:`compact_line`, about 90 bytes) holds the run's id, its status, a digest of its
inputs and of the FMU (:func:`run_digest`) and a seal: a CRC-32 of the line and of the run's
result columns in the summary (:func:`row_bytes`).  The results themselves are in the
columnar files only (``.parts`` and ``summary.parquet``): a run counts as done when its line
matches its inputs and its FMU, a summary row of it matches the seal, and its log, if it kept
one, ends with a ``result`` metadata record (or the executor killed it).  Lines of older
batches held the whole result record (``record``, sealed by :func:`line_check`): they are read
as they always were.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import string
import zlib
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from wmr.adapters.mcap.reader import finished_result, log_finished, log_stamp
from wmr.adapters.mcap.schemas import MAGIC
from wmr.infra.durable import open_own, write_all

JOURNAL = "journal.jsonl"
#: Longest journal line read, in bytes (a line is about 1.5 kB): a longer one is skipped
#: unread, whatever a hand or a disk put there.
MAX_LINE_BYTES = 1 << 20
#: Longest run id taken (``NNNN-hhhhhhhh``): a 5,000-digit one is not a run of any spec.
MAX_RUN_ID_CHARS = 64
#: What a compact line's seal is made of (:func:`compact_line` writes lower case).
_HEX_DIGITS = frozenset(string.hexdigits)
#: Record fields the log's ``result`` metadata keeps as text (the others are JSON).
_TEXT_FIELDS = frozenset(("name", "status", "message", "mcap"))


class WallClockLimit(Exception):
    """Raised from a run's progress callback when it passes its wall-clock limit
    (:func:`wmr.apps.batch.worker.execute`); here, where a record made again from a log maps
    it to ``timeout``, so that the workers, which write journal lines, import this module and
    not the other way round."""


def line_check(row: Mapping[str, Any]) -> str:
    """The seal of a journal line: a hash of everything else in it.  A line edited by hand
    (or damaged) without it being recomputed is verified against the spec and its log."""
    body = {k: v for k, v in row.items() if k != "check"}
    return hashlib.sha256(json.dumps(body, sort_keys=True, allow_nan=False,
                                     separators=(",", ":")).encode()).hexdigest()[:32]


#: Hex digits of a compact line's digest (:func:`run_digest`): 64 bits.
DIGEST_CHARS = 16


def run_digest(spec_digest: str, fmu_sha256: str) -> str:
    """What a compact journal line keeps of a run's inputs and FMU: a hash of both (the
    resume compares it with the spec's run and the FMU of the batch)."""
    return hashlib.sha256(f"{spec_digest}|{fmu_sha256}".encode()).hexdigest()[:DIGEST_CHARS]


def row_bytes(values: Mapping[str, Any]) -> bytes:
    """A summary row's result columns (name -> value) as the seal hashes them: canonical JSON
    (sorted keys, no spaces; floats as their shortest exact decimal, so a row read back from
    Parquet hashes as the worker's did)."""
    return json.dumps(values, sort_keys=True, allow_nan=False, separators=(",", ":")).encode()


def _body(run_id: str, status: str, digest: str, killed: bool) -> dict[str, Any]:
    body: dict[str, Any] = {"run_id": run_id, "status": status, "digest": digest}
    if killed:
        body["killed"] = True
    return body


def body_crc(line: Mapping[str, Any]) -> int:
    """The CRC-32 of a compact line without its seal (the seal goes on over the row)."""
    body = _body(str(line["run_id"]), str(line["status"]), str(line["digest"]),
                 bool(line.get("killed")))
    return zlib.crc32(json.dumps(body, separators=(",", ":")).encode())


def compact_line(run_id: str, status: str, digest: str, row: Mapping[str, Any],
                 killed: bool = False) -> bytes:
    """A run's journal line, with its newline: id, status, :func:`run_digest`, ``killed``
    only when its executor stopped it, and ``seal``, the CRC-32 (8 hex digits) of the rest
    and of ``row``, the run's result columns in the summary (:func:`row_bytes`)."""
    body = _body(run_id, status, digest, killed)
    seal = zlib.crc32(row_bytes(row), zlib.crc32(json.dumps(body, separators=(",", ":"))
                                                 .encode()))
    return (json.dumps({**body, "seal": f"{seal:08x}"}, separators=(",", ":")) + "\n").encode()


def is_compact(line: Mapping[str, Any]) -> bool:
    """Whether ``line`` is a compact line (:func:`compact_line`), not one of an older batch."""
    return "seal" in line


def logged_record(path: Path) -> dict[str, Any] | None:
    """The result record a batch journals for the run logged at ``path``, made again from the
    log's ``result`` metadata record (:func:`wmr.adapters.mcap.reader.finished_result`);
    ``None`` if the log is missing, unfinished or damaged.

    A run stopped by its wall-clock limit is logged ``failed`` with the ``WallClockLimit``
    error (it was stopped from outside the loop) and journalled ``timeout``
    (:func:`wmr.apps.batch.worker.execute`): the same mapping is made here.
    """
    meta = finished_result(path)
    if meta is None:
        return None
    record: dict[str, Any] = {}
    for key, text in meta.items():
        try:
            record[key] = text if key in _TEXT_FIELDS else json.loads(text)
        except ValueError:
            return None
    message = str(record.get("message", ""))
    if record.get("status") == "failed" and message.startswith(WallClockLimit.__name__):
        record["status"] = "timeout"
        record["message"] = message.partition(": ")[2]
    record["mcap"] = str(path)
    return record


def log_complete(path: Path, stamp: Mapping[str, Any] | None = None) -> bool:
    """Whether ``path`` is a finished MCAP log with a ``result`` metadata record: the MCAP
    adapter's :func:`~wmr.adapters.mcap.reader.log_finished`, trusting a log whose
    :func:`log_stamp` is the ``stamp`` journalled when the run finished."""
    return log_finished(path, stamp)


def log_ends_whole(path: Path) -> bool:
    """Whether the file at ``path`` (a link is not followed) ends with the MCAP magic: what a
    compact journal line's run needs of its log (a stat and an 8-byte read, about 20 µs).  A
    log cut, or zeroed in place by a crash before its data reached the disk, does not; its
    result itself is in the summary row, which the line's seal covers."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        size = os.fstat(fd).st_size
        return size >= 2 * len(MAGIC) and os.pread(fd, len(MAGIC), size - len(MAGIC)) == MAGIC
    except OSError:
        return False
    finally:
        os.close(fd)


def sealed_line(row: Mapping[str, Any]) -> bytes:
    """``row`` as a journal line: sealed (:func:`line_check`), JSON on one line, with its
    newline.  A batch's workers make the lines of their runs, the parent writes them."""
    sealed = {**row, "check": line_check(row)}
    return (json.dumps(sealed, allow_nan=False, separators=(",", ":")) + "\n").encode()


class Journal:
    """Append-only record of finished runs.

    Parameters
    ----------
    path
        The ``journal.jsonl`` file (created on first append).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._checked = False
        #: the file, open for appending from the first append to :meth:`close` (a batch
        #: appends once per range: an open, fstat and close each time cost more than the
        #: write), and its size (the batch folder's lock makes this the only writer)
        self._fd: int | None = None
        self._size = 0

    def scan(self) -> Iterator[tuple[int, dict[str, Any]]]:
        """Each well-formed line, with the byte offset where it starts, in file order; cut or
        garbled lines are skipped.  One line in memory at a time."""
        try:
            stream = open(self.path, "rb")
        except FileNotFoundError:
            return
        with stream:
            offset = 0
            while line := stream.readline(MAX_LINE_BYTES + 1):
                start, offset = offset, offset + len(line)
                if len(line) > MAX_LINE_BYTES:  # skip the rest of an overlong line unread
                    while line and not line.endswith(b"\n"):
                        line = stream.readline(MAX_LINE_BYTES)
                        offset += len(line)
                    continue
                row = _parse(line)
                if row is not None:
                    yield start, row

    def read_at(self, offsets: Iterable[int]) -> Iterator[dict[str, Any]]:
        """The lines starting at ``offsets`` (from :meth:`scan` or :meth:`append`).

        Raises
        ------
        ValueError
            No well-formed line starts at an offset (the file changed under the batch).
        """
        pending = iter(offsets)
        first = next(pending, None)
        if first is None:  # no line asked for: a batch stopped before its first run has none
            return
        with open(self.path, "rb") as stream:
            for offset in itertools.chain([first], pending):
                stream.seek(offset)
                row = _parse(stream.readline(MAX_LINE_BYTES + 1))
                if row is None:
                    raise ValueError(f"{self.path}: no journal line at byte {offset}")
                yield row

    def load(self) -> dict[str, dict[str, Any]]:
        """Rows by run id; the last whole line of an id wins, cut or garbled lines are skipped."""
        return {row["run_id"]: row for _, row in self.scan()}

    def append(self, row: Mapping[str, Any]) -> int:
        """Append ``row`` as one line, sealed (:func:`line_check`; a short write is continued,
        a full disk raises :class:`~wmr.infra.errors.DiskFullError`); return the byte offset
        where it starts (the batch folder's lock makes the parent the only writer)."""
        return self.append_lines(sealed_line(row))

    def append_lines(self, data: bytes) -> int:
        """Append whole lines (:func:`sealed_line` each, a range's in one write: a batch's
        parent writes once per range, not per run); return the byte offset where the first
        starts.  The file stays open until :meth:`close`."""
        if self._fd is None:
            fd = open_own(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, "batch journal")
            try:
                size = os.fstat(fd).st_size
                # a line that a previous batch cut short must not swallow this one
                if not self._checked:
                    if size and not self._ends_with_newline():
                        write_all(fd, b"\n", self.path)
                        size += 1
                    # only once mended: a full disk here leaves the next append to mend it
                    self._checked = True
            except BaseException:
                os.close(fd)
                raise
            self._fd, self._size = fd, size
        try:
            write_all(self._fd, data, self.path)  # os.write may write less than asked: loop
        except BaseException:  # a part may be written: the next append looks at the file
            self.close()
            raise
        start, self._size = self._size, self._size + len(data)
        return start

    def close(self) -> None:
        """Close the file (appended to since the first append); the next append opens it."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)

    def __del__(self) -> None:
        self.close()

    def _ends_with_newline(self) -> bool:
        with open(self.path, "rb") as f:
            f.seek(-1, os.SEEK_END)
            return f.read(1) == b"\n"


def _parse(line: bytes) -> dict[str, Any] | None:
    """A journal line's row, ``None`` if the line is cut, garbled or not a row."""
    if not line.strip() or len(line) > MAX_LINE_BYTES:
        return None
    try:
        row = json.loads(line)
    except (ValueError, RecursionError):  # garbled, or nested deeper than Python recurses
        return None
    if not isinstance(row, dict) or not isinstance(row.get("run_id"), str) \
            or len(row["run_id"]) > MAX_RUN_ID_CHARS:
        return None
    if isinstance(row.get("record"), dict):  # a line of an older batch: the whole record
        return row
    if all(isinstance(row.get(k), str) for k in ("status", "digest", "seal")) \
            and len(row["seal"]) == 8 and len(row["digest"]) == DIGEST_CHARS:
        # hex digits only: int(seal, 16) also takes a sign, spaces and '_', and a negative
        # seal stopped the resume (its array of seals holds unsigned ints)
        return row if _HEX_DIGITS.issuperset(row["seal"]) else None
    return None


__all__ = ["DIGEST_CHARS", "JOURNAL", "Journal", "WallClockLimit", "body_crc", "compact_line",
           "is_compact", "line_check", "log_complete", "log_ends_whole", "log_stamp",
           "logged_record", "row_bytes", "run_digest", "sealed_line"]
