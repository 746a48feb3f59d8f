"""Writes that a planted file cannot redirect (issue 17): a symbolic link, a hard link or a
FIFO at a temporary file's name (``X.mcap.partial``, the summary's temporary files) is never
written through; the file it points to stays as it was, and the refusal is one line."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pyarrow as pa
import pytest

from wmr.apps.batch.summary import SUMMARY_CSV, SUMMARY_PARQUET, write_summary
from wmr.infra.durable import AtomicFile, partial_path
from wmr.infra.errors import LogError

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
