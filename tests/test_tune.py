"""``wmr tune``: Nelder-Mead gain tuning never ends worse than it started."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from wmr.adapters.fmi.robot import FmuPlant
from wmr.apps.batch.spec import load_batch
from wmr.apps.tune import PENALTY_S, case_cost, default_cases, evaluate, tune, with_gains
from wmr.cli import main
from wmr.core.closedloop import LoopOutcome
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
def test_tune_peers_improves_or_equals(fmu3_plant: FmuPlant, controller: str) -> None:
    specs = [RunSpec(name="a", start=Pose(0, 0, 0), goal=Pose(3.0, 1.0, 0.5), t_max_s=40.0)]
    res = tune(controller, specs, fmu3_plant, budget=6)
    assert res.evaluations <= 6
    assert res.cost_s <= res.start_cost_s
    again, _ = evaluate(controller, res.gains, specs, fmu3_plant)
    assert again == pytest.approx(res.cost_s)  # deterministic


def test_inadmissible_gains_cost_the_penalty(fmu3_plant: FmuPlant) -> None:
    specs = [RunSpec(name="a", start=Pose(0, 0, 0), goal=Pose(3.0, 0.0, 0.0), t_max_s=30.0)]
    cost, results = evaluate("astolfi", {"k_rho": 5.0, "k_alpha": 1.0}, specs, fmu3_plant)
    assert results == [None] and cost == pytest.approx(2 * 30.0 + PENALTY_S)


def test_case_cost_orders_outcomes() -> None:
    spec = RunSpec(name="a", start=Pose(0, 0, 0), goal=Pose(3.0, 0.0, 0.0), t_max_s=30.0)

    def result(status: str, t: float | None, d: float) -> LoopOutcome:
        return LoopOutcome(status, "", d, 0.0, t, 1.0, 0.0, 0.0, 0.0, 0.0, 1, Pose(0, 0, 0))

    ok = case_cost(result("converged", 12.0, 0.01), spec)
    late = case_cost(result("timeout", None, 0.5), spec)
    bad = case_cost(result("failed", None, 0.5), spec)
    assert ok == pytest.approx(12.0) and ok < late < bad


def test_default_set_and_pi_gains_go_to_the_gains_table() -> None:
    specs = default_cases()
    assert len(specs) == 10 and {s.scenario for s in specs} == {"fig9", "fig10"}
    s = with_gains(specs[0], "pi", {"K_ps": 0.7})
    assert s.gains.K_ps == 0.7 and s.controller == "pi"


TINY_MC = """
name = "tiny_mc"
start = [0.0, 0.0, 0.0]
goal = [2.0, 1.0, 20.0]
max_time_s = 40.0

[random]
seed = 7
n = 5

[random.params]
m = { dist = "uniform", low = 20.0, high = 70.0 }

[random.limits]
torque_max_nm = { dist = "uniform", low = 3.0, high = 8.0 }
"""


def _draw_of(spec: RunSpec) -> tuple[object, ...]:
    """What a run's random draw decides (everything but the tuned gains)."""
    return (spec.name, spec.start, spec.goal, spec.params, spec.limits, spec.t_max_s)


def test_wmr_tune_on_a_spec_scores_every_candidate_on_the_same_draws(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch, fmu3_plant: FmuPlant) -> None:
    import wmr.apps.tune as tune_mod

    spec = tmp_path / "tiny_mc.toml"
    spec.write_text(TINY_MC, encoding="utf-8")
    seen: list[tuple[tuple[object, ...], tuple[float, ...]]] = []
    real = tune_mod.run_closed_loop

    def counting(s: RunSpec, *args: Any, **kwargs: Any) -> LoopOutcome:
        seen.append((_draw_of(s), (s.gains.K_ps, s.gains.K_is, s.gains.K_ptheta,
                                   s.gains.K_itheta)))
        return real(s, *args, **kwargs)

    monkeypatch.setattr(tune_mod, "run_closed_loop", counting)
    code = main(["tune", "--spec", str(spec), "--runs", "3", "--budget", "5", "--json"])
    captured = capsys.readouterr()
    rec = json.loads(captured.out.strip().splitlines()[-1])
    assert code == 0, captured.err
    assert rec["runs"] == 3 and rec["evaluations"] == 5
    # the spec's first 3 draws, as wmr batch expands them, in every one of the 5 evaluations
    draws = [_draw_of(r.spec) for r in load_batch(spec).runs[:3]]
    assert len({d[3] for d in draws}) == 3 and len({d[4] for d in draws}) == 3
    assert len(seen) == 5 * 3
    for k in range(5):
        assert [d for d, _ in seen[3 * k:3 * k + 3]] == draws
    # the start, then Nelder-Mead's simplex (the start again, then +30 % in each of 3 gains)
    assert len({g for _, g in seen}) == 4
    # no worse than its start on those draws, scored again here
    monkeypatch.setattr(tune_mod, "run_closed_loop", real)
    specs = tune_mod.batch_cases(spec, 3)
    start_cost, _ = evaluate("pi", {g.name: g.default for g in tune_mod.tunable_gains("pi")},
                             specs, fmu3_plant)
    tuned_cost, results = evaluate("pi", rec["gains"], specs, fmu3_plant)
    assert start_cost == pytest.approx(rec["start_objective_s"])
    assert tuned_cost == pytest.approx(rec["objective_s"]) and tuned_cost <= start_cost
    assert rec["converged"] == sum(r is not None and r.status == "converged" for r in results)


@pytest.mark.parametrize(("argv", "field", "words"), [
    (["--runs", "9"], "--runs", "the spec tiny_mc has 5"),
    (["--runs", "0"], "--runs", "must be an integer >= 1"),
    (["SCEN"], "--spec", "given with scenarios"),
])
def test_wmr_tune_spec_refuses_bad_runs_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], field: str,
        words: str) -> None:
    spec = tmp_path / "tiny_mc.toml"
    spec.write_text(TINY_MC, encoding="utf-8")
    argv = [str(spec) if a == "SCEN" else a for a in argv]
    code = main(["tune", "--spec", str(spec), *argv, "--budget", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and field in err[0] and words in err[0], err


def test_wmr_tune_runs_without_spec_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["tune", "--runs", "3", "--budget", "1", "--no-optimal"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "--runs" in err[0] and "--spec" in err[0], err
