"""Issue 30, "the rest of the same walk-through": defects a new user hit, each pinned here.

Every test was seen failing on the code before its fix (see the commit messages).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from wmr.apps.batch.spec import BATCH_SECTIONS, parse_batch
from wmr.config.scenario import TOP_FIELDS
from wmr.infra.errors import ConfigError

_BASE = {"name": "walk", "start": [0.0, 0.0, 0.0], "goal": [4.0, 2.0, 0.0]}


@pytest.mark.parametrize(("typo", "value", "meant"), [
    ("randm", {"seed": 1, "n": 3}, "random"),
    ("lists", [{"name": "x"}], "list"),
    ("logs", {"keep": "all"}, "log"),
    ("gird", {"params": {"m": [20.0]}}, "grid"),
])
def test_a_misspelled_section_names_every_section_and_the_closest(
        typo: str, value: object, meant: str) -> None:
    """Before: ``randm: unknown field (allowed fields: name, ..., fmu_map)``, the list of a
    plain scenario's fields, without grid, list, random and log."""
    with pytest.raises(ConfigError) as err:
        parse_batch({**_BASE, typo: value})
    assert err.value.field == typo
    assert f"did you mean {meant!r}?" in err.value.fix
    listed = err.value.fix.split("allowed fields: ", 1)[1].split(", ")
    assert listed == [*TOP_FIELDS, *BATCH_SECTIONS]
    assert {"grid", "list", "random", "log"} <= set(listed)


def test_an_unknown_field_far_from_every_name_gets_no_guess() -> None:
    with pytest.raises(ConfigError) as err:
        parse_batch({**_BASE, "grid": {"params": {"zzzz": [1.0]}}})
    assert err.value.field == "grid.params.zzzz"
    assert "did you mean" not in err.value.fix
    assert err.value.fix.startswith("allowed fields: ")


def test_the_fmu_documentation_prints_start_values_as_written() -> None:
    """Before: ``0.14999999999999999`` for a start of 0.15 (``%.17g``) and ``nan`` for the
    outputs, which have no start value."""
    from wmr.build.documentation import index_html
    from wmr.build.flatten import flatten
    from wmr.infra import paths

    model = flatten(paths.modelica_dir())
    page = index_html(model)
    starts = {v.name: v.start for v in (*model.inputs, *model.outputs, *model.parameters)}
    assert starts["r"] == 0.15  # the case a user saw as 0.14999999999999999
    assert "<td>nan</td>" not in page and "0.14999999999999999" not in page
    for name, start in starts.items():
        row = re.search(rf"<code>{re.escape(name)}</code></td><td>[^<]*</td><td>([^<]*)</td>",
                        page)
        assert row is not None, name
        shown = row.group(1)
        if start != start:  # NaN: no start value
            assert shown == "none", (name, shown)
        else:
            assert float(shown) == start and shown == repr(start), (name, shown)


def test_the_path_of_a_run_without_a_log_warns_how_to_get_it() -> None:
    """Before: ``wmr.run(..., log="none").path`` was an empty DataFrame, without a word."""
    import wmr

    res = wmr.RunResult({"name": "fig11", "status": "converged", "mcap": None}, None)
    with pytest.warns(UserWarning, match=r'log="none".*log="full"') as seen:
        path = res.path
    assert len(seen) == 1 and "'fig11'" in str(seen[0].message)
    assert path.empty and list(path.columns) == ["x_m", "y_m", "theta_rad"]


@pytest.mark.parametrize(("heading_deg", "as_pi"), [
    (1.5708, "pi/2"), (3.1416, "pi"), (0.7854, "pi/4"), (-1.5708, "-pi/2"),
    (6.2832, "2pi"), (2.3562, "3pi/4"), (0.2618, "pi/12"),
    (0.0, None), (1.0, None), (5.0, None), (5.5, None), (6.0, None), (30.0, None),
    (45.0, None), (90.0, None), (180.0, None), (-90.0, None), (1.57, "pi/2"), (1.56, None),
    (7.0, None),
])
def test_a_heading_that_looks_like_radians_is_told_apart(heading_deg: float,
                                                         as_pi: str | None) -> None:
    from wmr.config.scenario import heading_looks_like_radians

    assert heading_looks_like_radians(heading_deg) == as_pi


def test_a_goal_heading_in_radians_is_warned_and_the_result_says_its_units(
        tmp_path: Path, capfd: pytest.CaptureFixture[str], fmu3: Path) -> None:
    """Before: ``wmr run --goal 5 5 1.5708`` ran to 1.57 deg without a word, and the result
    gave the heading error in rad only, while the headings it takes are in degrees."""
    from wmr.cli import main

    code = main(["run", "--goal", "5", "5", "1.5708", "--fmu", str(fmu3),
                 "--out", str(tmp_path / "g.mcap")])
    out, err = capfd.readouterr()
    assert code == 0, err
    warned = [line for line in err.splitlines() if "looks like" in line]
    assert warned == ["wmr: warning: --goal heading 1.5708 is in degrees but looks like "
                      "pi/2 rad: give 90 if you meant pi/2 rad"], err
    line = out.strip().splitlines()[-1]
    assert re.search(r"heading error \d+\.\d{5} rad \(\d+\.\d{3} deg\)", line), line
    # an ordinary heading in degrees: no warning
    code = main(["run", "--goal", "5", "5", "90", "--fmu", str(fmu3),
                 "--out", str(tmp_path / "h.mcap")])
    assert code == 0 and "looks like" not in capfd.readouterr().err


def test_a_multi_run_scenario_names_all_its_runs_and_lists_them(
        capsys: pytest.CaptureFixture[str]) -> None:
    """Before: ``wmr run fig9`` named 6 of its 13 runs then "...", and there was no way to
    list them but reading the TOML."""
    from wmr.cli import main
    from wmr.config.scenario import load_scenario

    runs = load_scenario("fig9").runs
    assert main(["run", "fig9"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("wmr: error: --run:")
    assert all(r.name in err[0] for r in runs) and "wmr run fig9 --list" in err[0]
    assert main(["run", "fig9", "--list"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split(":")[0] for line in lines] == [r.name for r in runs]
    assert lines[0] == "fig9-thd-090: --start 0 0 0 --goal 20 10 -90"


def test_a_scenario_of_many_runs_names_the_first_20_and_the_count() -> None:
    from wmr.apps.run import select_run
    from wmr.config.scenario import parse_scenario

    sc = parse_scenario({"name": "many", "runs": [
        {"name": f"r{i:02d}", "start": [0.0, 0.0, 0.0], "goal": [float(i + 1), 0.0, 0.0]}
        for i in range(25)]})
    with pytest.raises(ConfigError) as err:
        select_run(sc, None)
    assert "its 25 runs: r00, " in err.value.fix and "r19, ..." in err.value.fix
    assert "r20" not in err.value.fix


def test_a_shipped_scenario_file_name_resolves_and_suggestions_are_runnable(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: ``wmr run fig11.toml`` outside the repository was "no such file", and an
    unknown name was answered with the batch specs too (mc_fig10, ...), which ``wmr run``
    refuses."""
    from wmr.config.scenario import load_scenario, resolve_scenario_path, shipped_names
    from wmr.infra.paths import scenarios_dir

    monkeypatch.chdir(tmp_path)
    assert resolve_scenario_path("fig11.toml") == scenarios_dir() / "fig11.toml"
    assert load_scenario("fig11.toml").name == "fig11"
    (tmp_path / "fig11.toml").write_text('name = "mine"\nstart = [0.0, 0.0, 0.0]\n'
                                         'goal = [1.0, 0.0, 0.0]\n')
    assert load_scenario("fig11.toml").name == "mine"  # a file here comes first
    assert resolve_scenario_path("nothing.toml") == Path("nothing.toml")
    with pytest.raises(ConfigError) as err:
        load_scenario("fig1")
    offered = err.value.fix.split("one of: ")[1].split(", ")
    assert offered == shipped_names(batch_specs=False)
    assert {"fig9", "fig10", "fig11"} <= set(offered)
    for name in shipped_names():  # every other shipped file is a batch spec wmr run refuses
        if name not in offered:
            with pytest.raises(ConfigError, match="is a batch spec"):
                load_scenario(name)
    assert set(offered) < set(shipped_names())


def test_progress_off_a_terminal_is_a_line_every_interval_with_count_and_time_left() -> None:
    """Before: a batch whose stderr was not a terminal said nothing until it ended (tqdm's
    bar, disabled off a terminal), and ``wmr benchmark`` printed a line per run with no
    count or time left."""
    import io

    from wmr.apps.progress import ProgressLines

    ticks = iter(float(t) for t in range(0, 1000, 3))  # 3 s per item
    out = io.StringIO()
    bar = ProgressLines(20, "mc", "run", initial=5, file=out, interval_s=10.0,
                        clock=lambda: next(ticks))
    for _ in range(9):
        bar.set_postfix_str("ok 3, timeout 0, failed 0")
        bar.update(1)
    bar.close()
    lines = out.getvalue().splitlines()
    # items at 3, 6, ..., 27 s: a line at 12 s and at 24 s, and the last at close (30 s)
    assert lines[0] == ("wmr: mc: 9/20 runs (45 %), ok 3, timeout 0, failed 0; 12 s elapsed, "
                        "about 33 s left")  # 4 runs in 12 s: 3 s a run, 11 to go
    assert lines[1].startswith("wmr: mc: 13/20 runs (65 %)") and "about 21 s left" in lines[1]
    assert lines[2].startswith("wmr: mc: 14/20 runs (70 %)") and len(lines) == 3
    quiet = io.StringIO()  # shorter than the interval: nothing, as before
    short = ProgressLines(3, "mc", "run", file=quiet, interval_s=10.0)
    short.update(3)
    short.close()
    assert quiet.getvalue() == ""


def test_a_notebook_gets_one_bar_and_a_file_gets_lines(monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: ``progress=True`` in a notebook left about 33 lines of text bars."""
    import sys

    from tqdm.auto import tqdm as auto

    from wmr.apps.progress import NOTEBOOK_INTERVAL_S, ProgressLines, count_progress

    bar = count_progress(10, "mc", "run", None)  # pytest's stderr is no terminal
    assert isinstance(bar, ProgressLines)
    monkeypatch.setitem(sys.modules, "ipykernel", sys)  # as in a Jupyter kernel
    nb = count_progress(10, "mc", "run", True)
    try:
        assert isinstance(nb, auto) and nb.mininterval == NOTEBOOK_INTERVAL_S
    finally:
        nb.close()
    assert isinstance(count_progress(10, "mc", "run", None), ProgressLines)
    off = count_progress(10, "mc", "run", False)
    assert getattr(off, "disable", False) is True


def test_a_batch_off_a_terminal_prints_progress_lines(
        tmp_path: Path, capfd: pytest.CaptureFixture[str], fmu3: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    from wmr.apps import progress
    from wmr.apps.batch.command import BatchRequest, batch_command

    monkeypatch.setattr(progress, "LINE_INTERVAL_S", 0.0)  # every run, not every 10 s
    spec = tmp_path / "masses.toml"
    spec.write_text('name = "masses"\nstart = [0.0, 0.0, 0.0]\ngoal = [2.0, 1.0, 0.0]\n'
                    'max_time_s = 20.0\n[grid.params]\nm = [20.0, 40.0]\n')
    batch_command(BatchRequest(spec, tmp_path / "out", workers=1, fmu=fmu3), progress=None)
    lines = [line for line in capfd.readouterr().err.splitlines()
             if line.startswith("wmr: masses: ")]
    assert [line.split(" runs")[0] for line in lines] == ["wmr: masses: 1/2",
                                                          "wmr: masses: 2/2"], lines
    assert "ok 1, timeout 0, failed 0" in lines[0] and "left" in lines[0]
