"""A Rerun blueprint for a run log as Rerun's own MCAP loader reads it (no ``wmr replay``).

The log draws itself: its scene topics (``/scene/*``, :mod:`wmr.adapters.mcap.scene`) are
``foxglove.PointCloud`` messages, which Rerun's loader turns into ``Points3D`` (the robot placed
by ``InstancePoses3D``).  The signals arrive as one struct component per ``wmr.*`` message
(``wmr.RobotState:message`` with fields ``x_m``, ``v_mps``, ...), which a time series view
does not plot by itself: this blueprint maps each plotted field onto a ``SeriesLines``
visualizer (a Rerun component mapping with a ``.field`` selector).  Its views match the
dashboard of ``wmr replay`` (one unit per axis): a top view of the scene with a metre grid,
and the panels of :data:`RAW_PANELS`.  Steps (``docs/replay.md``)::

    wmr replay --blueprint wmr.rbl
    rerun mcap convert run.mcap --timeline-type duration --application-id wmr-run -o run.rrd
    rerun run.rrd wmr.rbl

``--timeline-type duration`` makes the log times (simulation time, ns from the start) a
duration timeline instead of dates in 1970; ``--application-id`` must be the blueprint's
(:data:`APPLICATION_ID`) for the viewer to apply it.

A log opened directly (``rerun run.mcap``) is named by Rerun after its file
(:func:`log_application_id`): the blueprint written beside it for that name
(:func:`write_log_blueprint`, ``wmr replay --blueprint-for run.mcap``) applies when both are
opened together, ``rerun run.mcap run.rbl``; the log time then stays a timestamp (Rerun's
viewer shows it as seconds from the start with its "seconds since Unix epoch" time format).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from wmr.adapters.mcap.scene import PHASE_TOPIC
from wmr.adapters.mcap.schemas import STEP_TOPICS, TORQUE_TOPIC, TopicLayout
from wmr.adapters.mcap.sensing import COVARIANCE_TOPIC

#: The application id the blueprint is saved for (``rerun mcap convert --application-id``).
APPLICATION_ID: Final = "wmr-run"
#: The scalar slot of Rerun's ``SeriesLines`` visualizer.
SCALARS: Final = "Scalars:scalars"
#: The timeline of Rerun's MCAP loader (the messages' log time).
LOG_TIMELINE: Final = "message_log_time"

_SCHEMAS: Final = {layout.topic: layout.schema_name for layout in (*STEP_TOPICS, TORQUE_TOPIC)}
_SCHEMAS[PHASE_TOPIC] = "wmr.ControlPhase"
_SCHEMAS[COVARIANCE_TOPIC] = "wmr.PoseCovariance"

Rgb = tuple[int, int, int]


@dataclass(frozen=True)
class RawLine:
    """One plotted field: the topic, its message field, the line's name and colour."""

    topic: str
    field: str
    label: str
    color: Rgb


@dataclass(frozen=True)
class RawPanel:
    """A time series view of the raw log."""

    title: str
    lines: tuple[RawLine, ...]


#: The panel folded into a tab behind the torques: over a whole run the phase is a line at 0
#: with a sliver at the end (the alignment), not worth a cell of its own.
PHASE_PANEL: Final = "Phase: 0 approach, 1 align"
TORQUE_PANEL: Final = "Torques τ_r, τ_l [N m]"
COVARIANCE_PANEL: Final = "Estimate covariance [m²]"

_S, _E, _C = "/robot/state", "/controller/errors", "/controller/commands"
#: The time series views, one unit per axis (angles stay in radians: a selector cannot scale);
#: titles under ~30 characters (a plot of the three-column grid cuts a longer one).
RAW_PANELS: Final[tuple[RawPanel, ...]] = (
    RawPanel("Distance Δr, e_s [m]", (
        RawLine(_E, "dr_m", "Δr", (110, 110, 110)), RawLine(_E, "e_s_m", "e_s", (31, 119, 180)))),
    RawPanel("Heading error e_θ [rad]", (RawLine(_E, "e_theta_rad", "e_θ", (214, 39, 40)),)),
    RawPanel("Speed v, u_s [m/s]", (
        RawLine(_S, "v_mps", "v", (31, 119, 180)),
        RawLine(_C, "u_s_mps", "u_s", (255, 187, 120)))),
    RawPanel("Turn rate ω, u_θ [rad/s]", (
        RawLine(_S, "omega_radps", "ω", (44, 160, 44)),
        RawLine(_C, "u_theta_radps", "u_θ", (255, 187, 120)))),
    RawPanel("Wheels ω_r, ω_l [rad/s]", (
        RawLine(_S, "omega_r_radps", "ω_r", (255, 127, 14)),
        RawLine(_S, "omega_l_radps", "ω_l", (148, 103, 189)),
        RawLine(_C, "omega_r_ref_radps", "ω_r ref", (255, 187, 120)),
        RawLine(_C, "omega_l_ref_radps", "ω_l ref", (197, 176, 213)))),
    RawPanel(TORQUE_PANEL, (
        RawLine(_C, "tau_r_nm", "τ_r", (255, 127, 14)),
        RawLine(_C, "tau_l_nm", "τ_l", (148, 103, 189)),
        # an open-loop log (no controller) carries its torques on a topic of their own
        RawLine(TORQUE_TOPIC.topic, "tau_r_nm", "τ_r", (255, 127, 14)),
        RawLine(TORQUE_TOPIC.topic, "tau_l_nm", "τ_l", (148, 103, 189)))),
    RawPanel(PHASE_PANEL, (
        RawLine(PHASE_TOPIC, "phase", "phase", (110, 110, 110)),)),
    RawPanel(COVARIANCE_PANEL, (
        RawLine(COVARIANCE_TOPIC, "xx_m2", "σ_x²", (204, 0, 153)),
        RawLine(COVARIANCE_TOPIC, "yy_m2", "σ_y²", (140, 86, 75)))),
)


def signal_mappings() -> dict[str, list[tuple[str, str]]]:
    """Per topic, ``(source component, selector)`` of each plotted field: the struct
    component Rerun's MCAP loader makes of the topic's message, and ``.field``."""
    out: dict[str, list[tuple[str, str]]] = {}
    for panel in RAW_PANELS:
        for line in panel.lines:
            pair = (f"{_SCHEMAS[line.topic]}:message", f".{line.field}")
            if pair not in out.setdefault(line.topic, []):
                out[line.topic].append(pair)
    return out


#: The robot's outline in the scene view: dark, so that the robot and its 1 m heading arrow
#: read on the path it drives along (the log draws it in the phase's colour, the path's).
ROBOT_COLOR: Final[Rgb] = (25, 25, 25)
def _view(panel: RawPanel, y_range: tuple[float, float] | None = None) -> Any:
    import rerun as rr
    import rerun.blueprint as rrb
    from rerun.blueprint.encodings import ComponentSourceKind, VisualizerComponentMapping

    overrides: dict[str, list[Any]] = {}
    for line in panel.lines:
        mapping = VisualizerComponentMapping(
            SCALARS, ComponentSourceKind.SourceComponent,
            source_component=f"{_SCHEMAS[line.topic]}:message", selector=f".{line.field}")
        overrides.setdefault(line.topic, []).append(
            # min-max: a step (the phase) sampled only at its changes stays a step; the
            # default average merges the two sides of a change into a ramp
            rr.SeriesLines(names=line.label, colors=[line.color],
                           aggregation_policy="minmax").visualizer(
                mappings=[mapping]))
    if panel.title == PHASE_PANEL:
        y_range = (-0.1, 1.1)
    return rrb.TimeSeriesView(name=panel.title, origin="/",
                              contents=[f"+ {t}" for t in overrides],
                              overrides=overrides,  # type: ignore[arg-type]
                              plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.RightTop),
                              axis_y=rrb.ScalarAxis(range=y_range) if y_range else None)


def raw_blueprint(frame: tuple[float, float, float, float] | None = None, *,
                  sensing: bool = False,
                  y_ranges: dict[str, tuple[float, float]] | None = None) -> Any:
    """The blueprint: the scene's top view beside a three-column grid of the signal panels
    (the phase, and with sensors the covariance, in tabs behind the torques: six cells, none
    empty, each tall enough for its y axis' values).

    Parameters
    ----------
    frame
        ``(x_min, x_max, y_min, y_max)`` [m] to look straight down on (the runs' paths and
        goals); None: Rerun's own camera (a slanted view of the whole scene).
    sensing
        Add the estimate covariance panel (a run with sensors): without sensors it would
        stay empty.
    y_ranges
        Per panel title: its fixed y range (:func:`wmr.adapters.rerun.replay.raw_view`: the
        runs' values widened to values Rerun labels); a panel not given scales itself.
    """
    import rerun as rr
    import rerun.blueprint as rrb

    eye = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, eye_up=(0.0, 0.0, 1.0))
    if frame is not None:
        x_min, x_max, y_min, y_max = frame
        cx, cy = 0.5 * (x_min + x_max), 0.5 * (y_min + y_max)
        # high enough for the larger side to fit a ~60 degree field of view
        height = 1.1 * max(x_max - x_min, y_max - y_min, 4.0)
        eye = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=(cx, cy - 1e-3, height),
                                look_target=(cx, cy, 0.0), eye_up=(0.0, 1.0, 0.0))
    scene = rrb.Spatial3DView(
        name="Scene: robot, path, goal (x right, y up) [m]", origin="/",
        contents=["+ /scene/**"],
        background=(252, 252, 252),
        line_grid=rrb.LineGrid3D(visible=True, spacing=1.0, plane=rr.components.Plane3D.XY,
                                 color=(200, 200, 200)),
        eye_controls=eye,
        # the robot dark and its points larger than the path's: it reads on its path
        overrides={"/scene/robot": rr.Points3D.from_fields(
            colors=[ROBOT_COLOR], radii=[-1.2])},
    )
    ranges = y_ranges or {}
    views = [_view(p, ranges.get(p.title)) for p in RAW_PANELS
             if sensing or all(line.topic != COVARIANCE_TOPIC for line in p.lines)]
    folded = [v for v in views if v.name in (PHASE_PANEL, COVARIANCE_PANEL)]
    cells = [rrb.Tabs(v, *folded, active_tab=0) if v.name == TORQUE_PANEL else v
             for v in views if v not in folded]
    return rrb.Blueprint(
        rrb.Horizontal(scene, rrb.Grid(*cells, grid_columns=3), column_shares=[9, 11]),
        rrb.TimePanel(timeline=LOG_TIMELINE, state="collapsed"),
        collapse_panels=True,
    )


def log_application_id(log: str | Path) -> str:
    """The application id Rerun's viewer gives a log it opens itself (``rerun run.mcap``).

    Rerun 0.41's importer names the recording after the file: its stem with each ``.`` made
    ``_`` (``run.v2.mcap`` -> ``run_v2``); a name with other characters Rerun does not take
    (``+``, non-ASCII, ...) is then migrated (``a+b`` -> ``a-b53b7``), which saving a
    blueprint under the same name does identically (checked by ``tests/test_rerun_views.py``
    against ``rerun run.mcap --save``).
    """
    return Path(log).stem.replace(".", "_")


def log_blueprint_path(log: str | Path) -> Path:
    """Where :func:`write_log_blueprint` writes the blueprint of ``log``: ``X.rbl`` beside
    ``X.mcap``."""
    return Path(log).with_suffix(".rbl")


def write_log_blueprint(log: str | Path, frame: tuple[float, float, float, float] | None = None,
                        *, sensing: bool = False,
                        y_ranges: dict[str, tuple[float, float]] | None = None) -> Path:
    """Write the blueprint for ``log`` opened directly in Rerun (``rerun X.mcap X.rbl``):
    ``X.rbl`` beside it, saved under :func:`log_application_id` (``frame``, ``sensing``,
    ``y_ranges``: see :func:`raw_blueprint`; the caller gives this log's)."""
    return write_blueprint(log_blueprint_path(log), log_application_id(log), frame,
                           sensing=sensing, y_ranges=y_ranges)


def write_blueprint(path: str | Path, application_id: str = APPLICATION_ID,
                    frame: tuple[float, float, float, float] | None = None, *,
                    sensing: bool = False,
                    y_ranges: dict[str, tuple[float, float]] | None = None) -> Path:
    """Write the blueprint to ``path`` (``.rbl``) and return it (``frame``, ``sensing``,
    ``y_ranges``: see :func:`raw_blueprint`)."""
    from wmr.infra.durable import replacing_path

    out = Path(path)
    # Rerun writes a pipe, we write out (replacing_path): a full disk keeps the previous whole
    with replacing_path(out) as pipe:
        raw_blueprint(frame, sensing=sensing, y_ranges=y_ranges).save(application_id, pipe)
    return out


__all__ = ["APPLICATION_ID", "LOG_TIMELINE", "RAW_PANELS", "RawLine", "RawPanel", "TopicLayout",
           "log_application_id", "log_blueprint_path", "raw_blueprint", "signal_mappings",
           "write_blueprint", "write_log_blueprint"]
