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
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, SeekingReader, make_reader
from mcap.records import DataEnd
from mcap.stream_reader import StreamReader

from wmr.adapters.mcap import RunData, RunLogWriter, read_run
from wmr.adapters.mcap.reader import LogScan, ReadLimits, scan_file
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
    scene = ["/scene/goal", "/scene/path", "/scene/robot", "/controller/phase"]
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
    assert scan.warnings == ["the log holds more than 2 MiB (ReadLimits.total_bytes): read stops "
                             "at record 3; give a higher limit to read it all"]
