"""Replay run logs in Rerun as a dashboard, and watch a run live while it is simulated.

``wmr replay`` reads one or more MCAP run logs (:func:`wmr.adapters.mcap.read_run`) and sends them
to Rerun as whole columns (``send_columns``): one recording, one ``sim_time`` timeline (simulation
seconds from the log's ``t_ns``), and a default blueprint with

* a 2-D world view with a metre grid and fixed bounds (every start, goal and path in frame, and
  D and R for one run): the path of each run (coloured by the control phase for one run, by run
  for several), the robot (body and a dark heading arrow, moved by a transform per control step),
  the goal (arrow along theta_d, ring of the stop radius), the point D on the heading line
  (Fig. 4) and the ROC reference point R (Fig. 6) with their construction lines from B; for runs
  with sensors the GPS fixes and the estimated path on top of the true one;
* one time-series panel per quantity (:data:`PANELS`: one unit per axis, angles in degrees, a
  fixed y range Rerun labels: :func:`y_range`), the control phase, and for runs with sensors
  the estimation error, three to a row;
* a run summary: status, times, final errors, start, goal, robot, gains and limits (angles in
  degrees), and, for several runs, one row per run with the inputs that vary, its start and goal.

An open-loop log (an optimal manoeuvre's) gets the stabiliser's errors along its path
(:func:`complete_open_loop`), so that it is compared with a closed-loop run in the same panels.

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
    .../D_label, .../R_label      Points2D per step: their labels, above D and below R
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
from dataclasses import dataclass, field, replace
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
#: The robot's heading arrow, per control phase (approach, align): dark, to stand out on the
#: path under it (blue, orange, or the run's colour) and on the light world background.
HEADING_COLORS: Final[tuple[Rgb, Rgb]] = ((25, 25, 25), (70, 0, 55))
#: Least relative luminance (WCAG 2) of a plotted line: the plots' background in Rerun's dark
#: theme is near black, and 0.1 is a contrast ratio of 3 against black (navy, (8, 48, 107),
#: is 0.03).
MIN_SERIES_LUMINANCE: Final = 0.1
#: Label text takes its point's colour, on a grey box: a run's colour darkened by this
#: factor reads on it (the colour itself did not, for a mid green or purple).
LABEL_SHADE: Final = 0.4
#: Width of the rulers (the grid's values) outside the runs, as a fraction of the world
#: view's larger side: no path, start or label of a run under a grid value.
RULER_FRAC: Final = 0.07
#: Most intervals between labelled values of a plot's y axis.  Rerun's plots (egui_plot's
#: grid) label multiples of powers of ten only (1 and 10 apart, never 2 or 5) and fade a
#: label out below 30 points between values (none below 20): a y range of 0.95 shows only
#: "0", of 9 in 150 points none but "0".  A panel is ~250 points high in a 1600 x 1000
#: window (three rows); 7 intervals, and at most 1.5 more of room at the ends, keep 29
#: points or more between labels (:func:`y_range`).
Y_INTERVALS: Final = 7
_DEG: Final = 180.0 / math.pi


def relative_luminance(rgb: Sequence[int]) -> float:
    """WCAG 2 relative luminance of an sRGB colour (0 black, 1 white)."""
    c = np.asarray(rgb[:3], np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return float(lin @ np.array([0.2126, 0.7152, 0.0722]))


def _shade(rgb: Rgb, factor: float) -> Rgb:
    r, g, b = (round(c * factor) for c in rgb)
    return r, g, b


def y_range(lo: float, hi: float, intervals: int = Y_INTERVALS) -> tuple[float, float]:
    """A plot's y range around ``[lo, hi]`` that Rerun labels with at least two values.

    Its ends are multiples of the smallest power of ten ``s`` that spans ``[lo, hi]`` in at
    most ``intervals`` steps (Rerun labels multiples of powers of ten only:
    :data:`Y_INTERVALS`), widened by 3 % so that a line at an end is not on the frame (a
    value less than 10 % of the span past a multiple is in that room, not a step further).
    A constant or empty series gets ``value ± 1`` (or ``± |value|/10``).
    """
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return -1.0, 1.0
    if hi - lo <= 1e-12 * max(1.0, abs(lo), abs(hi)):
        pad = max(1.0, 0.1 * abs(lo)) if abs(lo) < 10 else 0.1 * abs(lo)
        lo, hi = lo - pad, hi + pad
    step = 10.0 ** math.floor(math.log10((hi - lo) / intervals))
    while True:
        # a value past a multiple by under 10 % of the span goes in the room, not a step
        # more (v peaks at 1.0004 m/s: [0, 1.03], not [0, 2])
        tol = 0.1 * (hi - lo) / step
        a, b = math.floor(lo / step + tol), math.ceil(hi / step - tol)
        room = 0.03 * (hi - lo)
        lo_out, hi_out = min(a * step, lo) - room, max(b * step, hi) + room
        # the room and the values past the ends add at most 1.5 steps to the span
        if b - a <= intervals and b > a and hi_out - lo_out <= (intervals + 1.5) * step:
            return lo_out, hi_out
        step *= 10.0


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
    under ``overlay_title``; ``command``: they are the controller's output (an open-loop run
    has none), this their short name for a title that says so; ``limit`` names the run's
    ``limits`` entry that bounds a symmetric axis range (so a saturated start-up does not
    flatten the rest).
    """

    entity: str
    title: str
    series: tuple[Series, ...]
    overlay: int = 1
    overlay_title: str = ""
    limit: str | None = None
    command: str = ""


_BLUE, _ORANGE, _GREEN = (31, 119, 180), (255, 127, 14), (44, 160, 44)
_RED, _PURPLE, _GREY = (214, 39, 40), (148, 103, 189), (150, 150, 150)
_LIGHT_ORANGE, _LIGHT_PURPLE = (255, 187, 120), (197, 176, 213)
_LIGHT_BLUE, _LIGHT_RED = (158, 202, 225), (252, 146, 114)

#: The time-series panels, in reading order (three columns); one unit per axis.  Titles stay
#: under ~30 characters: a plot is ~320 points wide, and a longer title is cut.  Every line
#: is drawn on the viewer's dark plot background: each colour's relative luminance is at least
#: :data:`MIN_SERIES_LUMINANCE` (a command is light orange wherever it is drawn).
PANELS: Final[tuple[Panel, ...]] = (
    Panel("distance", "Distance Δr, e_s [m]", (
        Series("dr_m", "Δr", _GREY),
        Series("e_s_m", "e_s", _BLUE),
    ), overlay_title="Distance to goal Δr [m]"),
    Panel("heading", "Heading error e_θ [°]", (
        Series("e_theta_rad", "e_θ", _RED, _DEG),
    ), overlay_title="Heading error e_θ [°]"),
    Panel("speed", "Speed v, u_s [m/s]", (
        Series("v_mps", "v", _BLUE),
        Series("u_s_mps", "u_s", _LIGHT_ORANGE),
    ), overlay_title="Speed v [m/s]"),
    Panel("turn_rate", "Turn rate ω, u_θ [rad/s]", (
        Series("omega_radps", "ω", _GREEN),
        Series("u_theta_radps", "u_θ", _LIGHT_ORANGE),
    ), overlay_title="Turn rate ω [rad/s]"),
    Panel("wheels", "Wheels ω_r, ω_l [rad/s]", (
        Series("omega_r_radps", "ω_r", _ORANGE),
        Series("omega_l_radps", "ω_l", _PURPLE),
        Series("omega_r_ref_radps", "ω_r ref", _LIGHT_ORANGE),
        Series("omega_l_ref_radps", "ω_l ref", _LIGHT_PURPLE),
    ), overlay_title="Wheel ω_r [rad/s]"),
    Panel("torques", "Torques τ_r, τ_l [N m]", (
        Series("tau_r_nm", "τ_r", _ORANGE),
        Series("tau_l_nm", "τ_l", _PURPLE),
    ), overlay_title="Torque τ_r [N m]", limit="torque_max_nm"),
    # the PI's output first: several runs overlay it (the first series), not the P term
    Panel("pi_distance", "Distance PI u_s [m/s]", (
        Series("u_s_mps", "u_s", _LIGHT_ORANGE),
        Series("p_s_mps", "P_s", _BLUE),
        Series("i_s_mps", "I_s", _LIGHT_BLUE),
    ), overlay_title="Distance PI u_s [m/s]", command="u_s [m/s]"),
    Panel("pi_heading", "Heading PI u_θ [rad/s]", (
        Series("u_theta_radps", "u_θ", _LIGHT_ORANGE),
        Series("p_theta_radps", "P_θ", _RED),
        Series("i_theta_radps", "I_θ", _LIGHT_RED),
    ), overlay_title="Heading PI u_θ [rad/s]", command="u_θ [rad/s]"),
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
    (distinct for any number of runs, alternating two lightnesses, each raised until the
    colour reads on the plots' dark background: :data:`MIN_SERIES_LUMINANCE`)."""
    if n_runs <= len(RUN_COLORS):
        return RUN_COLORS[k % len(RUN_COLORS)]
    hue = (0.6 + 0.381966 * k) % 1.0
    lightness = 0.42 if k % 2 else 0.55
    while True:  # a blue or a purple at 0.42 is too dark for the plots' black background
        r, g, b = colorsys.hls_to_rgb(hue, lightness, 0.75)
        rgb = round(255 * r), round(255 * g), round(255 * b)
        if relative_luminance(rgb) >= MIN_SERIES_LUMINANCE + 0.02 or lightness > 0.8:
            return rgb
        lightness += 0.02


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
        """The finite ``points`` (shape ``(n, 2)``) with a margin on every side, and a band
        for the rulers (:data:`RULER_FRAC`) on the left and at the bottom."""
        p = points[np.isfinite(points).all(axis=1)]
        if p.size == 0:
            p = np.zeros((1, 2))
        lo, hi = p.min(axis=0), p.max(axis=0)
        size = np.maximum(hi - lo, min_size_m)
        mid = 0.5 * (lo + hi)
        half = 0.5 * size * (1.0 + 2.0 * margin_frac) + 0.5  # + room for labels and arrows
        # the rulers (the grid's values) left and below, outside what is drawn
        ruler = RULER_FRAC * 2.0 * float(half.max())
        return cls(float(mid[0] - half[0] - ruler), float(mid[0] + half[0]),
                   float(mid[1] - half[1] - ruler), float(mid[1] + half[1]))

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
    # the line values along the bottom and the left edge (a ruler: the view has no axes), in
    # the band Bounds.around leaves for them, centred in it; none where a label, centred on
    # its line, would be cut by an edge or meet the other ruler in the corner
    span = max(bounds.x_max - bounds.x_min, bounds.y_max - bounds.y_min)
    inset = 0.5 * RULER_FRAC / (1.0 + RULER_FRAC) * span
    keep_x = [x for x in xs if bounds.x_min + 3.0 * inset < x < bounds.x_max - 1.5 * inset]
    keep_y = [y for y in ys if bounds.y_min + 2.0 * inset < y < bounds.y_max - inset]
    marks = ([[x, bounds.y_min + inset] for x in keep_x]
             + [[bounds.x_min + inset, y] for y in keep_y])
    texts = [f"{v:g} m" for v in (*keep_x, *keep_y)]
    rec.log(f"{GRID_ENTITY}/labels",
            rr.Points2D(marks, radii=[0.0], colors=[GRID_LABEL_COLOR], labels=texts,
                        show_labels=True,
                        draw_order=-9.0), static=True)


# --------------------------------------------------------------------------- blueprint


def replay_blueprint(run_names: Sequence[str], *, live: bool = False,
                     bounds: Bounds | None = None, sensing: bool = False,
                     torque_range_nm: float | None = None,
                     y_ranges: Mapping[str, tuple[float, float]] | None = None,
                     open_loop: Sequence[str] = (),
                     phase_window_s: tuple[float, float] | None = None,
                     extra_plots: Sequence[rrb.TimeSeriesView] = ()) -> rrb.Blueprint:
    """The dashboard: world view and run summary on the left, the time-series panels on the
    right in a three-column grid (the phase in its last cell; with sensors, the estimation
    error there and the phase in a tab behind it); side panels collapsed.

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
        start-up runs off the top instead of flattening the rest), widened to labelled values
        (:func:`y_range`); ``y_ranges`` wins.
    y_ranges
        Per panel entity (:data:`PANELS`, ``estimation``): the plot's fixed y range
        (:func:`panel_ranges`); a panel not given scales itself (the live view).
    open_loop
        The runs without a controller (open-loop logs, an optimal manoeuvre's): the titles
        of the panels of the controller's commands and of the phase say they have none.
    phase_window_s
        The phase plot shows this window of ``sim_time``, s (one run: its last seconds,
        where the alignment is; over the whole run it is a line at 0 and a sliver at the
        end); None: the whole run.
    extra_plots
        More panels after the others (the deviation of a real robot's path,
        :func:`wmr.adapters.rerun.overlay.deviation_view`).
    """
    roots = [f"/{run_entity(n)}" for n in run_names]
    many = len(run_names) > 1
    ranges = dict(y_ranges or {})
    if torque_range_nm:
        for p in PANELS:
            if p.limit:
                ranges.setdefault(p.entity, y_range(-torque_range_nm, torque_range_nm))
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
    # short: a longer title is cut, and this is the note that must show
    absent = f": {', '.join(open_loop) if many else ''} open loop".replace(":  ", ": ")

    def plot(entity: str, title: str, axis: rrb.ScalarAxis | None = None) -> rrb.TimeSeriesView:
        if axis is None and entity in ranges:
            axis = rrb.ScalarAxis(range=ranges[entity])
        return rrb.TimeSeriesView(name=title, origin="/",
                                  contents=[f"{r}/{entity}/**" for r in roots],
                                  plot_legend=legend, time_ranges=time_range, axis_y=axis)

    cells: list[Any] = [plot(p.entity, p.command + absent if p.command and open_loop
                             else p.overlay_title if many else p.title) for p in PANELS]
    phase = rrb.TimeSeriesView(
        name=(("Phase" + absent if open_loop else "Phase, 0 approach 1 align")
              if phase_window_s is None
              else f"Phase, last {phase_window_s[1] - phase_window_s[0]:g} s: 1 align"),
        origin="/", contents=[f"{r}/{PHASE_ENTITY}/**" for r in roots], plot_legend=legend,
        axis_y=rrb.ScalarAxis(range=(-0.1, 1.1)),
        time_ranges=time_range if phase_window_s is None else rrb.VisibleTimeRange(
            TIMELINE, start=rrb.TimeRangeBoundary.absolute(seconds=phase_window_s[0]),
            end=rrb.TimeRangeBoundary.absolute(seconds=phase_window_s[1])))
    cells += list(extra_plots)
    if sensing:
        estimation = plot(ESTIMATION_ENTITY, "Position error: estimate, GPS fixes [m]")
        cells.append(rrb.Tabs(estimation, phase, active_tab=0))
    else:
        cells.append(phase)
    summary = rrb.TextDocumentView(name="Run summary" if not many else
                                   f"{len(run_names)} runs", origin=f"/{SUMMARY_ENTITY}")
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(world, summary, row_shares=[3, 2]),
            # three rows of three: each plot tall enough for its y axis' values at a
            # 1600 x 1000 window (Y_INTERVALS), and no empty cell
            rrb.Grid(*cells, grid_columns=3),
            column_shares=[9, 11],
        ),
        # live: the time cursor follows the newest rows (a live .rrd opens at its end); the
        # collapsed time panel keeps its play bar
        rrb.TimePanel(timeline=TIMELINE, state="collapsed",
                      play_state="following" if live else None),
        collapse_panels=True,
    )


def panel_ranges(runs: Sequence[RunData], *, many: bool, torque_range_nm: float | None,
                 estimation: Sequence[NDArray[np.float64]] = ()
                 ) -> dict[str, tuple[float, float]]:
    """The fixed y range of each plot (:func:`y_range`) over what it draws of ``runs``: every
    series of a panel for one run, the overlaid ones for several; the torques within
    ``± torque_range_nm``; ``estimation``: the estimation panel's values."""
    out: dict[str, tuple[float, float]] = {}
    for p in PANELS:
        shown = p.series[:p.overlay] if many else p.series
        parts = [r.signals[s.signal] * s.scale for r in runs for s in shown]
        values = np.concatenate(parts) if parts else np.zeros(0)
        values = values[np.isfinite(values)]
        if p.limit and torque_range_nm:
            values = np.clip(values, -torque_range_nm, torque_range_nm)
            values = np.concatenate([values, [-torque_range_nm, torque_range_nm]])
        if values.size:
            out[p.entity] = y_range(float(values.min()), float(values.max()))
    est = np.concatenate([np.ravel(e) for e in estimation]) if estimation else np.zeros(0)
    est = est[np.isfinite(est)]
    if est.size:
        out[ESTIMATION_ENTITY] = y_range(0.0, float(est.max()))
    return out


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


def start_label_point(path_xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Where a run's start label goes: 0.6 m behind the start, against the direction of the
    first 50 rows of the path."""
    ahead = path_xy[min(len(path_xy) - 1, 50)] - path_xy[0]
    return np.asarray(path_xy[0] - 0.6 * ahead / max(1e-9, float(np.linalg.norm(ahead))))


def heading_arrow_m(bounds: Bounds) -> float:
    """Length of the robot's heading arrow in a world view of ``bounds``: 7 % of its larger
    side, at least the goal's 1 m (longer than the body, which is under 1 m)."""
    return max(_ARROW_M, 0.07 * max(bounds.x_max - bounds.x_min, bounds.y_max - bounds.y_min))


def label_groups(points: Sequence[NDArray[np.float64] | None], min_gap_m: float
                 ) -> list[list[int]]:
    """The start labels, grouped: each label joins the first group whose first point is
    closer than ``min_gap_m`` (runs from one start share a label, ``#0 #1``); None: no
    label."""
    groups: list[list[int]] = []
    for k, pt in enumerate(points):
        if pt is None:
            continue
        for g in groups:
            first = points[g[0]]
            if first is not None and float(np.hypot(*(pt - first))) < min_gap_m:
                g.append(k)
                break
        else:
            groups.append([k])
    return groups


@dataclass(frozen=True)
class RunView:
    """How :func:`log_run_static` draws a run: its colours, labels and geometry.

    Attributes
    ----------
    run_color
        When several runs share the plots: the run's colour for its path and lines (None: the
        path coloured by phase, the lines per signal).
    half_track_m, wheel_radius_m
        Robot geometry for the body drawing.
    info
        Kept for callers of the single-run API: Markdown of the run panel (the summary).
    phase
        The control phase per row of the path (colours the path of a single run).
    start_label
        Label at the start of the path (the run's number in a multi-run replay).
    stop_radius_m
        Radius of the ring drawn around the goal.
    goal_label
        The goal's label: ``""`` its pose ``goal (x, y, θ_d°)``, None none (a goal another
        run already labelled), else this text.
    arrow_m
        Length of the robot's heading arrow, m (:func:`heading_arrow_m` of the view).
    start_label_color
        Colour of the start label's text; None: the run's colour darkened.
    run_label
        The run's name in its plot lines (``#3``); None: ``start_label``, else the run's name.
    """

    run_color: Rgb | None = None
    half_track_m: float = 0.3
    wheel_radius_m: float = 0.15
    info: str | None = None
    phase: NDArray[np.int8] | None = None
    start_label: str | None = None
    stop_radius_m: float | None = None
    goal_label: str | None = ""
    arrow_m: float = _ARROW_M
    start_label_color: Rgb | None = None
    run_label: str | None = None


def log_run_static(rec: rr.RecordingStream, name: str, *, goal: Pose2D | None,
                   path_xy: NDArray[np.float64] | None, color: Rgb,
                   view: RunView | None = None) -> None:
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
        Colour of the robot (and of the path when the view's ``run_color`` is given).
    view
        How to draw it (:class:`RunView`); None: its defaults.
    """
    v = RunView() if view is None else view
    run_color, phase, start_label = v.run_color, v.phase, v.start_label
    half_track_m, wheel_radius_m, arrow_m = v.half_track_m, v.wheel_radius_m, v.arrow_m
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
            # the number behind the start (the robot stands on the start at t = 0), its text
            # dark enough to read on the label's grey box
            rec.log(f"{world}/start",
                    rr.Points2D([start_label_point(path_xy)],
                                colors=[v.start_label_color or _shade(color, LABEL_SHADE)],
                                radii=[-3.0], labels=[start_label],
                                # above the robots' bodies and arrows: never hidden by them
                                show_labels=bool(start_label), draw_order=45.0),
                    static=True)
    if goal is not None:
        gx, gy, gth = goal
        vec = [_ARROW_M * math.cos(gth), _ARROW_M * math.sin(gth)]
        ring = []
        if v.stop_radius_m and v.stop_radius_m > 0:
            a = np.linspace(0.0, 2 * math.pi, 48)
            ring = [np.column_stack([gx + v.stop_radius_m * np.cos(a),
                                     gy + v.stop_radius_m * np.sin(a)])]
        rec.log(f"{world}/goal",
                rr.Arrows2D(origins=[[gx, gy]], vectors=[vec], colors=[GOAL_COLOR],
                            radii=[0.04], draw_order=20.0),
                rr.LineStrips2D(ring, colors=[GOAL_COLOR], radii=[0.01], draw_order=20.0),
                static=True)
        # the label apart from the arrow, in a neutral colour (red on red did not read)
        rec.log(f"{world}/goal/label",
                rr.Points2D([[gx, gy - 0.45]], radii=[0.0], colors=[LABEL_COLOR],
                            labels=[v.goal_label or f"goal ({gx:g}, {gy:g}, "
                                                  f"{math.degrees(gth):.0f}°)"],
                            show_labels=v.goal_label is not None, draw_order=21.0), static=True)
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
            # the heading: dark (HEADING_COLORS, per step), wider than the path (UI points)
            # and ahead of the body, so that it reads on the path it lies along
            rr.Arrows2D.from_fields(origins=[[0.0, 0.0]], vectors=[[arrow_m, 0.0]],
                                    radii=[-2.0], draw_order=41.0),
            static=True)
    # D and R unlabelled: their labels are entities of their own, D's above and R's below
    # (send_run_columns), so that they do not cover each other where D and R meet
    rec.log(f"{world}/D", rr.Points2D.from_fields(colors=[D_COLOR], radii=[0.1],
                                                   draw_order=35.0), static=True)
    rec.log(f"{world}/R", rr.Points2D.from_fields(colors=[R_COLOR], radii=[0.1],
                                                   draw_order=35.0), static=True)
    for point, point_color in (("D", D_COLOR), ("R", R_COLOR)):
        rec.log(f"{world}/{point}_label",
                rr.Points2D.from_fields(colors=[_shade(point_color, 0.55)], radii=[0.0],
                                        labels=[point], show_labels=True, draw_order=36.0),
                static=True)
    rec.log(f"{world}/construction",
            rr.LineStrips2D.from_fields(colors=[D_COLOR, R_COLOR], radii=[0.012],
                                        draw_order=34.0), static=True)
    label = v.run_label or (start_label if start_label is not None else name)
    for panel in PANELS:
        rec.log(f"{root}/{panel.entity}", _series_style(panel, label, run_color), static=True)
    rec.log(f"{root}/{PHASE_ENTITY}",
            rr.SeriesLines(names=[f"{label}: phase" if run_color else "phase"],
                           colors=[run_color or _GREY], widths=[1.5],
                           aggregation_policy="minmax"), static=True)
    if v.info:
        rec.log(SUMMARY_ENTITY, rr.TextDocument(v.info, media_type=rr.MediaType.MARKDOWN),
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
                     construction: bool = True, label_offset_m: float = 0.5) -> None:
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
        phase panel and the colour of the robot's heading arrow (:data:`HEADING_COLORS`);
        None: not known (live view).
    construction
        Send the points D and R and their construction lines (off for several runs: one pair
        per run hides the paths).
    label_offset_m
        How far D's label is above D, and R's below R, m.
    """
    n = int(t_ns.shape[0])
    if n == 0:
        return
    root = run_entity(name)
    world = f"{root}/world"
    times = [_time_column(t_ns)]
    x, y, theta = block[:, _X], block[:, _Y], block[:, _TH]
    translation = np.column_stack([x, y, np.zeros(n)])
    colors = np.asarray(HEADING_COLORS, np.uint8)[phase if phase is not None
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
        # the labels apart: D's above D, R's below R (the view's y is mirrored: world y up)
        for label, xy, sign in (("D_label", d_xy, 1.0), ("R_label", r_xy, -1.0)):
            rec.send_columns(f"{world}/{label}", indexes=times, columns=rr.Points2D.columns(
                positions=xy + np.array([0.0, sign * label_offset_m])))
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


#: Units of the robot parameters (the ``run`` record's ``params``) in the summary.
_PARAM_UNITS: Final = {"m": "kg", "Ig": "kg m²", "Iwm": "kg m²", "l": "m", "L": "m",
                       "r": "m", "b_f": "N m s/rad", "tau_c": "N m", "w_c": "rad/s"}

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
    log = Path(run.path)
    # the log's path first, as text that wraps (a code span at the end was cut off)
    rows = [f"### {name}: {_status_text(result, run)}", "",
            f"log **{log.name}** in {log.parent}", "",
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
    params = _json(meta, "params") or {}
    if isinstance(params, dict) and params:
        # the robot: a failure looked at was the robot's (a heavy load, a weak motor); two
        # rows, as a longer one is cut at the panel's edge
        for title, keys in (("robot", ("m", "Ig", "l", "r", "L")),
                            ("motors", ("Iwm", "b_f", "tau_c", "w_c"))):
            shown = [k for k in keys if _float(params.get(k)) is not None]
            shown += [k for k in params if title == "motors" and k not in _PARAM_UNITS
                      and _float(params.get(k)) is not None]
            if shown:
                rows.append(f"| {title} | " + ", ".join(
                    f"{k} {_cell(params[k])}" + (f" {_PARAM_UNITS[k]}" if k in _PARAM_UNITS
                                                 else "") for k in shown) + " |")
    rows.append("| gains | " + ", ".join(f"{k} {v:g}" for k, v in gains.items()
                                         if isinstance(v, int | float)) + " |")
    rows.append("| limits | " + ", ".join(
        f"{label} {float(limits[k]) * f:.3g} {unit}" for k, (label, unit, f)
        in _LIMIT_TEXT.items() if k in limits) + " |")
    rows.append(f"| steps, h, ε | {run.n_steps}, {1000 * (h or 0):g} ms, "
                f"{100 * (eps or 0):g} cm |")
    legend = ("**World:** path blue = approach, orange = align (turn in place), robot's "
              "heading = black arrow (purple when aligning), red = goal (arrow along θ_d, "
              "ring = stop radius ε); D cyan (Fig. 4), R amber (Fig. 6)")
    if sensing:
        legend += "; magenta = estimated path, grey dots = GPS fixes"
    return "\n".join([*rows, "", legend])


def _flat(prefix: str, value: object) -> dict[str, object]:
    if isinstance(value, dict):
        out: dict[str, object] = {}
        for k, v in value.items():
            out.update(_flat(f"{prefix}.{k}", v))
        return out
    return {prefix: value}


def varied_inputs(runs: Sequence[RunData]) -> list[str]:
    """The ``run`` record's inputs (``params.m``, ``gains.K_ps``, ...) whose values differ
    between the runs that have one (a real robot's log of poses only has none: it varies
    nothing), start and goal left out (every row shows them)."""
    keys = ("params", "gains", "limits", "controller", "controller_gains", "stop_radius_m",
            "control_period_s", "sensors", "fmu_file")
    flats = []
    for r in runs:
        meta = r.metadata.get("run", {})
        if not meta:
            continue
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
    # the inputs that vary first (the point of a Monte Carlo: a narrow panel cut them off),
    # the log's name last
    head = ["run", *short, "status", "t [s]", "final error", "start (x, y, θ)",
            "goal (x, y, θ)", "log"]
    lines = [f"### {len(runs)} runs: {counts}", "",
             "Each run's number labels its start in the world view; its lines share its "
             "colour.", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]
    for label, name, run, flat in zip(labels, names, runs, flats, strict=True):
        meta, result = run.metadata.get("run", {}), run.metadata.get("result", {})
        t_goal = _float(result.get("time_to_goal_s"))
        t = f"{t_goal:.2f}" if t_goal is not None else f"{run.t_s[-1]:.1f}+"
        cells = [label, *(_cell(flat.get(k)) for k in varied), _status(run),
                 t, _final_errors(result), _pose_text(_json(meta, "start")),
                 _pose_text(_json(meta, "goal")), f"`{name}`"]
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


def sensing_errors(trace: Any, run: RunData
                   ) -> dict[str, tuple[NDArray[np.int64], NDArray[np.float64]]]:
    """Distance from the true path of each estimate (``estimate``) and each fix (``gps``) of a
    :class:`~wmr.adapters.mcap.sensing.SensingTrace`, at its time within the run: times (ns)
    and errors (m)."""
    t_true = run.t_ns.astype(np.float64)
    x_true, y_true = run.signals["x_m"], run.signals["y_m"]
    out: dict[str, tuple[NDArray[np.int64], NDArray[np.float64]]] = {}
    for key, t_ns, xy in (("gps", trace.gps_t_ns, trace.gps_xy_m),
                          ("estimate", trace.est_t_ns, trace.est_pose[:, :2])):
        if not len(t_ns):
            continue
        inside = t_ns <= run.t_ns[-1]
        t_in = t_ns[inside].astype(np.float64)
        tx, ty = np.interp(t_in, t_true, x_true), np.interp(t_in, t_true, y_true)
        out[key] = (t_ns[inside], np.asarray(np.hypot(xy[inside, 0] - tx, xy[inside, 1] - ty)))
    return out


def log_sensing(rec: rr.RecordingStream, name: str, path: str | os.PathLike[str],
                run: RunData, trace: Any = None) -> bool:
    """Draw a log's fixes and estimated path over the true one, and plot the position error
    of the estimate (per step) and of each fix (at its measurement time) against the truth.

    ``trace``: the log's :func:`~wmr.adapters.mcap.sensing.read_sensing` when already read.

    Returns
    -------
    bool
        Whether the log had sensing topics.
    """
    from wmr.adapters.mcap.sensing import read_sensing

    if trace is None:
        trace = read_sensing(path)
    if trace is None:
        return False
    root = run_entity(name)
    world = f"{root}/world"
    errors = sensing_errors(trace, run)

    def send_error(key: str, style: Any) -> None:
        entity = f"{root}/{ESTIMATION_ENTITY}/{key}"
        t_ns, err = errors[key]
        rec.log(entity, style, static=True)
        rec.send_columns(entity, indexes=[_time_column(t_ns)],
                         columns=rr.Scalars.columns(scalars=err))

    if len(trace.gps_xy_m):
        # light dots of 1 UI point (not metres: a fix's noise is a few cm, the view tens of
        # m), drawn under the true path and the estimate
        rec.log(f"{world}/gps", rr.Points2D(trace.gps_xy_m, colors=[GPS_DOT_COLOR],
                                            radii=[-1.0], draw_order=5.0), static=True)
        # the plot's dots light grey: the log's scene grey is too dark on the plots' black
        send_error("gps", rr.SeriesPoints(names=["GPS fix"], colors=[GPS_DOT_COLOR],
                                          marker_sizes=[1.5]))
    if len(trace.est_pose):
        # half the true path's width and above it: both stay visible where they overlap
        rec.log(f"{world}/estimate",
                rr.LineStrips2D([trace.est_pose[:, :2]], colors=[ESTIMATE_COLOR],
                                radii=[-0.75], draw_order=12.0), static=True)
        send_error("estimate", rr.SeriesLines(names=["estimate"], colors=[ESTIMATE_COLOR],
                                              widths=[1.5]))
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
    """Every point the world view must show: paths, goals with their arrow tips, and for one
    run the points D and R (drawn with their construction lines: the view holds them)."""
    pts = [np.column_stack([r.signals["x_m"], r.signals["y_m"]]) for r in runs]
    if len(runs) == 1:
        sig = runs[0].signals
        pts += [np.column_stack([sig["D_x_m"], sig["D_y_m"]]),
                np.column_stack([sig["R_x_m"], sig["R_y_m"]])]
    for r in runs:
        if r.goal is not None:
            gx, gy, gth = r.goal
            pts.append(np.array([[gx, gy], [gx + _ARROW_M * math.cos(gth),
                                            gy + _ARROW_M * math.sin(gth)]]))
    return np.concatenate(pts)


@dataclass(frozen=True)
class RawView:
    """What the blueprint of a raw log needs of its runs (:func:`raw_view`)."""

    #: ``(x_min, x_max, y_min, y_max)`` of the top view, m.
    frame: tuple[float, float, float, float]
    #: Whether a run has sensors (the covariance panel).
    sensing: bool
    #: Per raw panel title (:data:`wmr.adapters.rerun.blueprint.RAW_PANELS`): its y range.
    y_ranges: dict[str, tuple[float, float]]


def raw_view(inputs: Sequence[str | os.PathLike[str]]) -> RawView:
    """The top view's frame (as :func:`framing`), whether a run has sensors, and the y range
    of each panel of the raw-log blueprint over these logs' values (:func:`y_range`: values
    Rerun labels; the torques within :func:`torque_range`)."""
    from wmr.adapters.rerun.blueprint import PHASE_PANEL, RAW_PANELS

    runs, _ = read_logs(find_logs(inputs))
    datas = [d for _, d in runs]
    b = Bounds.around(_world_points(datas))
    sensing = any("sensors" in d.metadata.get("run", {}) for d in datas)
    limits = [_float((_json(d.metadata.get("run", {}), "limits") or {}).get("torque_max_nm"))
              for d in datas]
    tau = torque_range(datas, max((v for v in limits if v is not None), default=None))
    ranges: dict[str, tuple[float, float]] = {}
    for panel in RAW_PANELS:
        fields = [line.field for line in panel.lines if line.field in COLUMN]
        if panel.title == PHASE_PANEL or not fields:
            continue
        values = np.concatenate([d.signals[f] for d in datas for f in fields])
        values = values[np.isfinite(values)]
        if any(f.startswith("tau_") for f in fields) and tau:
            values = np.concatenate([np.clip(values, -tau, tau), [-tau, tau]])
        if values.size:
            ranges[panel.title] = y_range(float(values.min()), float(values.max()))
    return RawView((b.x_min, b.x_max, b.y_min, b.y_max), sensing, ranges)


def framing(inputs: Sequence[str | os.PathLike[str]]
            ) -> tuple[tuple[float, float, float, float], bool]:
    """``(x_min, x_max, y_min, y_max)`` [m] of the world view of these logs (every path,
    start and goal, with a margin: the bounds ``wmr replay`` fixes, and the top view of the
    raw-log blueprint, :func:`wmr.adapters.rerun.blueprint.raw_blueprint`), and whether any
    of them is a run with sensors."""
    view = raw_view(inputs)
    return view.frame, view.sensing


#: The phase plot of one run shows its last this many seconds (the alignment in place).
PHASE_WINDOW_S: Final = 4.0


def _phase_window(run: RunData) -> tuple[float, float] | None:
    """The last :data:`PHASE_WINDOW_S` of a run longer than twice that, s; else None."""
    t_end = float(run.t_s[-1]) if run.n_steps else 0.0
    return (t_end - PHASE_WINDOW_S, t_end) if t_end > 2 * PHASE_WINDOW_S else None


#: The signals of an open-loop log (no controller) that the replay computes from its poses
#: and goal, as the stabiliser would see them (:func:`complete_open_loop`).
OPEN_LOOP_DERIVED: Final = ("dr_m", "e_s_m", "e_theta_rad", "alpha_rad", "beta_rad",
                            "gamma_rad", "D_x_m", "D_y_m", "R_x_m", "R_y_m")


def is_open_loop(run: RunData) -> bool:
    """Whether ``run`` is an open-loop log (an optimal manoeuvre's: poses and torques, no
    controller topics): it has a goal and a path but no distance to the goal."""
    x, dr = run.signals.get("x_m"), run.signals.get("dr_m")
    return (run.goal is not None and x is not None and dr is not None and run.n_steps > 0
            and bool(np.isfinite(x).any()) and not bool(np.isfinite(dr).any()))


def complete_open_loop(run: RunData, stop_radius_m: float = 0.05) -> RunData:
    """An open-loop log with the stabiliser's errors along its path: the distance to the
    goal, e_s, e_theta (and alpha, beta, gamma, D, R) of
    :class:`~wmr.core.control.stabiliser.PointStabiliser` fed its poses row by row (they
    depend on the goal and the stop radius only, not on gains or limits), so that it is
    compared with a closed-loop run in the same panels; its commands (u_s, u_theta, the PI
    terms) stay NaN: it has no controller."""
    from wmr.core.control.stabiliser import Gains, Limits, PointStabiliser

    if run.goal is None:
        raise ValueError(f"{run.path}: an open-loop log without a goal has no errors")
    stab = PointStabiliser(run.goal.x_m, run.goal.y_m, run.goal.theta_rad, Gains(), Limits(),
                           0.15, 0.3, 0.01, stop_radius_m)
    rows = np.array([stab.update(float(x), float(y), float(th)) for x, y, th in zip(
        run.signals["x_m"], run.signals["y_m"], run.signals["theta_rad"], strict=True)])
    from wmr.core.signals import CONTROL_SIGNALS

    order = [s for s in CONTROL_SIGNALS if s not in ("tau_r_nm", "tau_l_nm")]
    signals = dict(run.signals)
    for name in OPEN_LOOP_DERIVED:
        signals[name] = np.ascontiguousarray(rows[:, order.index(name)])
    return replace(run, signals=signals)


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
    eps_all = [_float(d.metadata.get("run", {}).get("stop_radius_m")) for _, d in runs]
    eps_known = [e for e in eps_all if e]
    open_loop = [log.name for log, d in runs if is_open_loop(d)]
    # an open-loop run gets the stabiliser's errors along its path (the others' stop radius)
    runs = [(log, complete_open_loop(d, *eps_known[:1]) if log.name in open_loop else d)
            for log, d in runs]
    datas = [d for _, d in runs]
    many = len(runs) > 1
    sensing = [("sensors" in d.metadata.get("run", {})) for d in datas]
    from wmr.adapters.mcap.sensing import read_sensing

    traces = [read_sensing(log.path) if sensing[k] else None for k, (log, _) in enumerate(runs)]
    limits = [_float((_json(d.metadata.get("run", {}), "limits") or {}).get("torque_max_nm"))
              for d in datas]
    torque_limit = max((v for v in limits if v is not None), default=None)
    tau_range = torque_range(datas, torque_limit)
    bounds = Bounds.around(_world_points(datas))
    extra = ([deviation_view([run_entity(names[a.run]) for a in alignments],
                             names[alignments[0].reference])] if alignments else [])
    span_m = max(bounds.x_max - bounds.x_min, bounds.y_max - bounds.y_min)
    estimation = [e for tr, d in zip(traces, datas, strict=True) if tr is not None
                  for _, e in sensing_errors(tr, d).values()]
    blueprint = replay_blueprint(
        names, bounds=bounds, sensing=any(sensing), torque_range_nm=tau_range,
        y_ranges=panel_ranges(datas, many=many, torque_range_nm=tau_range,
                              estimation=estimation),
        open_loop=[f"#{names.index(n)}" if many else n for n in open_loop],
        phase_window_s=_phase_window(datas[0]) if not many and not open_loop else None,
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
        paths = [np.column_stack([d.signals["x_m"], d.signals["y_m"]]) for d in datas]
        paths = [xy[np.isfinite(xy).all(axis=1)] for xy in paths]
        # the start labels: runs whose labels would cover each other share one ("#0 #1")
        points = [start_label_point(xy) if many and len(xy) and k % label_every == 0 else None
                  for k, xy in enumerate(paths)]
        start_text = ["" for _ in runs]
        start_color: list[Rgb | None] = [None for _ in runs]
        for group in label_groups(points, 0.05 * span_m):
            start_text[group[0]] = " ".join(labels[k] for k in group)
            if len(group) > 1:
                start_color[group[0]] = LABEL_COLOR
        # one label per goal position, with the goal headings of the runs to it
        headings: dict[tuple[float, float], list[str]] = {}
        for d in datas:
            if d.goal is not None:
                key = (round(d.goal.x_m, 2), round(d.goal.y_m, 2))
                deg = f"{math.degrees(d.goal.theta_rad):.0f}°"
                if deg not in headings.setdefault(key, []):
                    headings[key].append(deg)
        goals_labelled: set[tuple[float, float]] = set()
        for k, (log, data) in enumerate(runs):
            color = run_color(k, len(runs))
            half_track, radius = robot_geometry(data.metadata.get("run", {}))
            phase = _run_phase(data) if log.name not in open_loop else None
            finite = np.isfinite(np.column_stack([data.signals["x_m"],
                                                  data.signals["y_m"]])).all(axis=1)
            goal_label: str | None = None
            if data.goal is not None:
                key = (round(data.goal.x_m, 2), round(data.goal.y_m, 2))
                if key not in goals_labelled:
                    goals_labelled.add(key)
                    goal_label = (f"goal ({key[0]:g}, {key[1]:g}, θ_d "
                                  f"{' or '.join(headings[key])})" if many else "")
            view = RunView(run_color=color if many else None, half_track_m=half_track,
                           wheel_radius_m=radius,
                           phase=phase[finite] if phase is not None else None,
                           start_label=start_text[k] if many else None,
                           start_label_color=start_color[k],
                           run_label=labels[k] if many else None,
                           stop_radius_m=eps_all[k], goal_label=goal_label,
                           arrow_m=heading_arrow_m(bounds))
            log_run_static(rec, log.name, goal=data.goal, path_xy=paths[k], color=color,
                           view=view)
            optimum = optimal_by_log.get(log.path.resolve())
            if optimum is not None:
                log_optimal_path(rec, log.name, optimum, color)
            send_run_columns(rec, log.name, data.t_ns, data.block(), phase, construction=not many,
                             label_offset_m=0.025 * span_m)
            if traces[k] is not None:
                log_sensing(rec, log.name, log.path, data, traces[k])
            if k in aligned:
                log_deviation(rec, run_entity(log.name), TIMELINE,
                              f"{labels[k]} {log.name} - {names[aligned[k].reference]}", color,
                              aligned[k])
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
    "RawView",
    "ReplayResult",
    "RunLog",
    "RunView",
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
    "raw_view",
    "read_logs",
    "replay",
    "replay_blueprint",
    "run_color",
    "run_entity",
    "send_run_columns",
    "spawn_viewer",
    "varied_inputs",
]
