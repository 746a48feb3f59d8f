"""Replay run logs in Rerun as a dashboard, and watch a run live while it is simulated.

``wmr replay`` reads one or more MCAP run logs (:func:`wmr.adapters.mcap.read_run`) and sends them
to Rerun as whole columns (``send_columns``): one recording, one ``sim_time`` timeline (simulation
seconds from the log's ``t_ns``), and a default blueprint with

* a 2-D world view with a metre grid and fixed bounds (every start, goal and path in frame): the
  path of each run (coloured by the control phase for one run, by run for several), the robot
  (body and heading arrow, moved by a transform per control step, its arrow coloured by phase),
  the goal (arrow along theta_d, ring of the stop radius), the point D on the heading line
  (Fig. 4) and the ROC reference point R (Fig. 6) with their construction lines from B; for runs
  with sensors the GPS fixes and the estimated path on top of the true one;
* one time-series panel per quantity (:data:`PANELS`: one unit per axis, angles in degrees),
  the control phase, and for runs with sensors the estimation error;
* a run summary: status, times, final errors, start, goal, gains and limits (angles in degrees),
  and, for several runs, one row per run with its start, goal and the inputs that vary.

Entity layout, one subtree per run (``<run>`` is the log's file name without ``.mcap``)::

    grid                          static: the metre grid and its labels (y-up flip)
    summary                       static TextDocument: the run(s) at a glance
    runs/<run>/world              static: y-up flip (2-D views draw y downwards)
    runs/<run>/world/path         static LineStrips2D: the path, a strip per phase
    runs/<run>/world/goal         static Arrows2D + LineStrips2D ring; .../goal/label Points2D
    runs/<run>/world/start        static Points2D: the start, labelled with the run's number
    runs/<run>/world/robot        Transform3D per step (+ its arrow's phase colour);
                                  static Boxes2D body
    runs/<run>/world/D, .../R     Points2D per step (Figs. 4 and 6)
    runs/<run>/world/construction LineStrips2D per step: B -> D and B -> R
    runs/<run>/world/gps          static Points2D: the position fixes (runs with sensors)
    runs/<run>/world/estimate     static LineStrips2D: the estimated path (runs with sensors)
    runs/<run>/<panel>            Scalars per step, one instance per series (PANELS)
    runs/<run>/phase              Scalars per step: 0 approach, 1 align
    runs/<run>/estimation/...     Scalars: position error of the estimate (per step) and
                                  of each fix (runs with sensors)

:class:`~wmr.adapters.rerun.live_view.LiveViewSink` (in :mod:`wmr.adapters.rerun.live_view`,
which imports this module, never the other way) sends the same layout block by block from the
closed loop, and :class:`~wmr.adapters.rerun.live_view.TeeSink` feeds it next to the MCAP
writer.
"""

from __future__ import annotations

import colorsys
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb
from numpy.typing import NDArray

from wmr.adapters.mcap import Pose2D, RunData, read_run
from wmr.adapters.mcap.reader import metadata_json
from wmr.adapters.mcap.scene import (
    ESTIMATE_COLOR,
    GOAL_COLOR,
    GPS_COLOR,
    PHASE_COLORS,
    control_phases,
    robot_geometry,
)
from wmr.adapters.rerun.overlay import (
    align_runs,
    alignment_lines,
    deviation_view,
    log_deviation,
)
from wmr.core.signals import COLUMN
from wmr.infra.durable import replacing_path
from wmr.infra.errors import ConfigError, LogError, WmrError

#: The Rerun application id of every recording written here.
APPLICATION_ID: Final = "wmr-cosim"
#: The one timeline: simulation time from the start of the run.
TIMELINE: Final = "sim_time"
#: Root of the per-run subtrees.
RUNS_ROOT: Final = "runs"
#: The metre grid of the world view, and the run summary.
GRID_ENTITY: Final = "grid"
SUMMARY_ENTITY: Final = "summary"

Rgb = tuple[int, int, int]

#: Run colours (matplotlib's tab10), in the order the runs are given; beyond ten runs the
#: hues are spread by the golden angle instead (:func:`run_color`), so no two runs share one.
RUN_COLORS: Final[tuple[Rgb, ...]] = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
)
D_COLOR: Final[Rgb] = (0, 170, 255)
R_COLOR: Final[Rgb] = (230, 150, 0)
LABEL_COLOR: Final[Rgb] = (60, 60, 60)
GRID_COLOR: Final[Rgb] = (215, 215, 215)
AXIS_COLOR: Final[Rgb] = (150, 150, 150)
#: Label text takes the colour of its point: dark, to read on the label's light box.
GRID_LABEL_COLOR: Final[Rgb] = (70, 70, 70)
#: The GPS fixes in the world view: lighter than the log's scene colour, under the paths.
GPS_DOT_COLOR: Final[Rgb] = (150, 150, 150)
_DEG: Final = 180.0 / math.pi


@dataclass(frozen=True)
class Series:
    """One plotted signal: its column in :data:`wmr.core.signals.SIGNALS`, its label and colour,
    and the factor from the column's unit to the plotted one (rad -> degrees)."""

    signal: str
    label: str
    color: Rgb
    scale: float = 1.0


@dataclass(frozen=True)
class Panel:
    """A time-series view: one multi-instance ``Scalars`` entity per run, one line per series.

    ``overlay`` series (the first ones) are drawn per run when several runs share the plots,
    under ``overlay_title``; ``limit`` names the run's ``limits`` entry that fixes a symmetric
    axis range (so a saturated start-up does not flatten the rest).
    """

    entity: str
    title: str
    series: tuple[Series, ...]
    overlay: int = 1
    overlay_title: str = ""
    limit: str | None = None


_BLUE, _ORANGE, _GREEN = (31, 119, 180), (255, 127, 14), (44, 160, 44)
_RED, _PURPLE, _GREY = (214, 39, 40), (148, 103, 189), (110, 110, 110)
_LIGHT_ORANGE, _LIGHT_PURPLE = (255, 187, 120), (197, 176, 213)

#: The time-series panels, in reading order (two columns); one unit per axis.
PANELS: Final[tuple[Panel, ...]] = (
    Panel("distance", "Distance to goal Δr and error e_s [m] (Fig. 11)", (
        Series("dr_m", "Δr", _GREY),
        Series("e_s_m", "e_s", _BLUE),
    ), overlay_title="Distance to goal Δr [m]"),
    Panel("heading", "Heading error e_θ [°] (Fig. 11)", (
        Series("e_theta_rad", "e_θ", _RED, _DEG),
    ), overlay_title="Heading error e_θ [°]"),
    Panel("speed", "Speed v and command u_s [m/s]", (
        Series("v_mps", "v", _BLUE),
        Series("u_s_mps", "u_s", _LIGHT_ORANGE),
    ), overlay_title="Speed v [m/s]"),
    Panel("turn_rate", "Turn rate ω and command u_θ [rad/s] (Fig. 12)", (
        Series("omega_radps", "ω", _GREEN),
        Series("u_theta_radps", "u_θ", _LIGHT_ORANGE),
    ), overlay_title="Turn rate ω [rad/s]"),
    Panel("wheels", "Wheel speeds and references [rad/s] (Fig. 12)", (
        Series("omega_r_radps", "ω_r", _ORANGE),
        Series("omega_l_radps", "ω_l", _PURPLE),
        Series("omega_r_ref_radps", "ω_r ref", _LIGHT_ORANGE),
        Series("omega_l_ref_radps", "ω_l ref", _LIGHT_PURPLE),
    ), overlay_title="Right wheel speed ω_r [rad/s]"),
    Panel("torques", "Motor torques [N m]", (
        Series("tau_r_nm", "τ_r", _ORANGE),
        Series("tau_l_nm", "τ_l", _PURPLE),
    ), overlay_title="Right motor torque τ_r [N m]", limit="torque_max_nm"),
    Panel("pi_distance", "Distance PI, eq. 29 [m/s]", (
        Series("p_s_mps", "P_s", _BLUE),
        Series("i_s_mps", "I_s", (158, 202, 225)),
        Series("u_s_mps", "u_s", (8, 48, 107)),
    ), overlay_title="Distance PI output u_s [m/s]"),
    Panel("pi_heading", "Heading PI, eq. 29 [rad/s]", (
        Series("p_theta_radps", "P_θ", _RED),
        Series("i_theta_radps", "I_θ", (252, 146, 114)),
        Series("u_theta_radps", "u_θ", (103, 0, 13)),
    ), overlay_title="Heading PI output u_θ [rad/s]"),
)
#: The control phase panel (0 approach, 1 align) and the estimation error (runs with sensors).
PHASE_ENTITY: Final = "phase"
ESTIMATION_ENTITY: Final = "estimation"

#: Entities under ``runs/<run>/world`` that get one row per control step.
WORLD_SERIES: Final = ("robot", "D", "R", "construction")
#: Entities under ``runs/<run>/world`` logged once (static).
WORLD_STATIC: Final = ("path", "goal", "start")

_PANEL_COLUMNS: Final = {p.entity: [COLUMN[s.signal] for s in p.series] for p in PANELS}
_PANEL_SCALES: Final = {p.entity: np.array([s.scale for s in p.series]) for p in PANELS}
_X, _Y, _TH = COLUMN["x_m"], COLUMN["y_m"], COLUMN["theta_rad"]
_DX, _DY, _RX, _RY = COLUMN["D_x_m"], COLUMN["D_y_m"], COLUMN["R_x_m"], COLUMN["R_y_m"]
_DR = COLUMN["dr_m"]

#: Length of the heading arrow of the robot and of the goal, m.
_ARROW_M: Final = 1.0
#: Beyond this many runs the world view labels only every k-th start (k = n // this + 1).
_MAX_LABELS: Final = 25


# --------------------------------------------------------------------------- inputs


@dataclass(frozen=True)
class RunLog:
    """A log to replay and the name of its subtree (``runs/<name>``)."""

    name: str
    path: Path


def find_logs(inputs: Sequence[str | os.PathLike[str]],
              skipped: list[str] | None = None) -> list[RunLog]:
    """The MCAP logs named by ``inputs``: files as given, folders searched recursively.

    Parameters
    ----------
    inputs
        ``.mcap`` files and folders (a batch output folder may hold sub-folders).
    skipped
        Gets one line per file of a folder left out: a symbolic link (or a file under one)
        that leads outside the folder is not followed.

    Returns
    -------
    list of RunLog
        In the order given (folder contents sorted), each with a unique run name: the file
        name without ``.mcap``, prefixed by its parent folder when two logs share a name.

    Raises
    ------
    LogError
        An input does not exist, or no ``.mcap`` file was found.
    """
    paths: list[Path] = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            root = p.resolve()
            found = []
            for f in sorted(f for f in p.rglob("*.mcap") if f.is_file()):
                if f.resolve().is_relative_to(root):
                    found.append(f)
                elif skipped is not None:
                    skipped.append(f"{f}: skipped: a link to {f.resolve()}, outside {p}")
            if not found:
                raise LogError(f"{p}: no .mcap files in this folder")
            paths.extend(found)
        elif p.is_file():
            paths.append(p)
        elif p.exists():  # a FIFO or a device: opening it could block, reading it never ends
            raise LogError(f"{p}: not a regular file or folder; give .mcap files or folders")
        else:
            raise LogError(f"{p}: no such file or folder")
    if not paths:
        raise LogError("no log to replay (give FILE.mcap or a folder of logs)")
    stems = [p.stem for p in paths]
    logs: list[RunLog] = []
    used: set[str] = set()
    for p in paths:
        name = p.stem if stems.count(p.stem) == 1 else f"{p.parent.name}_{p.stem}"
        base, k = name, 2
        while name in used:
            name, k = f"{base}-{k}", k + 1
        used.add(name)
        logs.append(RunLog(name, p))
    return logs


def has_screen() -> bool:
    """True when a viewer window can be opened (X11 or Wayland display, or macOS/Windows)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


#: How to get the inline viewer of :func:`replay` (``notebook=True``).
NOTEBOOK_EXTRA: Final = "pip install 'wmr-cosim[notebook]'"


def check_notebook(rrd: str | os.PathLike[str] | None = None,
                   spawn: bool | None = None) -> None:
    """Refuse ``notebook=True`` where no inline viewer can be shown, before any log is read.

    Raises
    ------
    ConfigError
        Given with an ``rrd`` or a viewer to ``spawn``; rerun-notebook (or the widget
        packages it needs) is not installed, naming the extra; or there is no notebook
        kernel to show a widget in (a plain script would only print the widget's repr and
        drop the recording).
    """
    if rrd is not None or spawn:
        # the widget is the recording's one sink (Rerun has no tee of a callback sink)
        raise ConfigError("notebook", "given with " + ("rrd" if rrd is not None
                                                       else "a viewer"),
                          "give one of them: replay twice to see it inline and keep an .rrd")
    from rerun import notebook as rr_notebook

    # False when rerun_notebook, anywidget or ipywidgets cannot be imported; rerun's own error
    # comes later (inside Viewer, after the logs are read) and names no extra
    if not rr_notebook.HAS_NOTEBOOK:
        raise ConfigError("notebook", "the inline viewer needs rerun-notebook, which is not "
                          "installed", NOTEBOOK_EXTRA)
    from rerun_notebook import running_in_marimo

    try:
        from IPython import get_ipython
    except ImportError:  # pragma: no cover - ipywidgets, hence HAS_NOTEBOOK, needs IPython
        shell = None
    else:
        shell = get_ipython()
    if getattr(shell, "kernel", None) is None and not running_in_marimo():
        raise ConfigError("notebook", "not in a notebook: the inline viewer needs a Jupyter "
                          "(or marimo) kernel",
                          "call it from a notebook, or replay to a viewer or rrd= instead")


#: The port a spawned viewer listens on (Rerun's own default: a viewer already open there is
#: reused, as ``rr.spawn`` does).
VIEWER_PORT: Final = 9876
#: How long a spawned viewer may take to listen before the recording goes to a file instead, s.
VIEWER_READY_S: Final = 10.0


def _listening(port: int) -> bool:
    """Whether something accepts TCP connections on 127.0.0.1:``port``."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def _bundled_rerun() -> str:
    """The viewer of the installed ``rerun-sdk`` (when its ``bin`` folder is not on PATH)."""
    import rerun_cli

    exe = Path(rerun_cli.__file__).parent / "rerun"
    if not exe.is_file():
        raise FileNotFoundError("no rerun executable on PATH")
    return str(exe)


def viewer_log_path() -> Path:
    """Where a spawned viewer's own output goes (appended): ``viewer.log`` in the cache."""
    from wmr.infra.paths import cache_dir

    return cache_dir() / "viewer.log"


def spawn_viewer(rec: rr.RecordingStream, blueprint: rrb.BlueprintLike | None, *,
                 connect: bool = True, port: int = VIEWER_PORT,
                 ready_s: float = VIEWER_READY_S) -> Path | None:
    """Start the ``rerun`` viewer detached from us, and connect ``rec`` to it.

    ``rr.spawn`` lets the viewer inherit our stdout and stderr: a pipe we write to
    (``wmr replay ... | tail``) stays open as long as the viewer runs, and its INFO/WARN lines
    flood the caller's terminal.  Here the viewer gets no stdin, writes to
    :func:`viewer_log_path`, and runs in its own session (a Ctrl-C in our terminal leaves it
    open, as before).

    Parameters
    ----------
    rec
        The recording to connect (when ``connect``).
    blueprint
        Its default blueprint.
    connect
        Connect ``rec`` to the viewer (else the caller sets its sinks).
    port
        The viewer's port; a viewer already listening there is used, none started.
    ready_s
        How long to wait for a started viewer to listen, s.

    Returns
    -------
    Path or None
        The viewer's log file, None when a viewer was already open.

    Raises
    ------
    FileNotFoundError
        No ``rerun`` executable on ``PATH`` nor in the ``rerun-sdk`` package.
    RuntimeError
        The viewer exited, or did not listen within ``ready_s`` (it is left running).
    """
    log_path: Path | None = None
    if not _listening(port):
        exe = shutil.which("rerun") or _bundled_rerun()
        log_path = viewer_log_path()
        log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(log_path, "ab") as out:
            proc = subprocess.Popen(
                [exe, "--port", str(port), "--memory-limit", "75%",
                 "--server-memory-limit", "1GiB", "--expect-data-soon"],
                stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                start_new_session=True, env={**os.environ, "RERUN_APP_ONLY": "true"})
        deadline = time.monotonic() + ready_s
        while not _listening(port):
            if proc.poll() is not None:
                raise RuntimeError(f"the viewer exited with status {proc.returncode}; "
                                   f"its output is in {log_path}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the viewer (pid {proc.pid}) is not listening on port "
                                   f"{port} after {ready_s:g} s; its output is in {log_path}")
            time.sleep(0.05)
    if connect:
        rec.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy", default_blueprint=blueprint)
    return log_path


def default_rrd_path(inputs: Sequence[str | os.PathLike[str]]) -> Path:
    """Where ``wmr replay`` writes its recording when no ``--rrd`` is given.

    One file ``X.mcap`` -> ``X.rrd`` beside it; one folder ``D`` -> ``D.rrd`` beside it;
    several inputs -> ``replay.rrd`` in the folder of the first.
    """
    first = Path(inputs[0])
    if len(inputs) == 1:
        if first.is_dir():
            resolved = first.resolve()
            return resolved.parent / f"{resolved.name}.rrd"
        return first.with_suffix(".rrd")
    return (first if first.is_dir() else first.parent) / "replay.rrd"


# --------------------------------------------------------------------------- entity paths


def run_entity(name: str) -> str:
    """Entity path of a run's subtree: ``runs/<name>`` (the name escaped for Rerun)."""
    return f"{RUNS_ROOT}/{rr.escape_entity_path_part(name)}"


def run_color(k: int, n_runs: int) -> Rgb:
    """Colour of the ``k``-th of ``n_runs`` runs: tab10 up to ten runs, else golden-angle hues
    (distinct for any number of runs, alternating two lightnesses)."""
    if n_runs <= len(RUN_COLORS):
        return RUN_COLORS[k % len(RUN_COLORS)]
    hue = (0.6 + 0.381966 * k) % 1.0
    r, g, b = colorsys.hls_to_rgb(hue, 0.42 if k % 2 else 0.55, 0.75)
    return round(255 * r), round(255 * g), round(255 * b)


def _series_style(panel: Panel, label: str | None, run_color: Rgb | None) -> rr.SeriesLines:
    """Line names and colours of a panel: per signal, or (several runs) the overlay series in
    the run's colour, named after the run."""
    if run_color is None:
        return rr.SeriesLines(names=[s.label for s in panel.series],
                              colors=[s.color for s in panel.series], widths=[1.5])
    shown = panel.series[:panel.overlay]
    return rr.SeriesLines(names=[f"{label}: {s.label}" for s in shown],
                          colors=[run_color] * len(shown), widths=[1.0],
                          visible_series=[True] * len(shown) + [False] * (
                              len(panel.series) - len(shown)))


# --------------------------------------------------------------------------- world bounds


@dataclass(frozen=True)
class Bounds:
    """A rectangle of the world plane, m."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float

    @classmethod
    def around(cls, points: NDArray[np.float64], margin_frac: float = 0.08,
               min_size_m: float = 4.0) -> Bounds:
        """The finite ``points`` (shape ``(n, 2)``) with a margin on every side."""
        p = points[np.isfinite(points).all(axis=1)]
        if p.size == 0:
            p = np.zeros((1, 2))
        lo, hi = p.min(axis=0), p.max(axis=0)
        size = np.maximum(hi - lo, min_size_m)
        mid = 0.5 * (lo + hi)
        half = 0.5 * size * (1.0 + 2.0 * margin_frac) + 0.5  # + room for labels and arrows
        return cls(float(mid[0] - half[0]), float(mid[0] + half[0]),
                   float(mid[1] - half[1]), float(mid[1] + half[1]))

    def contains(self, points: NDArray[np.float64]) -> bool:
        """Whether every finite point of ``points`` (shape ``(n, 2)``) is inside."""
        p = points[np.isfinite(points).all(axis=1)]
        return bool(np.all((p[:, 0] >= self.x_min) & (p[:, 0] <= self.x_max)
                           & (p[:, 1] >= self.y_min) & (p[:, 1] <= self.y_max)))

    def view(self) -> rrb.VisualBounds2D:
        """The 2-D view's bounds: its y axis points down, the world's is mirrored up."""
        return rrb.VisualBounds2D(x_range=[self.x_min, self.x_max],
                                  y_range=[-self.y_max, -self.y_min])


def grid_spacing(span_m: float) -> float:
    """A round grid spacing (1, 2 or 5 times a power of ten) giving 5 to 12 lines over
    ``span_m``."""
    raw = span_m / 8.0
    power = 10.0 ** math.floor(math.log10(raw))
    return next(k * power for k in (1.0, 2.0, 5.0, 10.0) if k * power >= raw)


def log_grid(rec: rr.RecordingStream, bounds: Bounds) -> None:
    """The metre grid of the world view, its labelled lines and the axes through the origin."""
    step = grid_spacing(max(bounds.x_max - bounds.x_min, bounds.y_max - bounds.y_min))
    xs = np.arange(math.ceil(bounds.x_min / step), math.floor(bounds.x_max / step) + 1) * step
    ys = np.arange(math.ceil(bounds.y_min / step), math.floor(bounds.y_max / step) + 1) * step
    lines = ([[[x, bounds.y_min], [x, bounds.y_max]] for x in xs]
             + [[[bounds.x_min, y], [bounds.x_max, y]] for y in ys])
    colors = [AXIS_COLOR if abs(v) < 1e-9 else GRID_COLOR for v in (*xs, *ys)]
    rec.log(GRID_ENTITY, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
    rec.log(f"{GRID_ENTITY}/lines", rr.LineStrips2D(lines, colors=colors, radii=[-0.6],
                                                    draw_order=-10.0), static=True)
    # the line values along the bottom and the left edge (a ruler: the view has no axes),
    # far enough inside for the label, centred on its point, not to be cut by the edge
    inset = 0.035 * max(bounds.x_max - bounds.x_min, bounds.y_max - bounds.y_min)
    marks = ([[x, bounds.y_min + inset] for x in xs]
             + [[bounds.x_min + inset, y] for y in ys])
    texts = [f"{v:g} m" for v in (*xs, *ys)]
    rec.log(f"{GRID_ENTITY}/labels",
            rr.Points2D(marks, radii=[0.0], colors=[GRID_LABEL_COLOR], labels=texts,
                        show_labels=True,
                        draw_order=-9.0), static=True)


# --------------------------------------------------------------------------- blueprint


def replay_blueprint(run_names: Sequence[str], *, live: bool = False,
                     bounds: Bounds | None = None, sensing: bool = False,
                     torque_range_nm: float | None = None,
                     extra_plots: Sequence[rrb.TimeSeriesView] = ()) -> rrb.Blueprint:
    """The dashboard: world view and run summary on the left, the time-series panels on the
    right (two columns), the phase strip below them; side panels collapsed.

    Parameters
    ----------
    run_names
        The runs of the recording (their subtrees ``runs/<name>``).
    live
        For a live view: the time follows the newest rows, and the plots show the latest
        30 s instead of the whole run.
    bounds
        Fixed bounds of the world view (every start, goal and path); None: Rerun's own
        (follows what is drawn, for a live run whose path is not known yet).
    sensing
        Add the estimation-error panel (runs with sensors).
    torque_range_nm
        The torque axis spans ``[-range, range]`` (:func:`torque_range`: the saturated
        start-up runs off the top instead of flattening the rest).
    extra_plots
        More panels after the others (the deviation of a real robot's path,
        :func:`wmr.adapters.rerun.overlay.deviation_view`).
    """
    roots = [f"/{run_entity(n)}" for n in run_names]
    many = len(run_names) > 1
    world = rrb.Spatial2DView(
        name="World: x right, y up [m]", origin="/",
        contents=[f"/{GRID_ENTITY}/**", *(f"{r}/world/**" for r in roots)],
        background=(252, 252, 252),
        visual_bounds=bounds.view() if bounds is not None else None,
    )
    time_range = (
        rrb.VisibleTimeRange(TIMELINE, start=rrb.TimeRangeBoundary.cursor_relative(seconds=-30.0),
                             end=rrb.TimeRangeBoundary.cursor_relative())
        if live else None
    )
    # several runs: the run's colour names it (world view labels, summary): no legend
    legend = rrb.PlotLegend(visible=not many, corner=rrb.Corner2D.RightTop)

    def plot(entity: str, title: str, axis: rrb.ScalarAxis | None = None) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(name=title, origin="/",
                                  contents=[f"{r}/{entity}/**" for r in roots],
                                  plot_legend=legend, time_ranges=time_range, axis_y=axis)

    plots = []
    for p in PANELS:
        axis = (rrb.ScalarAxis(range=(-torque_range_nm, torque_range_nm))
                if p.limit and torque_range_nm else None)
        plots.append(plot(p.entity, p.overlay_title if many else p.title, axis))
    if sensing:
        plots.append(plot(ESTIMATION_ENTITY, "Position error of the estimate and the GPS "
                                             "fixes [m]"))
    plots += extra_plots
    phase = plot(PHASE_ENTITY, "Control phase: 0 approach, 1 align",
                 rrb.ScalarAxis(range=(-0.2, 1.2)))
    summary = rrb.TextDocumentView(name="Run summary" if not many else
                                   f"{len(run_names)} runs", origin=f"/{SUMMARY_ENTITY}")
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(world, summary, row_shares=[3, 2]),
            rrb.Vertical(rrb.Grid(*plots, grid_columns=2), phase, row_shares=[9, 1]),
            column_shares=[5, 6],
        ),
        # live: the time cursor follows the newest rows (a live .rrd opens at its end); the
        # collapsed time panel keeps its play bar and leaves the phase strip its height
        rrb.TimePanel(timeline=TIMELINE, state="collapsed",
                      play_state="following" if live else None),
        collapse_panels=True,
    )


# --------------------------------------------------------------------------- logging


def _yaw_quaternions(theta: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quaternions ``(x, y, z, w)`` of yaws ``theta`` about z, shape ``(n, 4)``."""
    q = np.zeros((theta.shape[0], 4))
    q[:, 2] = np.sin(0.5 * theta)
    q[:, 3] = np.cos(0.5 * theta)
    return q


def _time_column(t_ns: NDArray[np.int64]) -> rr.TimeColumn:
    return rr.TimeColumn(TIMELINE, duration=np.asarray(t_ns, np.int64).astype("timedelta64[ns]"))


def _segments_column(strips: NDArray[np.float64], per_row: int) -> rr.ComponentColumn:
    """``LineStrips2D:strips`` of two-point strips (shape ``(k, 2, 2)``), ``per_row`` strips a
    row, built as one Arrow array: Rerun's own conversion walks the strips in Python (about
    4 us each, the larger part of a replay's sending)."""
    batch_type = rr.components.LineStrip2DBatch
    arrow_type = batch_type._ARROW_DATATYPE
    points = pa.FixedSizeListArray.from_arrays(
        pa.array(np.ascontiguousarray(strips, np.float32).reshape(-1), type=pa.float32()),
        type=arrow_type.value_type)
    offsets = pa.array(np.arange(0, 2 * len(strips) + 1, 2, dtype=np.int32))
    return rr.ComponentColumn(rr.LineStrips2D.descriptor_strips(),
                              batch_type(pa.ListArray.from_arrays(offsets, points,
                                                                  type=arrow_type)),
                              lengths=np.full(len(strips) // per_row, per_row))


def phase_strips(path_xy: NDArray[np.float64], phase: NDArray[np.int8] | None
                  ) -> tuple[list[NDArray[np.float64]], list[Rgb]]:
    """The path cut where the phase changes (each piece shares its end point with the next),
    and the colour of each piece."""
    if phase is None or phase.size != len(path_xy):
        return [path_xy], [PHASE_COLORS[0]]
    cuts = np.flatnonzero(phase[1:] != phase[:-1]) + 1
    starts = np.concatenate([[0], cuts])
    ends = np.concatenate([cuts + 1, [len(path_xy)]])
    return ([path_xy[a:b] for a, b in zip(starts, ends, strict=True)],
            [PHASE_COLORS[int(phase[a])] for a in starts])


def log_run_static(rec: rr.RecordingStream, name: str, *, goal: Pose2D | None,
                   path_xy: NDArray[np.float64] | None, color: Rgb,
                   run_color: Rgb | None = None, half_track_m: float = 0.3,
                   wheel_radius_m: float = 0.15, info: str | None = None,
                   phase: NDArray[np.int8] | None = None, start_label: str | None = None,
                   stop_radius_m: float | None = None, goal_label: str | None = "") -> None:
    """Log the timeless part of a run once: frame flip, path, goal, robot shape, plot styles.

    Parameters
    ----------
    rec
        The recording.
    name
        The run name (subtree ``runs/<name>``).
    goal
        Goal pose, or None when the log has none.
    path_xy
        The whole path, shape ``(n, 2)``; None for a live run (logged block by block).
    color
        Colour of the robot (and of the path when ``run_color`` is given).
    run_color
        When several runs share the plots: the run's colour for its path and lines (None: the
        path coloured by phase, the lines per signal).
    half_track_m, wheel_radius_m
        Robot geometry for the body drawing.
    info
        Kept for callers of the single-run API: Markdown of the run panel (the summary).
    phase
        The control phase per row of ``path_xy`` (colours the path of a single run).
    start_label
        Label at the start of the path (the run's number in a multi-run replay).
    stop_radius_m
        Radius of the ring drawn around the goal.
    goal_label
        The goal's label: ``""`` its pose ``goal (x, y, θ_d°)``, None none (a goal another
        run already labelled), else this text.
    """
    root = run_entity(name)
    world = f"{root}/world"
    # 2-D views draw y downwards: a mirror about the x axis puts y up, as in the paper's plots
    rec.log(world, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
    if path_xy is not None and path_xy.shape[0] >= 1:
        if run_color is None:
            strips, colors = phase_strips(path_xy, phase)
        else:
            strips, colors = [path_xy], [run_color]
        # widths in UI points: a path stays visible (and no wider) at any zoom
        rec.log(f"{world}/path", rr.LineStrips2D(strips, colors=colors,
                                                 radii=[-1.5 if run_color is None else -1.0],
                                                 draw_order=10.0), static=True)
        if start_label is not None:
            # the number behind the start (the robot stands on the start at t = 0)
            back = path_xy[0] - 0.6 * (path_xy[min(len(path_xy) - 1, 50)] - path_xy[0]) / max(
                1e-9, float(np.linalg.norm(path_xy[min(len(path_xy) - 1, 50)] - path_xy[0])))
            rec.log(f"{world}/start",
                    rr.Points2D([back], colors=[color], radii=[0.06],
                                labels=[start_label], show_labels=bool(start_label),
                                draw_order=30.0),
                    static=True)
    if goal is not None:
        gx, gy, gth = goal
        vec = [_ARROW_M * math.cos(gth), _ARROW_M * math.sin(gth)]
        ring = []
        if stop_radius_m and stop_radius_m > 0:
            a = np.linspace(0.0, 2 * math.pi, 48)
            ring = [np.column_stack([gx + stop_radius_m * np.cos(a),
                                     gy + stop_radius_m * np.sin(a)])]
        rec.log(f"{world}/goal",
                rr.Arrows2D(origins=[[gx, gy]], vectors=[vec], colors=[GOAL_COLOR],
                            radii=[0.04], draw_order=20.0),
                rr.LineStrips2D(ring, colors=[GOAL_COLOR], radii=[0.01], draw_order=20.0),
                static=True)
        # the label apart from the arrow, in a neutral colour (red on red did not read)
        rec.log(f"{world}/goal/label",
                rr.Points2D([[gx, gy - 0.45]], radii=[0.0], colors=[LABEL_COLOR],
                            labels=[goal_label or f"goal ({gx:g}, {gy:g}, "
                                                  f"{math.degrees(gth):.0f}°)"],
                            show_labels=goal_label is not None, draw_order=21.0), static=True)
    # the robot in its own frame (B at the origin, x forward): chassis, two wheels, heading;
    # the heading arrow's colour is sent per step (the phase), so it is not static here
    chassis_len = 2.0 * half_track_m + 0.2
    rec.log(f"{world}/robot",
            rr.Boxes2D(centers=[[0.5 * chassis_len - 0.3, 0.0], [0.0, half_track_m],
                                [0.0, -half_track_m]],
                       half_sizes=[[0.5 * chassis_len, 0.8 * half_track_m],
                                   [wheel_radius_m, 0.05], [wheel_radius_m, 0.05]],
                       colors=[color, (40, 40, 40), (40, 40, 40)], radii=[0.025],
                       draw_order=40.0),
            rr.Arrows2D.from_fields(origins=[[0.0, 0.0]], vectors=[[_ARROW_M, 0.0]],
                                    radii=[0.04], draw_order=41.0),
            static=True)
    rec.log(f"{world}/D", rr.Points2D.from_fields(colors=[D_COLOR], radii=[0.1], labels=["D"],
                                                   show_labels=True, draw_order=35.0),
            static=True)
    rec.log(f"{world}/R", rr.Points2D.from_fields(colors=[R_COLOR], radii=[0.1], labels=["R"],
                                                   show_labels=True, draw_order=35.0),
            static=True)
    rec.log(f"{world}/construction",
            rr.LineStrips2D.from_fields(colors=[D_COLOR, R_COLOR], radii=[0.012],
                                        draw_order=34.0), static=True)
    label = start_label if start_label is not None else name
    for panel in PANELS:
        rec.log(f"{root}/{panel.entity}", _series_style(panel, label, run_color), static=True)
    rec.log(f"{root}/{PHASE_ENTITY}",
            rr.SeriesLines(names=[f"{label}: phase" if run_color else "phase"],
                           colors=[run_color or _GREY], widths=[1.5],
                           aggregation_policy="minmax"), static=True)
    if info:
        rec.log(SUMMARY_ENTITY, rr.TextDocument(info, media_type=rr.MediaType.MARKDOWN),
                static=True)


#: Entity of a run's optimal path, under its world: ``runs/<name>/world/optimal``.
OPTIMAL_ENTITY: Final = "world/optimal"


def log_optimal_path(rec: rr.RecordingStream, name: str, path_xy: NDArray[np.float64],
                     color: Rgb) -> None:
    """Draw the optimal path of run ``name`` beside its own: in a lighter tint of the run's
    ``color`` (Rerun has no dashed lines: lighter and thinner), under the run's path, labelled
    ``optimal``."""
    light = tuple(round(c + 0.55 * (255 - c)) for c in color)
    rec.log(f"{run_entity(name)}/{OPTIMAL_ENTITY}",
            rr.LineStrips2D([path_xy], colors=[light], radii=[-0.75], labels=["optimal"],
                            show_labels=True, draw_order=9.0), static=True)


def send_run_columns(rec: rr.RecordingStream, name: str, t_ns: NDArray[np.int64],
                     block: NDArray[np.float64], phase: NDArray[np.int8] | None = None, *,
                     construction: bool = True) -> None:
    """Send rows of a run as whole columns: the pose, D, R and every time-series panel.

    Parameters
    ----------
    rec
        The recording.
    name
        The run name (subtree ``runs/<name>``).
    t_ns
        Simulation times, ns, shape ``(n,)``.
    block
        The rows, shape ``(n, len(SIGNALS))``, columns as :data:`wmr.core.signals.SIGNALS`.
    phase
        The control phase of each row (:func:`wmr.adapters.mcap.scene.control_phases`): the
        phase panel and the colour of the robot's heading arrow; None: not known (live view).
    construction
        Send the points D and R and their construction lines (off for several runs: one pair
        per run hides the paths).
    """
    n = int(t_ns.shape[0])
    if n == 0:
        return
    root = run_entity(name)
    world = f"{root}/world"
    times = [_time_column(t_ns)]
    x, y, theta = block[:, _X], block[:, _Y], block[:, _TH]
    translation = np.column_stack([x, y, np.zeros(n)])
    colors = np.asarray(PHASE_COLORS, np.uint8)[phase if phase is not None
                                                 else np.zeros(n, np.int8)]
    rec.send_columns(f"{world}/robot", indexes=times, columns=[
        *rr.Transform3D.columns(translation=translation, quaternion=_yaw_quaternions(theta)),
        *rr.Arrows2D.columns(colors=colors)])
    if construction:
        d_xy = np.ascontiguousarray(block[:, [_DX, _DY]])
        r_xy = np.ascontiguousarray(block[:, [_RX, _RY]])
        rec.send_columns(f"{world}/D", indexes=times,
                         columns=rr.Points2D.columns(positions=d_xy))
        rec.send_columns(f"{world}/R", indexes=times,
                         columns=rr.Points2D.columns(positions=r_xy))
        b_xy = np.column_stack([x, y])
        strips = np.stack([np.stack([b_xy, d_xy], axis=1), np.stack([b_xy, r_xy], axis=1)],
                          axis=1).reshape(2 * n, 2, 2)
        rec.send_columns(f"{world}/construction", indexes=times,
                         columns=[_segments_column(strips, per_row=2)])
    for panel in PANELS:
        values = block[:, _PANEL_COLUMNS[panel.entity]] * _PANEL_SCALES[panel.entity]
        rec.send_columns(f"{root}/{panel.entity}", indexes=times,
                         columns=rr.Scalars.columns(scalars=np.ascontiguousarray(values)))
    if phase is not None:
        rec.send_columns(f"{root}/{PHASE_ENTITY}", indexes=times,
                         columns=rr.Scalars.columns(scalars=phase.astype(np.float64)))


# --------------------------------------------------------------------------- summary


def _json(meta: Mapping[str, str], key: str) -> Any:
    """A JSON value of a metadata record, or None (bounded: a stranger's log may hold a value
    nested too deep for ``json.loads``)."""
    try:
        return metadata_json(meta[key])
    except (KeyError, ValueError, TypeError, LogError):
        return None


def _float(value: object) -> float | None:
    try:
        f = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _pose_text(pose: object) -> str:
    """``(x, y, θ°)`` of a ``{"x_m", "y_m", "heading_rad"}`` record."""
    if not isinstance(pose, dict):
        return "?"
    x, y, th = (_float(pose.get(k)) for k in ("x_m", "y_m", "heading_rad"))
    if x is None or y is None or th is None:
        return "?"
    return f"({x:.2f}, {y:.2f}, {math.degrees(th):.0f}°)"


def _status_text(result: Mapping[str, str], run: RunData) -> str:
    status = result.get("status", "no result record (a cut log)")
    t_goal = _float(result.get("time_to_goal_s"))
    t_end = float(run.t_s[-1]) if run.n_steps else 0.0
    when = f"at t = {t_goal:.2f} s" if t_goal is not None else f"ran {t_end:.2f} s"
    return f"**{status}** {when}" + (" (**log truncated**)" if run.truncated else "")


def _final_errors(result: Mapping[str, str]) -> str:
    pos, head = (_float(result.get(k)) for k in ("final_position_error_m",
                                                  "final_heading_error_rad"))
    if pos is None or head is None:
        return "?"
    return f"{1000 * pos:.1f} mm, {math.degrees(head):.2f}°"


_LIMIT_TEXT: Final = {"v_max_mps": ("v_max", "m/s", 1.0),
                      "omega_max_radps": ("ω_max", "°/s", _DEG),
                      "wheel_speed_max_radps": ("wheel_max", "rad/s", 1.0),
                      "torque_max_nm": ("τ_max", "N m", 1.0)}


def _summary_single(name: str, run: RunData, sensing: bool) -> str:
    """The run summary of a single-run replay: reads in one glance."""
    meta, result = run.metadata.get("run", {}), run.metadata.get("result", {})
    gains = _json(meta, "gains") or {}
    limits = _json(meta, "limits") or {}
    eps = _float(meta.get("stop_radius_m"))
    h = _float(meta.get("control_period_s"))
    rows = [f"### {name}: {_status_text(result, run)}", "",
            "| | |", "|---|---|",
            f"| start → goal (x, y [m], θ) | {_pose_text(_json(meta, 'start'))} → "
            f"{_pose_text(_json(meta, 'goal'))} |",
            f"| final error (position, heading) | {_final_errors(result)} |"]
    if sensing:
        rows.append("| believed final error | " + _final_errors(
            {"final_position_error_m": result.get("estimated_final_position_error_m", ""),
             "final_heading_error_rad": result.get("estimated_final_heading_error_rad", "")})
            + " |")
    length = _float(result.get("path_length_m"))
    energy = _float(result.get("energy_positive_j"))
    rows.append(f"| path, energy | {length or 0:.2f} m, {energy or 0:.1f} J |")
    rows.append("| gains | " + ", ".join(f"{k} {v:g}" for k, v in gains.items()
                                         if isinstance(v, int | float)) + " |")
    rows.append("| limits | " + ", ".join(
        f"{label} {float(limits[k]) * f:.3g} {unit}" for k, (label, unit, f)
        in _LIMIT_TEXT.items() if k in limits) + " |")
    rows.append(f"| steps, h, ε | {run.n_steps}, {1000 * (h or 0):g} ms, "
                f"{100 * (eps or 0):g} cm |")
    legend = ("**World:** path blue = approach, orange = align (turn in place), red = goal "
              "(arrow along θ_d, ring = stop radius ε); D cyan (Fig. 4), R amber (Fig. 6)")
    if sensing:
        legend += "; magenta = estimated path, grey dots = GPS fixes"
    return "\n".join([*rows, "", legend, "", f"`{run.path}`"])


def _flat(prefix: str, value: object) -> dict[str, object]:
    if isinstance(value, dict):
        out: dict[str, object] = {}
        for k, v in value.items():
            out.update(_flat(f"{prefix}.{k}", v))
        return out
    return {prefix: value}


def varied_inputs(runs: Sequence[RunData]) -> list[str]:
    """The ``run`` record's inputs (``params.m``, ``gains.K_ps``, ...) whose values differ
    between the runs, start and goal left out (every row shows them)."""
    keys = ("params", "gains", "limits", "controller", "controller_gains", "stop_radius_m",
            "control_period_s", "sensors", "fmu_file")
    flats = []
    for r in runs:
        meta = r.metadata.get("run", {})
        flat: dict[str, object] = {}
        for k in keys:
            parsed = _json(meta, k) if k in meta else None
            flat.update(_flat(k, parsed if parsed is not None else meta.get(k)))
        flats.append(flat)
    names = sorted(set().union(*flats)) if flats else []
    return [k for k in names if len({json.dumps(f.get(k), sort_keys=True) for f in flats}) > 1]


def _cell(value: object) -> str:
    f = _float(value)
    if f is not None and not isinstance(value, bool):
        return f"{f:.3g}"
    return "?" if value is None else str(value)


def _status(run: RunData) -> str:
    """A run's status: its ``result`` record's; else a real robot's log is "poses only" and
    a log of ours without one is "cut"."""
    default = "poses only" if run.pose_topic is not None else "cut"
    return run.metadata.get("result", {}).get("status", default)


def _summary_many(labels: Sequence[str], names: Sequence[str], runs: Sequence[RunData]) -> str:
    """The summary of a multi-run replay: one row per run, with the inputs that vary."""
    varied = varied_inputs(runs)
    flats = [dict(_flat_meta(r)) for r in runs]
    statuses = [_status(r) for r in runs]
    counts = ", ".join(f"{statuses.count(s)} {s}" for s in dict.fromkeys(statuses))
    short = [k.split(".", 1)[1] if k.startswith(("params.", "gains.", "limits.")) else k
             for k in varied]
    head = ["run", "log", "status", "t [s]", "start (x, y, θ)", "goal (x, y, θ)",
            "final error", *short]
    lines = [f"### {len(runs)} runs: {counts}", "",
             "Each run's number labels its start in the world view; its lines share its "
             "colour.", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]
    for label, name, run, flat in zip(labels, names, runs, flats, strict=True):
        meta, result = run.metadata.get("run", {}), run.metadata.get("result", {})
        t_goal = _float(result.get("time_to_goal_s"))
        t = f"{t_goal:.2f}" if t_goal is not None else f"{run.t_s[-1]:.1f}+"
        cells = [label, f"`{name}`", _status(run), t,
                 _pose_text(_json(meta, "start")), _pose_text(_json(meta, "goal")),
                 _final_errors(result), *(_cell(flat.get(k)) for k in varied)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _flat_meta(run: RunData) -> dict[str, object]:
    meta = run.metadata.get("run", {})
    out: dict[str, object] = {}
    for k, v in meta.items():
        parsed = _json(meta, k)
        out.update(_flat(k, parsed if parsed is not None else v))
    return out


# --------------------------------------------------------------------------- sensing


def log_sensing(rec: rr.RecordingStream, name: str, path: str | os.PathLike[str],
                run: RunData) -> bool:
    """Draw a log's fixes and estimated path over the true one, and plot the position error
    of the estimate (per step) and of each fix (at its measurement time) against the truth.

    Returns
    -------
    bool
        Whether the log had sensing topics.
    """
    from wmr.adapters.mcap.sensing import read_sensing

    trace = read_sensing(path)
    if trace is None:
        return False
    root = run_entity(name)
    world = f"{root}/world"
    t_true = run.t_ns.astype(np.float64)
    x_true, y_true = run.signals["x_m"], run.signals["y_m"]

    def error(t_ns: NDArray[np.int64], xy: NDArray[np.float64]) -> NDArray[np.float64]:
        tx = np.interp(t_ns.astype(np.float64), t_true, x_true)
        ty = np.interp(t_ns.astype(np.float64), t_true, y_true)
        return np.asarray(np.hypot(xy[:, 0] - tx, xy[:, 1] - ty))

    def send_error(name: str, style: Any, t_ns: NDArray[np.int64],
                   xy: NDArray[np.float64]) -> None:
        """The distance of ``xy`` from the true path over the run's time, as series ``name``."""
        inside = t_ns <= run.t_ns[-1]
        entity = f"{root}/{ESTIMATION_ENTITY}/{name}"
        rec.log(entity, style, static=True)
        rec.send_columns(entity, indexes=[_time_column(t_ns[inside])],
                         columns=rr.Scalars.columns(scalars=error(t_ns[inside], xy[inside])))

    if len(trace.gps_xy_m):
        # light dots of 1 UI point (not metres: a fix's noise is a few cm, the view tens of
        # m), drawn under the true path and the estimate
        rec.log(f"{world}/gps", rr.Points2D(trace.gps_xy_m, colors=[GPS_DOT_COLOR],
                                            radii=[-1.0], draw_order=5.0), static=True)
        send_error("gps", rr.SeriesPoints(names=["GPS fix"], colors=[GPS_COLOR],
                                          marker_sizes=[1.5]),
                   trace.gps_t_ns, trace.gps_xy_m)
    if len(trace.est_pose):
        # half the true path's width and above it: both stay visible where they overlap
        rec.log(f"{world}/estimate",
                rr.LineStrips2D([trace.est_pose[:, :2]], colors=[ESTIMATE_COLOR],
                                radii=[-0.75], draw_order=12.0), static=True)
        send_error("estimate", rr.SeriesLines(names=["estimate"], colors=[ESTIMATE_COLOR],
                                              widths=[1.5]),
                   trace.est_t_ns, trace.est_pose[:, :2])
    return True


# --------------------------------------------------------------------------- replay


@dataclass
class ReplayResult:
    """What :func:`replay` did."""

    runs: list[str]
    steps: dict[str, int]
    rrd: Path | None
    spawned: bool
    warnings: list[str] = field(default_factory=list)
    #: One line per log left out (unreadable, damaged past reading, a link outside a folder).
    skipped: list[str] = field(default_factory=list)
    #: One line per real robot's log aligned to a simulation's (:mod:`.overlay`): its time
    #: shift and the distance between the two paths.
    aligned: list[str] = field(default_factory=list)
    #: The notebook's inline viewer that got it (``notebook=True``; a
    #: ``rerun.notebook.Viewer``: show it again in a later cell, or drive it with its
    #: ``update_panels`` and ``set_time_ctrl``), else None.
    viewer: Any = None


def read_logs(logs: Sequence[RunLog], skipped: list[str] | None = None, *,
              pose_topic: str | None = None
              ) -> tuple[list[tuple[RunLog, RunData]], list[str]]:
    """Read every log; warn about truncated ones; raise on unreadable ones, or, given
    ``skipped``, put one line there for each and read the others.  ``pose_topic``: the
    topic of the poses of a log that is not ours (:func:`wmr.adapters.mcap.read_run`).

    Raises
    ------
    LogError
        A file is not an MCAP log, or holds no complete control step (the first such file
        when ``skipped`` is None, else when no log is left).
    """
    runs: list[tuple[RunLog, RunData]] = []
    warnings: list[str] = []
    first: LogError | None = None
    for log in logs:
        try:
            data = read_run(log.path, pose_topic=pose_topic)
            if data.n_steps == 0:
                why = f" ({data.warnings[0]})" if data.warnings else ""
                raise LogError(f"{log.path}: no readable control step in this log{why}")
        except LogError as exc:
            if skipped is None:
                raise
            skipped.append(f"skipped: {exc}")
            first = first or exc
            continue
        if data.truncated:
            warnings.append(f"{log.path}: truncated log, replaying its first {data.n_steps} "
                            f"steps (to t = {data.t_s[-1]:.2f} s)")
        # what the reader left out or could not check: never replayed silently
        warnings += [f"{log.path}: {line}" for line in data.warnings]
        runs.append((log, data))
    if not runs and first is not None:  # nothing to replay: the first reason is the error
        raise first
    return runs, warnings


def _run_phase(run: RunData) -> NDArray[np.int8] | None:
    """The control phase of each step, from the logged ``dr_m`` and the run's stop radius."""
    eps = _float(run.metadata.get("run", {}).get("stop_radius_m"))
    dr = run.signals.get("dr_m")
    if eps is None or eps <= 0 or dr is None or not np.isfinite(dr).any():
        return None
    return control_phases(dr, eps)


def torque_range(runs: Sequence[RunData], limit_nm: float | None) -> float | None:
    """Half-span of the torque axis: 1.5 times the 98th percentile of |tau| over the runs
    (at least 0.5 N m, at most the limit): the start-up spike at the limit lasts a few hundred
    ms and would flatten everything else on a +-limit axis."""
    taus = [np.abs(np.concatenate([r.signals["tau_r_nm"], r.signals["tau_l_nm"]]))
            for r in runs]
    tau = np.concatenate(taus) if taus else np.zeros(0)
    tau = tau[np.isfinite(tau)]
    if tau.size == 0:
        return limit_nm
    span = max(0.5, 1.5 * float(np.percentile(tau, 98.0)))
    return min(span, 1.05 * limit_nm) if limit_nm else span


def _world_points(runs: Sequence[RunData]) -> NDArray[np.float64]:
    """Every point the world view must show: paths, and goals with their arrow tips."""
    pts = [np.column_stack([r.signals["x_m"], r.signals["y_m"]]) for r in runs]
    for r in runs:
        if r.goal is not None:
            gx, gy, gth = r.goal
            pts.append(np.array([[gx, gy], [gx + _ARROW_M * math.cos(gth),
                                            gy + _ARROW_M * math.sin(gth)]]))
    return np.concatenate(pts)


def framing(inputs: Sequence[str | os.PathLike[str]]
            ) -> tuple[tuple[float, float, float, float], bool]:
    """``(x_min, x_max, y_min, y_max)`` [m] of the world view of these logs (every path,
    start and goal, with a margin: the bounds ``wmr replay`` fixes, and the top view of the
    raw-log blueprint, :func:`wmr.adapters.rerun.blueprint.raw_blueprint`), and whether any
    of them is a run with sensors."""
    runs, _ = read_logs(find_logs(inputs))
    b = Bounds.around(_world_points([d for _, d in runs]))
    sensing = any("sensors" in d.metadata.get("run", {}) for _, d in runs)
    return (b.x_min, b.x_max, b.y_min, b.y_max), sensing


def replay(inputs: Sequence[str | os.PathLike[str]], *, rrd: str | os.PathLike[str] | None = None,
           spawn: bool | None = None, notebook: bool = False,
           optimal_paths: Mapping[Path, NDArray[np.float64]] | None = None,
           pose_topic: str | None = None) -> ReplayResult:
    """Replay run logs in one Rerun recording: a viewer, an ``.rrd`` file, or a notebook.

    Parameters
    ----------
    inputs
        ``.mcap`` files and folders of them.
    rrd
        Write the recording to this file (and do not spawn a viewer).
    spawn
        Open a viewer; default: when there is a screen and no ``rrd`` is given.  Without a
        viewer the recording goes to ``rrd`` or :func:`default_rrd_path`.
    notebook
        Show the recording in the notebook's output, in rerun-notebook's inline viewer (the
        same recording and blueprint; no viewer spawned, no ``.rrd`` written, so ``rrd`` and
        ``spawn`` must not be given).
    optimal_paths
        By log file: the optimal path (x, y, m; shape ``(n, 2)``) of that log's run, drawn
        beside it (:func:`log_optimal_path`).
    pose_topic
        The topic of the poses of a log that is not ours (a real robot's), when it cannot be
        found (:func:`wmr.adapters.mcap.read_run`).  A real robot's log replayed with one of
        ours is aligned to it at the start of motion, with the distance between the two
        paths plotted (:mod:`wmr.adapters.rerun.overlay`).

    Returns
    -------
    ReplayResult
        Run names, steps per run, the ``.rrd`` written (None when only a viewer got it),
        and warnings (truncated logs, a viewer that could not start).

    Raises
    ------
    LogError
        No log found, or a log that cannot be read.
    ConfigError
        ``notebook`` without rerun-notebook or outside a notebook (:func:`check_notebook`).
    """
    if rrd is not None and Path(rrd).suffix != ".rrd":
        raise WmrError(f"{rrd}: the recording file must end in .rrd")
    if notebook:
        check_notebook(rrd, spawn)
    skipped: list[str] = []
    runs, warnings = read_logs(find_logs(inputs, skipped), skipped, pose_topic=pose_topic)
    # a real robot's log beside a simulation: on the simulation's time axis
    datas_aligned, alignments, align_warnings = align_runs([log.name for log, _ in runs],
                                                           [d for _, d in runs])
    runs = [(log, d) for (log, _), d in zip(runs, datas_aligned, strict=True)]
    warnings += align_warnings
    aligned = {a.run: a for a in alignments}
    optimal_by_log = {Path(k).resolve(): v for k, v in (optimal_paths or {}).items()}
    names = [log.name for log, _ in runs]
    datas = [d for _, d in runs]
    many = len(runs) > 1
    sensing = [("sensors" in d.metadata.get("run", {})) for d in datas]
    limits = [_float((_json(d.metadata.get("run", {}), "limits") or {}).get("torque_max_nm"))
              for d in datas]
    torque_limit = max((v for v in limits if v is not None), default=None)
    bounds = Bounds.around(_world_points(datas))
    extra = ([deviation_view([run_entity(names[a.run]) for a in alignments],
                             names[alignments[0].reference])] if alignments else [])
    blueprint = replay_blueprint(names, bounds=bounds, sensing=any(sensing),
                                 torque_range_nm=torque_range(datas, torque_limit),
                                 extra_plots=extra)
    rec = rr.RecordingStream(APPLICATION_ID)
    rec.send_recording_name(names[0] if len(names) == 1 else f"{len(names)} runs")

    out: Path | None = Path(rrd) if rrd is not None else None
    spawned = False
    if spawn is None:
        spawn = out is None and not notebook and has_screen()
    inline: Any = None
    if notebook:
        from rerun.notebook import Viewer

        # the widget becomes the recording's sink: everything logged below is queued for it
        # until the notebook's front end has loaded the viewer
        inline = Viewer(recording=rec, blueprint=blueprint)
        inline.display()
    elif spawn:
        try:
            spawn_viewer(rec, blueprint)
            spawned = True
        except Exception as exc:  # no viewer binary, or it would not start: save instead
            warnings.append(f"could not start the Rerun viewer ({exc}): writing an .rrd instead")
    if not spawned and not notebook and out is None:
        out = default_rrd_path(inputs)
    with ExitStack() as stack:
        if out is not None:
            out.parent.mkdir(parents=True, exist_ok=True)
            # Rerun writes a pipe, we write out (beside it, renamed over it once whole): a full
            # disk is our error, not a hang in Rerun's file writer, and keeps the previous file
            pipe = stack.enter_context(replacing_path(out))
            rec.save(pipe, default_blueprint=blueprint)
            stack.callback(rec.disconnect)  # closes the pipe, also when logging raised

        log_grid(rec, bounds)
        labels = [f"#{k}" for k in range(len(runs))]
        label_every = len(runs) // _MAX_LABELS + 1
        goals_labelled: set[tuple[float, float]] = set()
        for k, (log, data) in enumerate(runs):
            color = run_color(k, len(runs))
            half_track, radius = robot_geometry(data.metadata.get("run", {}))
            path_xy = np.column_stack([data.signals["x_m"], data.signals["y_m"]])
            phase = _run_phase(data)
            finite = np.isfinite(path_xy).all(axis=1)
            # one label per goal position (runs to one goal with several headings: one label;
            # the summary has each run's heading)
            goal_label: str | None = None
            if data.goal is not None:
                key = (round(data.goal.x_m, 2), round(data.goal.y_m, 2))
                if key not in goals_labelled:
                    goals_labelled.add(key)
                    goal_label = f"goal ({key[0]:g}, {key[1]:g})" if many else ""
            log_run_static(rec, log.name, goal=data.goal, path_xy=path_xy[finite], color=color,
                           run_color=color if many else None, half_track_m=half_track,
                           wheel_radius_m=radius,
                           phase=phase[finite] if phase is not None else None,
                           start_label=(labels[k] if k % label_every == 0 else "")
                           if many else None,
                           stop_radius_m=_float(data.metadata.get("run", {}).get("stop_radius_m")),
                           goal_label=goal_label)
            optimum = optimal_by_log.get(log.path.resolve())
            if optimum is not None:
                log_optimal_path(rec, log.name, optimum, color)
            send_run_columns(rec, log.name, data.t_ns, data.block(), phase, construction=not many)
            if k in aligned:
                log_deviation(rec, run_entity(log.name), TIMELINE,
                              f"{labels[k]} {log.name} - {names[aligned[k].reference]}", color,
                              aligned[k])
            if sensing[k]:
                log_sensing(rec, log.name, log.path, data)
        summary = (_summary_many(labels, names, datas) if many
                   else _summary_single(names[0], datas[0], sensing[0]))
        notes = alignment_lines(names, alignments)
        if notes:
            summary += "\n\n" + "\n\n".join(notes)
        rec.log(SUMMARY_ENTITY, rr.TextDocument(summary, media_type=rr.MediaType.MARKDOWN),
                static=True)
        rec.flush()
    return ReplayResult(runs=names, steps={log.name: d.n_steps for log, d in runs}, rrd=out,
                        spawned=spawned, warnings=warnings, skipped=skipped, viewer=inline,
                        aligned=notes)


def iter_signal_names() -> Iterable[str]:
    """Every signal the replay plots, panel by panel (for tests and docs)."""
    for panel in PANELS:
        for s in panel.series:
            yield s.signal


__all__ = [
    "APPLICATION_ID",
    "NOTEBOOK_EXTRA",
    "OPTIMAL_ENTITY",
    "PANELS",
    "TIMELINE",
    "Bounds",
    "Panel",
    "ReplayResult",
    "RunLog",
    "Series",
    "check_notebook",
    "default_rrd_path",
    "find_logs",
    "framing",
    "grid_spacing",
    "has_screen",
    "log_optimal_path",
    "log_run_static",
    "log_sensing",
    "phase_strips",
    "read_logs",
    "replay",
    "replay_blueprint",
    "run_color",
    "run_entity",
    "send_run_columns",
    "spawn_viewer",
    "varied_inputs",
]
