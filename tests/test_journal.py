"""The batch journal (``wmr.apps.batch.journal``) against bytes written by hand.

Each test checks a promise of docs/batch.md ("Resume"), docs/reliability.md ("Journal lines
are verified, not trusted") or a docstring of the module against a fact made here, not by
the module: journal bytes and offsets counted by hand, a journal cut or edited on disk, MCAP
logs written with the ``mcap`` library's own writer, a file's size and time set with
``os.utime``.  They are fast (no batch is run) and are the journal's mutation tests
(``tools/mutation.py batch_journal``, docs/testing.md).
"""

from __future__ import annotations

import hashlib
import json
import os
import tracemalloc
from pathlib import Path
from typing import Any

import pytest
from mcap.writer import Writer

from wmr.apps.batch.journal import (
    MAX_LINE_BYTES,
    MAX_RUN_ID_CHARS,
    Journal,
    line_check,
    log_complete,
    log_ends_whole,
    log_stamp,
    logged_record,
)

#: The MCAP magic, from the MCAP specification (not from wmr's schemas module).
MCAP_MAGIC = b"\x89MCAP0\r\n"


def _line(run_id: str, **extra: Any) -> bytes:
    """One journal line, as a hand or another tool would write it (unsealed)."""
    return (json.dumps({"run_id": run_id, "record": {"status": "converged"}, **extra})
            + "\n").encode()


def _padded_line(run_id: str, n_bytes: int, pad: str = " ") -> bytes:
    """A well-formed line of exactly ``n_bytes`` bytes (newline included), padded inside the
    JSON with spaces (or a string of ``pad``, for characters of more than one byte)."""
    head = _line(run_id)[:-1]
    if pad == " ":
        body = head + b" " * (n_bytes - len(head) - 1)
    else:
        stub = head[:-1] + b', "pad": ""}'
        per = len(pad.encode())
        n_pad, rest = divmod(n_bytes - len(stub) - 1, per)
        body = stub[:-2] + pad.encode() * n_pad + b'"}' + b" " * rest
    line = body + b"\n"
    assert len(line) == n_bytes and json.loads(line)["run_id"] == run_id
    return line


def _log(path: Path, result: dict[str, str] | None, *, finish: bool = True) -> Path:
    """An MCAP log by the ``mcap`` library's own writer, with a ``result`` metadata record
    (or none); ``finish=False`` leaves it without its footer (a killed writer)."""
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="test_journal")
        if result is not None:
            writer.add_metadata("result", result)
        if finish:
            writer.finish()
        else:
            stream.flush()
    return path


# -- log_stamp ---------------------------------------------------------------------------------

def test_a_log_stamp_is_the_size_and_the_nanosecond_time_of_the_file(tmp_path: Path) -> None:
    """docs/batch.md: a journal line keeps its log's size and time (``log``); the resume
    compares them with the log's own: the keys are the journal's format."""
    path = tmp_path / "run.mcap"
    path.write_bytes(b"x" * 1234)
    mtime_ns = 1_700_000_000_123_456_789
    os.utime(path, ns=(mtime_ns, mtime_ns))
    assert log_stamp(path) == {"size": 1234, "mtime_ns": mtime_ns}
    assert log_stamp(tmp_path / "missing.mcap") is None


# -- line_check --------------------------------------------------------------------------------

def test_the_seal_is_a_hash_of_the_rest_of_the_line_in_key_order(tmp_path: Path) -> None:
    """docs/reliability.md: each line is sealed with a hash of the rest of it.  The hash of a
    journal written before must stay the same: the canonical form (sorted keys, no spaces) and
    its SHA-256 are written out here by hand."""
    row = {"run_id": "0001-abc", "record": {"status": "converged", "t_s": 1.5}, "n": 3}
    canonical = b'{"n":3,"record":{"status":"converged","t_s":1.5},"run_id":"0001-abc"}'
    expected = hashlib.sha256(canonical).hexdigest()[:32]
    assert line_check(row) == expected
    # the seal itself is not part of what it seals; key order does not matter
    assert line_check({**row, "check": "anything"}) == expected
    assert line_check(dict(reversed(list(row.items())))) == expected
    with pytest.raises(ValueError):  # NaN is not JSON: never sealed as if it were
        line_check({**row, "n": float("nan")})


# -- Journal.append ----------------------------------------------------------------------------

def test_append_writes_sealed_lines_and_returns_where_each_starts(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    journal = Journal(path)
    rows = [{"run_id": f"000{i}-x", "record": {"status": "converged", "i": i}} for i in range(3)]
    offsets = [journal.append(row) for row in rows]
    data = path.read_bytes()
    lines = data.splitlines(keepends=True)
    assert len(lines) == 3 and data.endswith(b"\n")
    assert offsets == [0, len(lines[0]), len(lines[0]) + len(lines[1])]
    for row, line in zip(rows, lines, strict=True):
        written = json.loads(line)
        assert written == {**row, "check": line_check(row)}
        assert b" " not in line  # compact: about 1.5 kB a line, not more
    assert list(journal.read_at(offsets)) == [json.loads(x) for x in lines]


def test_append_after_a_cut_line_starts_a_new_line(tmp_path: Path) -> None:
    """A batch killed mid-write leaves a cut last line; the next batch's first line must not
    be glued to it (docs/batch.md: cut journal lines are redone, whole lines kept)."""
    path = tmp_path / "journal.jsonl"
    whole = _line("0000-a")
    cut = _line("0001-b")[:25]
    path.write_bytes(whole + cut)
    journal = Journal(path)
    offset = journal.append({"run_id": "0002-c", "record": {"status": "converged"}})
    data = path.read_bytes()
    assert offset == len(whole) + len(cut) + 1  # after the cut line and its new newline
    assert data[:offset] == whole + cut + b"\n"
    assert [row["run_id"] for _, row in journal.scan()] == ["0000-a", "0002-c"]
    assert next(journal.read_at([offset]))["run_id"] == "0002-c"
    # only once: the next line follows directly
    second = journal.append({"run_id": "0003-d", "record": {}})
    assert second == len(path.read_bytes()) - len(path.read_bytes().splitlines(True)[-1])
    assert path.read_bytes()[offset:].count(b"\n") == 2


def test_append_to_a_journal_ending_with_a_newline_adds_none(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    whole = _line("0000-a") + _line("0001-b")
    path.write_bytes(whole)
    offset = Journal(path).append({"run_id": "0002-c", "record": {}})
    assert offset == len(whole)
    assert path.read_bytes().startswith(whole) and b"\n\n" not in path.read_bytes()


def test_append_to_an_empty_journal_starts_at_byte_0(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    path.write_bytes(b"")
    assert Journal(path).append({"run_id": "0000-a", "record": {}}) == 0
    assert path.read_bytes().startswith(b"{")


# -- Journal.scan and load ---------------------------------------------------------------------

def test_scan_gives_each_whole_line_with_its_byte_offset(tmp_path: Path) -> None:
    """Cut, garbled, overlong and not-a-row lines are skipped; the others keep the offsets
    counted here by hand, past the skipped ones."""
    good = [_line("0000-a"), _line("0001-b", extra="é"), _line("0002-c")]
    overlong = _padded_line("0009-z", MAX_LINE_BYTES + 1)
    garbled = b'{"run_id": "0005-x", "record": {\n'
    not_rows = [b"[1, 2]\n", b'{"run_id": 5, "record": {}}\n', b'{"run_id": "x", "record": 1}\n',
                b"\n", b"   \n"]
    parts = [good[0], garbled, overlong, *not_rows, good[1], good[2], _line("0003-d")[:10]]
    path = tmp_path / "journal.jsonl"
    path.write_bytes(b"".join(parts))
    starts = [sum(len(p) for p in parts[:i]) for i in range(len(parts))]
    scanned = list(Journal(path).scan())
    assert [(off, row["run_id"]) for off, row in scanned] == [
        (starts[0], "0000-a"), (starts[8], "0001-b"), (starts[9], "0002-c")]
    assert scanned[1][1]["extra"] == "é"
    assert list(Journal(tmp_path / "none.jsonl").scan()) == []


def test_a_line_of_exactly_the_bound_is_read_one_byte_more_is_skipped(tmp_path: Path) -> None:
    """docs/reliability.md: lines over 1 MB (``MAX_LINE_BYTES``, newline included) are
    skipped, whatever they hold; one of exactly the bound is read, as is the next line."""
    at = _padded_line("0000-a", MAX_LINE_BYTES)
    over = _padded_line("0001-b", MAX_LINE_BYTES + 1)
    far_over = _padded_line("0002-c", 3 * MAX_LINE_BYTES + 7)
    after = _line("0003-d")
    path = tmp_path / "journal.jsonl"
    path.write_bytes(at + over + far_over + after)
    journal = Journal(path)
    assert [(off, row["run_id"]) for off, row in journal.scan()] == [
        (0, "0000-a"), (len(at) + len(over) + len(far_over), "0003-d")]
    assert next(journal.read_at([0]))["run_id"] == "0000-a"
    for offset in (len(at), len(at) + len(over)):
        with pytest.raises(ValueError, match=f"byte {offset}$"):
            next(journal.read_at([offset]))


def test_an_overlong_line_is_skipped_unread(tmp_path: Path) -> None:
    """journal.py: a line over the bound is skipped unread, whatever a hand or a disk put
    there: a 32 MiB line (a disk's zeros, say) costs scan and read_at at most about the
    bound in memory, not the line (traced here: Python's bytes objects)."""
    huge = 32 * MAX_LINE_BYTES
    path = tmp_path / "journal.jsonl"
    with open(path, "wb") as f:
        f.write(b'{"run_id": "0000-a", "record": {}, "pad": "')
        f.truncate(huge)  # zeros, as a disk leaves them
        f.seek(huge)
        f.write(b'"}\n' + _line("0001-b"))
    journal = Journal(path)
    tracemalloc.start()
    try:
        assert [(off, row["run_id"]) for off, row in journal.scan()] == [(huge + 3, "0001-b")]
        with pytest.raises(ValueError):
            next(journal.read_at([0]))
        _, peak_bytes = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak_bytes < 4 * MAX_LINE_BYTES


def test_the_line_bound_counts_bytes_not_characters(tmp_path: Path) -> None:
    """A line of fewer than 2^20 characters but more than 2^20 bytes (two-byte characters) is
    over the bound: skipped by scan, refused by read_at."""
    line = _padded_line("0000-a", MAX_LINE_BYTES + 2, pad="é")
    assert len(line.decode()) < MAX_LINE_BYTES
    path = tmp_path / "journal.jsonl"
    path.write_bytes(_line("0001-b") + line)
    journal = Journal(path)
    assert [row["run_id"] for _, row in journal.scan()] == ["0001-b"]
    with pytest.raises(ValueError):
        next(journal.read_at([len(_line("0001-b"))]))


def test_run_ids_up_to_64_characters_are_taken(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    path.write_bytes(_line("r" * MAX_RUN_ID_CHARS) + _line("s" * (MAX_RUN_ID_CHARS + 1)))
    assert [row["run_id"] for _, row in Journal(path).scan()] == ["r" * MAX_RUN_ID_CHARS]
    assert MAX_RUN_ID_CHARS == 64  # docs/reliability.md: "a run id over 64 characters"


def test_load_keeps_the_last_whole_line_of_each_run(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    path.write_bytes(_line("0000-a", n=1) + _line("0001-b", n=1) + _line("0000-a", n=2)
                     + _line("0001-b", n=3)[:-5])
    rows = Journal(path).load()
    assert {k: v["n"] for k, v in rows.items()} == {"0000-a": 2, "0001-b": 1}


# -- Journal.read_at ---------------------------------------------------------------------------

def test_read_at_reads_the_lines_at_the_offsets_in_the_order_asked(tmp_path: Path) -> None:
    lines = [_line("0000-a"), _line("0001-b", note="ü"), _line("0002-c")]
    path = tmp_path / "journal.jsonl"
    path.write_bytes(b"".join(lines))
    starts = [0, len(lines[0]), len(lines[0]) + len(lines[1])]
    journal = Journal(path)
    got = list(journal.read_at([starts[2], starts[0], starts[1], starts[2]]))
    assert [row["run_id"] for row in got] == ["0002-c", "0000-a", "0001-b", "0002-c"]
    assert got[2]["note"] == "ü"
    # no offset asked: nothing read, not even a journal that does not exist
    assert list(Journal(tmp_path / "none.jsonl").read_at([])) == []
    assert list(journal.read_at(iter(()))) == []


def test_read_at_a_changed_journal_says_which_file_and_byte(tmp_path: Path) -> None:
    """The file changed under the batch (an offset inside a line, or past the end): one line
    naming the journal and the byte (docs: one-line errors name the file)."""
    path = tmp_path / "journal.jsonl"
    path.write_bytes(_line("0000-a") + _line("0001-b"))
    journal = Journal(path)
    for offset in (3, len(path.read_bytes())):
        with pytest.raises(ValueError) as info:
            list(journal.read_at([0, offset]))
        message = str(info.value)
        assert message.startswith(f"{path}: ") and message.endswith(f"byte {offset}")
        assert "no journal line" in message and "\n" not in message


def test_read_at_takes_a_line_with_carriage_returns_as_one_line(tmp_path: Path) -> None:
    """Bytes, not text: a line edited on another system (CRLF, or a lone CR between fields,
    which JSON takes as white space) is one line, as scan reads it."""
    line = b'{"run_id": "0000-a",\r "record": {"status": "converged"}}\r\n'
    path = tmp_path / "journal.jsonl"
    path.write_bytes(line + _line("0001-b"))
    journal = Journal(path)
    assert [(off, row["run_id"]) for off, row in journal.scan()] == [
        (0, "0000-a"), (len(line), "0001-b")]
    assert [row["run_id"] for row in journal.read_at([0, len(line)])] == ["0000-a", "0001-b"]


# -- log_complete and logged_record ------------------------------------------------------------

RESULT = {"name": "run-a", "status": "converged", "message": "", "mcap": "elsewhere.mcap",
          "final_distance_m": "0.004", "steps": "1500", "gains": '{"K_ps": 0.8}'}


def test_a_log_with_a_result_record_is_complete_one_without_or_cut_is_not(
        tmp_path: Path) -> None:
    done = _log(tmp_path / "done.mcap", RESULT)
    assert log_complete(done)
    assert not log_complete(_log(tmp_path / "no_result.mcap", None))
    assert not log_complete(_log(tmp_path / "killed.mcap", RESULT, finish=False))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(done.read_bytes()[:-40])
    assert not log_complete(cut)
    assert not log_complete(tmp_path / "missing.mcap")


def test_a_stamped_log_is_trusted_from_its_stamp_and_last_8_bytes_only(tmp_path: Path) -> None:
    """docs/batch.md: a log with the size and time journalled for it that still ends with the
    MCAP magic is taken as finished (not read); any other log is read for its result."""
    fake = tmp_path / "fake.mcap"
    fake.write_bytes(b"not a log at all, but it ends with the magic" + MCAP_MAGIC)
    stamp = {"size": fake.stat().st_size, "mtime_ns": fake.stat().st_mtime_ns}
    assert log_complete(fake, stamp)  # trusted, unread
    assert not log_complete(fake)  # read: not MCAP
    for changed in ({**stamp, "size": stamp["size"] + 1},
                    {**stamp, "mtime_ns": stamp["mtime_ns"] + 1}):
        assert not log_complete(fake, changed)
    # the magic no longer at the end (the same size and time kept by hand): read, refused
    data = fake.read_bytes()
    fake.write_bytes(data[:-1] + b"X")
    os.utime(fake, ns=(stamp["mtime_ns"], stamp["mtime_ns"]))
    assert log_stamp(fake) == stamp
    assert not log_complete(fake, stamp)
    # a real log with a stamp that no longer holds is read and found complete
    done = _log(tmp_path / "done.mcap", RESULT)
    assert log_complete(done, {"size": 1, "mtime_ns": 1})


def test_the_record_made_again_from_a_log_is_its_result_with_the_log_path(
        tmp_path: Path) -> None:
    """docs/reliability.md: an unsealed line's record is made again from its log's ``result``
    metadata: text fields as text, the others parsed as JSON, ``mcap`` the log's path."""
    path = _log(tmp_path / "run.mcap", RESULT)
    assert logged_record(path) == {
        "name": "run-a", "status": "converged", "message": "", "mcap": str(path),
        "final_distance_m": 0.004, "steps": 1500, "gains": {"K_ps": 0.8}}
    # text fields stay text even when they read as JSON
    numeric = _log(tmp_path / "numeric.mcap", {**RESULT, "name": "12", "message": "null"})
    record = logged_record(numeric)
    assert record is not None and record["name"] == "12" and record["message"] == "null"


def test_a_run_stopped_by_its_wall_clock_limit_is_made_again_as_a_timeout(
        tmp_path: Path) -> None:
    """docs/reliability.md: a run stopped by its wall-clock limit (logged failed with the
    WallClockLimit error) is mapped to ``timeout`` as the worker maps it."""
    message = "wall-clock limit of 2.5 s exceeded"
    path = _log(tmp_path / "slow.mcap",
                {**RESULT, "status": "failed", "message": f"WallClockLimit: {message}"})
    record = logged_record(path)
    assert record is not None
    assert (record["status"], record["message"]) == ("timeout", message)
    # another failure, even one naming the limit later, stays a failure with its message
    other = f"FmuError: WallClockLimit: {message}"
    record = logged_record(_log(tmp_path / "fail.mcap",
                                {**RESULT, "status": "failed", "message": other}))
    assert record is not None and (record["status"], record["message"]) == ("failed", other)
    # a converged run whose message happens to start so is left alone
    record = logged_record(_log(tmp_path / "ok.mcap",
                                {**RESULT, "message": f"WallClockLimit: {message}"}))
    assert record is not None and record["status"] == "converged"


def test_no_record_is_made_from_a_log_that_is_not_finished_or_not_json(tmp_path: Path) -> None:
    done = _log(tmp_path / "done.mcap", RESULT)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(done.read_bytes()[:-40])
    for path in (tmp_path / "missing.mcap", cut, _log(tmp_path / "none.mcap", None),
                 _log(tmp_path / "killed.mcap", RESULT, finish=False),
                 _log(tmp_path / "bad.mcap", {**RESULT, "steps": "{not json"})):
        assert logged_record(path) is None, path.name


def test_a_record_is_made_again_exactly_from_the_logs_the_resume_counts_finished(
        tmp_path: Path) -> None:
    """A record is made from a log only if :func:`log_complete` takes it as finished (its
    summary indexes a ``result`` record), so that a resume never trusts a record from a log
    it would redo: among them another writer's log that holds the ``result`` record but no
    summary section (written without indexes), and a log whose ``result`` record is there
    but whose summary lists it under another name (its index's name edited in place)."""
    from mcap.writer import IndexType

    no_summary = tmp_path / "no_summary.mcap"
    with open(no_summary, "wb") as stream:
        writer = Writer(stream, index_types=IndexType.NONE, repeat_channels=False,
                        repeat_schemas=False, use_statistics=False, use_summary_offsets=False)
        writer.start(profile="", library="another writer")
        writer.add_metadata("result", RESULT)
        writer.finish()
    done = _log(tmp_path / "done.mcap", RESULT)
    # the MCAP string "result" (uint32 length, bytes) twice: the Metadata record in the data
    # section, then its MetadataIndex in the summary, which is renamed
    name = len(b"result").to_bytes(4, "little") + b"result"
    data = done.read_bytes()
    assert data.count(name) == 2
    at = data.rindex(name)
    unlisted = tmp_path / "unlisted.mcap"
    unlisted.write_bytes(data[:at] + name.replace(b"result", b"Result") + data[at + len(name):])
    logs = [done, no_summary, _log(tmp_path / "none.mcap", None),
            _log(tmp_path / "killed.mcap", RESULT, finish=False), tmp_path / "missing.mcap",
            unlisted]
    assert [logged_record(p) is not None for p in logs] == [log_complete(p) for p in logs]
    assert [log_complete(p) for p in logs] == [True, False, False, False, False, False]


def test_a_stamped_path_that_cannot_hold_a_log_is_not_complete(tmp_path: Path) -> None:
    """The stamp's fast path reads the last 8 bytes: a file shorter than the MCAP magic, or a
    folder put where the log was (each with its own, matching, stamp), is not a finished
    log, and the run is done again."""
    short = tmp_path / "short.mcap"
    short.write_bytes(MCAP_MAGIC[-3:])
    folder = tmp_path / "folder.mcap"
    folder.mkdir()
    for path in (short, folder):
        stamp = log_stamp(path)
        assert stamp is not None
        assert not log_complete(path, stamp), path.name


def test_a_log_ends_whole_when_a_file_there_ends_with_the_magic_after_the_leading_one(
        tmp_path: Path) -> None:
    """What a compact line's run needs of its log (``log_ends_whole``): a regular file at the
    path (a link is not followed) that ends with the MCAP magic, past the magic an MCAP file
    starts with (the MCAP specification: a file opens and closes with it), so at least 16
    bytes; a file holding only the leading magic (a writer killed at once), a log cut or
    zeroed in place, a missing file and a folder are not."""
    done = _log(tmp_path / "done.mcap", RESULT)
    assert log_ends_whole(done)
    both = tmp_path / "both.mcap"
    both.write_bytes(MCAP_MAGIC + MCAP_MAGIC)
    assert log_ends_whole(both)
    for name, data in (("leading.mcap", MCAP_MAGIC), ("short.mcap", MCAP_MAGIC[1:] + MCAP_MAGIC),
                       ("cut.mcap", done.read_bytes()[:-1]),
                       ("zeroed.mcap", bytes(done.stat().st_size))):
        (tmp_path / name).write_bytes(data)
        assert not log_ends_whole(tmp_path / name), name
    assert not log_ends_whole(tmp_path / "missing.mcap")
    (tmp_path / "folder.mcap").mkdir()
    assert not log_ends_whole(tmp_path / "folder.mcap")
    link = tmp_path / "link.mcap"
    link.symlink_to(done)
    assert not log_ends_whole(link)


def test_a_link_at_the_journal_is_refused_naming_the_file_and_nothing_written(
        tmp_path: Path) -> None:
    """docs/reliability.md: a symbolic or hard link at a batch folder's ``journal.jsonl`` is
    refused in one line naming the file (and what it is), nothing written to its target."""
    from wmr.infra.errors import LogError

    target = tmp_path / "elsewhere.txt"
    target.write_bytes(b"someone else's file\n")
    for kind in ("symbolic", "hard"):
        folder = tmp_path / kind
        folder.mkdir()
        path = folder / "journal.jsonl"
        if kind == "symbolic":
            path.symlink_to(target)
        else:
            os.link(target, path)
        with pytest.raises(LogError) as info:
            Journal(path).append({"run_id": "0000-a", "record": {}})
        message = str(info.value)
        assert message.startswith(f"{path}: ") and "\n" not in message
        assert "the batch journal" in message, message
        assert target.read_bytes() == b"someone else's file\n"


def test_a_full_disk_while_appending_is_one_line_naming_the_journal(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/reliability.md: ENOSPC anywhere (the journal among them) becomes one line naming
    the file; a write cut short by the system is continued (here 7 bytes at a time)."""
    import errno

    from wmr.infra.errors import DiskFullError

    path = tmp_path / "journal.jsonl"
    real_write = os.write
    monkeypatch.setattr(os, "write", lambda fd, data: real_write(fd, bytes(data[:7])))
    row = {"run_id": "0000-a", "record": {"status": "converged"}}
    assert Journal(path).append(row) == 0
    assert json.loads(path.read_bytes()) == {**row, "check": line_check(row)}

    def full(fd: int, data: bytes) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "write", full)
    with pytest.raises(DiskFullError) as info:
        Journal(path).append({"run_id": "0001-b", "record": {}})
    message = str(info.value)
    assert str(path) in message and "no space left" in message and "\n" not in message


# -- compact lines -----------------------------------------------------------------------------

def test_a_compact_line_is_94_bytes_sealed_over_itself_and_the_runs_row(tmp_path: Path) -> None:
    """docs/batch.md ("The journal"): id, status, digest, ``killed`` only when true, and the
    CRC-32 of the line's other fields continued over the row's result columns (sorted keys,
    no spaces): the CRC of the two texts one after the other, computed here by binascii."""
    import binascii

    from wmr.apps.batch.journal import compact_line

    row = {"status": "converged", "steps": 695, "mcap": None, "final_position_error_m": 0.01}
    body = '{"run_id":"0042-1f2e3d4c","status":"converged","digest":"9c1d0f5e2a7b3c48"}'
    text = '{"final_position_error_m":0.01,"mcap":null,"status":"converged","steps":695}'
    seal = binascii.crc32((body + text).encode())
    line = compact_line("0042-1f2e3d4c", "converged", "9c1d0f5e2a7b3c48", row)
    assert line == (body[:-1] + f',"seal":"{seal:08x}"}}\n').encode()
    assert len(line) == 94
    killed = compact_line("0042-1f2e3d4c", "converged", "9c1d0f5e2a7b3c48", row, killed=True)
    body = body[:-1] + ',"killed":true}'
    assert killed == (body[:-1] + f',"seal":"{binascii.crc32((body + text).encode()):08x}"}}\n'
                      ).encode()
    # another row (a result changed): another seal
    assert compact_line("0042-1f2e3d4c", "converged", "9c1d0f5e2a7b3c48",
                        {**row, "steps": 696}) != line
    path = tmp_path / "journal.jsonl"
    path.write_bytes(line + line.replace(b'"seal":"', b'"seal":"0') + killed)
    assert [row["run_id"] for _, row in Journal(path).scan()] == ["0042-1f2e3d4c"] * 2


def test_a_compact_line_whose_seal_is_not_8_hex_digits_is_garbled_and_skipped(
        tmp_path: Path) -> None:
    """docs/batch.md ("The journal"): the seal is 8 hex digits (a CRC-32); a line whose seal
    holds another character (``g``, the first past hex; ``z``; a sign, a space or an ``_``,
    which Python's ``int(text, 16)`` takes) is garbled, skipped as a cut line is, and its run
    is done again: a negative seal stopped the resume (OverflowError), whose seals are
    unsigned."""
    from wmr.apps.batch.journal import compact_line

    line = compact_line("0042-1f2e3d4c", "converged", "9c1d0f5e2a7b3c48", {"steps": 695})
    seal = json.loads(line)["seal"]
    path = tmp_path / "journal.jsonl"
    edited = [line.replace(seal.encode(), other.encode())
              for other in ("g" + seal[1:], seal[:-1] + "z", "zzzzzzzz", "-" + seal[1:],
                            "+" + seal[1:], " " + seal[1:], seal[:4] + "_" + seal[5:])]
    path.write_bytes(b"".join(edited) + line)
    assert [(offset, row["seal"]) for offset, row in Journal(path).scan()] == [
        (len(line) * len(edited), seal)]


def test_a_full_disk_while_mending_a_cut_journal_says_which_file_and_keeps_no_fd(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A journal a killed batch left cut short gets its newline before the first append; if
    the disk is full right then, the error is the full disk's, naming the journal (not another
    error raised while giving up), the file is closed, and the next append, space freed,
    mends it and appends: the cut line stays apart from the new one."""
    import errno

    import wmr.apps.batch.journal as journal_mod
    from wmr.infra.durable import storage_error
    from wmr.infra.errors import DiskFullError

    path = tmp_path / "journal.jsonl"
    path.write_bytes(b'{"run_id": "cu')
    journal = Journal(path)
    real = journal_mod.write_all

    def full_at_the_newline(fd: int, data: bytes, where: Any) -> None:
        if bytes(data) == b"\n":
            raise storage_error(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)), where)
        real(fd, data, where)

    fds = len(os.listdir("/proc/self/fd"))
    monkeypatch.setattr(journal_mod, "write_all", full_at_the_newline)
    with pytest.raises(DiskFullError, match=str(path)):
        journal.append_lines(b'{"run_id": "a"}\n')
    assert len(os.listdir("/proc/self/fd")) == fds
    monkeypatch.setattr(journal_mod, "write_all", real)
    assert journal.append_lines(b'{"run_id": "b"}\n') == len(b'{"run_id": "cu\n')
    journal.close()
    assert path.read_bytes() == b'{"run_id": "cu\n{"run_id": "b"}\n'
