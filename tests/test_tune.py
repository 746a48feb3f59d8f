"""``wmr tune``: Nelder-Mead gain tuning never ends worse than it started."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from wmr.adapters.fmi.robot import FmuPlant
from wmr.apps.tune import PENALTY_S, case_cost, default_cases, evaluate, tune, with_gains
from wmr.cli import main
from wmr.core.closedloop import RunResult
from wmr.core.plant import Pose
from wmr.core.runspec import RunSpec

SMALL = """
name = "small"
start = [0.0, 0.0, 0.0]
max_time_s = 40.0

[[runs]]
name = "a"
goal = [3.0, 1.0, 0.0]

[[runs]]
name = "b"
goal = [2.0, -2.0, -60.0]
"""



@pytest.fixture(scope="module")
def fmu(fmu3: Path) -> Iterator[FmuPlant]:
    with FmuPlant(fmu3) as p:
        yield p


def test_wmr_tune_small_budget_improves_or_equals(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scen = tmp_path / "small.toml"
    scen.write_text(SMALL, encoding="utf-8")
    save = tmp_path / "tuned.json"
    code = main(["tune", str(scen), "--budget", "8", "--save", str(save), "--json"])
    rec = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 0
    assert rec["evaluations"] <= 8
    assert rec["objective_s"] <= rec["start_objective_s"]
    assert rec["mean_time_ratio"] >= 1.0  # no controller beats the optimum
    assert json.loads(save.read_text())["pi"] == rec["gains"]


@pytest.mark.parametrize("controller", ["astolfi", "graceful"])
def test_tune_peers_improves_or_equals(fmu: FmuPlant, controller: str) -> None:
    specs = [RunSpec(name="a", start=Pose(0, 0, 0), goal=Pose(3.0, 1.0, 0.5), t_max_s=40.0)]
    res = tune(controller, specs, fmu, budget=6)
    assert res.evaluations <= 6
    assert res.cost_s <= res.start_cost_s
    again, _ = evaluate(controller, res.gains, specs, fmu)
    assert again == pytest.approx(res.cost_s)  # deterministic


def test_inadmissible_gains_cost_the_penalty(fmu: FmuPlant) -> None:
    specs = [RunSpec(name="a", start=Pose(0, 0, 0), goal=Pose(3.0, 0.0, 0.0), t_max_s=30.0)]
    cost, results = evaluate("astolfi", {"k_rho": 5.0, "k_alpha": 1.0}, specs, fmu)
    assert results == [None] and cost == pytest.approx(2 * 30.0 + PENALTY_S)


def test_case_cost_orders_outcomes() -> None:
    spec = RunSpec(name="a", start=Pose(0, 0, 0), goal=Pose(3.0, 0.0, 0.0), t_max_s=30.0)

    def result(status: str, t: float | None, d: float) -> RunResult:
        return RunResult(status, "", d, 0.0, t, 1.0, 0.0, 0.0, 0.0, 0.0, 1, Pose(0, 0, 0))

    ok = case_cost(result("converged", 12.0, 0.01), spec)
    late = case_cost(result("timeout", None, 0.5), spec)
    bad = case_cost(result("failed", None, 0.5), spec)
    assert ok == pytest.approx(12.0) and ok < late < bad


def test_default_set_and_pi_gains_go_to_the_gains_table() -> None:
    specs = default_cases()
    assert len(specs) == 10 and {s.scenario for s in specs} == {"fig9", "fig10"}
    s = with_gains(specs[0], "pi", {"K_ps": 0.7})
    assert s.gains.K_ps == 0.7 and s.controller == "pi"
