"""Watch a run live in Rerun while it is simulated (``wmr run --view``).

:class:`LiveViewSink` sends the layout of :mod:`wmr.adapters.rerun.replay` block by block from the
closed loop
(:class:`wmr.core.closedloop.BlockSink`), and :class:`TeeSink` feeds it next to the MCAP writer.
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
from wmr.adapters.rerun.replay import (
    APPLICATION_ID,
    RUN_COLORS,
    TIMELINE,
    has_screen,
    log_run_static,
    replay_blueprint,
    run_entity,
    send_run_columns,
)
from wmr.core.closedloop import BlockSink
from wmr.core.signals import COLUMN, SIGNALS

_X, _Y = COLUMN["x_m"], COLUMN["y_m"]


class _GoalLike(Protocol):
    x_m: float
    y_m: float
    heading_rad: float


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
    (every ``path_stride``-th row) is re-sent with each as one line strip.

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
    """

    def __init__(self, rec: rr.RecordingStream, name: str,
                 goal: _GoalLike | Pose2D | Sequence[float] | None, *,
                 path_stride: int = 5, send_rows: int = 400) -> None:
        self.rec = rec
        self.name = name
        self.rows = 0
        self._stride = max(1, int(path_stride))
        self._path: list[NDArray[np.float64]] = []
        self._send_rows = max(1, int(send_rows))
        self._waiting_t: list[NDArray[np.int64]] = []
        self._waiting: list[NDArray[np.float64]] = []
        self._color = RUN_COLORS[0]
        self._path_entity = f"{run_entity(name)}/world/path"
        log_run_static(rec, name, goal=_as_pose2d(goal), path_xy=None, color=self._color,
                       info=f"### {name}\n\nlive run")

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
        send_run_columns(self.rec, self.name, t, rows)
        first = (-self.rows) % self._stride
        self._path.append(rows[first::self._stride, [_X, _Y]])
        self.rows += n
        path = np.concatenate([*self._path, rows[-1:, [_X, _Y]]])
        path = path[np.isfinite(path).all(axis=1)]
        self.rec.set_time(TIMELINE, duration=np.timedelta64(int(t[-1]), "ns"))
        self.rec.log(self._path_entity, rr.LineStrips2D([path], colors=[self._color],
                                                        radii=[0.03]))

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
                   spawn: bool | None = None) -> LiveViewSink:
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

    Returns
    -------
    LiveViewSink
        Call :meth:`LiveViewSink.close` (or use it as a context manager) after the run.
    """
    from wmr.infra.paths import safe_filename

    rec = rr.RecordingStream(APPLICATION_ID)
    rec.send_recording_name(f"{spec_name} (live)")
    blueprint = replay_blueprint([spec_name], live=True)
    spawned = False
    if spawn if spawn is not None else has_screen():
        try:
            rec.spawn(default_blueprint=blueprint, connect=rrd is None)
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
    return LiveViewSink(rec, spec_name, goal)


__all__ = ["LiveViewSink", "TeeSink", "live_view_sink"]
