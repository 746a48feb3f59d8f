"""``wmr report`` (issue 30, "a report an engineer reads"): every input ranked by its influence
on convergence, time to goal and energy; the ``--json`` numbers against pandas; the worst runs
and the failed ones with the command that reruns them; maps, legends, and no spec field
dropped while a derived one is plotted.  Summaries are made here with pyarrow: no batch runs."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from wmr.apps.batch.report import write_report
from wmr.apps.batch.report_data import report_data
from wmr.apps.batch.sensitivity import MAIN_EFFECT, RBD_FAST, rank_inputs
from wmr.apps.batch.summary import SUMMARY_PARQUET
from wmr.cli import main

POSES = ("start.x_m", "start.y_m", "start.heading_deg", "goal.x_m", "goal.y_m",
         "goal.heading_deg")


def _summary(folder: Path, inputs: Mapping[str, Sequence[float]], status: Sequence[str],
             ttg: Sequence[float] | None = None, extra: Mapping[str, Sequence[Any]] = {},
             poses: Mapping[str, Sequence[float]] = {}) -> Path:
    """A summary as ``wmr batch`` writes one: ids, the pose columns (fixed unless given),
    the inputs, the results (time to goal NaN where the run did not converge)."""
    n = len(status)
    rng = np.random.default_rng(7)
    ok = np.array([s == "converged" for s in status])
    t = np.asarray(ttg if ttg is not None else 10.0 + rng.uniform(0, 5, n), dtype=np.float64)
    cols: dict[str, Any] = {"run_id": [f"{i:04d}-{i * 2654435761 % 16**8:08x}" for i in range(n)],
                            "name": ["mc"] * n, "base": ["mc"] * n, "variant": [""] * n}
    for c in POSES:
        cols[c] = list(poses.get(c, [5.0 if c == "goal.x_m" else 0.0] * n))
    cols.update({k: list(map(float, v)) for k, v in inputs.items()})
    cols.update({"status": list(status),
                 "message": ["ok" if s == "converged" else f"{s}: limit | reached\nat 60 s"
                             for s in status],
                 "final_position_error_m": (0.01 + 0.5 * ~ok + rng.uniform(0, 0.01, n)).tolist(),
                 "final_heading_error_rad": [0.001] * n,
                 "time_to_goal_s": [float(v) if o else None for v, o in zip(t, ok, strict=True)],
                 "path_length_m": (6.0 + rng.uniform(0, 1, n)).tolist(),
                 "energy_positive_j": (50.0 + rng.uniform(0, 20, n)).tolist(),
                 "peak_torque_nm": [8.0] * n, "torque_sq_integral_n2m2s": [100.0] * n,
                 "mcap": [None if o else f"runs/{cols['run_id'][i]}.mcap"
                          for i, o in enumerate(ok)]})
    cols.update(extra)
    pq.write_table(pa.table(cols), folder / SUMMARY_PARQUET)
    return folder


def _json(folder: Path, capsys: pytest.CaptureFixture[str], *more: str) -> dict[str, Any]:
    assert main(["report", str(folder), "--json", *more]) == 0
    out = capsys.readouterr().out
    assert len(out.splitlines()) == 1  # one JSON object, one line

    def refuse(name: str) -> None:
        raise AssertionError(f"{name} in the JSON")

    data: dict[str, Any] = json.loads(out, parse_constant=refuse)
    return data


def _ranked(data: Mapping[str, Any], outcome: str) -> list[str]:
    return [k["input"] for k in data["sensitivity"][outcome]]


# -- sensitivity -------------------------------------------------------------------------------

def test_a_monte_carlo_outcome_decided_by_one_input_ranks_it_first_and_a_shuffled_one_last(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Convergence decided by ``limits.torque_max_nm`` alone; the time to goal by three inputs
    of decreasing weight (variances 16 : 4 : 1); ``params.shuffled`` is a permutation of the
    strongest input, so the same values and no influence: ranked last everywhere."""
    rng = np.random.default_rng(3)
    n = 2000
    torque, tau, mass = rng.uniform(4, 12, n), rng.uniform(0, 1, n), rng.uniform(15, 35, n)
    shuffled = rng.permutation(torque)
    status = np.where(torque < 6.0, "failed", "converged")
    ttg = 10.0 + 4.0 * tau * math.sqrt(12) + 2.0 * (mass - 15) / 20 * math.sqrt(12) \
        + 1.0 * (torque - 4) / 8 * math.sqrt(12)
    data = _json(_summary(tmp_path, {"limits.torque_max_nm": torque, "params.tau_c": tau,
                                     "params.m": mass, "params.shuffled": shuffled},
                          status.tolist(), ttg), capsys)
    assert data["design"] == "sampled"
    conv = data["sensitivity"]["converged"]
    assert conv[0]["input"] == "limits.torque_max_nm" and conv[0]["index"] > 0.5
    assert conv[-1]["input"] == "params.shuffled" or conv[-1]["index"] < 0.02
    assert all(k["method"] == RBD_FAST for k in conv)
    assert _ranked(data, "time_to_goal_s") == ["params.tau_c", "params.m",
                                               "limits.torque_max_nm", "params.shuffled"]
    index = [k["index"] for k in data["sensitivity"]["time_to_goal_s"]]
    assert index == sorted(index, reverse=True) and index[-1] < 0.02
    assert data["sensitivity_line"].startswith(
        "Convergence depends most on limits.torque_max_nm (RBD-FAST ")
    assert "time to goal depends most on params.tau_c" in data["sensitivity_line"]
    # the index in runs: the failures at the lowest and the highest torque bin, from pandas
    df = pd.DataFrame({"t": torque, "bad": status != "converged"})
    edges = np.linspace(torque.min(), torque.max(), 11)
    low = df[df["t"] < edges[1]]["bad"].mean()
    text = write_report(tmp_path).read_text()
    assert (f"* Not converged against `limits.torque_max_nm`: {100 * low:.1f} % at "
            f"{(edges[0] + edges[1]) / 2:.3g}, 0.0 % at") in text


def test_an_outcome_decided_by_the_interaction_of_two_inputs_ranks_both_first(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A run fails only when the friction is high *and* the torque limit low (the issue's
    pandas finding): both share the top (1/3 of the variance each in theory), the
    independent inputs are far below."""
    rng = np.random.default_rng(5)
    n = 3000
    tau, torque = rng.uniform(0, 1, n), rng.uniform(4, 12, n)
    other, shuffled = rng.uniform(0, 1, n), rng.permutation(tau)
    status = np.where((tau > 0.5) & (torque < 8.0), "timeout", "converged")
    data = _json(_summary(tmp_path, {"params.other": other, "params.tau_c": tau,
                                     "params.shuffled": shuffled,
                                     "limits.torque_max_nm": torque}, status.tolist()), capsys)
    conv = data["sensitivity"]["converged"]
    assert {k["input"] for k in conv[:2]} == {"params.tau_c", "limits.torque_max_nm"}
    assert all(0.2 < k["index"] < 0.45 for k in conv[:2])
    assert all(k["index"] < 0.03 for k in conv[2:])
    # the map over the two that matter: every run of the failing corner failed, against pandas
    g = data["grid_map"]
    assert g["design"] == "sampled" and g["binned"]
    assert (g["x"], g["y"]) == (conv[0]["input"], conv[1]["input"])
    df = pd.DataFrame({g["x"]: tau if g["x"] == "params.tau_c" else torque,
                       g["y"]: torque if g["x"] == "params.tau_c" else tau,
                       "ok": status == "converged"})
    for axis, key in ((g["x"], "ix"), (g["y"], "iy")):
        edges = np.linspace(df[axis].min(), df[axis].max(), 11)
        df[key] = np.clip(np.searchsorted(edges, df[axis], side="right") - 1, 0, 9)
    rate = df.pivot_table(index="iy", columns="ix", values="ok", aggfunc="mean")
    runs = df.pivot_table(index="iy", columns="ix", values="ok", aggfunc="size")
    assert g["success_rate"] == rate.values.tolist() and g["runs"] == runs.values.tolist()
    assert min(min(row) for row in g["success_rate"]) == 0.0


def test_a_full_grid_is_ranked_by_its_exact_main_effects(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    """A 5 x 4 x 3 grid whose convergence depends on K_ps alone: main effect 1 for it and
    exactly 0 for the others; a time to goal of two inputs' interaction ranks both above
    the third."""
    k_ps, k_th, m = (np.array(v, dtype=np.float64).ravel() for v in np.meshgrid(
        [0.1, 0.2, 0.4, 0.8, 1.6], [0.5, 1.0, 2.0, 4.0], [20.0, 30.0, 40.0], indexing="ij"))
    status = np.where(k_ps < 0.3, "timeout", "converged")
    ttg = 10.0 + (k_th - 2.0) * (m - 30.0) + k_th
    data = _json(_summary(tmp_path, {"gains.K_ps": k_ps, "gains.K_theta": k_th, "params.m": m},
                          status.tolist(), ttg), capsys)
    assert data["design"] == "grid"
    conv = data["sensitivity"]["converged"]
    assert conv == [{"input": "gains.K_ps", "index": 1.0, "method": MAIN_EFFECT},
                    {"input": "gains.K_theta", "index": 0.0, "method": MAIN_EFFECT},
                    {"input": "params.m", "index": 0.0, "method": MAIN_EFFECT}]
    assert _ranked(data, "time_to_goal_s")[:2] == ["gains.K_theta", "params.m"]
    # against pandas: the variance of the means per value over the variance
    df = pd.DataFrame({"k": k_th, "m": m, "t": ttg})[status == "converged"]
    expected = df.groupby("k")["t"].transform("mean").var(ddof=0) / df["t"].var(ddof=0)
    got = {k["input"]: k["index"] for k in data["sensitivity"]["time_to_goal_s"]}
    assert got["gains.K_theta"] == pytest.approx(expected, abs=1e-4)


def test_rank_inputs_orders_by_index_and_keeps_each_name_with_its_column() -> None:
    """The bare ranking: most influential first, each index with its own column."""
    rng = np.random.default_rng(11)
    x = rng.uniform(0, 1, (1500, 3))
    y = 3.0 * x[:, 2] + 1.0 * x[:, 0]
    r = rank_inputs("y", ["a", "b", "c"], x, y, grid=False)
    assert [k.input for k in r.ranked] == ["c", "a", "b"]
    assert r.ranked[0].index > 0.8 and r.ranked[2].index < 0.02
    assert r.runs == 1500 and r.note == ""


def test_a_constant_outcome_and_too_few_runs_are_said_not_ranked(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(2)
    n = 300
    data = _json(_summary(tmp_path, {"params.m": rng.uniform(15, 35, n),
                                     "params.tau_c": rng.uniform(0, 1, n)},
                          ["converged"] * n), capsys)
    assert data["sensitivity"]["converged"] == []
    assert data["sensitivity_notes"]["converged"] == \
        "the same in all 300 runs: no input changes it"
    assert "Convergence: the same in all 300 runs" in data["sensitivity_line"]
    assert len(data["sensitivity"]["time_to_goal_s"]) == 2
    # every run converged: the worst runs are still listed (they were not before)
    assert [len(data["worst"][m]) for m in data["worst"]] == [10, 10, 10]
    assert data["not_converged"] == []
    few = tmp_path / "few"
    few.mkdir()
    data = _json(_summary(few, {"params.m": rng.uniform(15, 35, 40),
                                "params.tau_c": rng.uniform(0, 1, 40)},
                          ["converged", "failed"] * 20), capsys)
    assert data["sensitivity"]["converged"] == []
    assert "too few runs to rank the inputs (40, RBD-FAST needs 100)" in \
        data["sensitivity_notes"]["converged"]
    text = write_report(few).read_text()
    assert "Not converged against" not in text  # nothing ranked, nothing to explain
    assert "too few runs to rank the inputs" in text and "nan" not in text.lower()


# -- the numbers against pandas ---------------------------------------------------------------

def test_the_json_numbers_equal_pandas_on_the_summary(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """Success rate and its Wilson interval (scipy's own), per status, per controller, the
    worst runs in order, every run that did not converge with its inputs and rerun command."""
    from scipy.stats import binomtest

    rng = np.random.default_rng(13)
    n = 400
    torque = rng.uniform(4, 12, n)
    status = rng.choice(["converged"] * 8 + ["failed", "timeout"], n).tolist()
    controller = rng.choice(["pi", "astolfi"], n).tolist()
    folder = _summary(tmp_path, {"limits.torque_max_nm": torque}, status,
                      extra={"controller": controller})
    data = _json(folder, capsys, "--worst", "7")
    df = pq.read_table(folder / SUMMARY_PARQUET).to_pandas()
    ok = df["status"] == "converged"

    def wilson(k: int, m: int) -> list[float]:
        ci = binomtest(k, m).proportion_ci(confidence_level=0.95, method="wilson")
        return [ci.low, ci.high]

    assert data["runs"] == n and data["success"]["converged"] == int(ok.sum())
    assert data["success"]["rate"] == pytest.approx(ok.mean(), abs=1e-12)
    assert data["success"]["ci95"] == pytest.approx(wilson(int(ok.sum()), n), abs=1e-9)
    per = df["status"].value_counts()
    assert {e["status"]: e["runs"] for e in data["status"]} == per.to_dict()
    for e in data["status"]:
        assert e["share"] == pytest.approx(per[e["status"]] / n)
        assert e["ci95"] == pytest.approx(wilson(int(per[e["status"]]), n), abs=1e-9)
    by = df.groupby("controller")
    assert [c["controller"] for c in data["controllers"]] == ["astolfi", "pi"]
    for c in data["controllers"]:
        g = by.get_group(c["controller"])
        k = int((g["status"] == "converged").sum())
        assert (c["runs"], c["converged"]) == (len(g), k)
        assert c["ci95"] == pytest.approx(wilson(k, len(g)), abs=1e-9)
        assert c["median_time_to_goal_s"] == pytest.approx(g["time_to_goal_s"].median())
    for metric in ("time_to_goal_s", "final_position_error_m", "energy_positive_j"):
        expected = df.dropna(subset=[metric]).sort_values(
            [metric, "run_id"], ascending=[False, True])["run_id"].head(7).tolist()
        assert [e["run_id"] for e in data["worst"][metric]] == expected
    bad = df[~ok].sort_values(["status", "run_id"])  # failed before timeout
    assert [e["run_id"] for e in data["not_converged"]] == bad["run_id"].tolist()
    first = data["not_converged"][0]
    row = df.set_index("run_id").loc[first["run_id"]]
    assert first["inputs"] == {"limits.torque_max_nm": row["limits.torque_max_nm"]}
    assert first["rerun"] == f"wmr rerun {folder} {first['run_id']}"
    assert first["mcap"] == row["mcap"] and first["controller"] == row["controller"]
    assert data["spread"][0]["metric"] == "time_to_goal_s"
    assert data["spread"][0]["median"] == pytest.approx(df.loc[ok, "time_to_goal_s"].median())


def test_the_markdown_lists_the_first_50_failed_runs_with_a_count_and_their_rerun(
        tmp_path: Path) -> None:
    rng = np.random.default_rng(17)
    n = 300
    status = ["failed" if i % 4 == 0 else "converged" for i in range(n)]
    folder = _summary(tmp_path, {"params.m": rng.uniform(15, 35, n)}, status)
    text = write_report(folder, worst=3).read_text()
    section = text.split("## Runs that did not converge")[1].split("\n## ")[0]
    assert "75 runs failed or timed out; the first 50" in section
    assert section.count("`wmr rerun ") == 50 and "... and 25 more." in section
    assert f"`wmr rerun {folder} 0000-" in section
    # a '|' or a line break in a message keeps the table
    assert "| failed: limit / reached at 60 s |" in section
    worst = text.split("### By time to goal, s")[1].split("###")[0]
    assert worst.count("`wmr rerun ") == 3


# -- plots ------------------------------------------------------------------------------------

def test_every_panel_has_a_legend_and_the_timeouts_show_in_the_time_panel(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figures: dict[str, Any] = {}
    save = matplotlib.figure.Figure.savefig

    def keep(fig: Any, path: Any, *args: Any, **kw: Any) -> None:
        figures[Path(path).name] = fig
        save(fig, path, *args, **kw)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", keep)
    monkeypatch.setattr(plt, "close", lambda fig=None: None)
    rng = np.random.default_rng(19)
    n = 120
    m = rng.uniform(15, 35, n)
    status = np.where(m > 30, "timeout", "converged").tolist()
    write_report(_summary(tmp_path, {"params.m": m}, status))
    for name in ("vs_params_m.png", "status.png", "spread.png"):
        for ax in figures[name].axes:
            if ax.has_data():
                assert ax.get_legend() is not None, (name, ax.get_ylabel())
    time_panel = figures["vs_params_m.png"].axes[1]
    labels = [t.get_text() for t in time_panel.get_legend().get_texts()]
    assert "timeout: no time to goal (at the top)" in labels and "converged" in labels
    plt.close("all")


def test_no_spec_field_is_dropped_while_a_derived_one_is_plotted(tmp_path: Path) -> None:
    """A polar start (``start.r_m``, ``start.bearing_deg``) makes the start's x and y vary:
    they follow from the spec and are plotted last; ``goal.heading_deg``, the spec's own, is
    plotted (it was dropped 'over --max-plots' before them)."""
    rng = np.random.default_rng(23)
    n = 150
    r, b = rng.uniform(5, 12, n), rng.uniform(0, 360, n)
    gh = rng.choice([0.0, 180.0], n)
    poses = {"start.x_m": 5.0 + r * np.cos(np.radians(b)),
             "start.y_m": r * np.sin(np.radians(b)), "goal.heading_deg": gh}
    folder = _summary(tmp_path, {"params.m": rng.uniform(15, 35, n), "start.r_m": r,
                                 "start.bearing_deg": b}, ["converged"] * n, poses=poses)
    text = write_report(folder, max_plots=4).read_text()
    assert "![goal.heading_deg](vs_goal_heading_deg.png)" in text
    assert "Not plotted (over --max-plots): start.x_m, start.y_m." in text
    data = report_data(folder)
    assert [i["input"] for i in data["inputs"] if i["derived"]] == ["start.x_m", "start.y_m"]
    assert (folder / "report" / "roa.png").stat().st_size > 10_000  # the start varies
    assert "## Region of attraction" in text


def test_a_2d_grid_gets_maps_of_success_and_median_time(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    k_ps, k_th = (np.array(v, dtype=np.float64).ravel() for v in np.meshgrid(
        [0.2, 0.5, 1.0], [1.0, 2.0], [0, 1, 2, 3], indexing="ij")[:2])
    rng = np.random.default_rng(29)
    status = np.where((k_ps == 0.2) & (rng.uniform(size=k_ps.size) < 0.5), "failed",
                      "converged").tolist()
    folder = _summary(tmp_path, {"gains.K_ps": k_ps, "gains.K_theta": k_th}, status)
    data = _json(folder, capsys)
    grid = data["grid_map"]
    df = pq.read_table(folder / SUMMARY_PARQUET).to_pandas()
    df["ok"] = df["status"] == "converged"
    rate = df.pivot_table(index="gains.K_theta", columns="gains.K_ps", values="ok",
                          aggfunc="mean")
    assert (grid["x"], grid["y"]) == ("gains.K_ps", "gains.K_theta")
    assert grid["design"] == "grid" and not grid["binned"]
    assert grid["runs"] == [[4, 4, 4], [4, 4, 4]]
    assert grid["success_rate"] == rate.values.tolist()
    med = df[df["ok"]].pivot_table(index="gains.K_theta", columns="gains.K_ps",
                                   values="time_to_goal_s", aggfunc="median")
    got = np.array([[math.nan if v is None else v for v in row]
                    for row in grid["median_time_to_goal_s"]])
    assert np.isnan(got).any()  # a cell where every run failed: null, not a number
    np.testing.assert_allclose(got, med.reindex(columns=rate.columns).values, rtol=1e-12)
    write_report(folder)
    assert (folder / "report" / "grid_map.png").stat().st_size > 10_000


def test_a_negative_worst_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                      ) -> None:
    _summary(tmp_path, {"params.m": [1.0, 2.0]}, ["converged", "failed"])
    assert main(["report", str(tmp_path), "--worst", "-1"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("wmr: ") and "--worst: must be >= 0, got -1" in err and "\n" not in err


def test_the_runs_per_status_of_a_large_summary_are_counted_in_one_pass(tmp_path: Path) -> None:
    """The count per status was quadratic in the runs (each run counted its status again):
    223 s of a 10^5-run report went there.  Another status a summary holds is counted too."""
    import time

    from wmr.apps.batch.report_data import Summary

    n = 100_000
    status = ["converged"] * (n - 30) + ["failed"] * 20 + ["timeout"] * 9 + ["other"]
    pq.write_table(pa.table({"run_id": [f"{i:07d}" for i in range(n)], "status": status,
                             "message": [""] * n}), tmp_path / SUMMARY_PARQUET)
    s = Summary(tmp_path)
    t0 = time.perf_counter()
    counts = s.counts()
    assert time.perf_counter() - t0 < 5.0
    assert counts == {"converged": n - 30, "timeout": 9, "failed": 20, "other": 1}
    assert list(counts) == ["converged", "timeout", "failed", "other"]


def test_a_hostile_run_id_or_folder_is_quoted_in_the_rerun_command(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A summary may come from anyone: the command printed for a run is one the shell reads
    back as exactly ``wmr rerun DIR RUN_ID``, whatever the id and the folder hold."""
    import shlex

    folder = tmp_path / "my batch; rm -rf ~"
    folder.mkdir()
    _summary(folder, {"params.m": [1.0, 2.0]}, ["failed", "converged"])
    table = pq.read_table(folder / SUMMARY_PARQUET)
    evil = "0000-$(touch pwned)`id`"
    table = table.set_column(0, "run_id", pa.array([evil, "0001-ok"]))
    pq.write_table(table, folder / SUMMARY_PARQUET)
    data = _json(folder, capsys)
    assert shlex.split(data["not_converged"][0]["rerun"]) == ["wmr", "rerun", str(folder), evil]


def test_a_real_2d_grid_batch_reports_its_own_summary(fmu3: Path, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """Six short runs of a real 3 x 2 grid (no synthetic table): the JSON's numbers are those
    pandas reads from the batch's summary, the design is a grid ranked by main effects, and
    the report draws the grid's map."""
    from wmr.apps.batch import load_batch
    from wmr.apps.batch.runner import BatchOptions, run_batch

    spec = tmp_path / "g6.toml"
    spec.write_text('name = "g6"\nstart = [1.0, 0.0, 0.0]\ngoal = [0.0, 0.0, 180.0]\n'
                    "max_time_s = 15.0\n[grid.gains]\nK_ps = [0.3, 0.5, 0.8]\n"
                    "[grid.params]\nm = [20.0, 30.0]\n")
    out = tmp_path / "out"
    result = run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3),
                       progress=False)
    assert result.finished == 6
    data = _json(out, capsys)
    df = pq.read_table(out / SUMMARY_PARQUET).to_pandas()
    ok = df["status"] == "converged"
    assert data["runs"] == 6 and data["success"]["converged"] == int(ok.sum())
    assert data["design"] == "grid"
    assert [i["input"] for i in data["inputs"]] == ["gains.K_ps", "params.m"]
    assert (data["grid_map"]["x"], data["grid_map"]["y"]) == ("gains.K_ps", "params.m")
    ttg = data["sensitivity"]["time_to_goal_s"]
    assert {k["method"] for k in ttg} == {MAIN_EFFECT}
    conv = df[ok]
    for k in ttg:
        means = conv.groupby(k["input"])["time_to_goal_s"].transform("mean")
        expected = means.var(ddof=0) / conv["time_to_goal_s"].var(ddof=0)
        assert k["index"] == pytest.approx(expected, abs=1e-4)
    assert main(["report", str(out)]) == 0
    assert (out / "report" / "grid_map.png").stat().st_size > 10_000


def test_controllers_side_by_side_with_their_optimality_gaps(tmp_path: Path) -> None:
    """A batch with the optimum (``time_gap``, ``energy_gap``) and two controllers: the gaps'
    spread in the JSON equals pandas, each controller's median gap is in its row, and the
    report draws their distributions."""
    rng = np.random.default_rng(31)
    n = 200
    controller = np.repeat(["pi", "astolfi"], n // 2)
    gap = np.where(controller == "pi", 1.3, 1.1) + rng.uniform(0, 0.2, n)
    status = ["converged"] * (n - 2) + ["failed"] * 2
    folder = _summary(tmp_path, {"params.m": np.tile(rng.uniform(15, 35, n // 2), 2)}, status,
                      extra={"controller": controller.tolist(), "time_gap": gap.tolist(),
                             "energy_gap": (gap * 1.5).tolist()})
    data = report_data(folder)
    df = pq.read_table(folder / SUMMARY_PARQUET).to_pandas()
    conv = df[df["status"] == "converged"]
    spread = {e["metric"]: e for e in data["spread"]}
    assert spread["time_gap"]["median"] == pytest.approx(conv["time_gap"].median())
    assert spread["energy_gap"]["p95"] == pytest.approx(conv["energy_gap"].quantile(0.95))
    rows = {c["controller"]: c for c in data["controllers"]}
    for name, g in conv.groupby("controller"):
        assert rows[name]["median_time_gap"] == pytest.approx(g["time_gap"].median())
    text = write_report(folder).read_text()
    assert "## Against the optimum" in text and "| time to goal / optimal time | 198 |" in text
    assert (folder / "report" / "optimality_gap.png").stat().st_size > 10_000


def test_the_help_says_what_the_report_holds(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["report", "--help"])
    assert info.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "95 % Wilson interval" in out and "%%" not in out and "--json" in out


def test_the_optimum_s_columns_are_never_ranked_as_inputs(tmp_path: Path) -> None:
    """A batch with ``optimal``: ``optimal_time_s``, ``optimal_energy_j``, ``time_gap`` and
    ``energy_gap`` follow from each run (they vary with it), so they were ranked among the
    inputs that "explain" its outcomes; only the spec's inputs are."""
    rng = np.random.default_rng(5)
    n = 400
    m = rng.uniform(15, 35, n)
    status = ["converged" if x < 30 else "timeout" for x in m]
    optimal_time = 4.0 + 0.05 * m
    folder = _summary(tmp_path, {"params.m": m}, status,
                      extra={"optimal_time_s": optimal_time.tolist(),
                             "optimal_energy_j": (2.0 * m).tolist(),
                             "time_gap": (1.2 + 0.01 * m).tolist(),
                             "energy_gap": (0.5 + 0.01 * m).tolist()})
    data = report_data(folder)
    ranked = {e["input"] for entries in data["sensitivity"].values() for e in entries}
    assert ranked == {"params.m"}, ranked


def test_the_sensitivity_table_never_runs_into_the_list_before_it(tmp_path: Path) -> None:
    """Markdown takes a table right after a list item into that item: the "Not converged
    against" bullets are followed by a blank line before the table."""
    rng = np.random.default_rng(9)
    n = 400
    torque = rng.uniform(4, 12, n)
    status = np.where(torque < 6.0, "failed", "converged")
    folder = _summary(tmp_path, {"limits.torque_max_nm": torque,
                                 "params.m": rng.uniform(15, 35, n)}, status.tolist())
    from itertools import pairwise

    lines = write_report(folder).read_text().splitlines()
    assert any(line.startswith("* Not converged against") for line in lines)
    for before, line in pairwise(lines):
        if line.startswith("| rank |"):
            assert not before.startswith("* "), before
