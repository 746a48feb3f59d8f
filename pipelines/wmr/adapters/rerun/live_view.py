"""Watch a run live in Rerun while it is simulated (``wmr run --view``).

:class:`LiveViewSink` sends the layout of :mod:`wmr.adapters.rerun.replay` block by block from the
closed loop
(:class:`wmr.core.closedloop.BlockSink`), and :class:`TeeSink` feeds it next to the MCAP writer.
As in the replay, the control phase is a signal and the colour of the path and of the robot's
heading (the stabiliser's hysteresis on the logged ``dr_m``, carried from block to block), and
the world view has fixed bounds with a grid: around the start and the goal, widened only when
the path would leave them (on that side, by a quarter more than needed: a few re-framings a
run at most).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import rerun as rr
from numpy.typing import NDArray

from wmr.adapters.mcap import Pose2D
from wmr.adapters.mcap.scene import APPROACH, control_phases
from wmr.adapters.rerun.replay import (
    APPLICATION_ID,
    RUN_COLORS,
    TIMELINE,
    Bounds,
    RunView,
    has_screen,
    log_grid,
    log_run_static,
    phase_strips,
    replay_blueprint,
    run_entity,
    send_run_columns,
    spawn_viewer,
)
from wmr.core.closedloop import BlockSink
from wmr.core.signals import COLUMN, SIGNALS

_X, _Y, _DR = COLUMN["x_m"], COLUMN["y_m"], COLUMN["dr_m"]
#: When the path leaves the world view's bounds, they grow to hold it and this much more of
#: their size on the sides it left by (a few re-framings over a run, not one per send).
GROW_FRACTION = 0.25


class _GoalLike(Protocol):
    x_m: float
    y_m: float
    heading_rad: float


def live_bounds(start: Pose2D | None, goal: Pose2D | None,
                path_xy: NDArray[np.float64] | None = None) -> Bounds:
    """The live world view's bounds: the start, the goal with its arrow, and the path so far,
    as the replay frames them (:meth:`Bounds.around`)."""
    pts = [np.zeros((0, 2))] if path_xy is None else [path_xy]
    for pose in (start, goal):
        if pose is not None:
            x, y, th = pose
            pts.append(np.array([[x, y], [x + np.cos(th), y + np.sin(th)]]))
    return Bounds.around(np.concatenate(pts))


def _grown(bounds: Bounds, need: Bounds) -> Bounds:
    """``bounds`` widened to hold ``need``, each side that grows by :data:`GROW_FRACTION` of
    the new size more (the path goes on that way); the other sides stay."""
    old_lo, old_hi = np.array([bounds.x_min, bounds.y_min]), np.array([bounds.x_max, bounds.y_max])
    lo = np.minimum(old_lo, [need.x_min, need.y_min])
    hi = np.maximum(old_hi, [need.x_max, need.y_max])
    pad = GROW_FRACTION * (hi - lo)
    lo = np.where(lo < old_lo, lo - pad, lo)
    hi = np.where(hi > old_hi, hi + pad, hi)
    return Bounds(float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))


def _as_pose2d(goal: _GoalLike | Pose2D | Sequence[float] | None) -> Pose2D | None:
    """A goal given as a Pose, a Pose2D or ``(x_m, y_m, heading_rad)``, as a Pose2D."""
    if goal is None or isinstance(goal, Pose2D):
        return goal
    if isinstance(goal, Sequence):
        x, y, th = (float(v) for v in goal)
        return Pose2D(x, y, th)
    return Pose2D(float(goal.x_m), float(goal.y_m), float(goal.heading_rad))


class LiveViewSink:
    """A :class:`wmr.core.closedloop.BlockSink` that shows a run in Rerun while it is simulated.

    Rows are sent every ``send_rows`` rows (four blocks of the master loop: about 20 ms of
    computing, still a live view) as a handful of ``send_columns`` calls, whose fixed cost
    the dashboard's twelve entities would otherwise pay per 100-row block; the path so far
    (every ``path_stride``-th row) is re-sent with each, one line strip per control phase.

    Parameters
    ----------
    rec
        The recording to send to (a spawned viewer or an ``.rrd`` file sink).
    name
        The run name (subtree ``runs/<name>``).
    goal
        The goal pose (``x_m``, ``y_m``, ``heading_rad``), or None.
    path_stride
        Keep every this many rows of the path (the path strip is re-sent per send).
    send_rows
        Send once this many rows are waiting (and what is left at :meth:`close`).
    start
        The start pose (framed from the first send on when None).
    stop_radius_m
        The run's stop radius: the control phase (panel and colours) and the goal's ring;
        None: no phase (one colour).
    bounds
        The world view's bounds the recording's blueprint was given (default
        :func:`live_bounds` of the start and the goal); the sink widens them, re-sending the
        blueprint, when the path would leave them.
    """

    def __init__(self, rec: rr.RecordingStream, name: str,
                 goal: _GoalLike | Pose2D | Sequence[float] | None, *,
                 path_stride: int = 5, send_rows: int = 400,
                 start: _GoalLike | Pose2D | Sequence[float] | None = None,
                 stop_radius_m: float | None = None, bounds: Bounds | None = None) -> None:
        self.rec = rec
        self.name = name
        self.rows = 0
        self._stride = max(1, int(path_stride))
        self._path: list[NDArray[np.float64]] = []
        self._path_phase: list[NDArray[np.int8]] = []
        self._send_rows = max(1, int(send_rows))
        self._waiting_t: list[NDArray[np.int64]] = []
        self._waiting: list[NDArray[np.float64]] = []
        self._color = RUN_COLORS[0]
        self._path_entity = f"{run_entity(name)}/world/path"
        self._eps = stop_radius_m if stop_radius_m and stop_radius_m > 0 else None
        self._phase = APPROACH
        goal_pose = _as_pose2d(goal)
        self.bounds = bounds or live_bounds(_as_pose2d(start), goal_pose)
        self.reframed = 0
        log_grid(rec, self.bounds)
        log_run_static(rec, name, goal=goal_pose, path_xy=None, color=self._color,
                       view=RunView(info=f"### {name}\n\nlive run", stop_radius_m=self._eps))

    def write_block(self, t_ns: NDArray[np.int64], block: NDArray[np.float64]) -> None:
        """Send ``block`` (shape ``(n, len(SIGNALS))``) at times ``t_ns`` (ns)."""
        n = int(t_ns.shape[0])
        if n == 0:
            return
        # the master reuses its arrays: take our own copies before they leave
        self._waiting_t.append(np.array(t_ns, dtype=np.int64, copy=True))
        self._waiting.append(np.array(block, dtype=np.float64, copy=True).reshape(n,
                                                                                   len(SIGNALS)))
        if sum(len(w) for w in self._waiting_t) >= self._send_rows:
            self._send()

    def _send(self) -> None:
        """Send the waiting rows, and the path so far."""
        if not self._waiting_t:
            return
        t = np.concatenate(self._waiting_t)
        rows = np.concatenate(self._waiting)
        self._waiting_t, self._waiting = [], []
        n = len(t)
        phase = None
        if self._eps is not None:  # the hysteresis goes on from the last row sent
            phase = control_phases(rows[:, _DR], self._eps, start_phase=self._phase)
            self._phase = int(phase[-1])
        send_run_columns(self.rec, self.name, t, rows, phase)
        first = (-self.rows) % self._stride
        self._path.append(rows[first::self._stride, [_X, _Y]])
        self._path_phase.append(np.zeros(0, np.int8) if phase is None
                                else phase[first::self._stride])
        self.rows += n
        path = np.concatenate([*self._path, rows[-1:, [_X, _Y]]])
        path_phase = (None if phase is None
                      else np.concatenate([*self._path_phase, phase[-1:]]))
        ok = np.isfinite(path).all(axis=1)
        path = path[ok]
        path_phase = None if path_phase is None else path_phase[ok]
        self.rec.set_time(TIMELINE, duration=np.timedelta64(int(t[-1]), "ns"))
        strips, colors = phase_strips(path, path_phase)
        if path_phase is None:
            colors = [self._color]
        self.rec.log(self._path_entity, rr.LineStrips2D(strips, colors=colors, radii=[-1.5],
                                                        draw_order=10.0))
        if len(path) and not self.bounds.contains(path):
            self._reframe(path)

    def _reframe(self, path: NDArray[np.float64]) -> None:
        """Widen the world view to hold ``path`` (the blueprint and the grid)."""
        self.bounds = _grown(self.bounds, Bounds.around(path))
        self.reframed += 1
        log_grid(self.rec, self.bounds)
        self.rec.send_blueprint(replay_blueprint([self.name], live=True, bounds=self.bounds),
                                make_active=True)

    def close(self) -> None:
        """Send the waiting rows, flush (and finish the ``.rrd`` file, if any)."""
        self._send()
        self.rec.flush()
        self.rec.disconnect()

    def __enter__(self) -> LiveViewSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class TeeSink:
    """A :class:`wmr.core.closedloop.BlockSink` that hands each block to several sinks, in order.

    E.g. ``TeeSink(log, live)`` for ``wmr run --view``: the MCAP writer and the live view.
    """

    def __init__(self, *sinks: BlockSink) -> None:
        self.sinks: tuple[BlockSink, ...] = sinks

    def write_block(self, t_ns: NDArray[np.int64], block: NDArray[np.float64]) -> None:
        """Pass the block to every sink."""
        for sink in self.sinks:
            sink.write_block(t_ns, block)


def live_view_sink(spec_name: str, goal: Any, rrd: Path | None = None, *,
                   spawn: bool | None = None, start: Any = None,
                   stop_radius_m: float | None = None) -> LiveViewSink:
    """A live view of one run: a spawned viewer when there is a screen, else an ``.rrd`` file.

    Parameters
    ----------
    spec_name
        The run's name.
    goal
        The goal pose: :class:`wmr.core.plant.Pose` (``x_m``, ``y_m``, ``heading_rad``), a
        :class:`~wmr.adapters.mcap.Pose2D` or ``(x_m, y_m, heading_rad)``.
    rrd
        Save the recording here (also when a viewer is spawned).  Without a viewer and without
        ``rrd``: ``runs/<spec_name>.rrd``.
    spawn
        Open a viewer; default: when there is a screen.
    start
        The start pose (same forms as ``goal``): framed from the start; None: from the
        first rows sent.
    stop_radius_m
        The run's stop radius (``RunSpec.stop_radius_m``): the control phase as a signal and
        as colours, and the goal's ring; None: no phase.

    Returns
    -------
    LiveViewSink
        Call :meth:`LiveViewSink.close` (or use it as a context manager) after the run.
    """
    from wmr.infra.paths import safe_filename

    rec = rr.RecordingStream(APPLICATION_ID)
    rec.send_recording_name(f"{spec_name} (live)")
    bounds = live_bounds(_as_pose2d(start), _as_pose2d(goal))
    blueprint = replay_blueprint([spec_name], live=True, bounds=bounds)
    spawned = False
    if spawn if spawn is not None else has_screen():
        try:
            spawn_viewer(rec, blueprint, connect=rrd is None)
            spawned = True
        except Exception as exc:  # no viewer binary, or it would not start
            print(f"wmr: warning: could not start the Rerun viewer ({exc}); saving an .rrd",
                  file=sys.stderr)
    if rrd is None and not spawned:
        rrd = Path("runs") / f"{safe_filename(spec_name)}.rrd"
    if rrd is not None:
        rrd = Path(rrd)
        rrd.parent.mkdir(parents=True, exist_ok=True)
        if spawned:  # both: the viewer spawned above, and the file
            rec.set_sinks(rr.GrpcSink(), rr.FileSink(rrd), default_blueprint=blueprint)
        else:
            rec.save(rrd, default_blueprint=blueprint)
    return LiveViewSink(rec, spec_name, goal, start=start, stop_radius_m=stop_radius_m,
                        bounds=bounds)


__all__ = ["GROW_FRACTION", "LiveViewSink", "TeeSink", "live_bounds", "live_view_sink"]
