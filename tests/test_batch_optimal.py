"""The optimum beside every run of a batch (issue 30): a spec's top-level ``optimal`` solves the
CasADi OCP for each run's start, goal, robot and limits; the summary gains the optimum's
columns, a solver failure is a row's status with its message, and a resume solves nothing
again."""

from __future__ import annotations

import math
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from wmr.apps.batch import load_batch
from wmr.apps.batch.runner import BatchOptions, _test_hooks, run_batch
from wmr.apps.batch.summary import OPTIMUM_RESULT_COLUMNS, RESULT_COLUMNS, SUMMARY_PARQUET
from wmr.infra.errors import ConfigError

#: How far below the optimum the PI's time may be: the PI's run ends when B is within the
#: stop radius (5 cm) at the heading tolerance, counted in whole control periods (0.01 s),
#: the OCP's at the goal exactly and at rest, on RK4 over 60 intervals (its replay's own error
#: is millimetres, docs/optimal.md).  A PI cannot beat the optimum by more than the time the
#: last 5 cm take at the end of a rest-to-rest manoeuvre; 2 % of a 5 to 8 s manoeuvre is
#: 0.1 to 0.16 s, which covers it.
GAP_TOLERANCE = 0.02

SPEC = """name = "opt"
start = [3.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 30.0
optimal = "time"
[[list]]
name = "light"
params = { m = 20.0 }
[[list]]
name = "nominal"
[[list]]
name = "heavy"
params = { m = 40.0 }
[[list]]
name = "far"
goal = [150.0, 0.0, 0.0]
max_time_s = 1.0
"""


def _summary(out: Path) -> dict[str, dict[str, object]]:
    rows = pq.read_table(out / SUMMARY_PARQUET).to_pylist()
    return {str(r["variant"]): r for r in rows}


def test_a_batch_with_the_optimum_has_its_columns_and_records_a_failure(
        fmu3: Path, tmp_path: Path) -> None:
    """Four short runs with ``optimal = "time"``: the optimum's columns follow the results,
    the PI is never faster than the optimum (up to :data:`GAP_TOLERANCE`), a heavier robot has
    a longer optimum, and a goal the OCP cannot resolve is a ``failed`` optimum with the
    solver's message, not a bare NaN."""
    spec = tmp_path / "opt.toml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    result = run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3),
                       progress=False)
    assert result.finished == 4
    table = pq.read_table(out / SUMMARY_PARQUET)
    assert table.column_names[-len(OPTIMUM_RESULT_COLUMNS) - 1:] == \
        ["mcap", *OPTIMUM_RESULT_COLUMNS]
    rows = _summary(out)
    for name in ("light", "nominal", "heavy"):
        r = rows[name]
        assert r["status"] == "converged" and r["optimal_status"] == "solved", r
        assert 0.0 < r["optimal_time_s"] < r["time_to_goal_s"] * (1 + GAP_TOLERANCE)  # type: ignore[operator]
        assert r["time_gap"] == pytest.approx(r["time_to_goal_s"] / r["optimal_time_s"])  # type: ignore[operator]
        assert r["time_gap"] >= 1.0 - GAP_TOLERANCE  # type: ignore[operator]
        assert r["energy_gap"] == pytest.approx(
            r["energy_positive_j"] / r["optimal_energy_j"])  # type: ignore[operator]
    assert rows["light"]["optimal_time_s"] < rows["nominal"]["optimal_time_s"] \
        < rows["heavy"]["optimal_time_s"]  # type: ignore[operator]
    far = rows["far"]
    assert far["status"] == "timeout"
    assert far["optimal_status"] == "failed"
    assert "147 m from the start" in str(far["optimal_message"])
    assert far["optimal_time_s"] is None and far["time_gap"] is None


def test_a_spec_without_optimal_has_no_optimum_columns(fmu3: Path, tmp_path: Path) -> None:
    """The summary of a spec without ``optimal`` has exactly the columns it always had."""
    spec = tmp_path / "plain.toml"
    spec.write_text(SPEC.replace('optimal = "time"\n', "").split("[[list]]\nname = \"far\"")[0])
    out = tmp_path / "out"
    run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    names = pq.read_table(out / SUMMARY_PARQUET).column_names
    assert names[-len(RESULT_COLUMNS):] == list(RESULT_COLUMNS)
    assert not set(OPTIMUM_RESULT_COLUMNS) & set(names)


def test_a_resumed_batch_does_not_solve_again(fmu3: Path, tmp_path: Path) -> None:
    """The optimum is in each run's journal line: a batch stopped after two runs and resumed
    executes the other two only, and the summary keeps the first two's optimum; a spec that
    asks for the optimum after its runs were done without it runs them again with it."""
    text = SPEC.split("[[list]]\nname = \"far\"")[0]
    spec = tmp_path / "opt.toml"
    spec.write_text(text.replace('optimal = "time"\n', ""))
    out = tmp_path / "out"
    run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    spec.write_text(text)
    with _test_hooks(stop_after=2):
        first = run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3),
                          progress=False)
    assert len(first.executed) == 2  # the runs without an optimum were run again
    before = _summary(out)
    resumed = run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3),
                        progress=False)
    assert resumed.skipped == 2 and len(resumed.executed) == 1
    after = _summary(out)
    assert all(r["optimal_status"] == "solved" for r in after.values())
    for name, row in before.items():
        if row["optimal_status"] == "solved":
            assert after[name]["optimal_time_s"] == row["optimal_time_s"]
    again = run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.executed == [] and _summary(out) == after


def test_an_unknown_objective_is_refused_naming_the_field(tmp_path: Path) -> None:
    spec = tmp_path / "bad.toml"
    spec.write_text(SPEC.replace('optimal = "time"', 'optimal = "fastest"'))
    with pytest.raises(ConfigError) as err:
        load_batch(spec)
    assert err.value.field == "optimal" and "'time' or 'energy'" in str(err.value)


def test_the_previous_solution_warm_starts_the_same_manoeuvre_only() -> None:
    """A worker's previous optimum starts IPOPT when the new run is the same manoeuvre
    relative to its start (another robot); for another manoeuvre the kinematic path does."""
    from wmr.adapters.ocp import OptimalLimits, OptimalProblem, solve_optimal
    from wmr.core.control import Limits
    from wmr.core.plant import Pose, RobotParams

    limits = OptimalLimits.like(Limits())
    goal = Pose(0.0, 0.0, math.pi)
    first = solve_optimal(OptimalProblem(Pose(3.0, 0.0, 0.0), goal, limits=limits))
    assert first.extra["guess"] == "kinematic"
    # the same manoeuvre turned by -90 deg about the goal, on a heavier robot
    turned = OptimalProblem(Pose(0.0, -3.0, -math.pi / 2), Pose(0.0, 0.0, math.pi / 2),
                            RobotParams(m=40.0), limits=limits)
    same = solve_optimal(turned, previous=first)
    assert same.solved and same.extra["guess"] == "previous"
    fresh = solve_optimal(turned)
    assert same.final_time_s == pytest.approx(fresh.final_time_s, rel=1e-6)
    other = solve_optimal(OptimalProblem(Pose(2.0, 1.0, 0.0), goal, limits=limits),
                          previous=first)
    assert other.solved and other.extra["guess"] == "kinematic"


def test_wmr_optimal_takes_a_scenario_and_its_overrides(
        fmu3: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``wmr optimal SCENARIO --param m=40`` solves the scenario's run on the heavier robot
    (a longer optimum than the nominal one), names its log after the change, and a bad
    ``--param`` is one line naming it, exit 1."""
    import json

    from wmr.cli import main

    def solve(*extra: str) -> dict[str, object]:
        out = tmp_path / f"{len(extra)}.mcap"
        assert main(["optimal", "fig11", "--fmu", str(fmu3), "--out", str(out), "--json",
                     *extra]) == 0
        return dict(json.loads(capsys.readouterr().out.strip().splitlines()[-1]))

    nominal, heavy = solve(), solve("--param", "m=40")
    assert str(heavy["name"]).startswith("optimal-time-m=40")
    assert heavy["final_time_s"] > nominal["final_time_s"]  # type: ignore[operator]
    assert main(["optimal", "fig11", "--param", "bogus=1"]) == 1
    assert "bogus" in capsys.readouterr().err
