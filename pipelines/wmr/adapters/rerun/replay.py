"""Replay run logs in Rerun, and watch a run live while it is simulated.

``wmr replay`` reads one or more MCAP run logs (:func:`wmr.adapters.mcap.read_run`) and sends them
to Rerun as whole columns (``send_columns``): one recording, one ``sim_time`` timeline (simulation
seconds from the log's ``t_ns``), and a default blueprint with

* a 2-D world view: the path of each run (a line strip), the robot's pose (body and heading
  arrow, moved by a transform per control step), the goal pose, the point D on the heading line
  (Fig. 4) and the ROC reference point R (Fig. 6) with their construction lines from B;
* time series of the errors :math:`e_s`, :math:`e_\\theta` (Fig. 11), of the platform angular
  velocity and the wheel speeds (Fig. 12), of the motor torques and of the PI terms (eq. 29).

Entity layout, one subtree per run (``<run>`` is the log's file name without ``.mcap``)::

    runs/<run>/world              static: y-up flip (2-D views draw y downwards)
    runs/<run>/world/path         static LineStrips2D, the whole path
    runs/<run>/world/goal         static Arrows2D, the goal pose
    runs/<run>/world/robot        Transform3D per step; static Boxes2D + Arrows2D body
    runs/<run>/world/D, .../R     Points2D per step (Figs. 4 and 6)
    runs/<run>/world/construction LineStrips2D per step: B -> D and B -> R
    runs/<run>/world/gps          static Points2D: the position fixes (runs with sensors)
    runs/<run>/world/estimate     static LineStrips2D: the estimated path (runs with sensors)
    runs/<run>/errors             Scalars [e_s, e_theta]
    runs/<run>/speeds             Scalars [omega, omega_r, omega_l]
    runs/<run>/torques            Scalars [tau_r, tau_l]
    runs/<run>/pi                 Scalars [p_s, i_s, u_s, p_theta, i_theta, u_theta]
    runs/<run>/info               static TextDocument: the run and result metadata

:class:`~wmr.adapters.rerun.live_view.LiveViewSink` (in :mod:`wmr.adapters.rerun.live_view`,
importable from here too) sends the same layout block by block from the closed loop, and
:class:`~wmr.adapters.rerun.live_view.TeeSink` feeds it next to the MCAP writer.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from numpy.typing import NDArray

from wmr.adapters.mcap import Pose2D, RunData, read_run
from wmr.adapters.mcap.reader import metadata_json
from wmr.core.signals import COLUMN
from wmr.infra.errors import LogError, WmrError

#: The Rerun application id of every recording written here.
APPLICATION_ID: Final = "wmr-cosim"
#: The one timeline: simulation time from the start of the run.
TIMELINE: Final = "sim_time"
#: Root of the per-run subtrees.
RUNS_ROOT: Final = "runs"

Rgb = tuple[int, int, int]

#: Run colours (matplotlib's tab10), in the order the runs are given.
RUN_COLORS: Final[tuple[Rgb, ...]] = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
)
GOAL_COLOR: Final[Rgb] = (230, 50, 50)
D_COLOR: Final[Rgb] = (0, 170, 255)
R_COLOR: Final[Rgb] = (255, 170, 0)


@dataclass(frozen=True)
class Series:
    """One plotted signal: its column in :data:`wmr.core.signals.SIGNALS`, its label and colour."""

    signal: str
    label: str
    color: Rgb


@dataclass(frozen=True)
class Panel:
    """A time-series view: one multi-instance ``Scalars`` entity per run, one line per series."""

    entity: str
    title: str
    series: tuple[Series, ...]


#: The time-series panels of the default blueprint, top to bottom.
PANELS: Final[tuple[Panel, ...]] = (
    Panel("errors", "Errors e_s [m], e_θ [rad] (Fig. 11)", (
        Series("e_s_m", "e_s [m]", (31, 119, 180)),
        Series("e_theta_rad", "e_θ [rad]", (214, 39, 40)),
    )),
    Panel("speeds", "Angular velocity ω and wheel speeds [rad/s] (Fig. 12)", (
        Series("omega_radps", "ω [rad/s]", (44, 160, 44)),
        Series("omega_r_radps", "ω_r [rad/s]", (255, 127, 14)),
        Series("omega_l_radps", "ω_l [rad/s]", (148, 103, 189)),
    )),
    Panel("torques", "Motor torques [N m]", (
        Series("tau_r_nm", "τ_r [N m]", (255, 127, 14)),
        Series("tau_l_nm", "τ_l [N m]", (148, 103, 189)),
    )),
    Panel("pi", "PI terms (eq. 29): distance [m/s], angle [rad/s]", (
        Series("p_s_mps", "P_s [m/s]", (31, 119, 180)),
        Series("i_s_mps", "I_s [m/s]", (158, 202, 225)),
        Series("u_s_mps", "u_s [m/s]", (8, 48, 107)),
        Series("p_theta_radps", "P_θ [rad/s]", (214, 39, 40)),
        Series("i_theta_radps", "I_θ [rad/s]", (252, 146, 114)),
        Series("u_theta_radps", "u_θ [rad/s]", (103, 0, 13)),
    )),
)

#: Entities under ``runs/<run>/world`` that get one row per control step.
WORLD_SERIES: Final = ("robot", "D", "R", "construction")
#: Entities under ``runs/<run>/world`` logged once (static).
WORLD_STATIC: Final = ("path", "goal")

_PANEL_COLUMNS: Final = {p.entity: [COLUMN[s.signal] for s in p.series] for p in PANELS}
_X, _Y, _TH = COLUMN["x_m"], COLUMN["y_m"], COLUMN["theta_rad"]
_DX, _DY, _RX, _RY = COLUMN["D_x_m"], COLUMN["D_y_m"], COLUMN["R_x_m"], COLUMN["R_y_m"]

#: Robot geometry used when a log has no ``params`` (the paper's robot, Section 5).
_DEFAULT_L_M: Final = 0.3
_DEFAULT_R_M: Final = 0.15
#: Length of the heading arrow of the robot and of the goal, m.
_ARROW_M: Final = 1.0


# --------------------------------------------------------------------------- inputs


@dataclass(frozen=True)
class RunLog:
    """A log to replay and the name of its subtree (``runs/<name>``)."""

    name: str
    path: Path


def find_logs(inputs: Sequence[str | os.PathLike[str]]) -> list[RunLog]:
    """The MCAP logs named by ``inputs``: files as given, folders searched recursively.

    Parameters
    ----------
    inputs
        ``.mcap`` files and folders (a batch output folder may hold sub-folders).

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
            found = sorted(f for f in p.rglob("*.mcap") if f.is_file())
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


def _shade(color: Rgb, k: int) -> Rgb:
    """The ``k``-th shade of ``color``: 0 is the colour, then ever lighter/darker ones."""
    if k == 0:
        return color
    f = (0.45, -0.35, 0.7, -0.55, 0.25)[(k - 1) % 5]
    if f > 0:
        return tuple(round(c + (255 - c) * f) for c in color)  # type: ignore[return-value]
    return tuple(round(c * (1 + f)) for c in color)  # type: ignore[return-value]


def _series_style(panel: Panel, run_name: str, run_color: Rgb | None) -> rr.SeriesLines:
    """Line names and colours of a panel: per signal, or per run (in shades) for comparisons."""
    if run_color is None:
        return rr.SeriesLines(names=[s.label for s in panel.series],
                              colors=[s.color for s in panel.series])
    return rr.SeriesLines(names=[f"{run_name}: {s.label}" for s in panel.series],
                          colors=[_shade(run_color, k) for k in range(len(panel.series))])


# --------------------------------------------------------------------------- blueprint


def replay_blueprint(run_names: Sequence[str], *, live: bool = False) -> rrb.Blueprint:
    """The default layout: world view on the left, the time-series panels on the right.

    Parameters
    ----------
    run_names
        The runs of the recording (their subtrees ``runs/<name>``).
    live
        For a live view: the plots follow the latest 30 s instead of the whole run.
    """
    roots = [f"/{run_entity(n)}" for n in run_names]
    world = rrb.Spatial2DView(
        name="World (x right, y up) [m]", origin="/",
        contents=[f"+ {r}/world/**" for r in roots],
        background=(250, 250, 250),
    )
    time_range = (
        rrb.VisibleTimeRange(TIMELINE, start=rrb.TimeRangeBoundary.cursor_relative(seconds=-30.0),
                             end=rrb.TimeRangeBoundary.cursor_relative())
        if live else None
    )
    plots = [
        rrb.TimeSeriesView(name=p.title, origin="/", contents=[f"+ {r}/{p.entity}" for r in roots],
                           plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.RightTop),
                           time_ranges=time_range)
        for p in PANELS
    ]
    info = rrb.TextDocumentView(name="Run", origin="/", contents=[f"+ {r}/info" for r in roots])
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(world, info, row_shares=[5, 1]),
            rrb.Vertical(*plots),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=TIMELINE, state="expanded"),
        collapse_panels=False,
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


def _params(meta: dict[str, dict[str, str]]) -> tuple[float, float]:
    """Half track ``L`` and wheel radius ``r`` from a log's ``run`` record (or the paper's)."""
    try:  # bounded: a stranger's log may hold a value nested too deep for json.loads
        params = metadata_json(meta.get("run", {}).get("params", "{}"))
        half_track, radius = float(params.get("L", _DEFAULT_L_M)), float(
            params.get("r", _DEFAULT_R_M))
    except (ValueError, TypeError, AttributeError, LogError):
        return _DEFAULT_L_M, _DEFAULT_R_M
    if not (half_track > 0 and radius > 0 and math.isfinite(half_track + radius)):
        return _DEFAULT_L_M, _DEFAULT_R_M
    return half_track, radius


def log_run_static(rec: rr.RecordingStream, name: str, *, goal: Pose2D | None,
                   path_xy: NDArray[np.float64] | None, color: Rgb,
                   run_color: Rgb | None = None, half_track_m: float = _DEFAULT_L_M,
                   wheel_radius_m: float = _DEFAULT_R_M, info: str | None = None) -> None:
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
        Colour of the path and the robot.
    run_color
        When several runs share the plots: the run's colour for its lines (None: per signal).
    half_track_m, wheel_radius_m
        Robot geometry for the body drawing.
    info
        Markdown shown in the run panel.
    """
    root = run_entity(name)
    world = f"{root}/world"
    # 2-D views draw y downwards: a mirror about the x axis puts y up, as in the paper's plots
    rec.log(world, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
    if path_xy is not None and path_xy.shape[0] >= 1:
        rec.log(f"{world}/path", rr.LineStrips2D([path_xy], colors=[color], radii=[0.03],
                                                 labels=[name], show_labels=False), static=True)
    if goal is not None:
        gx, gy, gth = goal
        vec = [_ARROW_M * math.cos(gth), _ARROW_M * math.sin(gth)]
        rec.log(f"{world}/goal",
                rr.Arrows2D(origins=[[gx, gy]], vectors=[vec], colors=[GOAL_COLOR], radii=[0.05],
                            labels=[f"goal θ_d={math.degrees(gth):.0f}°"], show_labels=True),
                static=True)
    # the robot in its own frame (B at the origin, x forward): chassis, two wheels, heading
    chassis_len = 2.0 * half_track_m + 0.2
    rec.log(f"{world}/robot",
            rr.Boxes2D(centers=[[0.5 * chassis_len - 0.3, 0.0], [0.0, half_track_m],
                                [0.0, -half_track_m]],
                       half_sizes=[[0.5 * chassis_len, 0.8 * half_track_m],
                                   [wheel_radius_m, 0.05], [wheel_radius_m, 0.05]],
                       colors=[color, (40, 40, 40), (40, 40, 40)], radii=[0.025]),
            rr.Arrows2D(origins=[[0.0, 0.0]], vectors=[[_ARROW_M, 0.0]], colors=[color],
                        radii=[0.04]),
            static=True)
    rec.log(f"{world}/D", rr.Points2D.from_fields(colors=[D_COLOR], radii=[0.12], labels=["D"],
                                                   show_labels=True), static=True)
    rec.log(f"{world}/R", rr.Points2D.from_fields(colors=[R_COLOR], radii=[0.12], labels=["R"],
                                                   show_labels=True), static=True)
    rec.log(f"{world}/construction",
            rr.LineStrips2D.from_fields(colors=[D_COLOR, R_COLOR], radii=[0.015]), static=True)
    for panel in PANELS:
        rec.log(f"{root}/{panel.entity}", _series_style(panel, name, run_color), static=True)
    if info:
        rec.log(f"{root}/info", rr.TextDocument(info, media_type=rr.MediaType.MARKDOWN),
                static=True)


def send_run_columns(rec: rr.RecordingStream, name: str, t_ns: NDArray[np.int64],
                     block: NDArray[np.float64]) -> None:
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
    """
    n = int(t_ns.shape[0])
    if n == 0:
        return
    root = run_entity(name)
    world = f"{root}/world"
    times = [_time_column(t_ns)]
    x, y, theta = block[:, _X], block[:, _Y], block[:, _TH]
    translation = np.column_stack([x, y, np.zeros(n)])
    rec.send_columns(f"{world}/robot", indexes=times, columns=rr.Transform3D.columns(
        translation=translation, quaternion=_yaw_quaternions(theta)))
    d_xy = np.ascontiguousarray(block[:, [_DX, _DY]])
    r_xy = np.ascontiguousarray(block[:, [_RX, _RY]])
    rec.send_columns(f"{world}/D", indexes=times, columns=rr.Points2D.columns(positions=d_xy))
    rec.send_columns(f"{world}/R", indexes=times, columns=rr.Points2D.columns(positions=r_xy))
    b_xy = np.column_stack([x, y])
    strips = np.stack([np.stack([b_xy, d_xy], axis=1), np.stack([b_xy, r_xy], axis=1)],
                      axis=1).reshape(2 * n, 2, 2)
    rec.send_columns(f"{world}/construction", indexes=times,
                     columns=rr.LineStrips2D.columns(strips=strips.astype(np.float32))
                     .partition(np.full(n, 2)))
    for panel in PANELS:
        values = np.ascontiguousarray(block[:, _PANEL_COLUMNS[panel.entity]])
        rec.send_columns(f"{root}/{panel.entity}", indexes=times,
                         columns=rr.Scalars.columns(scalars=values))


def _info_markdown(name: str, run: RunData) -> str:
    """The run panel: where the log is, and its ``run`` and ``result`` records."""
    lines = [f"### {name}", f"`{run.path}`: {run.n_steps} steps, "
             f"{run.t_s[-1] if run.n_steps else 0.0:.2f} s"
             + (" **(truncated)**" if run.truncated else "")]
    result = run.metadata.get("result", {})
    if result:
        lines.append(f"**{result.get('status', '?')}**: {result.get('message', '')}")
    meta = run.metadata.get("run", {})
    for key in ("scenario", "start", "goal", "gains", "limits", "fmu_file", "software_version"):
        if key in meta:
            lines.append(f"- {key}: `{meta[key]}`")
    return "\n\n".join(lines[:3]) + "\n\n" + "\n".join(lines[3:])


# --------------------------------------------------------------------------- replay


@dataclass
class ReplayResult:
    """What :func:`replay` did."""

    runs: list[str]
    steps: dict[str, int]
    rrd: Path | None
    spawned: bool
    warnings: list[str] = field(default_factory=list)


def read_logs(logs: Sequence[RunLog]) -> tuple[list[tuple[RunLog, RunData]], list[str]]:
    """Read every log; warn about truncated ones; raise on unreadable ones.

    Raises
    ------
    LogError
        A file is not an MCAP log, or holds no complete control step.
    """
    runs: list[tuple[RunLog, RunData]] = []
    warnings: list[str] = []
    for log in logs:
        data = read_run(log.path)
        if data.n_steps == 0:
            why = f" ({data.warnings[0]})" if data.warnings else ""
            raise LogError(f"{log.path}: no readable control step in this log{why}")
        if data.truncated:
            warnings.append(f"{log.path}: truncated log, replaying its first {data.n_steps} "
                            f"steps (to t = {data.t_s[-1]:.2f} s)")
        # what the reader left out or could not check: never replayed silently
        warnings += [f"{log.path}: {line}" for line in data.warnings]
        runs.append((log, data))
    return runs, warnings


def replay(inputs: Sequence[str | os.PathLike[str]], *, rrd: str | os.PathLike[str] | None = None,
           spawn: bool | None = None) -> ReplayResult:
    """Replay run logs in one Rerun recording: a viewer, or an ``.rrd`` file.

    Parameters
    ----------
    inputs
        ``.mcap`` files and folders of them.
    rrd
        Write the recording to this file (and do not spawn a viewer).
    spawn
        Open a viewer; default: when there is a screen and no ``rrd`` is given.  Without a
        viewer the recording goes to ``rrd`` or :func:`default_rrd_path`.

    Returns
    -------
    ReplayResult
        Run names, steps per run, the ``.rrd`` written (None when only a viewer got it),
        and warnings (truncated logs, a viewer that could not start).

    Raises
    ------
    LogError
        No log found, or a log that cannot be read.
    """
    if rrd is not None and Path(rrd).suffix != ".rrd":
        raise WmrError(f"{rrd}: the recording file must end in .rrd")
    runs, warnings = read_logs(find_logs(inputs))
    names = [log.name for log, _ in runs]
    blueprint = replay_blueprint(names)
    rec = rr.RecordingStream(APPLICATION_ID)
    rec.send_recording_name(names[0] if len(names) == 1 else f"{len(names)} runs")

    out: Path | None = Path(rrd) if rrd is not None else None
    spawned = False
    if spawn is None:
        spawn = out is None and has_screen()
    if spawn:
        try:
            rec.spawn(default_blueprint=blueprint)
            spawned = True
        except Exception as exc:  # no viewer binary, or it would not start: save instead
            warnings.append(f"could not start the Rerun viewer ({exc}): writing an .rrd instead")
    if not spawned and out is None:
        out = default_rrd_path(inputs)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        rec.save(out, default_blueprint=blueprint)

    many = len(runs) > 1
    for k, (log, data) in enumerate(runs):
        color = RUN_COLORS[k % len(RUN_COLORS)]
        half_track, radius = _params(data.metadata)
        path_xy = np.column_stack([data.signals["x_m"], data.signals["y_m"]])
        path_xy = path_xy[np.isfinite(path_xy).all(axis=1)]
        log_run_static(rec, log.name, goal=data.goal, path_xy=path_xy, color=color,
                       run_color=color if many else None, half_track_m=half_track,
                       wheel_radius_m=radius, info=_info_markdown(log.name, data))
        send_run_columns(rec, log.name, data.t_ns, data.block())
        if "sensors" in data.metadata.get("run", {}):  # measured and estimated paths too
            from wmr.adapters.mcap.sensing import replay_sensing

            replay_sensing(rec, run_entity(log.name), log.path, color)
    rec.flush()
    if out is not None:
        rec.disconnect()
    return ReplayResult(runs=names, steps={log.name: d.n_steps for log, d in runs}, rrd=out,
                        spawned=spawned, warnings=warnings)


def iter_signal_names() -> Iterable[str]:
    """Every signal the replay plots, panel by panel (for tests and docs)."""
    for panel in PANELS:
        for s in panel.series:
            yield s.signal


#: The live view lives in wmr.adapters.rerun.live_view; these names stay importable from here.
_LIVE_VIEW: Final = ("LiveViewSink", "TeeSink", "live_view_sink")


def __getattr__(name: str) -> Any:
    if name in _LIVE_VIEW:
        from wmr.adapters.rerun import live_view

        return getattr(live_view, name)
    raise AttributeError(f"module 'wmr.adapters.rerun.replay' has no attribute {name!r}")


__all__ = [
    "APPLICATION_ID",
    "PANELS",
    "TIMELINE",
    "Panel",
    "ReplayResult",
    "RunLog",
    "Series",
    "default_rrd_path",
    "find_logs",
    "has_screen",
    "log_run_static",
    "read_logs",
    "replay",
    "replay_blueprint",
    "run_entity",
    "send_run_columns",
]
