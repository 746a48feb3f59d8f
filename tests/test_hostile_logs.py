"""MCAP logs from strangers (issue 17 B): reading is bounded, and never silently wrong.

Every hostile file is built here, small: a sparse file costs no disk, a zstd bomb of RLE blocks
inflates 4 bytes into 128 KiB.  Each case failed on the reader before this issue (or was planted
back to see the test fail): the commit messages say which.
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import textwrap
import tracemalloc
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from mcap.data_stream import RecordBuilder
from mcap.records import Attachment, Chunk, DataEnd, Footer, Header, Message, Metadata
from mcap.writer import CompressionType, Writer

from wmr.adapters.mcap import RunLogWriter, read_run
from wmr.adapters.mcap.reader import ReadLimits
from wmr.adapters.mcap.recover import recover_log
from wmr.adapters.mcap.schemas import MAGIC, STEP_TOPICS, file_descriptor_set, message_class
from wmr.adapters.rerun.replay import replay
from wmr.api import read_log
from wmr.cli import main
from wmr.core.signals import SIGNALS
from wmr.infra.durable import partial_path
from wmr.infra.errors import ConfigError, LogError

STEP_NS = 10_000_000
GiB = 1 << 30
MiB = 1 << 20
LAYOUT = {t.topic: t for t in STEP_TOPICS}


# -- building hostile files --------------------------------------------------------------------


def records(*recs: object) -> bytes:
    rb = RecordBuilder()
    for r in recs:
        r.write(rb)  # type: ignore[attr-defined]
    return bytes(rb.end())


def zstd_bomb(n_bytes: int) -> bytes:
    """A zstd frame of RLE blocks: 4 bytes per 128 KiB of zeros, no content size."""
    block = 128 * 1024
    out = bytearray(struct.pack("<I", 0xFD2FB528) + bytes([0x00, 7 << 3]))
    n_blocks = -(-n_bytes // block)
    for i in range(n_blocks):
        size = min(block, n_bytes - i * block)
        last = int(i == n_blocks - 1)
        out += (last | (1 << 1) | (size << 3)).to_bytes(3, "little") + b"\0"
    return bytes(out)


def chunk(data: bytes, *, declared: int, compression: str = "zstd", t_ns: int = 0) -> Chunk:
    return Chunk(compression=compression, data=data, message_start_time=t_ns,
                 message_end_time=t_ns, uncompressed_crc=0, uncompressed_size=declared)


def log_bytes(*body: object, finished: bool = True) -> bytes:
    """Magic, Header, the given records, then (finished) Data End, Footer and magic."""
    out = MAGIC + records(Header(profile="", library="hostile"), *body)
    if finished:
        out += records(DataEnd(data_section_crc=0),
                       Footer(summary_start=0, summary_offset_start=0, summary_crc=0)) + MAGIC
    return out


def sparse(path: Path, head: bytes, size: int) -> Path:
    """``head`` then zeros up to ``size`` bytes, without using the disk."""
    path.write_bytes(head)
    os.truncate(path, size)
    return path


def encode(topic: str, t_ns: int, values: dict[str, float]) -> bytes:
    msg = message_class(LAYOUT[topic].schema_name)(**values)
    msg.timestamp.FromNanoseconds(t_ns)
    return bytes(msg.SerializeToString())


def stranger_log(path: Path, streams: list[tuple[str, list[int]]], *,
                 chunk_size: int = 1 << 20) -> None:
    """A log written by ``mcap``'s own Writer: ``(topic, log times)`` per channel, in the
    given order; each message carries ``x = t`` in every signal (seconds), so a row shows
    at a glance whether its topics were joined at the same time."""
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=chunk_size)
        w.start()
        schemas: dict[str, int] = {}
        channels = []
        for topic, _ in streams:
            name = LAYOUT[topic].schema_name
            if name not in schemas:
                schemas[name] = w.register_schema(name, "protobuf", file_descriptor_set(name))
            channels.append(w.register_channel(topic, "protobuf", schemas[name]))
        w.add_metadata("run", {"scenario": "stranger"})
        for cid, (topic, times) in zip(channels, streams, strict=True):
            for t in times:
                data = encode(topic, t, {s: t * 1e-9 for s in LAYOUT[topic].signals})
                w.add_message(cid, log_time=t, data=data, publish_time=t)
        w.add_metadata("result", {"status": "converged"})
        w.finish()


def steps(n: int, every: int = 1, start: int = 0) -> list[int]:
    return [k * STEP_NS for k in range(start, n, every)]


@pytest.fixture
def peak_bytes() -> Iterator[Callable[[], int]]:
    """Peak of Python-visible allocations (numpy and zstandard buffers included)."""
    tracemalloc.start()
    yield lambda: tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()


def one_line(exc: pytest.ExceptionInfo[LogError], *words: str) -> None:
    text = str(exc.value)
    assert "\n" not in text
    for word in words:
        assert word in text, text


# -- 3: sparse files, lying lengths ------------------------------------------------------------


def test_a_sparse_file_is_refused_at_once_without_reading_it(
        tmp_path: Path, peak_bytes: Callable[[], int]) -> None:
    path = sparse(tmp_path / "sparse.mcap", MAGIC, 256 * MiB)
    run = read_run(path)
    assert run.n_steps == 0 and run.truncated
    assert any("no MCAP record at byte 8" in w for w in run.warnings), run.warnings
    assert peak_bytes() < 16 * MiB, "the file was read whole"
    with pytest.raises(LogError) as info:
        replay([path], rrd=tmp_path / "r.rrd")
    one_line(info, "sparse.mcap", "no readable control step")


@pytest.mark.parametrize("opcode", [0x06, 0x09, 0x80], ids=["chunk", "attachment", "user"])
def test_a_record_larger_than_any_limit_is_skipped_by_seeking(
        tmp_path: Path, peak_bytes: Callable[[], int], opcode: int) -> None:
    # a record of 1.5 GiB of zeros (sparse), then a finished file's end
    head = log_bytes(finished=False) + struct.pack("<BQ", opcode, 3 * GiB // 2)
    path = sparse(tmp_path / "big.mcap", head, len(head) + 3 * GiB // 2)
    with open(path, "ab") as f:
        f.write(records(DataEnd(data_section_crc=0),
                        Footer(summary_start=0, summary_offset_start=0, summary_crc=0)) + MAGIC)
    run = read_run(path)
    assert peak_bytes() < 16 * MiB
    if opcode == 0x80:  # a private record: skipped, as MCAP says, and not damage
        assert not any("limit" in w for w in run.warnings)
    else:
        assert run.truncated
        assert any("limit" in w and "left out" in w for w in run.warnings), run.warnings


def test_record_lengths_that_lie_stop_the_walk_with_a_warning(tmp_path: Path) -> None:
    good = tmp_path / "good.mcap"
    RunLogWriter(good, run={"a": 1}, goal=(1.0, 0.0, 0.0)).close({"status": "converged"})
    data = good.read_bytes()
    header_len = struct.unpack_from("<Q", data, 9)[0]
    at = 8 + 9 + header_len  # the first record after the Header
    for length in (2**64 - 1, len(data), 0):
        bad = bytearray(data)
        bad[at + 1 : at + 9] = struct.pack("<Q", length)
        path = tmp_path / "lie.mcap"
        path.write_bytes(bytes(bad))
        run = read_run(path)
        assert run.truncated and run.warnings


# -- 4: decompression bombs --------------------------------------------------------------------


@pytest.mark.parametrize("declared", [3 * GiB, 1000, 0], ids=["declares-3GiB", "lies-1kB",
                                                                "declares-0"])
def test_a_zstd_bomb_inflates_no_further_than_its_limit(
        tmp_path: Path, peak_bytes: Callable[[], int], declared: int) -> None:
    path = tmp_path / "bomb.mcap"
    path.write_bytes(log_bytes(chunk(zstd_bomb(GiB), declared=declared)))
    assert path.stat().st_size < 40_000
    run = read_run(path)
    assert run.truncated
    assert any("chunk at byte" in w for w in run.warnings), run.warnings
    assert peak_bytes() < 200 * MiB


def test_an_lz4_bomb_is_cut_at_its_declared_size(tmp_path: Path,
                                                 peak_bytes: Callable[[], int]) -> None:
    import lz4.frame

    path = tmp_path / "bomb.mcap"
    path.write_bytes(log_bytes(chunk(lz4.frame.compress(bytes(256 * MiB)), declared=1000,
                                     compression="lz4")))
    tracemalloc.reset_peak()
    run = read_run(path)
    assert run.truncated and any("inflates to more than" in w for w in run.warnings)
    assert peak_bytes() < 32 * MiB


def test_a_chunk_of_zeros_is_dropped_whole_not_walked(tmp_path: Path) -> None:
    # 32 MiB of zeros, honestly declared: 3.7 million empty "records" of opcode 0
    path = tmp_path / "zeros.mcap"
    path.write_bytes(log_bytes(chunk(zstd_bomb(32 * MiB), declared=32 * MiB)))
    run = read_run(path)
    assert any("opcode 0x00 inside the chunk" in w for w in run.warnings), run.warnings


def test_many_chunks_under_the_chunk_limit_stop_at_the_total_limit(tmp_path: Path) -> None:
    import zstandard

    # each chunk is one valid 8 MiB message, 20 of them: 160 MiB inflated
    inner = records(Message(channel_id=1, sequence=0, log_time=0, publish_time=0,
                            data=bytes(8 * MiB - 31)))
    bomb = chunk(zstandard.compress(inner), declared=len(inner))
    path = tmp_path / "many.mcap"
    path.write_bytes(log_bytes(*[bomb] * 20))
    limits = ReadLimits(chunk_bytes=16 * MiB, total_bytes=64 * MiB)
    run = read_run(path, limits)
    assert any("ReadLimits.total_bytes" in w for w in run.warnings), run.warnings
    assert run.truncated


# -- 6, 10: recover: the writer's lock, a killed run's partial file, FIFOs ----------------------


def test_recover_refuses_the_partial_log_of_a_live_run(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    t = np.arange(250, dtype=np.int64) * STEP_NS
    with RunLogWriter(path, run={"scenario": "live"}, goal=(1.0, 0.0, 0.0)) as w:
        w.write_block(t, np.ones((250, len(SIGNALS))))
        for out in (path, None):  # the issue's -o live.mcap, and the default output
            with pytest.raises(LogError) as info:
                recover_log(partial_path(path), out)
            one_line(info, "live.mcap.partial", "still writing")
        assert partial_path(path).exists()
        w.close({"status": "converged"})
    run = read_run(path)
    assert run.metadata["result"]["status"] == "converged" and run.n_steps == 250
    assert not list(tmp_path.glob("*.recovering")) and not list(tmp_path.glob("*.recovered*"))


def test_recover_of_a_killed_runs_log_names_its_partial_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "killed.mcap"
    partial_path(path).write_bytes(log_bytes(finished=False))
    assert main(["log", "recover", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "killed.mcap.partial" in err, err


def test_a_log_of_more_chunks_than_the_record_limit_stops_there(tmp_path: Path) -> None:
    tiny = records(Message(channel_id=1, sequence=0, log_time=0, publish_time=0, data=b""))
    path = tmp_path / "chunks.mcap"
    path.write_bytes(log_bytes(*[chunk(tiny, declared=len(tiny), compression="")] * 2000))
    run = read_run(path, ReadLimits(records=1000))
    assert run.truncated and any("ReadLimits.records" in w for w in run.warnings)


def test_recover_merges_tiny_chunks(tmp_path: Path) -> None:
    path = tmp_path / "tiny.mcap"
    stranger_log(path, [("/robot/state", steps(1000)), ("/controller/errors", steps(1000))],
                 chunk_size=1)  # one message per chunk: 2000 chunks
    rec = recover_log(path, tmp_path / "fixed.mcap")
    assert rec.messages == 2000 and rec.chunks == 1
    before, after = read_run(path), read_run(rec.output)
    assert np.array_equal(before.block(), after.block(), equal_nan=True)


def _in_subprocess(code: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
    """Run ``code`` in a fresh interpreter; the timeout only turns a hang into a failure."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env,
                          capture_output=True, text=True, timeout=timeout_s, check=False)


def test_a_fifo_or_a_folder_is_refused_in_one_line(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo.mcap"
    os.mkfifo(fifo)
    folder = tmp_path / "folder.mcap"
    folder.mkdir()
    for target, kind in ((fifo, "named pipe"), (folder, "folder")):
        proc = _in_subprocess(f"""
            from wmr.cli import main
            raise SystemExit(main(["log", "recover", {str(target)!r}]))
            """)
        assert proc.returncode == 1, proc.stderr
        assert proc.stderr.count("\n") == 1 and kind in proc.stderr, proc.stderr
        with pytest.raises(LogError) as info:
            read_run(target)
        one_line(info, target.name, kind)
    with pytest.raises(LogError) as info:
        read_run("/dev/zero")
    one_line(info, "/dev/zero", "character device")
    with pytest.raises(LogError) as info:
        replay([fifo], rrd=tmp_path / "r.rrd")
    one_line(info, "fifo.mcap", "not a regular file")


# -- 7: topics joined by time ------------------------------------------------------------------


def _row(run: object, t_ns: int, signal: str) -> float:
    i = int(np.searchsorted(run.t_ns, t_ns))  # type: ignore[attr-defined]
    assert run.t_ns[i] == t_ns  # type: ignore[attr-defined]
    return float(run.signals[signal][i])  # type: ignore[attr-defined]


def test_topics_at_different_rates_are_joined_by_time_not_by_index(tmp_path: Path) -> None:
    path = tmp_path / "rates.mcap"
    stranger_log(path, [("/robot/state", steps(200)), ("/controller/errors", steps(200, 2))])
    run = read_run(path)
    assert run.n_steps == 200
    assert _row(run, 198 * STEP_NS, "e_s_m") == pytest.approx(1.98)
    assert _row(run, 198 * STEP_NS, "x_m") == pytest.approx(1.98)
    assert np.isnan(_row(run, 99 * STEP_NS, "e_s_m"))
    warned = [w for w in run.warnings if "/controller/errors" in w]
    assert len(warned) == 1 and "NaN at the other 100" in warned[0], run.warnings
    frame = read_log(path).signals
    assert frame["e_s_m"].iloc[198] == pytest.approx(1.98)


def test_times_going_backwards_are_sorted_and_said(tmp_path: Path) -> None:
    path = tmp_path / "backwards.mcap"
    # reversed topic order in one channel, and chunks written later-first (64 kB chunks)
    later_first = steps(300, start=150) + steps(150)
    stranger_log(path, [("/robot/state", steps(300)[::-1]), ("/controller/errors", later_first)],
                 chunk_size=4096)
    run = read_run(path)
    assert np.array_equal(run.t_ns, np.array(steps(300)))
    for sig in ("x_m", "e_s_m"):
        assert np.allclose(run.signals[sig], run.t_s)
    for topic in ("/robot/state", "/controller/errors"):
        assert any(topic in w and "backwards" in w for w in run.warnings), run.warnings


def test_two_channels_on_one_topic_are_both_read(tmp_path: Path) -> None:
    path = tmp_path / "two.mcap"
    stranger_log(path, [("/robot/state", steps(100, 2)), ("/robot/state", steps(100, 2, 1)),
                        ("/controller/errors", steps(100))])
    run = read_run(path)
    assert run.n_steps == 100 and np.allclose(run.signals["x_m"], run.t_s)
    assert any("/robot/state has 2 channels" in w for w in run.warnings), run.warnings


# -- 9: out-of-range times, deep JSON, a blueprint into a new folder --------------------------


def test_a_log_time_beyond_int64_is_left_out_everywhere(tmp_path: Path) -> None:
    path = tmp_path / "late.mcap"
    stranger_log(path, [("/robot/state", [*steps(50), 2**64 - 1]),
                        ("/controller/errors", steps(50))])
    run = read_run(path)
    assert run.n_steps == 50 and run.truncated
    assert any("beyond 2^63-1" in w for w in run.warnings), run.warnings
    assert read_log(path).truncated
    assert replay([path], rrd=tmp_path / "r.rrd").steps == {"late": 50}
    out = tmp_path / "fixed.mcap"
    rec = recover_log(path, out)
    assert any("beyond 2^63-1" in line for line in rec.lost)
    assert not partial_path(out).exists()
    assert read_run(out).n_steps == 50


def test_deeply_nested_metadata_json_is_kept_as_text(tmp_path: Path) -> None:
    path = tmp_path / "deep.mcap"
    deep = "[" * 200_000 + "]" * 200_000
    RunLogWriter(path, run={"params": deep}, goal=(1.0, 0.0, 0.0)).close(
        {"status": "converged", "nested": deep})
    log = read_log(path)
    assert log.metadata["run"]["params"] == deep
    assert any("run.params" in w and "deeper" in w for w in log.warnings), log.warnings
    with pytest.raises(LogError):  # no control step: refused in one line, not a RecursionError
        replay([path], rrd=tmp_path / "r.rrd")


def test_replay_writes_a_blueprint_into_a_new_folder(tmp_path: Path) -> None:
    out = tmp_path / "new" / "folder" / "view.rbl"
    assert main(["replay", "--blueprint", str(out)]) == 0
    assert out.stat().st_size > 0


# -- the attack, repeated: only one-line refusals or warned reads ------------------------------


def _hostile_files(tmp_path: Path) -> Iterator[Path]:
    yield sparse(tmp_path / "sparse.mcap", MAGIC, 64 * MiB)
    yield sparse(tmp_path / "sparse_header.mcap", log_bytes(finished=False), 64 * MiB)
    yield tmp_path / "missing.mcap"
    p = tmp_path / "bomb.mcap"
    p.write_bytes(log_bytes(chunk(zstd_bomb(GiB), declared=0)))
    yield p
    p = tmp_path / "huge_metadata.mcap"
    p.write_bytes(log_bytes(finished=False) + struct.pack("<BQ", 0x0C, 2**62))
    yield p
    p = tmp_path / "chunk_counts.mcap"
    tiny = records(Message(channel_id=1, sequence=0, log_time=0, publish_time=0, data=b""))
    one = chunk(tiny, declared=len(tiny), compression="")
    p.write_bytes(log_bytes(*[one] * 20_000))
    yield p
    p = tmp_path / "attachment_crc.mcap"
    p.write_bytes(log_bytes(Attachment(log_time=0, create_time=0, name="a", media_type="x",
                                       data=b"abc"), Metadata(name="run", metadata={"a": "1"})))
    yield p
    p = tmp_path / "bad_compression.mcap"
    p.write_bytes(log_bytes(chunk(b"\xff" * 100, declared=10, compression="brotli")))
    yield p


def test_hostile_files_give_one_line_errors_or_warned_reads(tmp_path: Path) -> None:
    for path in _hostile_files(tmp_path):
        try:
            run = read_run(path)
        except LogError as exc:
            assert "\n" not in str(exc) and path.name in str(exc)
            continue
        assert run.truncated or run.n_steps == 0, path.name
        assert run.warnings, path.name
        out = tmp_path / "out.mcap"
        recover_log(path, out, overwrite=True)
        assert not partial_path(out).exists()


def test_crc_checks_still_cover_the_whole_file(tmp_path: Path) -> None:
    # the streamed data section and summary CRCs catch a flip outside every chunk
    path = tmp_path / "run.mcap"
    RunLogWriter(path, run={"scenario": "crc"}, goal=(1.0, 0.0, 0.0),
                 compression="").close({"status": "converged"})
    data = bytearray(path.read_bytes())
    good = read_run(path)
    assert not good.warnings and not good.truncated
    data[data.index(b"crc") + 1] ^= 1
    path.write_bytes(bytes(data))
    run = read_run(path)
    assert any("data section CRC mismatch" in w for w in run.warnings), run.warnings


# -- issue 28, items 7 and 12: the read budget bounds the memory used -------------------------


def nanosecond_log(path: Path, n: int) -> Path:
    """``n`` ``/robot/state`` messages 1 ns apart in 1 MiB zstd chunks: a few MB of file that
    make ``n`` rows of every signal (issue 28 item 7 used 3 * 10^6, 54 MB)."""
    topic = "/robot/state"
    data = encode(topic, 0, {s: 1.0 for s in LAYOUT[topic].signals})
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=1 << 20)
        w.start()
        name = LAYOUT[topic].schema_name
        cid = w.register_channel(topic, "protobuf",
                                 w.register_schema(name, "protobuf", file_descriptor_set(name)))
        for t in range(n):
            w.add_message(cid, log_time=t, data=data, publish_time=t)
        w.finish()
    return path


_PEAK = textwrap.dedent("""
    import resource, sys
    import pandas, wmr  # noqa: F401  (loaded before the baseline)
    from wmr.adapters.mcap.reader import ReadLimits, read_run
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    run = read_run(sys.argv[1], ReadLimits(total_bytes=int(sys.argv[2])))
    import pandas as pd
    frame = pd.DataFrame(run.signals, index=pd.Index(run.t_s))
    grew = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base
    print(run.n_steps, grew * 1024, *run.warnings, sep="\\n")
""")


def test_the_read_budget_bounds_the_memory_a_read_takes(tmp_path: Path) -> None:
    """600,000 messages 1 ns apart (3.5 MB of file) made 600,000 rows of 41 float64 signals,
    about 190 MB of columns and as much again for the DataFrame, while the budget counted 100
    bytes a message (60 MB, under its 64 MiB): the memory a read takes is now what is charged,
    the rows that fit are read and the warning names the limit and how to raise it.  Run in a
    subprocess under a 2 GiB address-space limit."""
    path = nanosecond_log(tmp_path / "ns.mcap", 600_000)
    budget = 64 * MiB
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run(
        ["bash", "-c", f'ulimit -v {2 << 20}; exec "$0" -c "$1" "$2" "$3"', sys.executable,
         _PEAK, str(path), str(budget)],
        env=env, capture_output=True, text=True, check=False, timeout=120)
    assert proc.returncode == 0, proc.stderr
    rows, grew, *warnings = proc.stdout.splitlines()
    # the inflated chunk being read (1 MiB) and the allocator's slack come on top
    assert int(grew) <= budget + 16 * MiB, (int(grew) / MiB, warnings)
    assert 0 < int(rows) < 600_000
    assert any("ReadLimits.total_bytes" in w and "WMR_READ_LIMIT_MIB" in w
               and "--read-limit" in w for w in warnings), warnings


def test_the_read_limit_is_raised_by_an_option_or_the_environment(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: "give a higher limit" with no option to give it.  ``--read-limit MIB`` (wmr
    replay, wmr log recover) and ``WMR_READ_LIMIT_MIB`` set the budget of every read."""
    path = nanosecond_log(tmp_path / "ns.mcap", 100_000)  # 100,000 rows: about 100 MB
    monkeypatch.delenv("WMR_READ_LIMIT_MIB", raising=False)
    assert main(["replay", str(path), "--rrd", str(tmp_path / "a.rrd"), "--read-limit", "16"]) == 0
    err = capsys.readouterr().err
    assert "more than 16 MiB of memory (ReadLimits.total_bytes)" in err, err
    assert "WMR_READ_LIMIT_MIB" not in os.environ  # the command's, not the process's
    assert not read_run(path).truncated  # the default budget holds it whole
    monkeypatch.setenv("WMR_READ_LIMIT_MIB", "16")
    assert read_run(path).n_steps < 100_000
    assert main(["replay", str(path), "--rrd", str(tmp_path / "b.rrd"),
                 "--read-limit", "0"]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("wmr: error: --read-limit: "), lines
    monkeypatch.setenv("WMR_READ_LIMIT_MIB", "lots")
    with pytest.raises(Exception, match="WMR_READ_LIMIT_MIB"):
        read_run(path)


def test_the_api_s_read_limit_is_the_option_s_for_the_replay_only(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``wmr.replay(..., read_limit_mib=16)`` is ``--read-limit 16``: the replay reads up to it,
    says so, and the process's limit is as it was afterwards; a bad value names the keyword."""
    import warnings

    import wmr

    path = nanosecond_log(tmp_path / "ns.mcap", 100_000)
    monkeypatch.delenv("WMR_READ_LIMIT_MIB", raising=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = wmr.replay(path, rrd=tmp_path / "a.rrd", read_limit_mib=16)
    said = [str(w.message) for w in caught] + list(getattr(result, "warnings", []))
    assert any("more than 16 MiB of memory" in w for w in said), said
    assert "WMR_READ_LIMIT_MIB" not in os.environ
    with pytest.raises(ConfigError, match="read_limit_mib"):
        wmr.replay(path, rrd=tmp_path / "b.rrd", read_limit_mib=0)
