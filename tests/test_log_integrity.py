"""Logs that survive kills, second writers and bit rot: atomic replacement, CRCs end to end,
recovery into a file any MCAP reader opens, and a fuzz of damaged files (issue 13)."""

from __future__ import annotations

import io
import json
import os
import random
import struct
import subprocess
import sys
import textwrap
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, SeekingReader, make_reader
from mcap.records import DataEnd
from mcap.stream_reader import StreamReader

from wmr.adapters.mcap import RunData, RunLogWriter, read_run
from wmr.adapters.mcap.reader import DEFAULT_LIMITS, LogScan, ReadLimits, scan_file
from wmr.adapters.mcap.recover import recover_log
from wmr.cli import main
from wmr.core.signals import SIGNALS
from wmr.infra.durable import partial_path
from wmr.infra.errors import LogError

N_SIG = len(SIGNALS)
STEP_NS = 10_000_000
RUN = {"scenario": "fig9", "name": "a-run", "gains": {"K_ps": 1.5}}
ATTACH = {"scenario.toml": ("application/toml", b"[goal]\nx_m = 20\n" * 4),
          "modelDescription.xml": ("application/xml", b"<fmiModelDescription/>" * 4)}
GOAL = (20.0, 10.0, 0.5)


def make_rows(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return np.arange(n, dtype=np.int64) * STEP_NS, rng.normal(scale=5.0, size=(n, N_SIG))


def write_log(path: Path, n: int = 350, seed: int = 0, compression: str = "lz4") -> np.ndarray:
    t, x = make_rows(n, seed)
    with RunLogWriter(path, run=RUN, goal=GOAL, attachments=ATTACH,
                      compression=compression) as w:  # type: ignore[arg-type]
        w.write_block(t, x)
        w.close({"status": "converged", "path_length_m": 22.5})
    return x


def plain_mcap_messages(path: Path) -> tuple[int, int]:
    """Messages seen by mcap's seeking reader (with the summary) and its streaming reader."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert isinstance(reader, SeekingReader)
        assert reader.get_summary() is not None
        seeking = sum(1 for _ in reader.iter_messages())
    with open(path, "rb") as f:
        streaming = sum(1 for _ in NonSeekingReader(f).iter_messages())
    return seeking, streaming


def same_run(a: RunData, b: RunData) -> bool:
    return (np.array_equal(a.t_ns, b.t_ns)
            and np.array_equal(a.block().view(np.uint64), b.block().view(np.uint64))
            and a.metadata == b.metadata and a.attachments == b.attachments
            and a.media_types == b.media_types and a.goal == b.goal)


# -- atomic replacement and a second writer ------------------------------------------------


def test_a_rewrite_replaces_the_old_log_only_when_finished(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_log(path, seed=1)
    old = path.read_bytes()
    t, x = make_rows(250, seed=2)
    with RunLogWriter(path, run=RUN, goal=GOAL) as w:
        w.write_block(t, x)  # 2 s: two chunks flushed to the partial file
        assert path.read_bytes() == old, "the finished log is untouched while the new one grows"
        assert partial_path(path).stat().st_size > 0
        w.close({"status": "converged"})
    assert not partial_path(path).exists()
    assert read_run(path).n_steps == 250


def test_a_second_writer_to_the_same_log_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    t, x = make_rows(150)
    with RunLogWriter(path, run=RUN, goal=GOAL) as first:
        first.write_block(t, x)
        with pytest.raises(LogError, match="another process is writing") as info:
            RunLogWriter(path, run=RUN, goal=GOAL)
        assert "\n" not in str(info.value)
        first.close({"status": "converged"})
    run = read_run(path)
    assert not run.truncated and not run.warnings
    assert run.n_steps == 150
    # the lock went with the first writer: a third one may write
    write_log(path, n=10)
    assert read_run(path).n_steps == 10


# -- CRCs -----------------------------------------------------------------------------------


def test_every_crc_is_filled_and_checks_with_the_mcap_library(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_log(path)
    data = path.read_bytes()
    ends = [r for r in StreamReader(io.BytesIO(data)).records if isinstance(r, DataEnd)]
    assert ends and ends[0].data_section_crc != 0
    # mcap's own validation of chunk and data section CRCs
    records = list(StreamReader(io.BytesIO(data), validate_crcs=True).records)
    assert len(records) > 10
    with open(path, "rb") as f:
        assert sum(1 for _ in make_reader(f, validate_crcs=True).iter_messages()) == 350 * 6 + 1


def _summary_schema_offset(path: Path) -> int:
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert isinstance(reader, SeekingReader)
        footer = reader.get_summary()
    assert footer is not None
    data = path.read_bytes()
    start = struct.unpack_from("<Q", data, len(data) - 8 - 29 + 9)[0]
    return int(start)


def test_a_damaged_summary_falls_back_to_the_data_section(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    block = write_log(path)
    data = bytearray(path.read_bytes())
    start = _summary_schema_offset(path)
    # the summary starts with the Schema records: flip a byte of the first one's descriptor
    data[start + 60] ^= 0x5A
    path.write_bytes(bytes(data))
    run = read_run(path)
    assert any("summary" in w and "CRC" in w for w in run.warnings)
    assert run.n_steps == 350
    assert np.array_equal(run.block().view(np.uint64), block.view(np.uint64)), \
        "every topic is read with the data section's schema"


@pytest.mark.parametrize("target", [b'"K_ps"', b"converged", b"x_m = 20"])
def test_damaged_metadata_or_attachment_is_reported(tmp_path: Path, target: bytes) -> None:
    path = tmp_path / "run.mcap"
    write_log(path, compression="")
    data = bytearray(path.read_bytes())
    at = bytes(data).index(target)
    data[at + 1] ^= 0x01
    path.write_bytes(bytes(data))
    run = read_run(path)
    assert run.truncated
    assert any("CRC" in w for w in run.warnings), run.warnings


def test_a_damaged_attachment_is_left_out_and_named(tmp_path: Path) -> None:
    """docs/reliability.md: a damaged attachment is left out, never given back as good data.
    The data-section CRC fails too (the attachment lies in it), so a warning that only says
    "CRC" proves nothing: the attachment's own warning, and its absence, are the promise."""
    path = tmp_path / "run.mcap"
    write_log(path, compression="")
    data = bytearray(path.read_bytes())
    at = bytes(data).index(b"x_m = 20")
    data[at + 1] ^= 0x01
    path.write_bytes(bytes(data))
    run = read_run(path)
    assert run.truncated
    assert any("attachment 'scenario.toml'" in w and "CRC" in w for w in run.warnings), \
        run.warnings
    assert "scenario.toml" not in run.attachments
    assert set(run.attachments) == set(ATTACH) - {"scenario.toml"}  # the intact ones stay
    assert run.n_steps == 350  # the messages are not in the attachment: all read


def test_data_after_the_closing_magic_is_reported(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_log(path)
    good = read_run(path)
    with open(path, "ab") as f:  # what two writers to one path used to make
        f.write(path.read_bytes()[:5000])
    run = read_run(path)
    assert run.truncated
    assert any("after the closing magic" in w for w in run.warnings)
    assert np.array_equal(run.t_ns, good.t_ns)


# -- recovery ---------------------------------------------------------------------------------


def _killed_writer(path: Path) -> None:
    script = textwrap.dedent(f"""
        import os
        import numpy as np
        from wmr.adapters.mcap import RunLogWriter
        w = RunLogWriter({str(path)!r}, run={{"scenario": "k"}}, goal=(1.0, 2.0, 0.0),
                         attachments={{"s.toml": ("application/toml", b"a = 1")}})
        t = np.arange(350, dtype=np.int64) * {STEP_NS}
        x = np.tile(np.arange({N_SIG}, dtype=float), (350, 1)) + t[:, None] * 1e-9
        w.write_block(t, x)
        os._exit(9)  # like SIGKILL: no close, no flush
        """)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run([sys.executable, "-c", script], env=env, check=False, timeout=60)
    assert proc.returncode == 9


def test_recover_makes_a_killed_log_readable_by_the_plain_mcap_reader(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "killed.mcap"
    _killed_writer(path)
    partial = partial_path(path)
    before = read_run(partial)
    assert before.truncated and before.n_steps == 300
    assert main(["log", "recover", str(partial), "--no-scene"]) == 0
    out = Path(capsys.readouterr().out.strip())
    assert out == tmp_path / "killed.recovered.mcap"
    assert plain_mcap_messages(out) == (300 * 6 + 1, 300 * 6 + 1)
    after = read_run(out)
    assert not after.truncated
    assert np.array_equal(after.block().view(np.uint64), before.block().view(np.uint64))
    assert after.attachments == before.attachments
    assert after.metadata["run"] == {"scenario": "k"}
    lost = after.metadata["recovery"]["lost"]
    assert "no footer" in lost and "no 'result' metadata record" in lost
    # never over an existing file unless asked
    assert main(["log", "recover", str(partial)]) == 1
    assert "exists" in capsys.readouterr().err
    assert main(["log", "recover", str(partial), "--force"]) == 0


def _scene_rows(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A drive to the goal: the distance falls through half the stop radius (the phase
    changes) within the first 300 rows."""
    t = np.arange(n, dtype=np.int64) * STEP_NS
    x = np.zeros((n, N_SIG))
    s = np.linspace(0.0, 6.0, n)
    x[:, SIGNALS.index("x_m")], x[:, SIGNALS.index("y_m")] = s, 0.3 * np.sin(s)
    x[:, SIGNALS.index("theta_rad")] = 0.3 * np.cos(s)
    x[:, SIGNALS.index("dr_m")] = 6.0 - s
    return t, x


_SCENE_RUN = {"scenario": "k", "stop_radius_m": "2.0", "params": '{"L": 0.25, "r": 0.1}'}


def _topic_messages(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append((message.log_time, message.data))
    return out


def test_recover_draws_the_rows_of_a_killed_run(tmp_path: Path) -> None:
    """A killed run's log has no scene topics (the recorder writes them at close); the
    recovered one has those of its rows: the same messages a log of exactly those rows gets
    when it is closed.  The copied messages stay as they were."""
    path = tmp_path / "killed.mcap"
    t, x = _scene_rows(350)
    np.save(tmp_path / "t.npy", t)
    np.save(tmp_path / "x.npy", x)
    script = textwrap.dedent(f"""
        import os
        import numpy as np
        from wmr.adapters.mcap import RunLogWriter
        w = RunLogWriter({str(path)!r}, run={_SCENE_RUN!r}, goal=(6.0, 0.0, 0.5), scene=True)
        w.write_block(np.load({str(tmp_path / "t.npy")!r}), np.load({str(tmp_path / "x.npy")!r}))
        os._exit(9)  # like SIGKILL: no close, no scene
        """)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run([sys.executable, "-c", script], env=env, check=False, timeout=60)
    assert proc.returncode == 9
    partial = partial_path(path)
    held = read_run(partial).n_steps
    assert held == 300  # three 1-s chunks flushed; the rest died with the run
    reference = tmp_path / "finished.mcap"
    with RunLogWriter(reference, run=_SCENE_RUN, goal=(6.0, 0.0, 0.5), scene=True) as w:
        w.write_block(t[:held], x[:held])
        w.close({"status": "failed"})
    rec = recover_log(partial, tmp_path / "recovered.mcap")
    scene = ["/scene/goal", "/scene/path", "/scene/robot", "/controller/phase", "/wmr/readme"]
    assert sorted(rec.scene_added) == sorted(scene)
    got, want = _topic_messages(rec.output), _topic_messages(reference)
    scan = scan_file(str(partial))  # no footer: mcap's own reader stops at the cut
    source = {c.topic: scan.messages[cid] for cid, c in scan.channels.items()
              if cid in scan.messages}
    for topic in scene:
        assert topic not in source
        assert got[topic] == want[topic], topic
    assert [v for _, v in want["/controller/phase"]]  # the phase changes within the rows
    for topic, messages in source.items():  # the rest byte for byte
        assert got[topic] == messages, topic
    assert read_run(rec.output).metadata["recovery"]["scene_added"] == json.dumps(rec.scene_added)
    # without the scene: exactly the source's messages
    bare = recover_log(partial, tmp_path / "bare.mcap", scene=False)
    assert not bare.scene_added and set(_topic_messages(bare.output)) == set(source)


def test_recover_keeps_the_chunks_after_a_damaged_one(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    block = write_log(path, compression="")
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert isinstance(reader, SeekingReader)
        summary = reader.get_summary()
    assert summary is not None
    second = summary.chunk_indexes[2]  # goal, second 0, second 1 <- damaged, ...
    data = bytearray(path.read_bytes())
    data[second.chunk_start_offset + second.chunk_length - 40] ^= 0xFF
    path.write_bytes(bytes(data))
    rec = recover_log(path, tmp_path / "fixed.mcap")
    assert rec.messages == (350 - 100) * 6 + 1
    run = read_run(rec.output)
    assert not run.truncated
    keep = np.r_[0:100, 200:350]
    assert np.array_equal(run.block().view(np.uint64), block[keep].view(np.uint64))
    assert any("left out" in line for line in rec.lost)


# -- fuzz -------------------------------------------------------------------------------------


def _mutations(data: bytes, seed: int) -> bytes:
    rng = random.Random(seed)
    kind = rng.choice(["flip", "flip", "flips", "cut", "zero", "append", "cut_flip"])
    buf = bytearray(data)
    if kind in ("flip", "cut_flip"):
        buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
    if kind == "flips":
        for _ in range(rng.randint(2, 20)):
            buf[rng.randrange(len(buf))] = rng.randrange(256)
    if kind == "zero":
        at = rng.randrange(len(buf))
        buf[at:at + rng.randint(1, 64)] = bytes(len(buf[at:at + 64]))[: rng.randint(1, 64)]
    if kind in ("cut", "cut_flip"):
        buf = buf[: rng.randrange(len(buf))]
    if kind == "append":
        buf += rng.randbytes(rng.randint(1, 300))
    return bytes(buf)


def _fuzz(tmp_path: Path, seeds: range) -> None:
    path = tmp_path / "good.mcap"
    write_log(path, n=250, compression="lz4")
    good = read_run(path)
    data = path.read_bytes()
    silent: list[int] = []
    for seed in seeds:
        bad = tmp_path / "bad.mcap"
        variant = _mutations(data, seed)
        bad.write_bytes(variant)
        try:
            run = read_run(bad)
        except LogError:
            continue  # one clear line: not MCAP at all
        if variant != data and not run.warnings and not same_run(run, good):
            silent.append(seed)
        if seed % 10 == 0:
            fixed = tmp_path / "fixed.mcap"
            recover_log(bad, fixed, overwrite=True)
            plain_mcap_messages(fixed)
    assert silent == [], "damaged files read as good data without a warning"


def test_fuzzed_logs_never_raise_and_never_pass_for_good(tmp_path: Path) -> None:
    _fuzz(tmp_path, range(300))


def _record_spans(data: bytes) -> list[tuple[int, int, int]]:
    """``(opcode, start, end)`` of every top-level record after the leading magic."""
    spans, at = [], 8
    while at + 9 <= len(data) - 8:
        opcode = data[at]
        length = struct.unpack_from("<Q", data, at + 1)[0]
        spans.append((opcode, at, at + 9 + length))
        at += 9 + length
    return spans


def test_every_record_damaged_or_cut_is_reported(tmp_path: Path) -> None:
    """The random fuzz lands mostly in chunk bytes; this one visits every kind of record
    (header, schemas, channels, chunks, message indexes, metadata, attachments, data end,
    every summary record, footer), its first and last one, flips a bit at the record's start,
    in its length field, in its middle and at its end, and cuts the file there.  Each
    variant must be read as good data, or warned about."""
    path = tmp_path / "good.mcap"
    write_log(path, n=250, compression="lz4")
    good = read_run(path)
    data = path.read_bytes()
    spans = _record_spans(data)
    assert len({op for op, _, _ in spans}) >= 10  # every kind of record the writer makes
    assert spans[-1][2] == len(data) - 8  # the walk ended at the closing magic
    # the first and the last record of each kind (a log has many chunks and indexes alike)
    firsts = {op: (op, a, b) for op, a, b in reversed(spans)}
    lasts = {op: (op, a, b) for op, a, b in spans}
    visit = sorted(set(firsts.values()) | set(lasts.values()), key=lambda span: span[1])
    silent: list[str] = []
    bad = tmp_path / "bad.mcap"
    for opcode, start, end in visit:
        variants = {f"cut@{start}": data[:start], f"cut@{(start + end) // 2}":
                    data[:(start + end) // 2]}
        for at in sorted({start + 1, start + 9, (start + end) // 2, end - 1}):
            flipped = bytearray(data)
            flipped[at] ^= 0x04
            variants[f"flip@{at}"] = bytes(flipped)
        for name, variant in variants.items():
            bad.write_bytes(variant)
            try:
                run = read_run(bad)
            except LogError:
                continue
            if not run.warnings and not same_run(run, good):
                silent.append(f"record 0x{opcode:02x} at {start}: {name}")
    assert silent == [], "damaged files read as good data without a warning"


@pytest.mark.slow
def test_fuzzed_logs_many_more(tmp_path: Path) -> None:
    _fuzz(tmp_path, range(300, 2300))


def test_replay_says_what_it_could_not_show(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "run.mcap"
    write_log(path, compression="")
    data = bytearray(path.read_bytes())
    data[bytes(data).index(b'"K_ps"') + 1] ^= 0x01  # the run record, outside every chunk
    path.write_bytes(bytes(data))
    assert main(["replay", str(path), "--no-viewer", "--rrd", str(tmp_path / "r.rrd")]) == 0
    err = capsys.readouterr().err
    assert "wmr: warning:" in err and "data section CRC mismatch" in err


def test_the_read_budget_admits_exactly_its_bytes_and_warns_once_naming_the_limit() -> None:
    """ReadLimits.total_bytes: everything up to the limit is kept, the first byte past it
    stops the read with one warning that names the limit, where it stopped and the fix."""
    mib = 1 << 20
    scan = LogScan(ReadLimits(total_bytes=2 * mib), keep_chunks=False)
    assert scan.charge(mib, "record 1") and scan.charge(mib, "record 2")  # exactly the budget
    assert scan.kept_bytes == 2 * mib and not scan.damaged
    assert not scan.charge(1, "record 3")
    assert not scan.charge(1, "record 4")
    assert scan.kept_bytes == 2 * mib and scan.damaged and scan.over_budget
    assert scan.warnings == ["reading the log takes more than 2 MiB of memory "
                             "(ReadLimits.total_bytes): read stops at record 3; raise it (wmr "
                             "replay/wmr log recover --read-limit MIB, or WMR_READ_LIMIT_MIB=MIB) "
                             "to read it all"]


# -- chunks built byte by byte, and another writer's log ---------------------------------------
# The logs below are written by hand from the MCAP specification (or by the ``mcap`` library's
# own writer), not by RunLogWriter: each fact checked is one of the file's bytes, and the
# ``mcap`` library's reader confirms that the hand-built framing is valid MCAP.

MIB = 1 << 20
MCAP_MAGIC = b"\x89MCAP0\r\n"
SECOND_NS = 1_000_000_000


def _rec(opcode: int, body: bytes) -> bytes:
    return struct.pack("<BQ", opcode, len(body)) + body


def _str(text: str) -> bytes:
    raw = text.encode()
    return struct.pack("<I", len(raw)) + raw


def _message(channel_id: int, log_time_ns: int, data: bytes) -> bytes:
    """A Message record: channel id, sequence, log time, publish time, data (22 + data bytes)."""
    return _rec(0x05, struct.pack("<HIQQ", channel_id, 0, log_time_ns, log_time_ns) + data)


def _second(s: int, n: int = 3) -> list[tuple[int, bytes]]:
    """``n`` messages of second ``s``: log times ``s`` s + k * 10 ms, data naming them."""
    return [(s * SECOND_NS + k * STEP_NS, f"s{s}m{k}".encode()) for k in range(n)]


def _records(messages: list[tuple[int, bytes]]) -> bytes:
    return b"".join(_message(1, t, data) for t, data in messages)


def _chunk(records: bytes, t0_ns: int = 0, t1_ns: int = 0, *, declared: int | None = None,
           crc: int | None = None, data_len: int | None = None, length: int | None = None,
           compression: str = "", data: bytes | None = None) -> bytes:
    """A Chunk record holding ``records``; ``declared`` (uncompressed size), ``crc``,
    ``data_len`` (the records' length field) replace the true values, ``data`` the stored
    bytes (compressed), ``length`` pads the record with zeros to that length (its length field)."""
    stored = records if data is None else data
    body = (struct.pack("<QQQI", t0_ns, t1_ns, len(records) if declared is None else declared,
                        zlib.crc32(records) if crc is None else crc)
            + _str(compression) + struct.pack("<Q", len(stored) if data_len is None else data_len)
            + stored)
    if length is not None:
        assert length >= len(body)
        body += bytes(length - len(body))
    return _rec(0x06, body)


def _zstd(data: bytes) -> bytes:
    """One zstd frame of ``data``, declaring its size (as our writer's and mcap's do)."""
    import zstandard

    return bytes(zstandard.ZstdCompressor(level=1).compress(data))


def _second_chunk(s: int, **kw: Any) -> bytes:
    msgs = _second(s)
    return _chunk(_records(msgs), msgs[0][0], msgs[-1][0], **kw)


_SCHEMA_AND_CHANNEL = (_rec(0x03, struct.pack("<H", 1) + _str("raw") + _str("")
                            + struct.pack("<I", 0))
                       + _rec(0x04, struct.pack("<HH", 1, 1) + _str("/data") + _str("raw")
                              + struct.pack("<I", 0)))


def _hand_log(*data: bytes, data_crc: bool = True, summary: bytes = b"",
              crc_xor: tuple[int, int] = (0, 0)) -> tuple[bytes, list[int]]:
    """A whole MCAP file: magic, header, a schema and a channel, the ``data`` records, Data End
    (with the CRC of everything before it, or 0), ``summary`` records, footer (with the CRC
    of the summary and of its own first fields) and magic; ``crc_xor`` is XORed into the data
    section's and the summary's CRC.  Returns the file and where each of ``data`` starts."""
    out = MCAP_MAGIC + _rec(0x01, _str("") + _str("by hand")) + _SCHEMA_AND_CHANNEL
    starts = []
    for record in data:
        starts.append(len(out))
        out += record
    out += _rec(0x0F, struct.pack("<I", (zlib.crc32(out) if data_crc else 0) ^ crc_xor[0]))
    summary_start = len(out) if summary else 0
    out += summary
    footer_head = struct.pack("<BQ", 0x02, 20) + struct.pack("<QQ", summary_start, 0)
    summary_crc = (zlib.crc32(summary + footer_head) if summary else 0) ^ crc_xor[1]
    return out + footer_head + struct.pack("<I", summary_crc) + MCAP_MAGIC, starts


def _scan(tmp_path: Path, data: bytes, limits: ReadLimits = DEFAULT_LIMITS) -> LogScan:
    path = tmp_path / "hand.mcap"
    path.write_bytes(data)
    return scan_file(str(path), limits)


def _mcap_library_messages(data: bytes) -> list[tuple[int, bytes]]:
    """The messages the ``mcap`` library reads from ``data``, checking every CRC it holds."""
    return [(m.log_time, m.data) for _, _, m in
            NonSeekingReader(io.BytesIO(data), validate_crcs=True).iter_messages()]


def test_a_hand_built_log_is_read_as_the_mcap_library_reads_it(tmp_path: Path) -> None:
    """The builder of the tests below makes valid MCAP: both readers agree, and ours warns of
    nothing.  A zero CRC means "not computed" (the data section's is the library's default),
    never a mismatch: the middle chunk has none."""
    for data_crc in (True, False):
        data, _ = _hand_log(_second_chunk(0), _second_chunk(1, crc=0), _second_chunk(2),
                            data_crc=data_crc)
        scan = _scan(tmp_path, data)
        assert scan.warnings == [] and not scan.damaged and scan.complete
        assert scan.messages == {1: _second(0) + _second(1) + _second(2)}
        assert _mcap_library_messages(data) == scan.messages[1]


def test_a_zstd_chunk_of_several_frames_is_read_whole(tmp_path: Path) -> None:
    """zstd frames end to end are one stream (as ``zstd -d`` reads them): a chunk stored as
    two frames (the first one declaring less than the chunk) is read whole, not taken for
    damage by the inflation at once, while one frame of the chunk's size followed by another
    is left out (``_BAD_CHUNKS``)."""
    records = _records(_second(1, n=6))
    data, _ = _hand_log(_chunk(records, SECOND_NS, SECOND_NS + 5 * STEP_NS, compression="zstd",
                               data=_zstd(records[:100]) + _zstd(records[100:])))
    scan = _scan(tmp_path, data)
    assert scan.warnings == [] and scan.messages == {1: _second(1, n=6)}


def _lookalike_chunk_records() -> tuple[bytes, list[tuple[int, bytes]]]:
    """Message records whose data hold bytes that read as Message headers: one pointing at
    the next true record, one at the start of a second look-alike, which points at a true
    record too, and one pointing past the chunk."""
    first = _message(1, 0, b"")  # 31 bytes: the records below start at 31, 31 + 69, ...
    head = struct.Struct("<BQ")
    # record 2 (at 31, 69 bytes: 9 + 22 + 38 of data); its data starts at 31 + 31 = 62
    lookalike_to_next = head.pack(5, 31 + 69 - 62 - 9)  # at 62: its end is record 3's start
    pad = bytes(38 - len(lookalike_to_next))
    second = _message(1, STEP_NS, lookalike_to_next + pad)
    # record 3 (at 100, 111 bytes, its data at 131): a chain of two look-alikes, at 131 and
    # 162, the second ending where record 4 starts (211)
    chain = head.pack(5, 22) + bytes(22) + head.pack(5, 211 - 162 - 9)
    third = _message(1, 2 * STEP_NS, chain + bytes(80 - len(chain)))
    past = head.pack(5, 1 << 40) + bytes(30)  # a length past the chunk: never a candidate
    fourth = _message(1, 3 * STEP_NS, past)
    records = first + second + third + fourth
    return records, [(k * STEP_NS, m[31:]) for k, m in enumerate((first, second, third,
                                                                    fourth))]


def test_a_chunks_records_are_found_at_once_past_bytes_that_look_like_headers(
        tmp_path: Path) -> None:
    """The record walk with numpy (``_message_starts``) finds exactly the records that the
    walk record by record finds, in a chunk whose messages hold bytes that read as Message
    headers (one pointing at a true record, a chain of two, one past the chunk): look-alikes
    are dropped because no record points at them, and the records left tile the chunk; the
    log reads as the ``mcap`` library reads it."""
    from wmr.adapters.mcap.reader import _chunk_messages, _message_starts

    records, want = _lookalike_chunk_records()
    data = np.frombuffer(records, np.uint8)
    assert int(np.count_nonzero(data == 5)) >= 4 + 4  # the true headers and the look-alikes
    found = _message_starts(data)
    assert found is not None, "the look-alikes were not dropped"
    walked = _chunk_messages(records, LogScan(DEFAULT_LIMITS, keep_chunks=False))
    assert [a.tolist() for a in found] == [a.tolist() for a in walked]
    assert walked[0].tolist() == [9, 40, 109, 220]
    log, _ = _hand_log(_chunk(records, 0, 3 * STEP_NS))
    scan = _scan(tmp_path, log)
    assert scan.warnings == [] and scan.messages == {1: want}
    assert _mcap_library_messages(log) == want


def test_a_chunk_that_is_not_all_messages_is_walked_record_by_record() -> None:
    """A chunk holding another record (a Schema, as the ``mcap`` library's writer puts one in
    the first chunk that uses it), or a message cut short, is not read at once: the record
    by record walk reads it, or names what is wrong."""
    from wmr.adapters.mcap.reader import _message_starts

    records = _records(_second(0))
    assert _message_starts(np.frombuffer(records, np.uint8)) is not None
    schema = _SCHEMA_AND_CHANNEL[: 9 + struct.unpack_from("<Q", _SCHEMA_AND_CHANNEL, 1)[0]]
    for other in (schema + records, records + schema, records[:-1],
                  records + _rec(0x05, bytes(21))):
        assert _message_starts(np.frombuffer(other, np.uint8)) is None


def test_a_chunk_record_is_read_up_to_the_chunk_limit_plus_1_mib_and_left_out_past_it(
        tmp_path: Path) -> None:
    """ReadLimits.chunk_bytes: compressed data never exceeds the uncompressed size by more than
    its frame overhead, so a Chunk record of ``chunk_bytes`` + 1 MiB is read and one byte more
    is skipped unread, each such chunk named and counted; the records after it are read."""
    limit = MIB + MIB
    data, at = _hand_log(_second_chunk(0, length=limit),
                         _second_chunk(1, length=limit + 1),
                         _second_chunk(2),
                         _second_chunk(3, length=limit + 1),
                         _second_chunk(4, length=limit))
    # valid MCAP (zeros after a chunk's records are allowed): the library reads every chunk
    assert len(_mcap_library_messages(data)) == 5 * 3
    assert _scan(tmp_path, data, ReadLimits(chunk_bytes=2 * MIB)).warnings == []
    scan = _scan(tmp_path, data, ReadLimits(chunk_bytes=MIB))
    assert scan.messages == {1: _second(0) + _second(2) + _second(4)}
    assert scan.bad_chunks == 2 and scan.damaged and scan.complete
    assert scan.warnings == [
        *(f"the chunk at byte {at[i]} is {limit + 1} bytes, above the 1 MiB chunk limit "
          "(ReadLimits.chunk_bytes): left out" for i in (1, 3)),
        "the data section CRC was not checked: records over a read limit were skipped unread"]


def _n_bytes(s: int) -> int:
    """The records of :func:`_second_chunk` ``s``, bytes (its uncompressed size)."""
    return len(_records(_second(s)))


_SPAN = "its messages from t = {s} s to {s}.02 s are left out"
#: A damaged chunk of second ``s``, and the reason the reader must give for it.
_BAD_CHUNKS: dict[str, tuple[Callable[[int], bytes], Callable[[int], str]]] = {
    "header cut": (lambda s: _rec(0x06, bytes(31)), lambda s: "its header is cut"),
    "CRC": (lambda s: _second_chunk(s, crc=zlib.crc32(_records(_second(s))) ^ 1),
            lambda s: "chunk crc validation failed"),
    "data past its record": (lambda s: _second_chunk(s, data_len=_n_bytes(s) + 1),
                             lambda s: "its data runs past the end of the record"),
    "records' length of 2^64 - 1": (lambda s: _second_chunk(s, data_len=(1 << 64) - 1),
                                    lambda s: "its data runs past the end of the record"),
    "empty schema record (EndOfFile, no message)": (
        lambda s: _chunk(_records(_second(s)) + _rec(0x03, b""), s * SECOND_NS,
                         s * SECOND_NS + 2 * STEP_NS),
        lambda s: "EndOfFile"),
    "fewer bytes than declared": (
        lambda s: _second_chunk(s, declared=_n_bytes(s) + 1),
        lambda s: f"it inflates to {_n_bytes(s)} bytes, not the {_n_bytes(s) + 1} it declares"),
    "unknown compression": (lambda s: _second_chunk(s, compression="brotli"),
                            lambda s: "unknown compression 'brotli'"),
    # a zstd frame declaring exactly the chunk's size, and another frame after it
    "zstd frame past its size": (
        lambda s: _second_chunk(s, compression="zstd", data=_zstd(_records(_second(s)))
                                + _zstd(b"more")),
        lambda s: f"it inflates to more than {_n_bytes(s) + 1} bytes, not the {_n_bytes(s)} "
                  "it declares"),
    "metadata inside": (lambda s: _chunk(_records(_second(s)) + _rec(0x0C, _str("m") + bytes(4)),
                                         s * SECOND_NS, s * SECOND_NS + 2 * STEP_NS),
                        lambda s: "a record of opcode 0x0c inside the chunk"),
    "21-byte message": (lambda s: _chunk(_records(_second(s)) + _rec(0x05, bytes(21)),
                                         s * SECOND_NS, s * SECOND_NS + 2 * STEP_NS),
                        lambda s: "message record too short"),
    "record past the chunk": (lambda s: _chunk(_records(_second(s)) + struct.pack("<BQ", 5, 30)
                                               + bytes(22), s * SECOND_NS,
                                               s * SECOND_NS + 2 * STEP_NS),
                              lambda s: "record runs past the end of its chunk"),
}


@pytest.mark.parametrize("kind", sorted(_BAD_CHUNKS))
def test_each_damaged_chunk_is_left_out_named_and_counted(tmp_path: Path, kind: str) -> None:
    """Two chunks damaged alike among three good ones: each is left out whole with a warning
    saying where it starts, why, and the times of the messages lost (a cut header has none);
    both are counted; the good chunks around them are read."""
    bad, why = _BAD_CHUNKS[kind]
    data, at = _hand_log(_second_chunk(0), bad(1), _second_chunk(2), bad(3), _second_chunk(4))
    scan = _scan(tmp_path, data)
    assert scan.messages == {1: _second(0) + _second(2) + _second(4)}
    assert scan.bad_chunks == 2 and scan.damaged and scan.complete
    lost = ("left out" if kind == "header cut" else _SPAN)
    assert scan.warnings == [f"the chunk at byte {at[s]} is damaged ({why(s)}): "
                             + lost.format(s=s) for s in (1, 3)]


def test_a_record_damaged_without_a_message_is_named_by_its_error(tmp_path: Path) -> None:
    """An error without a message (the ``mcap`` library's EndOfFile on an empty Schema
    record) is named by its type, inside a chunk and outside (an exception object is always
    true: its text must be tested, not the object)."""
    data, at = _hand_log(_second_chunk(0), _rec(0x03, b""), _second_chunk(1))
    scan = _scan(tmp_path, data)
    assert scan.warnings == [f"the record at byte {at[1]} (opcode 0x03) is damaged "
                             "(EndOfFile): left out"]
    assert scan.messages == {1: _second(0) + _second(1)}


def test_a_chunk_inflating_past_its_declared_size_is_left_out(tmp_path: Path) -> None:
    """A compressed chunk that holds more than it declares is inflated to one byte past the
    declared size and no further (a decompression bomb stops there)."""
    import lz4.frame

    records = _records(_second(1))
    packed = lz4.frame.compress(records)
    data, at = _hand_log(_second_chunk(0),
                         _chunk(records, SECOND_NS, SECOND_NS + 2 * STEP_NS, compression="lz4",
                                data=packed, declared=len(records) - 5),
                         _chunk(records, SECOND_NS, SECOND_NS + 2 * STEP_NS, compression="lz4",
                                data=packed))
    scan = _scan(tmp_path, data)
    assert scan.messages == {1: _second(0) + _second(1)}  # the same chunk, told its size
    assert scan.bad_chunks == 1
    (warning,) = scan.warnings
    assert warning.startswith(f"the chunk at byte {at[1]} is damaged (it inflates to more than ")
    assert warning.endswith(f"bytes, not the {len(records) - 5} it declares): "
                            + _SPAN.format(s=1))


def test_a_chunk_may_declare_exactly_the_chunk_limit_and_not_one_byte_more(
        tmp_path: Path) -> None:
    """ReadLimits.chunk_bytes bounds the declared uncompressed size, inclusive; a chunk over it
    is refused before it is inflated (a decompression bomb?), and counted."""
    big = [(SECOND_NS, bytes(MIB - 9 - 22))]  # one message record of exactly 1 MiB
    exact = _chunk(_records(big), SECOND_NS, SECOND_NS)
    over = [_second_chunk(s, declared=MIB + 1) for s in (2, 3)]
    data, at = _hand_log(exact, *over, _second_chunk(4))
    scan = _scan(tmp_path, data, ReadLimits(chunk_bytes=MIB))
    assert scan.messages == {1: big + _second(4)}
    assert scan.bad_chunks == 2
    assert scan.warnings == [
        f"the chunk at byte {at[i]} declares {MIB + 1} bytes uncompressed, above the 1 MiB "
        "chunk limit (ReadLimits.chunk_bytes; a decompression bomb?): "
        + _SPAN.format(s=i + 1) for i in (1, 2)]


@pytest.mark.parametrize(("limit", "said"), [(1000, "1000 B"), (3 << 19, f"{3 << 19} B"),
                                             (2 << 20, "2 MiB")])
def test_a_chunk_limit_is_said_in_mib_when_whole_else_in_bytes(
        tmp_path: Path, limit: int, said: str) -> None:
    """The warning names the limit the user set: 1000 bytes is not "0 MiB"."""
    data, at = _hand_log(_second_chunk(1, declared=limit + 1))
    scan = _scan(tmp_path, data, ReadLimits(chunk_bytes=limit))
    assert scan.warnings == [
        f"the chunk at byte {at[0]} declares {limit + 1} bytes uncompressed, above the {said} "
        "chunk limit (ReadLimits.chunk_bytes; a decompression bomb?): " + _SPAN.format(s=1)]


@pytest.mark.parametrize("short", [0, 1])
def test_the_read_budget_stops_at_the_first_chunk_past_it_and_counts_the_rest(
        tmp_path: Path, short: int) -> None:
    """ReadLimits.total_bytes counts what a chunk's messages keep (their data, 16 bytes each
    for time and place, 400 per channel's batch; a damaged chunk nothing): with a budget of
    exactly the first chunks' bytes they are read, with one byte less the last of them is not;
    after the first chunk past the budget (one warning) every chunk is left out without another
    warning, and counted (after a damaged one)."""
    chunks = [_second_chunk(0, crc=0xBAD), *(_second_chunk(s) for s in range(1, 5))]
    # second 0 is damaged
    kept = [sum(len(d) for _, d in _second(s)) + 3 * 16 + 400 for s in (1, 2)]
    data, at = _hand_log(*chunks)
    scan = _scan(tmp_path, data, ReadLimits(total_bytes=sum(kept) - short))
    stop = 3 - short  # the first second not read
    assert scan.messages == {1: [m for s in range(1, stop) for m in _second(s)]}
    assert scan.bad_chunks == 1 + (5 - stop)
    assert scan.warnings == [
        f"the chunk at byte {at[0]} is damaged (chunk crc validation failed): "
        + _SPAN.format(s=0),
        f"reading the log takes more than {sum(kept) - short} B of memory "
        f"(ReadLimits.total_bytes): read stops at the chunk at t = {stop} s; raise it (wmr "
        "replay/wmr log recover --read-limit MIB, or WMR_READ_LIMIT_MIB=MIB) to read it all",
        "the data section CRC was not checked: records over a read limit were skipped unread"]


@pytest.mark.parametrize("short", [0, 1])
def test_a_recovery_keeps_the_places_of_the_chunks_within_its_budget_and_names_where_it_stops(
        tmp_path: Path, short: int) -> None:
    """A recovery (``keep_chunks``: the chunks are read again when written) keeps only where
    each good chunk is, 16 bytes of the budget each: with exactly 3 chunks' worth the first 3
    are kept, with one byte less 2, and the one warning names the second the read stops at."""
    from wmr.adapters.mcap.reader import open_log, scan_log

    chunks = [_second_chunk(s) for s in range(5)]
    data, at = _hand_log(*chunks)
    path = tmp_path / "hand.mcap"
    path.write_bytes(data)
    budget = 3 * 16 - short
    with open_log(str(path)) as log:
        scan = scan_log(log, ReadLimits(total_bytes=budget), keep_chunks=True)
    n = 3 - short
    assert scan.chunks == [(at[i], len(chunks[i]) - 9) for i in range(n)]  # after opcode, length
    assert scan.bad_chunks == 5 - n
    assert scan.warnings[0] == (
        f"reading the log takes more than {budget} B of memory (ReadLimits.total_bytes): read "
        f"stops at the chunk at t = {n} s; raise it (wmr replay/wmr log recover --read-limit "
        "MIB, or WMR_READ_LIMIT_MIB=MIB) to read it all")


@pytest.mark.parametrize("compression", ["none", "lz4", "zstd"])
@pytest.mark.parametrize("cut", ["whole", "no summary", "no data end"])
def test_another_writers_log_with_its_schemas_and_channels_inside_the_chunks(
        tmp_path: Path, compression: str, cut: str) -> None:
    """The ``mcap`` library's writer puts each Schema and Channel record inside the chunk
    where it is first used (our writer puts them outside); with the summary left without them
    (``repeat_*=False``) or cut off, those records are the only ones: every schema, channel
    and message is read as the library's own reader reads the whole file, an empty message
    (a record of exactly 22 bytes) included."""
    from mcap.writer import CompressionType, Writer

    path = tmp_path / "other.mcap"
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=200, compression=CompressionType[compression.upper()],
                        repeat_schemas=False, repeat_channels=False, enable_data_crcs=True)
        writer.start(profile="", library="another writer")
        ids = []
        for k in range(3):
            schema = writer.register_schema(f"schema{k}", "jsonschema", b'{"k": %d}' % k)
            ids.append(writer.register_channel(f"/topic{k}", "json", schema,
                                               metadata={"k": str(k)} if k else {}))
            for i in range(8):  # chunks of 200 bytes: each channel's first chunk differs
                writer.add_message(ids[k], log_time=k * SECOND_NS + i * STEP_NS, data=(
                    b"" if i == 3 else b'{"i": %d}' % i), publish_time=0, sequence=i)
        writer.finish()
    data = path.read_bytes()
    outside = {op for op, _, _ in _record_spans(data)}
    assert 0x06 in outside and not outside & {0x03, 0x04}  # chunks, no schema or channel
    reader = NonSeekingReader(io.BytesIO(data), validate_crcs=True)
    want: dict[int, list[tuple[int, bytes]]] = {}
    schemas, channels = {}, {}
    for schema, channel, message in reader.iter_messages():
        assert schema is not None
        want.setdefault(channel.id, []).append((message.log_time, message.data))
        schemas[schema.id], channels[channel.id] = schema, channel
    records = list(StreamReader(io.BytesIO(data)).records)
    end = next(r for r in records if isinstance(r, DataEnd))
    assert end.data_section_crc != 0
    if cut != "whole":  # the file up to Data End (kept or not): no summary, no footer
        data_end = data.index(b"\x0f\x04\x00\x00\x00\x00\x00\x00\x00"
                              + struct.pack("<I", end.data_section_crc))
        data = data[:data_end + (13 if cut == "no summary" else 0)]
    scan = _scan(tmp_path, data)
    assert scan.schemas == schemas and len(schemas) == 3
    assert scan.channels == channels and channels[ids[2]].metadata == {"k": "2"}
    assert scan.messages == want and sum(map(len, want.values())) == 24
    assert (scan.warnings == []) == (cut == "whole")
    assert not scan.damaged and scan.bad_chunks == 0


_STATISTICS = _rec(0x0B, bytes(200))  # a summary record read only for its CRC


def test_crc_mismatches_say_what_is_damaged_and_what_follows(tmp_path: Path) -> None:
    """The data section's CRC names the records outside the chunks as suspect when every chunk
    passed its own CRC, and nothing more when a damaged chunk explains it; the summary's says
    the data section's records are read instead."""
    chunks = [_second_chunk(s) for s in range(3)]
    outside = "a record outside the chunks (metadata, attachment, schema, channel or index) "
    data, _ = _hand_log(*chunks, summary=_STATISTICS, crc_xor=(1, 0))
    scan = _scan(tmp_path, data)
    assert scan.warnings == [f"the data section is damaged (data section CRC mismatch): "
                             f"{outside}may be wrong"] and scan.damaged
    data, at = _hand_log(chunks[0], _second_chunk(1, crc=1), chunks[2], crc_xor=(1, 0))
    scan = _scan(tmp_path, data)
    assert scan.warnings == [f"the chunk at byte {at[1]} is damaged (chunk crc validation "
                             "failed): " + _SPAN.format(s=1),
                             "the data section is damaged (data section CRC mismatch)"]
    data, _ = _hand_log(*chunks, summary=_STATISTICS, crc_xor=(0, 1))
    scan = _scan(tmp_path, data)
    assert scan.warnings == ["the summary is damaged (summary CRC mismatch): read from the data "
                             "section's records instead"] and scan.damaged
    assert scan.messages == {1: _second(0) + _second(1) + _second(2)}
    data, _ = _hand_log(*chunks, summary=_STATISTICS)  # both right
    assert _scan(tmp_path, data).warnings == []


def test_a_crc_over_bytes_skipped_unread_is_not_checked_and_says_so(tmp_path: Path) -> None:
    """A record over ReadLimits.record_bytes that is read only for its CRC (a message index in
    the data section, statistics in the summary) is skipped unread: no damage, but neither
    CRC can be checked, and each says so (with either CRC right or wrong)."""
    index = _rec(0x07, bytes(200))
    limits = ReadLimits(record_bytes=199)
    for crc_xor in ((0, 0), (1, 1)):
        data, _ = _hand_log(_second_chunk(0), index, _second_chunk(1), summary=_STATISTICS,
                            crc_xor=crc_xor)
        scan = _scan(tmp_path, data, limits)
        assert scan.warnings == ["the data section CRC was not checked: records over a read "
                                 "limit were skipped unread", "the summary CRC was not checked: "
                                 "records over a read limit were skipped unread"]
        assert not scan.damaged and scan.complete
        assert scan.messages == {1: _second(0) + _second(1)}
    # a limit of exactly the record's length skips nothing: both CRCs are checked again
    data, _ = _hand_log(_second_chunk(0), index, _second_chunk(1), summary=_STATISTICS)
    assert _scan(tmp_path, data, ReadLimits(record_bytes=200)).warnings == []
