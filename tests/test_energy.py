"""Issue 11, defect 3: one energy definition (wmr.core.energy) and one key set in the results of
``wmr run``, ``wmr optimal``, ``wmr benchmark`` and the batch summaries."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from wmr.adapters.mcap import read_run
from wmr.apps.batch.summary import RESULT_COLUMNS
from wmr.apps.benchmark import FIELDS
from wmr.cli import main
from wmr.core.energy import ENERGY_KEYS, step_work, wheel_work


def _last_json(capsys: pytest.CaptureFixture[str]) -> dict[str, object]:
    out: dict[str, object] = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    return out


def test_the_integrals_of_a_known_power() -> None:
    # one wheel: +2 N m over speeds 0 -> 3 rad/s, then -2 N m over 3 -> -1 rad/s (h = 0.5 s)
    tau = [[2.0, 0.0], [-2.0, 0.0]]
    w = [[0.0, 0.0], [3.0, 0.0], [-1.0, 0.0]]
    e = wheel_work(tau, w, 0.5)
    # powers at the step ends: (0, 6) then (-6, 2); trapezoids of 0.25 s each
    assert e["energy_net_j"] == pytest.approx(0.25 * (0 + 6 - 6 + 2))
    assert e["energy_positive_j"] == pytest.approx(0.25 * (6 + 2))
    assert e["energy_abs_j"] == pytest.approx(0.25 * (6 + 6 + 2))
    steps = [step_work(0.5, t[0], t[1], a[0], b[0], a[1], b[1])
             for t, a, b in zip(tau, w[:-1], w[1:], strict=True)]
    assert [sum(x) for x in zip(*steps, strict=True)] == pytest.approx(
        [e[k] for k in ENERGY_KEYS])


def test_run_reports_the_energy_of_its_logged_signals(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r.mcap"
    assert main(["run", "--goal", "3", "1", "0", "--out", str(out), "--json"]) == 0
    rec = _last_json(capsys)
    assert "energy_j" not in rec  # the old, ambiguous key: net work under the name "energy"
    log = read_run(out)
    sig = log.signals
    tau = np.column_stack([sig["tau_r_nm"], sig["tau_l_nm"]])[:-1]
    w = np.column_stack([sig["omega_r_radps"], sig["omega_l_radps"]])
    again = wheel_work(tau, w, np.diff(log.t_s))
    for key in ENERGY_KEYS:
        assert rec[key] == pytest.approx(again[key], rel=1e-9, abs=1e-12)
    assert rec["energy_positive_j"] > 1.0 > abs(rec["energy_net_j"])  # type: ignore[operator]


def test_optimal_reports_the_same_keys_from_its_fmu_replay(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "o.mcap"
    assert main(["optimal", "--goal", "3", "1", "0", "--out", str(out), "--json"]) == 0
    rec = _last_json(capsys)
    assert "energy_J" not in rec
    log = read_run(out)
    tau = np.column_stack([log.signals["tau_r_nm"], log.signals["tau_l_nm"]])[:-1]
    w = np.column_stack([log.signals["omega_r_radps"], log.signals["omega_l_radps"]])
    again = wheel_work(tau, w, np.diff(log.t_s))  # the log's times are rounded to 1 ns
    for key in ENERGY_KEYS:
        assert rec[key] == pytest.approx(again[key], abs=1e-5 * again["energy_positive_j"])
    # the optimiser's own estimate of the same figure, on its finer RK4 grid
    assert rec["ocp_energy_positive_j"] == pytest.approx(rec["energy_positive_j"], rel=0.05)


def test_benchmark_and_batch_tables_carry_the_same_keys() -> None:
    assert set(ENERGY_KEYS) <= set(FIELDS)
    assert set(ENERGY_KEYS) <= set(RESULT_COLUMNS)
    assert not {"energy_j", "energy_J"} & (set(FIELDS) | set(RESULT_COLUMNS))
