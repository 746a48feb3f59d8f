"""Issue 33, items 12-14: logs of real robots (poses only), the control phase in
``wmr.read_log``, and a spawned viewer that keeps none of the caller's pipes."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import wmr
from test_replay import fig11_log, fmu_plant, spec  # noqa: F401  (its fixtures)
from wmr.adapters.mcap.scene import ALIGN, APPROACH, control_phases
from wmr.adapters.rerun.replay import VIEWER_PORT, _listening

# -- item 14: the spawned viewer and the caller's pipe -------------------------------------------

_FAKE_VIEWER = """#!/bin/sh
# a viewer that never exits (nor listens), chatty like Rerun's INFO/WARN lines
echo $$ > "{pid_file}"
i=0
while [ $i -lt 50 ]; do
  echo "INFO fake viewer line $i"; echo "WARN fake viewer $i" >&2; i=$((i+1))
done
exec sleep 600
"""


def test_a_spawned_viewer_keeps_neither_our_pipe_nor_our_terminal(
        fig11_log: Path, tmp_path: Path) -> None:  # noqa: F811
    """Before: ``wmr replay LOG 2>&1 | tail`` waited as long as the viewer ran (rr.spawn let it
    inherit our stdout/stderr) and its lines came out on ours.  Now it gets neither: our pipe
    closes when wmr ends; its lines are in its own log in the cache."""
    if _listening(VIEWER_PORT):
        pytest.skip(f"a viewer already listens on port {VIEWER_PORT}: nothing would be spawned")
    fake_bin = tmp_path / "bin"
    fake_bin.mkdir()
    pid_file = tmp_path / "viewer.pid"
    fake = fake_bin / "rerun"
    fake.write_text(_FAKE_VIEWER.format(pid_file=pid_file))
    fake.chmod(0o755)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), DISPLAY=":77",
               PATH=f"{fake_bin}{os.pathsep}{os.environ.get('PATH', '')}",
               WMR_CACHE_DIR=str(tmp_path / "cache"))
    log = tmp_path / "fig11.mcap"
    log.write_bytes(fig11_log.read_bytes())
    proc = subprocess.Popen([sys.executable, "-m", "wmr.cli", "replay", str(log)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    start = time.monotonic()
    try:
        out, _ = proc.communicate(timeout=90)  # to EOF of the pipe: every writer has closed it
        took_s = time.monotonic() - start
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise
    finally:
        if pid_file.exists():
            os.kill(int(pid_file.read_text()), signal.SIGKILL)
    text = out.decode()
    assert pid_file.exists(), "the fake viewer was not started"
    assert took_s < 60
    assert "fake viewer" not in text
    # it never listened: the recording went to a file, said in one line
    assert "not listening on port" in text and log.with_suffix(".rrd").is_file(), text
    assert "INFO fake viewer line 49" in (tmp_path / "cache" / "viewer.log").read_text()


# -- item 13: the control phase in wmr.read_log ---------------------------------------------------


def test_read_log_gives_the_logged_control_phase_at_each_row(fig11_log: Path) -> None:  # noqa: F811
    """Before: ``/controller/phase`` was logged but ``wmr.read_log`` had no phase.  Now
    ``Log.phase`` is a column on the rows' index: the logged step plot, forward-filled, which
    is the stabiliser's hysteresis on the logged distance to the goal."""
    log = wmr.read_log(fig11_log)
    phase = log.phase
    assert phase is not None and phase.name == "phase"
    assert phase.index.equals(log.signals.index)
    expected = control_phases(log.signals["dr_m"].to_numpy(),
                              float(log.metadata["run"]["stop_radius_m"]))
    np.testing.assert_array_equal(phase.to_numpy(), expected.astype(np.float64))
    # fig11 approaches, then aligns inside the stop radius until it converges
    assert phase.iloc[0] == APPROACH and phase.iloc[-1] == ALIGN
    assert set(np.unique(phase.to_numpy())) == {APPROACH, ALIGN}


def test_a_log_without_the_phase_topic_has_no_phase(fig11_log: Path, tmp_path: Path) -> None:  # noqa: F811
    """A log without ``/controller/phase`` (a killed run's) says so: ``phase`` is None."""
    cut = tmp_path / "cut.mcap"
    data = fig11_log.read_bytes()
    cut.write_bytes(data[: len(data) // 2])  # the scene topics are written at close
    log = wmr.read_log(cut)
    assert log.truncated and len(log.signals) > 0
    assert log.phase is None
