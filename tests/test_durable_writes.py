"""Writes that a planted file cannot redirect (issue 17): a symbolic link, a hard link or a
FIFO at a temporary file's name (``X.mcap.partial``, the summary's temporary files) is never
written through; the file it points to stays as it was, and the refusal is one line."""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Literal

import pyarrow as pa
import pytest

from wmr.apps.batch.summary import SUMMARY_CSV, SUMMARY_PARQUET, write_summary
from wmr.infra.durable import AtomicFile, partial_path, replacing
from wmr.infra.errors import ConfigError, LogError
from wmr.infra.outputs import check_output

PRECIOUS = b"precious data\n"


@pytest.fixture
def precious(tmp_path: Path) -> Path:
    path = tmp_path / "home" / "precious.txt"
    path.parent.mkdir()
    path.write_bytes(PRECIOUS)
    return path


def _plant(kind: str, at: Path, target: Path) -> None:
    if kind == "symlink":
        at.symlink_to(target)
    elif kind == "hardlink":
        os.link(target, at)
    elif kind == "fifo":
        os.mkfifo(at)
    elif kind == "dangling":
        at.symlink_to(target.with_name("not-yet.txt"))


@pytest.mark.parametrize("kind", ["symlink", "hardlink", "fifo", "dangling"])
def test_a_planted_partial_file_is_refused_not_written_through(
        kind: str, tmp_path: Path, precious: Path) -> None:
    out = tmp_path / "out.mcap"
    _plant(kind, partial_path(out), precious)
    with pytest.raises(LogError) as info:
        AtomicFile(out, "log")
    message = str(info.value)
    assert len(message.splitlines()) == 1 and "out.mcap.partial" in message
    assert "wmr never makes" in message
    assert precious.read_bytes() == PRECIOUS
    assert not out.exists() and not out.is_symlink()
    assert not precious.with_name("not-yet.txt").exists()


def test_wmr_run_does_not_overwrite_the_target_of_a_planted_partial(
        tmp_path: Path, precious: Path, fmu2: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The attack of the issue: ``ln -s ~/precious.txt out.mcap.partial; wmr run --out
    out.mcap``."""
    from wmr.cli import main

    out = tmp_path / "out.mcap"
    partial_path(out).symlink_to(precious)
    code = main(["run", "fig11", "--fmu", str(fmu2), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and "is a symbolic link" in err[-1], err
    assert precious.read_bytes() == PRECIOUS
    assert not out.exists() and not out.is_symlink()


def test_a_leftover_partial_of_a_killed_run_is_still_reused(tmp_path: Path) -> None:
    """A regular ``.partial`` of ours (a killed writer's) is emptied and written, as before."""
    out = tmp_path / "out.mcap"
    partial_path(out).write_bytes(b"killed run")
    f = AtomicFile(out, "log")
    f.write(b"new")
    f.commit()
    assert out.read_bytes() == b"new" and not partial_path(out).exists()


def test_a_new_partial_is_not_truncated_only_a_leftover_is(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    """A new ``.partial`` is empty already: not truncated (on ext4 a truncation to zero makes
    the file's close allocate and write back its blocks in the writer's process, 65 us of a
    batch log's close); a killed writer's leftover is, and only it."""
    import wmr.infra.durable as durable

    cut: list[int] = []
    real = os.ftruncate
    monkeypatch.setattr(durable.os, "ftruncate",
                        lambda fd, size: (cut.append(size), real(fd, size))[1])
    fresh = tmp_path / "fresh.mcap"
    f = AtomicFile(fresh, "log")
    f.write(b"new")
    f.commit()
    assert cut == [] and fresh.read_bytes() == b"new"
    left = tmp_path / "left.mcap"
    partial_path(left).write_bytes(b"killed run, longer than the new file")
    f = AtomicFile(left, "log")
    f.write(b"new")
    f.commit()
    assert cut == [0] and left.read_bytes() == b"new"


def _table() -> pa.Table:
    return pa.table({"run_id": ["a", "b"], "x": [1.0, 2.0]})


@pytest.mark.parametrize("name", ["summary.csv.tmp", "summary.parquet.tmp"])
def test_a_planted_summary_temp_file_is_not_followed(tmp_path: Path, precious: Path,
                                                     name: str) -> None:
    """The batch folder's summary on resume: a link at the old fixed temporary name."""
    (tmp_path / name).symlink_to(precious)
    write_summary(_table(), tmp_path)
    assert precious.read_bytes() == PRECIOUS
    assert (tmp_path / SUMMARY_CSV).read_text() == "run_id,x\na,1.0\nb,2.0\n"
    for final in (SUMMARY_CSV, SUMMARY_PARQUET):
        assert stat.S_ISREG((tmp_path / final).lstat().st_mode)


def test_a_link_at_the_final_name_is_replaced_not_written_through(tmp_path: Path,
                                                                  precious: Path) -> None:
    (tmp_path / SUMMARY_CSV).symlink_to(precious)
    write_summary(_table(), tmp_path)
    assert precious.read_bytes() == PRECIOUS
    assert not (tmp_path / SUMMARY_CSV).is_symlink()


def test_replacing_keeps_the_old_file_on_failure_and_uses_the_umask(tmp_path: Path) -> None:
    from wmr.infra.durable import replacing

    target = tmp_path / "f.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError), replacing(target) as f:
        f.write(b"half")
        raise RuntimeError("stop")
    assert target.read_bytes() == b"old" and os.listdir(tmp_path) == ["f.bin"]
    old_mask = os.umask(0o027)
    try:
        with replacing(target) as f:
            f.write(b"new")
    finally:
        os.umask(old_mask)
    assert target.read_bytes() == b"new"
    assert stat.S_IMODE(target.stat().st_mode) == 0o640


@pytest.mark.parametrize("kind", ["symlink", "hardlink"])
def test_a_batch_journal_planted_in_a_batch_folder_is_not_appended_through(
        kind: str, tmp_path: Path, precious: Path) -> None:
    """A batch folder copied from someone else may hold a link at ``journal.jsonl``: the
    journal's append must not write into what it points at."""
    from wmr.apps.batch.journal import Journal

    journal_path = tmp_path / "batch" / "journal.jsonl"
    journal_path.parent.mkdir()
    _plant(kind, journal_path, precious)
    with pytest.raises(LogError, match=r"journal\.jsonl") as info:
        Journal(journal_path).append({"run_id": "0000-00000000", "status": "converged"})
    assert len(str(info.value).splitlines()) == 1
    assert precious.read_bytes() == PRECIOUS


@pytest.mark.parametrize("name", [".lock", "journal.jsonl"])
def test_wmr_batch_refuses_a_batch_folder_with_a_planted_link(
        name: str, tmp_path: Path, precious: Path, fmu3: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    from wmr.cli import main

    spec = tmp_path / "spec.toml"
    spec.write_text('name = "s"\nstart = [0.0, 0.0, 0.0]\ngoal = [1.0, 0.0, 0.0]\n'
                    'max_time_s = 0.5\n[grid.gains]\nK_ps = [0.25, 0.5]\n')
    out = tmp_path / "batch"
    out.mkdir()
    _plant("symlink", out / name, precious)
    code = main(["batch", str(spec), "--out", str(out), "--workers", "1", "--fmu", str(fmu3)])
    err = capsys.readouterr().err
    assert code != 0 and name in err and "symbolic link" in err
    assert precious.read_bytes() == PRECIOUS


def test_a_link_at_the_build_lock_is_refused_not_truncated(tmp_path: Path,
                                                           precious: Path) -> None:
    """The build lock was opened with ``open(..., "w")``, which truncated whatever a link
    planted at its name pointed at."""
    from wmr.build.fmus import _locked

    out = tmp_path / "fmus"
    out.mkdir()
    _plant("symlink", out / ".wmr-build.lock", precious)
    # refused naming the lock, and the folder's field and fix (ConfigError, since the cache's
    # refusals name WMR_CACHE_DIR or --out)
    with pytest.raises(ConfigError, match=r"wmr-build\.lock: is a symbolic link"), _locked(out):
        pass
    assert precious.read_bytes() == PRECIOUS


@pytest.mark.parametrize("durable", [True, False])
def test_writeback_starts_once_per_writeback_bytes_of_a_durable_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, durable: bool) -> None:
    """A durable file hands its pages to the disk once every WRITEBACK_BYTES flushed, not at
    every flush (a log flushes every second of simulation time); a file that is not durable
    never; nothing is lost either way."""
    from wmr.infra import durable as durable_mod

    starts: list[int] = []
    monkeypatch.setattr(durable_mod, "_start_writeback", starts.append)
    f = durable_mod.AtomicFile(tmp_path / "out.bin", durable=durable)
    piece = bytes(range(256)) * 4096  # 1 MiB
    for _ in range(20):
        f.write(piece)
        f.flush()
    f.commit()
    assert (tmp_path / "out.bin").read_bytes() == piece * 20
    per = durable_mod.WRITEBACK_BYTES // len(piece)
    assert len(starts) == (20 // per if durable else 0)


# -- issue 28 item 8: an output that is a device or a FIFO is never replaced -------------------

def _special_node(kind: str, at: Path) -> None:
    """A FIFO, or a character device node (a copy of /dev/null's) in the test's folder."""
    if kind == "fifo":
        os.mkfifo(at)
        return
    try:
        os.mknod(at, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("making a device node needs CAP_MKNOD")


def _still_special(kind: str, at: Path) -> bool:
    mode = os.lstat(at).st_mode
    return stat.S_ISFIFO(mode) if kind == "fifo" else stat.S_ISCHR(mode)


_WORDS = {"fifo": "is a named pipe (FIFO), not a regular file",
          "chr": "is a character device, not a regular file"}


@pytest.mark.parametrize("kind", ["fifo", "chr"])
def test_wmr_run_refuses_a_device_or_fifo_as_its_log(kind: str, tmp_path: Path, fmu2: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """``wmr run --out X`` exited 0 and left a regular file where the FIFO or device was."""
    from wmr.cli import main

    out = tmp_path / "node.mcap"
    _special_node(kind, out)
    assert main(["run", "fig11", "--fmu", str(fmu2), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"wmr: error: --out: {out} {_WORDS[kind]}"), err
    assert "even with --force" in err[0]
    assert _still_special(kind, out) and not partial_path(out).exists()


@pytest.mark.parametrize("kind", ["fifo", "chr"])
def test_log_recover_with_force_never_replaces_a_device_or_fifo(
        kind: str, tmp_path: Path, fmu2: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``wmr log recover ok.mcap -o <a device node> --force`` replaced the node."""
    from wmr.adapters.mcap.recover import recover_log
    from wmr.cli import main

    ok = tmp_path / "ok.mcap"
    assert main(["run", "fig11", "--fmu", str(fmu2), "--out", str(ok)]) == 0
    capsys.readouterr()
    node = tmp_path / "node"
    _special_node(kind, node)
    assert main(["log", "recover", str(ok), "-o", str(node), "--force"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"wmr: error: --out: {node} {_WORDS[kind]}"), err
    with pytest.raises(ConfigError, match=f"^output: {node} {re.escape(_WORDS[kind])}"):  # the API
        recover_log(ok, node, overwrite=True)
    assert _still_special(kind, node) and not partial_path(node).exists()


@pytest.mark.parametrize("kind", ["fifo", "chr"])
def test_the_writers_themselves_refuse_a_device_or_fifo(kind: str, tmp_path: Path) -> None:
    """:class:`AtomicFile` (every log) and ``replacing`` (summaries, packages) check the
    target too, at the start and again just before the rename: a node made meanwhile keeps
    the written data in ``.partial``."""
    node = tmp_path / "x"
    _special_node(kind, node)
    refused = f"^output: {node} {re.escape(_WORDS[kind])}"
    with pytest.raises(ConfigError, match=refused):
        AtomicFile(node)
    with pytest.raises(ConfigError, match=refused), replacing(node) as f:
        f.write(b"data")
    assert _still_special(kind, node) and os.listdir(tmp_path) == ["x"]
    later = tmp_path / "later"
    out = AtomicFile(later)
    out.write(b"finished data")
    _special_node(kind, later)
    with pytest.raises(ConfigError, match=re.escape(_WORDS[kind])):
        out.commit()
    assert _still_special(kind, later) and partial_path(later).read_bytes() == b"finished data"


@pytest.mark.parametrize(("kind", "want", "words"), [
    ("fifo", "file", _WORDS["fifo"]), ("chr", "file", _WORDS["chr"]),
    ("fifo", "dir", "is a named pipe (FIFO), not a folder"),
    ("chr", "dir", "is a character device, not a folder"),
])
def test_check_output_names_what_the_node_is(kind: str, want: Literal["file", "dir"],
                                             words: str, tmp_path: Path) -> None:
    """The one check every option's output goes through (--out, -o, --rrd, --blueprint,
    wmr report's folder, wmr figures --out, wmr fmu build --out, wmr batch --out)."""
    node = tmp_path / "n"
    _special_node(kind, node)
    link = tmp_path / "link"
    link.symlink_to(node)  # /dev/stdout is a link: followed
    for p in (node, link):
        with pytest.raises(ConfigError, match=f"^--rrd: {p} {re.escape(words)}"):
            check_output(p, "--rrd", want)
    regular = tmp_path / "r"
    regular.write_bytes(b"")
    assert check_output(regular, "--out") == regular
    assert check_output(tmp_path, "--out", "dir") == tmp_path


def _summary_folder(tmp_path: Path) -> Path:
    from wmr.apps.batch.summary import SummaryRow, summary_table

    out = tmp_path / "batch"
    out.mkdir()
    rows = [SummaryRow(f"000{i}-00000000", f"r{i}", f"r{i}", "", {}, "pi", 0) for i in range(2)]
    records = {r.run_id: {"status": "converged", "message": "", "steps": 3} for r in rows}
    write_summary(summary_table(rows, [], records), out)
    return out


def test_wmr_report_refuses_a_device_among_its_outputs(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """``wmr report`` wrote its plots and ``report.md`` through whatever was there (a FIFO
    blocked it for ever, a device was written)."""
    from wmr.cli import main

    out = _summary_folder(tmp_path)
    (out / "report").mkdir()
    _special_node("chr", out / "report" / "status.png")
    assert main(["report", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    # the last line, after the progress lines; the whole path even where it is long (as the
    # field it was cut at 80 characters: CI's longer temporary folders failed this)
    assert err[-1].startswith(f"wmr: error: output: {out / 'report' / 'status.png'} "
                              f"{_WORDS['chr']}"), err
    assert _still_special("chr", out / "report" / "status.png")


def test_wmr_report_refuses_a_fifo_as_its_summary(tmp_path: Path) -> None:
    """In a subprocess with a timeout: the old code blocked for ever opening the FIFO."""
    import subprocess
    import sys

    out = _summary_folder(tmp_path)
    (out / SUMMARY_PARQUET).unlink()
    os.mkfifo(out / SUMMARY_PARQUET)
    proc = subprocess.run([sys.executable, "-m", "wmr.cli", "report", str(out)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines()[-1].startswith(
        f"wmr: error: DIR: {out / SUMMARY_PARQUET} is a named pipe (FIFO), not a regular "
        "file"), proc.stderr


def test_figures_refuse_a_device_where_a_figure_goes(tmp_path: Path) -> None:
    from matplotlib.figure import Figure

    from wmr.apps.figures import _save

    _special_node("chr", tmp_path / "fig9.png")
    with pytest.raises(ConfigError, match=f"^output: {tmp_path / 'fig9.png'} {_WORDS['chr']}"):
        _save(Figure(), tmp_path / "fig9.png")
    assert _still_special("chr", tmp_path / "fig9.png")
