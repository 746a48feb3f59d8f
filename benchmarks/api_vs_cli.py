"""The same long run through the Python API (``wmr.run``) and through ``wmr run``, side by side.

Each configuration runs in a fresh process, taking turns over ``REPEATS`` rounds; the table
gives the median wall time and the median peak resident memory of the process tree (the
command line supervises its run in a forked child: ``resource.RUSAGE_CHILDREN`` of this
script covers both), with the ratio to ``wmr run``:

* ``wmr run``: the command line;
* ``wmr.run``: the API, the result's record only (what a notebook holds after the call);
* ``wmr.run + .path``: the API, then the path read back from the log.

The run is a far-goal cruise of ``STEPS`` control steps (fig11's robot driving towards a goal
100 km away until ``max_time_s``), so that the loop and its log dominate start-up.

Run: ``python benchmarks/api_vs_cli.py [STEPS] [REPEATS]`` (defaults 400000 and 3).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_API = """
import sys, wmr
res = wmr.run("fig11", goal=(100000, 0, 0), max_time_s={max_time_s!r}, out=sys.argv[1])
assert res.status == "timeout", res.record
if {read_path!r}:
    assert len(res.path) == {rows}
"""


def _measure(argv: list[str]) -> tuple[float, float]:
    """Wall seconds and peak resident MB of one process tree (waited for with ``wait4``)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall_s = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode not in (0, 3):  # 3: the timeout the cruise ends in
        raise SystemExit(f"{argv[:3]} exited with {proc.returncode}")
    return wall_s, usage.ru_maxrss / 1024.0  # Linux: kB


def main(steps: int, repeats: int) -> None:
    max_time_s = steps * 0.01  # fig11's control period
    with tempfile.TemporaryDirectory(prefix="wmr-api-bench-") as tmp:
        log = str(Path(tmp) / "cruise.mcap")
        configs = {
            "wmr run": [sys.executable, "-m", "wmr.cli", "run", "fig11", "--goal", "100000",
                        "0", "0", "--max-time", str(max_time_s), "--out", log],
            "wmr.run": [sys.executable, "-c", _API.format(max_time_s=max_time_s,
                                                          read_path=False, rows=steps + 1),
                        log],
            "wmr.run + .path": [sys.executable, "-c",
                                _API.format(max_time_s=max_time_s, read_path=True,
                                            rows=steps + 1), log],
        }
        samples: dict[str, list[tuple[float, float]]] = {name: [] for name in configs}
        for _ in range(repeats):
            for name, argv in configs.items():
                samples[name].append(_measure(argv))
    ref_wall = statistics.median(s[0] for s in samples["wmr run"])
    ref_mem = statistics.median(s[1] for s in samples["wmr run"])
    print(f"{steps} steps, medians of {repeats} (load {os.getloadavg()[0]:.1f})")
    print("| how | wall s | peak MB | wall / wmr run | memory / wmr run |")
    print("|---|---|---|---|---|")
    for name, s in samples.items():
        wall = statistics.median(x[0] for x in s)
        mem = statistics.median(x[1] for x in s)
        print(f"| {name} | {wall:.2f} | {mem:.0f} | {wall / ref_wall:.2f} | "
              f"{mem / ref_mem:.2f} |")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 400_000,
         int(sys.argv[2]) if len(sys.argv) > 2 else 3)
