"""Cost of replaying a 60 s run (6001 control steps) in Rerun, several ways, side by side.

1. ``read_run``: decoding the MCAP log alone;
2. ``wmr replay``: read the log, send everything with ``send_columns``, write the ``.rrd``;
3. ``send_columns`` of the already-read rows (what ``wmr replay`` does after reading);
4. per-row ``rr.log`` of the same entities and components (the naive way);
5. the live view: :class:`wmr.adapters.rerun.live_view.LiveViewSink` fed 100-row blocks as the
   master loop does.

Run: ``PYTHONPATH=pipelines python benchmarks/replay.py``.  Prints medians, rows per second
and the ratio of each to ``send_columns``.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import rerun as rr
from numpy.typing import NDArray

from _common import median_seconds
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import read_run
from wmr.adapters.rerun.live_view import LiveViewSink
from wmr.adapters.rerun.replay import (
    APPLICATION_ID,
    PANELS,
    TIMELINE,
    log_run_static,
    replay,
    run_entity,
    send_run_columns,
)
from wmr.apps.run import default_fmu, run_to_log
from wmr.config.scenario import Overrides, load_scenario, with_overrides
from wmr.core.closedloop import BLOCK_ROWS
from wmr.core.signals import COLUMN

REPEATS = 5
NAME = "long"


def make_log(folder: Path) -> Path:
    """A run that times out at 60 s: the fig11 robot sent to a goal 80 m away."""
    spec = with_overrides(load_scenario("fig11").runs[0],
                          Overrides(goal=(80.0, 0.0, 0.0), max_time_s=60.0, name=NAME))
    path = folder / f"{NAME}.mcap"
    with FmuPlant(default_fmu()) as plant:
        record = run_to_log(spec, path, plant)
    print(f"log: {record['status']}, {record['steps']} steps, {path.stat().st_size / 1e6:.1f} MB",
          file=sys.stderr)
    return path


def file_recording(path: Path) -> rr.RecordingStream:
    rec = rr.RecordingStream(APPLICATION_ID)
    rec.save(path)
    return rec


def per_row_log(rec: rr.RecordingStream, t_ns: NDArray[np.int64],
                block: NDArray[np.float64]) -> None:
    """The same entities and components as :func:`send_run_columns`, one ``rr.log`` per row."""
    root = run_entity(NAME)
    world = f"{root}/world"
    cx, cy, cth = COLUMN["x_m"], COLUMN["y_m"], COLUMN["theta_rad"]
    cd = [COLUMN["D_x_m"], COLUMN["D_y_m"]]
    cr = [COLUMN["R_x_m"], COLUMN["R_y_m"]]
    panel_cols = [(p.entity, [COLUMN[s.signal] for s in p.series]) for p in PANELS]
    for t, row in zip(t_ns.tolist(), block, strict=True):
        rec.set_time(TIMELINE, duration=np.timedelta64(t, "ns"))
        th = float(row[cth])
        b = [float(row[cx]), float(row[cy])]
        d, r = row[cd].tolist(), row[cr].tolist()
        rec.log(f"{world}/robot", rr.Transform3D(
            translation=[b[0], b[1], 0.0],
            quaternion=rr.Quaternion(xyzw=[0.0, 0.0, np.sin(0.5 * th), np.cos(0.5 * th)])))
        rec.log(f"{world}/D", rr.Points2D([d]))
        rec.log(f"{world}/R", rr.Points2D([r]))
        rec.log(f"{world}/construction", rr.LineStrips2D([[b, d], [b, r]]))
        for entity, cols in panel_cols:
            rec.log(f"{root}/{entity}", rr.Scalars(row[cols]))


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        log = make_log(folder)
        run = read_run(log)
        n = run.n_steps
        t_ns, block = run.t_ns, run.block()

        def do_read() -> None:
            read_run(log)

        def do_replay() -> None:
            replay([log], rrd=folder / "replay.rrd")

        def do_columns() -> None:
            rec = file_recording(folder / "columns.rrd")
            send_run_columns(rec, NAME, t_ns, block)
            rec.flush()
            rec.disconnect()

        def do_rows() -> None:
            rec = file_recording(folder / "rows.rrd")
            per_row_log(rec, t_ns, block)
            rec.flush()
            rec.disconnect()

        def do_live() -> None:
            rec = file_recording(folder / "live.rrd")
            sink = LiveViewSink(rec, NAME, run.goal)
            for i in range(0, n, BLOCK_ROWS):
                sink.write_block(t_ns[i:i + BLOCK_ROWS], block[i:i + BLOCK_ROWS])
            sink.close()

        def do_static_only() -> None:
            rec = file_recording(folder / "static.rrd")
            log_run_static(rec, NAME, goal=run.goal, path_xy=block[:, :2], color=(0, 0, 0))
            rec.flush()
            rec.disconnect()

        rows = [
            ("read_run (MCAP decode only)", median_seconds(do_read, REPEATS)),
            ("wmr replay (read + send_columns + .rrd)", median_seconds(do_replay, REPEATS)),
            ("send_columns, whole series", median_seconds(do_columns, REPEATS)),
            ("LiveViewSink, 100-row blocks", median_seconds(do_live, REPEATS)),
            ("per-row rr.log", median_seconds(do_rows, repeats=3)),
            ("(static part alone)", median_seconds(do_static_only, REPEATS)),
        ]
    ref = dict(rows)["send_columns, whole series"]
    width = max(len(name) for name, _ in rows)
    print(f"Replay of a 60 s run: {n} control steps, {len(PANELS)} plot panels + 4 world "
          f"entities per step; medians of {REPEATS} (per-row: 3)")
    print(f"{'what':<{width}}  {'median ms':>10}  {'rows/s':>12}  {'ratio to send_columns':>22}")
    for name, seconds in rows:
        print(f"{name:<{width}}  {seconds * 1e3:>10.1f}  {n / seconds:>12,.0f}  "
              f"{seconds / ref:>22.2f}")


if __name__ == "__main__":
    main()
