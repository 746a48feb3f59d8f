"""What a logged control step costs against the unlogged loop, measured side by side in one run.

The far-goal cruise: the Fig. 11 robot, start and gains, its goal put 1 km away along x, so
that the run is all cruise (the same rows every step: no convergence, no alignment) and its
length is the time limit alone.  Every row is the marginal cost of one control step: two runs,
``max_time_s`` = :data:`LONG_S` and :data:`SHORT_S`, timed whole, so that the start-up (the
log's header, attachments and summary, its fsync and rename) cancels:
``(t_long - t_short) / (steps_long - steps_short)``, in CPU time (the process's, every thread:
steadier than the wall time on a shared machine, and what a batch that keeps every core busy
pays) and in wall time.  Each repetition runs every row once, in turn (interleaved); the table
shows medians over ``--repeats``.  The last column is what a log costs once a run whatever
its length (opening it, its header and attachments, the scene topics, its summary, an fsync
where there is one): the short run's CPU beyond its steps, less the unlogged loop's.

Rows:

* ``unlogged``: ``run_closed_loop`` with the default law (the paper's PI compiled into the C
  stepper) and no sink: the loop a log is measured against;
* ``wmr run, logged``: :func:`wmr.apps.run.run_to_log` as ``wmr run`` calls it (the shipped
  log: per-step topics, scene topics, default chunk compression, fsynced);
* ``a batch's log (not fsynced, a new file)``: the same log as a batch's worker writes it (no
  fsync: a resumed batch checks every log; a new file each run);
* ``logged, no scene topics``: the same without the drawable topics
  (:mod:`wmr.adapters.mcap.scene`), to show what they cost;
* ``logged, zstd level 1 chunks (before)``: the same with the chunk compression of the logs
  written before (zstd level 1, where the default is now lz4's fast mode,
  :data:`wmr.adapters.mcap.writer.DEFAULT_COMPRESSION`), to show what the choice saves;
* ``logged, uncompressed chunks``: what encoding and writing cost without compression.

Run: ``PYTHONPATH=pipelines python benchmarks/log_cost.py [--repeats 5]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from time import perf_counter, process_time
from typing import Any

from wmr.adapters.fmi.compiled_law import CompiledLawController
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.mcap import McapOpener
from wmr.apps import run as app_run
from wmr.build.fmus import build_fmus
from wmr.config.scenario import load_scenario
from wmr.core.closedloop import run_closed_loop
from wmr.core.runspec import Pose, RunSpec

LONG_S = 160.0
SHORT_S = 40.0
#: The far goal: 1 km ahead along x, beyond what any run here reaches.
FAR_GOAL = Pose(1000.0, 0.0, 0.0)
UNLOGGED = "unlogged (PI compiled into the stepper)"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="repetitions; medians shown")
    args = parser.parse_args(argv)
    base = load_scenario("fig11").runs[0]
    long = dataclasses.replace(base, goal=FAR_GOAL, t_max_s=LONG_S)
    short = dataclasses.replace(long, t_max_s=SHORT_S)
    fmu = build_fmus(platforms="host").fmus[3]
    samples: dict[str, list[tuple[float, float]]] = {}  # (CPU, wall) s per step
    fixed: dict[str, list[float]] = {}  # CPU s of a run beyond its steps
    with FmuPlant(fmu) as plant, tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "run.mcap"
        sizes: dict[str, int] = {}

        made = iter(range(1 << 30))
        last = {"path": log}  # the log last written, whose size is read

        def logged(fresh: bool = False, **options: Any) -> Callable[[RunSpec], int]:
            # the MCAP opener run_to_log opens for a path, with ``options`` in place of its own;
            # ``fresh``: a new file each run, as a batch's (ext4 writes out at once a file
            # renamed over another), all kept until the end (a few MB)
            opener = McapOpener(log, **options)

            def run(spec: RunSpec) -> int:
                if not fresh:
                    last["path"] = log
                    return int(app_run.run_to_log(spec, opener, plant)["steps"])
                last["path"] = path = Path(tmp) / f"fresh-{next(made)}.mcap"
                return int(app_run.run_to_log(spec, McapOpener(path, **options), plant)["steps"])
            return run

        rows: dict[str, Callable[[RunSpec], int]] = {
            UNLOGGED: lambda s: run_closed_loop(s, plant, controller=CompiledLawController()).steps,
            "wmr run, logged": logged(),
            "a batch's log (not fsynced, a new file)": logged(fresh=True, durable=False),
            "logged, no scene topics": logged(scene=False),
            "logged, zstd level 1 chunks (before)": logged(compression="zstd"),
            "logged, uncompressed chunks": logged(compression=""),
        }
        for fun in rows.values():  # warm-up
            fun(short)
        for _ in range(args.repeats):
            for name, fun in rows.items():
                c0, w0 = process_time(), perf_counter()
                n_long = fun(long)
                c1, w1 = process_time(), perf_counter()
                if name != UNLOGGED:
                    sizes[name] = last["path"].stat().st_size
                n_short = fun(short)
                c2, w2 = process_time(), perf_counter()
                per_step = n_long - n_short
                step_cpu = ((c1 - c0) - (c2 - c1)) / per_step
                samples.setdefault(name, []).append(
                    (step_cpu, ((w1 - w0) - (w2 - w1)) / per_step))
                # what the short run cost beyond its steps: start-up, the log's open and close
                fixed.setdefault(name, []).append((c2 - c1) - step_cpu * n_short)
    cpu0 = statistics.median(c for c, _ in samples[UNLOGGED])
    width = max(len(n) for n in samples)
    print(f"Far-goal cruise (Fig. 11 robot, goal 1 km ahead): marginal cost of one control step, "
          f"runs of {LONG_S:g} s and {SHORT_S:g} s, median of {args.repeats}")
    print(f"{'path':<{width}}  {'CPU us':>7}  {'x unlogged':>10}  {'wall us':>7}  "
          f"{'log B/step':>10}  {'fixed CPU us':>12}")
    steps = round(LONG_S / base.period_s) + 1
    fixed0 = statistics.median(fixed[UNLOGGED])
    for name, values in samples.items():
        cpu = statistics.median(c for c, _ in values)
        wall = statistics.median(w for _, w in values)
        size = f"{sizes[name] / steps:>10.0f}" if name in sizes else f"{'':>10}"
        # a log's own fixed cost: the run's beyond its steps, less the unlogged loop's
        extra = statistics.median(fixed[name]) - fixed0
        print(f"{name:<{width}}  {cpu * 1e6:>7.3f}  {cpu / cpu0:>10.2f}  {wall * 1e6:>7.3f}  "
              f"{size}  {extra * 1e6:>12.0f}")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    main()
