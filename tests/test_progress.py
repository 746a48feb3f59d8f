"""Long work says it is running (issue 21): ``wmr tune`` and ``wmr report`` print a line at
least every few seconds (the FMU build's and the optimiser's lines are tested in
``test_fmu_build.py`` and ``test_optimal.py``)."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from wmr.apps.batch.report import write_report
from wmr.apps.batch.summary import SUMMARY_PARQUET


def test_a_report_says_each_plot_before_it_draws_it(tmp_path: Path) -> None:
    n = 6
    table = pa.table({
        "run_id": [f"r{i}" for i in range(n)],
        "status": ["converged"] * (n - 1) + ["timeout"],
        "message": ["ok"] * n,
        "params.m": [20.0, 25.0, 30.0] * 2,
        "gains.K_ps": [0.5] * 3 + [1.0] * 3,
        "time_to_goal_s": [10.0 + i for i in range(n)],
        "path_length_m": [22.0 + i for i in range(n)],
        "final_position_error_m": [0.01] * n,
        "final_heading_error_rad": [0.001] * n,
        "peak_torque_nm": [8.0] * n,
        "torque_sq_integral_n2m2s": [100.0 + i for i in range(n)],
    })
    pq.write_table(table, tmp_path / SUMMARY_PARQUET)
    lines: list[str] = []
    write_report(tmp_path, progress=lines.append)
    assert lines[0].startswith("report: reading")
    assert "report: plotting the runs per status" in lines
    assert "report: plotting the spread of the metrics" in lines
    assert [line for line in lines if "plotting against" in line] == [
        "report: plotting against params.m (1/2)", "report: plotting against gains.K_ps (2/2)"]


def test_tune_reports_its_evaluations_at_least_every_interval(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """One line at the start, then whenever the interval has passed, and at the last
    evaluation (a clock that moves 2 s per evaluation, an interval of 5 s)."""
    from wmr.cli import tune as cli

    ticks = iter(range(0, 1000, 2))
    report = cli._TuneProgress("pi", budget=10, cases=3)
    monkeypatch.setattr(report, "clock", lambda: float(next(ticks)))
    for evaluation in range(1, 11):
        report(evaluation, 5.0 - 0.1 * evaluation, 4.0)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "wmr: tune pi: up to 10 evaluations of 3 runs each"
    evaluations = [int(line.split("evaluation ")[1].split("/")[0]) for line in lines[1:]]
    assert evaluations == [1, 4, 7, 10]


@pytest.mark.parametrize("content", [b"not parquet at all", b"PAR1" + b"\0" * 64 + b"PAR1"])
def test_a_report_of_a_damaged_summary_is_one_line(tmp_path: Path, content: bytes) -> None:
    """A batch folder may come from anyone: a summary that is not Parquet is a one-line
    :class:`LogError` naming it, never an Arrow traceback."""
    from wmr.infra.errors import LogError

    (tmp_path / SUMMARY_PARQUET).write_bytes(content)
    with pytest.raises(LogError, match="not a readable Parquet summary") as info:
        write_report(tmp_path)
    assert len(str(info.value).splitlines()) == 1 and SUMMARY_PARQUET in str(info.value)


def test_a_report_of_a_summary_without_run_ids_names_the_column(tmp_path: Path) -> None:
    from wmr.infra.errors import LogError

    pq.write_table(pa.table({"status": ["converged"], "message": ["ok"]}),
                   tmp_path / SUMMARY_PARQUET)
    with pytest.raises(LogError, match="no column run_id"):
        write_report(tmp_path)
