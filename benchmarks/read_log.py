"""Reading a run log back: a small log (Fig. 11, 2,672 rows) and a long one, this code against
another tree side by side.

Each reading runs in a fresh process, the trees taking turns over ``REPEATS`` rounds; the table
gives medians of the wall time and CPU time of the read (imports excluded, ``pandas``
included) and the peak resident memory of the process:

* ``read_log``: ``wmr.read_log(path)``, every signal as a DataFrame;
* ``.path``: ``RunResult.path`` of the run (what a notebook asks of ``wmr.run``): the path's
  topic alone where the reader can (``read_log(path, signals=...)``), the whole log before.

The small log is also read ``WARM`` times in one process, after a first read (the cost a
notebook sees reading logs one after another): its median.

The logs are made first with ``wmr run`` (``fig11``; the long one a far-goal cruise of
``STEPS`` control steps, as ``benchmarks/api_vs_cli.py``).

Run: ``python benchmarks/read_log.py [STEPS] [REPEATS] [--against DIR]`` (defaults 400000 and
3); ``DIR`` is the ``pipelines`` folder of another tree (e.g. ``git worktree add /tmp/old
HEAD~3``, then ``--against /tmp/old/pipelines``), read with the same interpreter.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

_READ = """
import resource, sys, time
what, path = sys.argv[1], sys.argv[2]
import pandas, wmr, wmr.api  # loaded before the clock starts: the read alone is timed
t0, c0 = time.perf_counter(), time.process_time()
if what == "read_log":
    n = len(wmr.read_log(path).signals)
else:
    n = len(wmr.api.RunResult({"mcap": path, "status": "timeout"}).path)
t1, c1 = time.perf_counter(), time.process_time()
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
print(n, t1 - t0, c1 - c0, peak)
"""

_WARM = """
import statistics, sys, time
import wmr
path, repeats = sys.argv[1], int(sys.argv[2])
wmr.read_log(path)
samples = []
for _ in range(repeats):
    t0 = time.perf_counter()
    wmr.read_log(path)
    samples.append(time.perf_counter() - t0)
print(statistics.median(samples))
"""


def _env(tree: str) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=tree)


def _read(tree: str, what: str, log: Path) -> tuple[int, float, float, float]:
    """Rows, wall s, CPU s and peak MB of one read in a fresh process."""
    out = subprocess.run([sys.executable, "-c", _READ, what, str(log)], env=_env(tree),
                         capture_output=True, text=True, check=True).stdout.split()
    return int(out[0]), float(out[1]), float(out[2]), float(out[3])


def _make_logs(tree: str, tmp: Path, steps: int) -> dict[str, Path]:
    logs = {"fig11": tmp / "fig11.mcap", f"{steps} steps": tmp / "cruise.mcap"}
    cli = [sys.executable, "-m", "wmr.cli", "run", "fig11"]
    for argv, log in ((cli, logs["fig11"]),
                      ([*cli, "--goal", "100000", "0", "0", "--max-time", str(steps * 0.01)],
                       logs[f"{steps} steps"])):
        proc = subprocess.run([*argv, "--out", str(log)], env=_env(tree),
                              stdout=subprocess.DEVNULL, check=False)
        if proc.returncode not in (0, 3):  # 3: the timeout the cruise ends in
            raise SystemExit(f"wmr run exited with {proc.returncode}")
    return logs


def main(steps: int, repeats: int, against: str | None, warm: int) -> None:
    here = str(Path(__file__).resolve().parents[1] / "pipelines")
    trees = {"this tree": here} | ({"against": against} if against else {})
    with tempfile.TemporaryDirectory(prefix="wmr-read-bench-") as tmp:
        logs = _make_logs(here, Path(tmp), steps)
        sizes = {name: log.stat().st_size for name, log in logs.items()}
        samples: dict[tuple[str, str, str], list[tuple[int, float, float, float]]] = {}
        for _ in range(repeats):
            for log_name, log in logs.items():
                for what in ("read_log", ".path"):
                    for tree_name, tree in trees.items():
                        samples.setdefault((log_name, what, tree_name), []).append(
                            _read(tree, what, log))
        warm_s = {tree_name: float(subprocess.run(
            [sys.executable, "-c", _WARM, str(logs["fig11"]), str(warm)], env=_env(tree),
            capture_output=True, text=True, check=True).stdout)
            for tree_name, tree in trees.items()}
    print(f"medians of {repeats} (load {os.getloadavg()[0]:.1f}; "
          f"{', '.join(f'{n}: {tree}' for n, tree in trees.items())})")
    print("| log | read | tree | rows | wall s | CPU s | peak MB |")
    print("|---|---|---|---|---|---|---|")
    for (log_name, what, tree_name), s in samples.items():
        med = [statistics.median(x[i] for x in s) for i in range(1, 4)]
        print(f"| {log_name} ({sizes[log_name] / 1e6:.1f} MB) | {what} | {tree_name} | "
              f"{s[0][0]} | {med[0]:.3f} | {med[1]:.3f} | {med[2]:.0f} |")
    for tree_name, seconds in warm_s.items():
        print(f"fig11 read_log, warm, median of {warm}: {tree_name} {seconds * 1e3:.1f} ms")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("steps", nargs="?", type=int, default=400_000)
    parser.add_argument("repeats", nargs="?", type=int, default=3)
    parser.add_argument("--against", help="the pipelines folder of another tree")
    parser.add_argument("--warm", type=int, default=15, help="warm reads of the small log")
    args = parser.parse_args()
    main(args.steps, args.repeats, args.against, args.warm)
