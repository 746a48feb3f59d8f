"""Issue 11, defects 1, 6 and 8 for ``wmr optimal``: a far goal fails fast in one line, the
default log is named after the manoeuvre, and the log has no NaN field, exact sample times and
the case attached."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from wmr.adapters.mcap import OPEN_LOOP_TOPICS, read_run
from wmr.adapters.mcap.readme import README_TOPIC
from wmr.adapters.mcap.scene import GOAL_TOPIC, PATH_TOPIC, ROBOT_TOPIC
from wmr.cli import main
from wmr.config.scenario import parse_scenario


def test_a_far_goal_fails_fast_in_one_line_naming_the_option(
        capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """(The host build the command uses is made first, so that its standard error holds the
    error alone, not a build's progress, whichever test ran before.)"""
    import wmr.adapters.ocp.solve
    from wmr.apps.run import default_fmu

    default_fmu(3)
    capfd.readouterr()

    def never(*_a: object) -> None:
        raise AssertionError("the NLP was built for a goal it cannot resolve (33 s of IPOPT)")

    monkeypatch.setattr(wmr.adapters.ocp.solve, "_nlp", never)
    assert main(["optimal", "--goal", "1000", "500", "0", "--json"]) == 1
    out, err = capfd.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("wmr: error: --goal:"), lines
    assert "CasADi" not in err and "NaN" not in err
    assert "within about 60 m" in lines[0] and "n_intervals in the Python API" in lines[0]
    assert json.loads(out.strip().splitlines()[-1])["field"] == "--goal"


def test_arguments_are_named_as_options(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["optimal", "--objective", "energy", "--final-time", "1000"]) == 1
    err = capsys.readouterr().err
    assert "wmr: error: --final-time:" in err and "final_time_s" not in err


def test_the_optimal_log_is_named_complete_and_exact(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["optimal", "--goal", "3", "1", "0", "--json"]) == 0
    rec = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    path = Path(rec["mcap"])
    assert path == Path("runs/optimal-time-to_3_1_0deg.mcap")
    assert not Path("runs/optimal-time.mcap").exists()
    log = read_run(path)
    assert log.warnings == []
    # only the topics that apply, each with every field finite
    with path.open("rb") as fh:
        topics = {c.topic for c in make_reader(fh).get_summary().channels.values()}  # type: ignore[union-attr]
    # the open-loop topics, the scene (no controller: no /controller/phase) and the note a
    # bare Rerun viewer shows
    assert topics == {t.topic for t in OPEN_LOOP_TOPICS} | {"/goal", ROBOT_TOPIC, PATH_TOPIC,
                                                            GOAL_TOPIC, README_TOPIC}
    for layout in OPEN_LOOP_TOPICS:
        for sig in layout.signals:
            assert np.all(np.isfinite(log.signals[sig])), sig
    # sample n at round(n h 1e9) ns, h the control_period_s of its metadata
    h = json.loads(log.metadata["run"]["control_period_s"])
    n = np.arange(log.n_steps)
    assert np.array_equal(log.t_ns, np.round(n * (h * 1e9)).astype(np.int64))
    assert 0.0 < h <= 0.01 and math.isclose(log.t_ns[-1] * 1e-9, rec["final_time_s"],
                                            abs_tol=1e-9)
    # the case attached as a scenario that wmr run reads
    (toml,) = [name for name in log.attachments if name.endswith(".toml")]
    runs = parse_scenario(tomllib.loads(log.attachments[toml].decode())).runs
    assert len(runs) == 1 and (runs[0].goal.x_m, runs[0].goal.y_m) == (3.0, 1.0)
