"""The paper's Figs. 9 to 12 from run logs, and a region-of-attraction map (``wmr figures``).

Each figure function takes read logs (:class:`wmr.adapters.mcap.RunData`) and returns a matplotlib
:class:`~matplotlib.figure.Figure` (no pyplot state, Agg only), labelled as the paper labels
them:

* :func:`fig9_paths`: paths from :math:`[0, 0, 0^\\circ]` to :math:`[20, 10]` for several
  :math:`\\theta_d`; dashed for :math:`\\theta_d > 0`, solid for :math:`\\theta_d < 0`.
* :func:`fig10_paths`: paths from starts around the origin to the goal :math:`(0, 0)`.
* :func:`fig11_errors`: distance and angular errors of RPC and ROC against time for the run
  :math:`[0, 0, 0^\\circ] \\to [20, 10, 0^\\circ]`.  The robot is driven by the ROC; the RPC
  errors (eqs. 26, 27: :math:`e_s = \\Delta r \\cos\\phi`, :math:`e_\\phi = \\alpha - \\theta`)
  are evaluated along the same path.
* :func:`fig12_speeds`: platform angular velocity :math:`\\dot\\theta` and the wheel speeds
  :math:`\\dot\\theta_l`, :math:`\\dot\\theta_r` times 0.1.
* :func:`roa_figure`: not in the paper: time to goal from a grid of start poses around the goal
  :math:`(0, 0, 0^\\circ)` (:func:`compute_roa`, closed loop on the FMU without logging).

:func:`make_figures` runs the ``fig9``, ``fig10`` and ``fig11`` scenarios (or reads their logs)
and writes the PNG files.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np
from numpy.typing import NDArray

from wmr.adapters.mcap import RunData, read_run
from wmr.config.naming import plural
from wmr.core.plant import Plant, Pose
from wmr.core.runspec import RunSpec
from wmr.infra.errors import ConfigError, LogError
from wmr.infra.outputs import refuse_special

if TYPE_CHECKING:  # matplotlib is imported where a figure is drawn: `wmr --help` need not wait
    from matplotlib.axes import Axes
    from matplotlib.colors import Colormap
    from matplotlib.figure import Figure
    from matplotlib.typing import ColorType

#: The scenarios whose logs the paper's figures need, by figure.
FIGURE_SCENARIOS: Final = ("fig9", "fig10", "fig11")
#: File names of the figures, in the order they are written.
PNG_NAMES: Final = {
    "fig9": "fig9_paths.png",
    "fig10": "fig10_paths.png",
    "fig11": "fig11_errors.png",
    "fig12": "fig12_speeds.png",
    "roa": "roa_time_to_goal.png",
}
#: Default region-of-attraction grid: positions per axis, start headings, half width (m).
ROA_GRID: Final = 13
ROA_HEADINGS: Final = 4
ROA_HALF_WIDTH_M: Final = 10.0
ROA_MAX_TIME_S: Final = 60.0
ROA_GOAL: Final = Pose(0.0, 0.0, 0.0)
DPI: Final = 150

Log = Callable[[str], None]


def _quiet(_: str) -> None:
    """A progress callback that says nothing."""


# --------------------------------------------------------------------------- helpers


def _wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angles wrapped into (-pi, pi]."""
    return np.asarray(np.pi - np.mod(np.pi - a, 2.0 * np.pi), np.float64)


def _run_meta(run: RunData, key: str) -> str | None:
    return run.metadata.get("run", {}).get(key)


def _start(run: RunData) -> tuple[float, float, float]:
    """Start pose from the first row of the log (x, y, heading in rad)."""
    s = run.signals
    return float(s["x_m"][0]), float(s["y_m"][0]), float(s["theta_rad"][0])


def _goal(run: RunData) -> tuple[float, float, float]:
    """Goal pose of a run: the ``/goal`` message, else the ``run`` metadata."""
    if run.goal is not None:
        return run.goal.x_m, run.goal.y_m, run.goal.theta_rad
    raw = _run_meta(run, "goal")
    if raw is None:
        raise LogError(f"{run.path}: the log has no goal pose")
    g = json.loads(raw)
    return float(g["x_m"]), float(g["y_m"]), float(g["heading_rad"])


def _stop_radius(run: RunData) -> float:
    try:
        return float(_run_meta(run, "stop_radius_m") or 0.05)
    except ValueError:
        return 0.05


def _status(run: RunData) -> str:
    status = run.metadata.get("result", {}).get("status")
    if status is None:
        return "truncated" if run.truncated else "unknown"
    return status


def _arrow(ax: Axes, x: float, y: float, heading: float, length: float, color: ColorType,
           **kw: object) -> None:
    ax.annotate("", xy=(x + length * math.cos(heading), y + length * math.sin(heading)),
                xytext=(x, y), arrowprops={"arrowstyle": "-|>", "color": color, "lw": 1.4,
                                           "shrinkA": 0, "shrinkB": 0, **kw})


def _world_axes(ax: Axes, title: str) -> None:
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, linewidth=0.4, alpha=0.6)


def _new_figure(width: float = 7.0, height: float = 5.0) -> Figure:
    from matplotlib.figure import Figure  # no pyplot: no GUI backend, no global state

    return Figure(figsize=(width, height), dpi=DPI, layout="constrained")


def _colormap(name: str) -> Colormap:
    import matplotlib

    return matplotlib.colormaps[name]


# --------------------------------------------------------------------------- the paper's figures


def fig9_paths(runs: Sequence[RunData]) -> Figure:
    """Fig. 9: robot paths from one start to (20, 10) with various desired headings.

    Parameters
    ----------
    runs
        The runs of the ``fig9`` scenario (any subset).

    Returns
    -------
    Figure
        Paths dashed for :math:`\\theta_d > 0`, solid for :math:`\\theta_d < 0` (dotted for
        :math:`\\theta_d = 0`); a heading arrow at the start and at each goal.
    """
    fig = _new_figure(7.5, 5.2)
    ax = fig.add_subplot()
    ordered = sorted(runs, key=lambda r: _goal(r)[2])
    cmap = _colormap("coolwarm")
    for run in ordered:
        gx, gy, thd = _goal(run)
        deg = math.degrees(thd)
        style = "--" if deg > 0.5 else "-" if deg < -0.5 else ":"
        color = (cmap(0.5 + 0.5 * float(np.clip(deg / 90.0, -1.0, 1.0))) if style != ":"
                 else "k")
        ax.plot(run.signals["x_m"], run.signals["y_m"], style, color=color, linewidth=1.4,
                label=f"θ_d = {deg:+.0f}°")
        _arrow(ax, gx, gy, thd, 1.5, "0.25")
    if ordered:
        x0, y0, th0 = _start(ordered[0])
        ax.plot([x0], [y0], "ko", markersize=5)
        _arrow(ax, x0, y0, th0, 1.5, "k")
        gx, gy, _ = _goal(ordered[0])
        ax.plot([gx], [gy], "o", color="0.25", markersize=5)
        ax.annotate(f"start [{x0:g}, {y0:g}, {math.degrees(th0):.0f}°]", (x0, y0),
                    textcoords="offset points", xytext=(-4, -16), fontsize=8, ha="right")
        ax.annotate(f"goal [{gx:g}, {gy:g}]", (gx, gy), textcoords="offset points",
                    xytext=(6, 24), fontsize=8)
    _world_axes(ax, "Fig. 9. Robot paths with various final desired orientation angle")
    ax.legend(fontsize=7, ncol=1, loc="center left", bbox_to_anchor=(1.01, 0.5),
              title="dashed θ_d > 0\nsolid θ_d < 0", title_fontsize=7)
    return fig


def fig10_paths(runs: Sequence[RunData]) -> Figure:
    """Fig. 10: robot paths from various initial postures to the centre point (0, 0).

    Parameters
    ----------
    runs
        The runs of the ``fig10`` scenario (any subset).

    Returns
    -------
    Figure
        One path per run, its start pose as an arrow, the goal headings at the origin.
    """
    fig = _new_figure(6.4, 6.0)
    ax = fig.add_subplot()
    cmap = _colormap("tab20")
    headings: set[float] = set()
    for k, run in enumerate(runs):
        color = cmap(k % 20)
        ax.plot(run.signals["x_m"], run.signals["y_m"], "-", color=color, linewidth=1.3)
        x0, y0, th0 = _start(run)
        ax.plot([x0], [y0], "o", color=color, markersize=4)
        _arrow(ax, x0, y0, th0, 1.2, color)
        thd = _goal(run)[2]
        headings.add(round(thd, 6))
    for thd in sorted(headings):
        _arrow(ax, 0.0, 0.0, thd, 1.5, "k")
    ax.plot([0.0], [0.0], "ko", markersize=5)
    ax.annotate("goal [0, 0]\nθ_d = 180° (x ≥ 0), 0° (x < 0)", (0.0, 0.0),
                textcoords="offset points", xytext=(6, -26), fontsize=7,
                bbox={"fc": "white", "alpha": 0.8, "lw": 0})
    _world_axes(ax, "Fig. 10. Robot paths from various initial posture")
    return fig


def fig11_errors(run: RunData) -> Figure:
    """Fig. 11: angular and distance errors of RPC and ROC for the run to (20, 10, 0°).

    Parameters
    ----------
    run
        The ``fig11`` run.

    Returns
    -------
    Figure
        Top: :math:`e_s` of RPC and ROC [m]; bottom: :math:`e_\\phi` (RPC) and
        :math:`e_\\theta` (ROC) [rad]; against time [s].  The RPC angle is undefined inside
        the stop radius, where it is not drawn.
    """
    s = run.signals
    t = run.t_s
    dr = s["dr_m"]
    e_phi = _wrap(s["alpha_rad"] - s["theta_rad"])  # eq. 27 (atan2, wrapped)
    e_s_rpc = dr * np.cos(e_phi)  # eq. 26
    inside = dr <= _stop_radius(run)
    e_phi_shown = np.where(inside, np.nan, e_phi)
    e_s_rpc = np.where(inside, np.nan, e_s_rpc)

    fig = _new_figure(7.0, 5.6)
    ax_s, ax_a = fig.subplots(2, 1, sharex=True)
    ax_s.plot(t, e_s_rpc, "--", color="tab:blue", label="RPC  e_s = Δr cos φ")
    ax_s.plot(t, s["e_s_m"], "-", color="tab:red", label="ROC  e_s = Δr cos γ")
    ax_s.set_ylabel("distance error e_s [m]")
    ax_a.plot(t, e_phi_shown, "--", color="tab:blue", label="RPC  e_φ = α − θ")
    ax_a.plot(t, s["e_theta_rad"], "-", color="tab:red", label="ROC  e_θ = γ")
    ax_a.set_ylabel("angular error [rad]")
    ax_a.set_xlabel("t [s]")
    if inside.any():
        t_in = float(t[int(np.argmax(inside))])
        for ax in (ax_s, ax_a):
            ax.axvline(t_in, color="0.5", linewidth=0.8, linestyle=":")
        ax_a.annotate("Δr ≤ ε: final alignment", (t_in, 1.0), xycoords=("data", "axes fraction"),
                      xytext=(-3, -10), textcoords="offset points", fontsize=7, color="0.4",
                      ha="right")
    for ax, corner in ((ax_s, "upper right"), (ax_a, "lower right")):
        ax.grid(True, linewidth=0.4, alpha=0.6)
        ax.axhline(0.0, color="k", linewidth=0.6)
        ax.legend(fontsize=8, loc=corner)
    x0, y0, th0 = _start(run)
    gx, gy, thd = _goal(run)
    ax_s.set_title("Fig. 11. Angular and distance errors of RPC and ROC for particular robot "
                   f"path\n[{x0:g}, {y0:g}, {math.degrees(th0):.0f}°] → "
                   f"[{gx:g}, {gy:g}, {math.degrees(thd):.0f}°]", fontsize=10)
    return fig


def fig12_speeds(run: RunData) -> Figure:
    """Fig. 12: platform angular velocity and the wheel speeds (times 0.1) against time.

    Parameters
    ----------
    run
        The ``fig11`` run.

    Returns
    -------
    Figure
        :math:`\\dot\\theta`, :math:`0.1\\,\\dot\\theta_l` and :math:`0.1\\,\\dot\\theta_r`
        in rad/s.
    """
    s = run.signals
    t = run.t_s
    fig = _new_figure(7.0, 4.2)
    ax = fig.add_subplot()
    ax.plot(t, s["omega_radps"], "-", color="k", linewidth=1.4, label="θ̇  (platform)")
    ax.plot(t, 0.1 * s["omega_l_radps"], "--", color="tab:blue", label="0.1 · θ̇_l  (left wheel)")
    ax.plot(t, 0.1 * s["omega_r_radps"], "-.", color="tab:red", label="0.1 · θ̇_r  (right wheel)")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("angular velocity [rad/s]")
    ax.set_title("Fig. 12. Angular velocity and angular velocities of left and right wheel",
                 fontsize=10)
    ax.axhline(0.0, color="0.3", linewidth=0.6)
    ax.grid(True, linewidth=0.4, alpha=0.6)
    ax.legend(fontsize=8, loc="upper right")
    return fig


# --------------------------------------------------------------------------- region of attraction


@dataclass(frozen=True)
class RoaResult:
    """Outcome of the runs from a grid of start poses.

    Attributes
    ----------
    xs, ys
        Grid positions along x and y, m.
    headings_rad
        Start headings, rad.
    time_to_goal_s
        Shape ``(len(headings), len(ys), len(xs))``; NaN where the run did not converge.
    status
        Same shape: ``converged``, ``timeout`` or ``failed``.
    goal
        The goal pose.
    t_max_s
        Time limit of each run (NaN when unknown: a batch's summary need not say).
    wall_s
        Wall-clock time of the sweep.
    """

    xs: NDArray[np.float64]
    ys: NDArray[np.float64]
    headings_rad: NDArray[np.float64]
    time_to_goal_s: NDArray[np.float64]
    status: NDArray[np.str_]
    goal: Pose
    t_max_s: float
    wall_s: float


def compute_roa(plant: Plant, base: RunSpec, *, grid: int = ROA_GRID,
                headings: int = ROA_HEADINGS, half_width_m: float = ROA_HALF_WIDTH_M,
                t_max_s: float = ROA_MAX_TIME_S, goal: Pose = ROA_GOAL,
                progress: Log = _quiet) -> RoaResult:
    """Run the closed loop (no log) from ``grid`` x ``grid`` positions and ``headings`` headings.

    Parameters
    ----------
    plant
        One plant for every run (reset per run).
    base
        Gains, limits, robot and control period of every run (e.g. the ``fig11`` run).
    grid
        Positions per axis, evenly spaced on ``[-half_width_m, half_width_m]`` around the goal.
    headings
        Start headings, evenly spaced from 0 (e.g. 4: 0, 90, 180, 270 degrees).
    half_width_m
        Half width of the square of start positions, m.
    t_max_s
        Time limit per run; runs that take longer are timeouts.
    goal
        The goal pose.
    progress
        Called with one line per heading.

    Returns
    -------
    RoaResult
        Times to goal and statuses on the grid.
    """
    from wmr.config.scenario import Overrides, with_overrides
    from wmr.core.closedloop import run_closed_loop
    from wmr.core.control.from_spec import SpecController

    if grid < 1 or headings < 1:
        raise ConfigError("--roa-grid", f"{grid} x {grid} positions and {headings} headings",
                          "give at least 1 of each")
    xs = goal.x_m + np.linspace(-half_width_m, half_width_m, grid) if grid > 1 else np.array(
        [goal.x_m + half_width_m])
    ys = goal.y_m + np.linspace(-half_width_m, half_width_m, grid) if grid > 1 else np.array(
        [goal.y_m])
    ths = np.asarray(np.arange(headings) * (2.0 * math.pi / headings), np.float64)
    ttg = np.full((headings, ys.size, xs.size), np.nan)
    status = np.full((headings, ys.size, xs.size), "", dtype="<U9")
    t0 = time.perf_counter()
    for k, th in enumerate(ths):
        for i, y in enumerate(ys):
            for j, x in enumerate(xs):
                spec = with_overrides(base, Overrides(
                    start=Pose(float(x), float(y), float(th)), goal=goal,
                    name=f"roa x={x:g} y={y:g} th={math.degrees(th):g}", max_time_s=t_max_s))
                res = run_closed_loop(spec, plant, controller=SpecController())
                status[k, i, j] = res.status
                if res.status == "converged" and res.time_to_goal_s is not None:
                    ttg[k, i, j] = res.time_to_goal_s
        done = status[k]
        progress(f"region of attraction, start heading {math.degrees(th):.0f}°: "
                 f"{int((done == 'converged').sum())}/{done.size} converged "
                 f"({time.perf_counter() - t0:.1f} s)")
    return RoaResult(xs=xs, ys=ys, headings_rad=ths, time_to_goal_s=ttg, status=status,
                     goal=goal, t_max_s=t_max_s, wall_s=time.perf_counter() - t0)


def _edges(c: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cell edges around grid centres ``c``."""
    if c.size == 1:
        return np.array([c[0] - 1.0, c[0] + 1.0])
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[2 * c[0] - mid[0]], mid, [2 * c[-1] - mid[-1]]])


def roa_figure(roa: RoaResult) -> Figure:
    """Time to goal over the grid of start poses, one panel per start heading.

    Parameters
    ----------
    roa
        The sweep of :func:`compute_roa`.

    Returns
    -------
    Figure
        Cells coloured by time to goal (shared colour scale), timeouts marked with a red
        ``x`` and failures with a black ``+``; the goal pose as an arrow at its position.
    """
    k = roa.headings_rad.size
    ncols = min(k, 2 if k == 4 else 3)
    nrows = math.ceil(k / ncols)
    fig = _new_figure(4.0 * ncols + 1.2, 3.9 * nrows + 0.6)
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False).ravel())
    finite = roa.time_to_goal_s[np.isfinite(roa.time_to_goal_s)]
    # a batch's region of attraction may not know its time limit (NaN): then 1 s
    vmax = float(finite.max()) if finite.size else (
        roa.t_max_s if math.isfinite(roa.t_max_s) else 1.0)
    vmin = float(finite.min()) if finite.size else 0.0
    from matplotlib.colors import Normalize

    norm = Normalize(vmin=vmin, vmax=max(vmax, vmin + 1e-9))
    mesh = None
    xe, ye = _edges(roa.xs), _edges(roa.ys)
    gx, gy, gth = roa.goal.x_m, roa.goal.y_m, roa.goal.heading_rad
    cell = float(min(np.diff(xe).min(), np.diff(ye).min()))
    for n, ax in enumerate(axes):
        if n >= k:
            ax.set_visible(False)
            continue
        ttg = np.ma.masked_invalid(roa.time_to_goal_s[n])
        mesh = ax.pcolormesh(xe, ye, ttg, cmap="viridis", norm=norm, shading="flat")
        xx, yy = np.meshgrid(roa.xs, roa.ys)
        st = roa.status[n]
        timeout = st == "timeout"
        failed = st == "failed"
        ax.plot(xx[timeout], yy[timeout], "x", color="tab:red", markersize=7, mew=2,
                label=f"timeout (> {roa.t_max_s:g} s)" if math.isfinite(roa.t_max_s)
                else "timeout")
        ax.plot(xx[failed], yy[failed], "+", color="k", markersize=8, mew=2, label="failed")
        th = float(roa.headings_rad[n])
        # start heading of this panel, drawn in every cell centre as a short tick
        u, v = math.cos(th), math.sin(th)
        ax.quiver(xx, yy, np.full_like(xx, u), np.full_like(yy, v), color="white", alpha=0.7,
                  angles="xy", scale_units="xy", scale=1.0 / (0.35 * cell), width=0.006)
        _arrow(ax, gx, gy, gth, 0.6 * cell, "tab:red")
        ax.plot([gx], [gy], "o", color="tab:red", markersize=4)
        ax.set_title(f"start heading θ₀ = {math.degrees(th):.0f}°", fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal")
        n_conv = int((st == "converged").sum())
        # a batch's map may have cells without runs (status ""): not counted
        ax.text(0.02, 0.02, f"{n_conv}/{int((st != '').sum())} converged",
                transform=ax.transAxes,
                fontsize=7, color="k", bbox={"fc": "white", "alpha": 0.7, "lw": 0})
        if n == 0 and (timeout.any() or failed.any()):
            ax.legend(fontsize=7, loc="upper right")
    if mesh is not None:
        fig.colorbar(mesh, ax=list(axes[:k]), label="time to goal [s]", shrink=0.9)
    fig.suptitle(f"Region of attraction: time to goal [{gx:g}, {gy:g}, "
                 f"{math.degrees(gth):.0f}°] from a grid of start poses (not in the paper)",
                 fontsize=10)
    return fig


# --------------------------------------------------------------------------- driver


def _read_dir(logs: Path) -> dict[str, list[RunData]]:
    """The logs under ``logs`` by scenario name (``run`` metadata, else the file name)."""
    if not logs.is_dir():
        raise ConfigError("--logs", f"{logs} is not a folder", "give the folder of the logs")
    by: dict[str, list[RunData]] = {}
    for path in sorted(logs.rglob("*.mcap")):
        run = read_run(path)
        if run.n_steps < 2:
            continue
        scenario = _run_meta(run, "scenario") or path.stem.split("-")[0]
        by.setdefault(scenario, []).append(run)
    return by


def _run_scenarios(names: Sequence[str], log_dir: Path, fmu: Path,
                   progress: Log) -> dict[str, list[RunData]]:
    """Run the named scenarios on one FMU plant, log to ``log_dir/<scenario>/``, read back."""
    from wmr.adapters.fmi.robot import FmuPlant
    from wmr.apps.run import run_to_log
    from wmr.config.scenario import load_scenario
    from wmr.infra.paths import safe_filename

    out: dict[str, list[RunData]] = {}
    with FmuPlant(fmu) as plant:
        for name in names:
            scenario = load_scenario(name)
            t0 = time.perf_counter()
            runs = []
            for spec in scenario.runs:
                path = log_dir / scenario.name / f"{safe_filename(spec.name)}.mcap"
                run_to_log(spec, path, plant, scenario_file=scenario.path)
                runs.append(read_run(path))
            progress(f"ran scenario {name}: {plural(len(runs), 'run')} in "
                     f"{time.perf_counter() - t0:.1f} s -> {log_dir / scenario.name}")
            out[name] = runs
    return out


def _save(fig: Figure, path: Path) -> Path:
    refuse_special(path)  # a FIFO there would block the save, a device be written
    fig.savefig(path, dpi=DPI)
    return path


def make_figures(out: Path, *, logs: Path | None = None, roa_grid: int = ROA_GRID,
                 roa_headings: int = ROA_HEADINGS, fmu: Path | None = None,
                 progress: Log = _quiet) -> list[Path]:
    """Write Figs. 9 to 12 and the region-of-attraction map as PNG files into ``out``.

    Parameters
    ----------
    out
        Output folder (created).  Scenario logs made here go to ``out/logs/<scenario>/``.
    logs
        A folder with the logs of the ``fig9``, ``fig10`` and ``fig11`` scenarios (searched
        recursively, sorted by the ``scenario`` of their ``run`` metadata); scenarios missing
        from it are run.  None: run all three.
    roa_grid, roa_headings
        Size of the region-of-attraction sweep: ``roa_grid`` x ``roa_grid`` positions, and
        start headings; ``roa_grid = 0`` skips it.
    fmu
        The FMU to simulate with; default: the project's FMI 3 build
        (:func:`wmr.apps.run.default_fmu`).
    progress
        Called with a line of progress now and then.

    Returns
    -------
    list of Path
        The PNG files written, in the order of :data:`PNG_NAMES`.
    """
    out.mkdir(parents=True, exist_ok=True)
    have = _read_dir(logs) if logs is not None else {}
    missing = [s for s in FIGURE_SCENARIOS if not have.get(s)]
    needs_fmu = bool(missing) or roa_grid > 0
    if needs_fmu and fmu is None:
        from wmr.apps.run import default_fmu

        fmu = default_fmu()
    if missing:
        assert fmu is not None
        have.update(_run_scenarios(missing, out / "logs", fmu, progress))
    fig11_run = have["fig11"][0]

    written = [
        _save(fig9_paths(have["fig9"]), out / PNG_NAMES["fig9"]),
        _save(fig10_paths(have["fig10"]), out / PNG_NAMES["fig10"]),
        _save(fig11_errors(fig11_run), out / PNG_NAMES["fig11"]),
        _save(fig12_speeds(fig11_run), out / PNG_NAMES["fig12"]),
    ]
    if roa_grid > 0:
        from wmr.adapters.fmi.robot import FmuPlant
        from wmr.config.scenario import load_scenario

        assert fmu is not None
        base = load_scenario("fig11").runs[0]
        with FmuPlant(fmu) as plant:
            roa = compute_roa(plant, base, grid=roa_grid, headings=roa_headings,
                              progress=progress)
        written.append(_save(roa_figure(roa), out / PNG_NAMES["roa"]))
    return written


__all__ = [
    "PNG_NAMES",
    "RoaResult",
    "compute_roa",
    "fig9_paths",
    "fig10_paths",
    "fig11_errors",
    "fig12_speeds",
    "make_figures",
    "roa_figure",
]
