"""``wmr figures``: the paper's Figs. 9 to 12 and the region-of-attraction map."""

from __future__ import annotations

import io
import math
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import RunData, read_run
from wmr.apps.figures import (
    PNG_NAMES,
    compute_roa,
    fig9_paths,
    fig10_paths,
    fig11_errors,
    fig12_speeds,
    make_figures,
    roa_figure,
)
from wmr.apps.run import run_to_log
from wmr.cli import main
from wmr.config.scenario import load_scenario

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory, fmu3_plant: FmuPlant) -> Path:
    """A few runs of each scenario, laid out like ``wmr figures`` lays out its own logs."""
    root = tmp_path_factory.mktemp("figlogs")
    picks = {"fig9": ("fig9-thd-045", "fig9-thd+000", "fig9-thd+045"),
             "fig10": ("fig10-from000deg", "fig10-from180deg"),
             "fig11": ("fig11",)}
    for name, runs in picks.items():
        scenario = load_scenario(name)
        for spec in scenario.runs:
            if spec.name in runs:
                run_to_log(spec, root / name / f"{spec.name}.mcap", fmu3_plant,
                           scenario_file=scenario.path)
    return root


def _read(logs: Path, scenario: str) -> list[RunData]:
    return [read_run(p) for p in sorted((logs / scenario).glob("*.mcap"))]


def _data_lines(fig: Figure) -> list[Line2D]:
    """The lines of a figure that carry data (more than 10 points)."""
    return [ln for ax in fig.axes for ln in ax.get_lines() if len(ln.get_xdata()) > 10]


def test_figures_cli_writes_the_pngs(logs: Path, tmp_path: Path) -> None:
    out_io, err_io = io.StringIO(), io.StringIO()
    with redirect_stdout(out_io), redirect_stderr(err_io):
        rc = main(["figures", "--out", str(tmp_path / "figs"), "--logs", str(logs),
                   "--roa-grid", "0"])
    assert rc == 0, err_io.getvalue()
    printed = [Path(line) for line in out_io.getvalue().splitlines()]
    expected = [tmp_path / "figs" / PNG_NAMES[k] for k in ("fig9", "fig10", "fig11", "fig12")]
    assert printed == expected
    for png in printed:
        data = png.read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 20_000
    assert not (tmp_path / "figs" / "logs").exists()  # the given logs were used, none run


def test_fig9_dashed_for_positive_solid_for_negative_theta_d(logs: Path) -> None:
    runs = _read(logs, "fig9")
    fig = fig9_paths(runs)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "y [m]"
    lines = _data_lines(fig)
    assert len(lines) == 3
    styles = {str(ln.get_label()): ln.get_linestyle() for ln in lines}
    assert styles["θ_d = -45°"] == "-"
    assert styles["θ_d = +45°"] == "--"
    for ln in lines:  # every path starts at the origin and ends at the goal (20, 10)
        x, y = np.asarray(ln.get_xdata()), np.asarray(ln.get_ydata())
        assert math.hypot(x[0], y[0]) < 1e-6
        assert math.hypot(x[-1] - 20.0, y[-1] - 10.0) < 0.1


def test_fig10_paths_end_at_the_origin(logs: Path) -> None:
    runs = _read(logs, "fig10")
    fig = fig10_paths(runs)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "y [m]"
    lines = _data_lines(fig)
    assert len(lines) == 2
    starts = sorted(float(np.asarray(ln.get_xdata())[0]) for ln in lines)
    assert starts == pytest.approx([-10.0, 10.0])
    for ln in lines:
        assert math.hypot(np.asarray(ln.get_xdata())[-1], np.asarray(ln.get_ydata())[-1]) < 0.1


def test_fig11_errors_of_rpc_and_roc(logs: Path) -> None:
    run = _read(logs, "fig11")[0]
    fig = fig11_errors(run)
    ax_s, ax_a = fig.axes[:2]
    assert ax_a.get_xlabel() == "t [s]"
    for ax in (ax_s, ax_a):
        labels = [str(ln.get_label()) for ln in ax.get_lines() if len(ln.get_xdata()) > 10]
        assert any(lb.startswith("RPC") for lb in labels)
        assert any(lb.startswith("ROC") for lb in labels)
    roc_s = next(ln for ln in ax_s.get_lines() if str(ln.get_label()).startswith("ROC"))
    np.testing.assert_array_equal(roc_s.get_ydata(), run.signals["e_s_m"])
    rpc_s = np.asarray(next(ln for ln in ax_s.get_lines()
                            if str(ln.get_label()).startswith("RPC")).get_ydata())
    # at the start (0, 0, 0) -> (20, 10): e_s = dr cos(phi) = the projection on the x axis
    assert rpc_s[0] == pytest.approx(20.0, abs=1e-6)
    assert abs(np.asarray(roc_s.get_ydata())[-1]) < 0.1


def test_fig12_wheel_speeds_scaled_by_a_tenth(logs: Path) -> None:
    run = _read(logs, "fig11")[0]
    fig = fig12_speeds(run)
    by_label = {str(ln.get_label()): np.asarray(ln.get_ydata()) for ln in _data_lines(fig)}
    assert len(by_label) == 3
    left = next(v for k, v in by_label.items() if "left" in k)
    right = next(v for k, v in by_label.items() if "right" in k)
    platform = next(v for k, v in by_label.items() if "platform" in k)
    np.testing.assert_allclose(left, 0.1 * run.signals["omega_l_radps"])
    np.testing.assert_allclose(right, 0.1 * run.signals["omega_r_radps"])
    np.testing.assert_array_equal(platform, run.signals["omega_radps"])
    assert fig.axes[0].get_xlabel() == "t [s]"


def test_region_of_attraction_small_grid(fmu3_plant: FmuPlant, tmp_path: Path) -> None:
    base = load_scenario("fig11").runs[0]
    roa = compute_roa(fmu3_plant, base, grid=3, headings=2, half_width_m=6.0, t_max_s=8.0)
    assert roa.status.shape == (2, 3, 3) == roa.time_to_goal_s.shape
    assert set(np.unique(roa.status)) <= {"converged", "timeout", "failed"}
    conv = roa.status == "converged"
    # the start on the goal converges at once; 8.5 m away cannot be reached in 8 s
    assert conv[0, 1, 1] and roa.time_to_goal_s[0, 1, 1] < 1.0
    assert roa.status[0, 0, 0] == "timeout" and np.isnan(roa.time_to_goal_s[0, 0, 0])
    assert np.all(np.isfinite(roa.time_to_goal_s[conv]))
    fig = roa_figure(roa)
    panels = [ax for ax in fig.axes if ax.get_visible() and ax.get_xlabel() == "x [m]"]
    assert len(panels) == 2
    timeouts = [ln for ln in panels[0].get_lines() if str(ln.get_label()).startswith("timeout")]
    assert len(timeouts) == 1
    assert len(timeouts[0].get_xdata()) == int((roa.status[0] == "timeout").sum()) > 0
    fig.savefig(tmp_path / "roa.png")
    assert (tmp_path / "roa.png").read_bytes().startswith(PNG_MAGIC)


def test_make_figures_runs_missing_scenarios(logs: Path, fmu3: Path, tmp_path: Path) -> None:
    """Logs without fig10: that scenario is run into OUT/logs, and the ROA map is drawn."""
    partial = tmp_path / "partial"
    for scenario in ("fig9", "fig11"):
        (partial / scenario).mkdir(parents=True)
        for p in (logs / scenario).glob("*.mcap"):
            (partial / scenario / p.name).write_bytes(p.read_bytes())
    out = tmp_path / "out"
    lines: list[str] = []
    written = make_figures(out, logs=partial, roa_grid=2, roa_headings=1, fmu=fmu3,
                           progress=lines.append)
    assert [p.name for p in written] == list(PNG_NAMES.values())
    assert len(list((out / "logs" / "fig10").glob("*.mcap"))) == len(
        load_scenario("fig10").runs)
    assert not (out / "logs" / "fig9").exists()
    assert any("fig10" in line for line in lines)


@pytest.mark.slow
def test_figures_default_run(tmp_path: Path, fmu3: Path) -> None:
    written = make_figures(tmp_path, fmu=fmu3)
    assert [p.name for p in written] == list(PNG_NAMES.values())
    for scenario in ("fig9", "fig10", "fig11"):
        assert len(list((tmp_path / "logs" / scenario).glob("*.mcap"))) == len(
            load_scenario(scenario).runs)
