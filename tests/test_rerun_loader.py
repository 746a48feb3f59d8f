"""Issue 33, item 2: the raw log in a Rerun viewer of default settings.

Rerun 0.41 never hands an ``.mcap`` file to an external importer (``rerun-importer-*`` on
``PATH``): checked here with a probe importer, so that the day Rerun does, this test says
that ``rerun X.mcap`` could call one of ours.  What its own importer does show is the note
every log carries (:mod:`wmr.adapters.mcap.readme`): checked through ``rerun mcap convert``
and Rerun's own ``.rrd`` reader."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
import rerun.chunk as rrc
import rerun_cli

from wmr.adapters.mcap import read_run
from wmr.adapters.mcap.readme import README_TEXT, README_TOPIC, read_readme, readme_message

RERUN = str(Path(rerun_cli.__file__).parent / "rerun")
#: The exit status that tells Rerun "not mine" (``EXTERNAL_IMPORTER_INCOMPATIBLE_EXIT_CODE``).
INCOMPATIBLE = 66

_PROBE = """#!/bin/sh
# an external importer that says where it was called and that the file is not its own
echo "$1" >> "{calls}"
exit {code}
"""


def _save(path: Path, out: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """What the viewer gets when it opens ``path``: ``rerun PATH --save OUT`` (the viewer's
    own import, without a window)."""
    return subprocess.run([RERUN, str(path), "--save", str(out)], env=env, capture_output=True,
                          text=True, timeout=120, check=False)


def test_rerun_hands_an_mcap_file_to_its_own_importer_only(fig11_log: Path,
                                                           tmp_path: Path) -> None:
    """An importer on PATH is called for a file type Rerun does not know (the probe works),
    and not for our ``.mcap`` log: ``rerun X.mcap`` cannot be made to call ours."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    calls = tmp_path / "calls.txt"
    probe = bin_dir / "rerun-importer-wmr-probe"
    probe.write_text(_PROBE.format(calls=calls, code=INCOMPATIBLE))
    probe.chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}")
    other = tmp_path / "run.wmrprobe"
    other.write_bytes(fig11_log.read_bytes())
    res = _save(other, tmp_path / "other.rrd", env)
    assert calls.read_text().split() == [str(other)], res.stderr  # the probe is called ...
    assert res.returncode != 0  # ... says "not mine", and no importer is left
    log = tmp_path / "fig11.mcap"
    log.write_bytes(fig11_log.read_bytes())
    res = _save(log, tmp_path / "log.rrd", env)
    assert res.returncode == 0, res.stderr
    assert calls.read_text().split() == [str(other)]  # not called for the .mcap


def test_rerun_shows_the_logs_note_saying_what_to_run(fig11_log: Path,
                                                      tmp_path: Path) -> None:
    """Rerun's own importer (what ``rerun X.mcap`` runs) makes the note a ``TextDocument``,
    whose text is the whole note; our reader leaves the topic alone."""
    out = tmp_path / "fig11.rrd"
    subprocess.run([RERUN, "mcap", "convert", str(fig11_log), "-o", str(out)], check=True,
                   capture_output=True, timeout=120)
    texts = []
    for chunk in rrc.RrdReader(out).stream():
        if chunk.entity_path == README_TOPIC:
            batch = chunk.to_record_batch()
            if "TextDocument:text" in batch.schema.names:
                texts += batch.column("TextDocument:text").to_pylist()
    assert texts == [[README_TEXT]]
    assert "wmr replay THIS_FILE.mcap" in README_TEXT
    data = read_run(fig11_log)
    assert not any(README_TOPIC in w for w in data.warnings) and not data.truncated


@pytest.mark.parametrize("text", ["", "a", "x" * 1001, "é ünïcode ✓\nlines"])
def test_the_note_is_cdr_of_a_ros2_string(text: str) -> None:
    """The CDR bytes: header 00 01 00 00, a uint32 length counting the NUL, the bytes, NUL."""
    data = readme_message(text)
    raw = text.encode()
    assert data[:4] == b"\x00\x01\x00\x00"
    assert int.from_bytes(data[4:8], "little") == len(raw) + 1
    assert data[8:] == raw + b"\x00"
    assert read_readme(data) == text
    with pytest.raises(ValueError, match="does not fit"):
        read_readme(data[:-1])
