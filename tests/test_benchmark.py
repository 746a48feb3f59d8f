"""``wmr benchmark`` and ``wmr optimal``: the PI against its peers and the optimum."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import read_run
from wmr.apps.benchmark import CONTROLLERS, FIELDS, OPTIMAL, run_benchmark, run_optimal
from wmr.cli import main
from wmr.config.scenario import load_scenario
from wmr.core.closedloop import run_closed_loop
from wmr.core.control.from_spec import SpecController

REQUIRED = {"case", "controller", "time_to_goal_s", "path_length_m", "final_heading_error_rad"}

TWO_CASES = """
name = "two"
start = [0.0, 0.0, 0.0]
max_time_s = 60.0

[[runs]]
name = "near-ahead"
goal = [4.0, 2.0, 0.0]

[[runs]]
name = "near-left"
goal = [2.0, 3.0, 90.0]
"""



def _last_json(capsys: pytest.CaptureFixture[str]) -> object:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_benchmark_json_on_two_cases(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scen = tmp_path / "two.toml"
    scen.write_text(TWO_CASES, encoding="utf-8")
    out = tmp_path / "bench"
    code = main(["benchmark", str(scen), "--out", str(out), "--json"])
    rows = _last_json(capsys)
    assert code == 0
    assert isinstance(rows, list)
    assert len(rows) == 2 * (len(CONTROLLERS) + 1)
    for r in rows:
        assert REQUIRED <= set(r)
        assert r["status"] in ("converged", "solved"), r
        assert r["final_heading_error_rad"] < math.radians(0.5) + 1e-9
    by = {(r["case"], r["controller"]): r for r in rows}
    for case in ("near-ahead", "near-left"):
        opt = by[(case, OPTIMAL)]
        assert opt["time_ratio"] == pytest.approx(1.0)
        assert by[(case, "pi")]["time_ratio"] >= 1.0  # nobody beats the optimum forward
        assert (out / "logs" / "pi" / f"{case}.mcap").is_file()
        log = read_run(out / "logs" / OPTIMAL / f"{case}.mcap")
        assert not log.truncated and log.metadata["run"]["controller"] == "optimal"
    with (out / "benchmark.csv").open(encoding="utf-8") as fh:
        table = list(csv.DictReader(fh))
    assert len(table) == len(rows) and tuple(table[0]) == FIELDS
    import pyarrow.parquet as pq

    assert pq.read_table(out / "benchmark.parquet").num_rows == len(rows)


def test_optimal_is_never_slower_than_the_pi_on_fig11(fmu3_plant: FmuPlant) -> None:
    spec = load_scenario("fig11").runs[0]
    pi = run_closed_loop(spec, fmu3_plant, controller=SpecController())
    opt = run_optimal(spec, fmu3_plant, None)
    assert pi.status == "converged" and opt.status == "solved"
    assert opt.final_time_s is not None and pi.time_to_goal_s is not None
    assert opt.final_time_s <= pi.time_to_goal_s
    # the replay on the FMU ends on the goal
    assert opt.figures["final_position_error_m"] < 0.1
    assert opt.figures["peak_torque_nm"] <= spec.limits.torque_max_nm + 1e-6


def test_wmr_optimal_json_and_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "opt.mcap"
    code = main(["optimal", "--goal", "10", "5", "30", "--out", str(out), "--json"])
    rec = _last_json(capsys)
    assert code == 0
    assert isinstance(rec, dict)
    assert {"status", "final_time_s", "path_length_m", "mcap"} <= set(rec)
    assert rec["status"] == "solved" and rec["final_time_s"] > 0
    log = read_run(out)
    assert not log.truncated
    # /robot/pose is the FMU at every 10 ms step, not the optimiser's 61 nodes
    assert log.n_steps > 10 * 60
    x, y = log.signals["x_m"][-1], log.signals["y_m"][-1]
    assert math.hypot(x - 10.0, y - 5.0) < 0.1
    assert abs(log.signals["tau_r_nm"]).max() <= 8.0 + 1e-6
    assert math.isnan(log.signals["e_s_m"][0])  # no controller
    assert log.metadata["result"]["status"] == "solved"


def test_wmr_optimal_energy_takes_longer_with_less_effort(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    main(["optimal", "--goal", "6", "2", "0", "--out", str(tmp_path / "t.mcap"), "--json"])
    fast = _last_json(capsys)
    main(["optimal", "--goal", "6", "2", "0", "--objective", "energy",
          "--out", str(tmp_path / "e.mcap"), "--json"])
    slow = _last_json(capsys)
    assert isinstance(fast, dict) and isinstance(slow, dict)
    assert slow["status"] == "solved"
    assert slow["final_time_s"] == pytest.approx(1.5 * fast["final_time_s"], rel=1e-6)
    assert slow["torque_sq_integral_n2m2s"] < fast["torque_sq_integral_n2m2s"]


def test_wmr_optimal_bad_torque_is_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["optimal", "--torque-limit", "0"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--torque-limit" in err[0]


@pytest.mark.slow
def test_optimal_never_slower_than_pi_across_fig9(fmu3_plant: FmuPlant) -> None:
    for spec in load_scenario("fig9").runs:
        pi = run_closed_loop(spec, fmu3_plant, controller=SpecController())
        opt = run_optimal(spec, fmu3_plant, None)
        assert pi.status == "converged" and opt.status == "solved", spec.name
        assert opt.final_time_s is not None and pi.time_to_goal_s is not None
        assert opt.final_time_s <= pi.time_to_goal_s, spec.name


@pytest.mark.slow
def test_full_fig9_fig10_benchmark(fmu3_plant: FmuPlant, tmp_path: Path) -> None:
    specs = list(load_scenario("fig9").runs) + list(load_scenario("fig10").runs)
    rows = run_benchmark(specs, fmu3_plant, tmp_path)
    assert len(rows) == len(specs) * (len(CONTROLLERS) + 1)
    assert all(r["status"] in ("converged", "solved") for r in rows)
    assert all(r["time_ratio"] is not None and r["time_ratio"] >= 0.999 for r in rows
               if r["controller"] in ("pi", "pi-tuned", "graceful", "graceful-tuned"))
    # tuning helps the PI on average
    mean = {c: sum(r["time_to_goal_s"] for r in rows if r["controller"] == c) for c in
            ("pi", "pi-tuned")}
    assert mean["pi-tuned"] < mean["pi"]
