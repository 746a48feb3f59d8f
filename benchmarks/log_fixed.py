"""Where a log's fixed cost goes: its header, open and close, phase by phase, in real runs.

60 runs of ``mc_fig10`` (as ``python benchmarks/batch.py phases``), each run with its full
MCAP log (not fsynced, a new file per run, as in a batch) and again keeping none (the rows
held, the run converged: a failed-only batch's run); the log's phases are timed by wrapping
the functions that do them: the run's header (``log_header``), the log's open (the opener,
header excluded), the chunks of rows, and its close (the scene topics, the note, their one
chunk, the summary with the file's commit).  CPU time of this process, medians per call (per
run: each is called once a run, except the chunks, a call per block of rows).  The wrappers
cost a microsecond or two a call: compare the code before and after with the same script, one
after the other.

A second table answers whether a lighter layout alone could make a full-log batch twice a
failed-only one (issue 31's aim): the same runs with fewer per-step topics (the writer's
``topics``; a layout the shipped logs do not have, measured only), each against the run
keeping no log.  Twice needs a whole log within one held run's CPU; a log's fixed cost (its
open, scene and close, the first table) takes most of that before any step is written.

Run: ``PYTHONPATH=pipelines python benchmarks/log_fixed.py [N_RUNS] [REPEATS]``.
"""

from __future__ import annotations

import contextlib
import functools
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).parent))

from batch import _mc_fig10, default_fmu

#: The row of the second table's runs keeping no log.
_HELD = "run keeping no log (rows held)"


@contextlib.contextmanager
def _removed(folder: Path) -> Iterator[None]:
    """Remove ``folder`` and its logs when the block ends."""
    try:
        yield
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def main(n_runs: int = 60, repeats: int = 3) -> None:
    import wmr.adapters.mcap.scene as scene
    import wmr.adapters.mcap.writer as writer
    import wmr.apps.run as run
    from wmr.adapters.fmi.robot import FmuPlant
    from wmr.adapters.mcap.schemas import STEP_TOPICS, TopicLayout
    from wmr.apps.run import LogPolicy, run_to_log

    def without(*names: str) -> tuple[TopicLayout, ...]:
        return tuple(t for t in STEP_TOPICS if t.topic not in names)

    #: the per-step topics of each layout measured: the shipped one first
    layouts: dict[str, tuple[TopicLayout, ...]] = {
        "the shipped six topics": STEP_TOPICS,
        "without /tf": without("/tf"),
        "without /robot/pose": without("/robot/pose"),
        "without /tf and /controller/points": without("/tf", "/controller/points"),
        "/robot/state alone": tuple(t for t in STEP_TOPICS if t.topic == "/robot/state"),
    }
    lighter: dict[str, list[float]] = {name: [] for name in (*layouts, _HELD)}
    sizes: dict[str, list[int]] = {name: [] for name in layouts}

    times: dict[str, list[float]] = {}

    def wrap(owner: Any, name: str, label: str) -> None:
        fun: Callable[..., Any] = getattr(owner, name)

        @functools.wraps(fun)
        def timed(*args: Any, **kwargs: Any) -> Any:
            cpu = time.process_time()
            try:
                return fun(*args, **kwargs)
            finally:
                times.setdefault(label, []).append(time.process_time() - cpu)

        setattr(owner, name, timed)

    wrap(run, "log_header", "the run's header (log_header)")
    wrap(writer.McapOpener, "__call__", "open (the opener, header excluded)")
    wrap(writer.RunLogWriter, "_flush_chunks", "chunks of rows (a call per block)")
    wrap(writer.RunLogWriter, "close", "close, all")
    wrap(scene.SceneRecorder, "write", "close: the scene topics")
    # since issue 31's third round the scene's topics and the note are one chunk, written by
    # the close after it gathered them: their drawing above, this their chunk
    wrap(writer.RunLogWriter, "_write_topics", "close: the scene's and note's chunk")
    wrap(writer, "write_readme", "close: the note")
    wrap(writer.McapFile, "finish", "close: the summary and the commit")
    batch = _mc_fig10(n_runs)
    # removed at the end (its logs are 0.6 MB a run): a folder of this machine's ext4 without
    # a journal makes files slower to create for 30 s after many were removed, so run the
    # next benchmark a little later (docs/batch.md, "Round three")
    folder = Path(tempfile.mkdtemp(prefix="wmr-bench-log-fixed-"))
    full: list[float] = []
    held: list[float] = []
    with FmuPlant(default_fmu()) as plant, _removed(folder):
        for i, r in enumerate(batch.runs[:10]):  # warm-up
            run_to_log(r.spec, writer.McapOpener(folder / f"w{i}.mcap", durable=False), plant)
        times.clear()
        for k in range(repeats):
            for i, r in enumerate(batch.runs):
                cpu = time.process_time()
                run_to_log(r.spec, writer.McapOpener(folder / f"{k}-{i}.mcap", durable=False),
                           plant)
                full.append(time.process_time() - cpu)
                cpu = time.process_time()
                run_to_log(r.spec, writer.McapOpener(folder / "held.mcap", durable=False), plant,
                           log=LogPolicy("failed"))
                held.append(time.process_time() - cpu)
        phases = {label: list(values) for label, values in times.items()}  # the shipped log's
        for _ in range(repeats):
            for i, r in enumerate(batch.runs):
                cpu = time.process_time()  # in turn with the layouts: the drift is shared
                run_to_log(r.spec, writer.McapOpener(folder / "held.mcap", durable=False), plant,
                           log=LogPolicy("failed"))
                lighter[_HELD].append(time.process_time() - cpu)
                for name, topics in layouts.items():
                    path = folder / f"layout-{i}.mcap"
                    cpu = time.process_time()
                    run_to_log(r.spec, writer.McapOpener(path, durable=False, topics=topics),
                               plant)
                    lighter[name].append(time.process_time() - cpu)
                    sizes[name].append(path.stat().st_size)
    n = len(full)
    print(f"{n_runs} runs of mc_fig10 x {repeats}, CPU us, medians")
    print(f"{'run with its full log':<44} {1e6 * statistics.median(full):>8.0f}")
    print(f"{'run keeping no log (rows held)':<44} {1e6 * statistics.median(held):>8.0f}")
    for label, values in phases.items():
        print(f"{label:<44} {1e6 * statistics.median(values):>8.0f}  "
              f"({len(values) / n:.1f} a run)")
    base = statistics.median(lighter.pop(_HELD))
    print(f"\nfull logs of fewer per-step topics, CPU us, medians; x: against the run keeping "
          f"no log ({1e6 * base:.0f} us, measured in turn with them); issue 31's aim: x2.00")
    for name, values in lighter.items():
        m = statistics.median(values)
        print(f"{name:<44} {1e6 * m:>8.0f}  x{m / base:.2f}  "
              f"{statistics.median(sizes[name]) / 1e3:>5.0f} kB")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
