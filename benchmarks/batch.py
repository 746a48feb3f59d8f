"""Batch throughput: runs per second with 1 and 2 local workers and on a 2-worker Dask cluster.

The workload is the first ``N_RUNS`` runs of ``scenarios/mc_fig10.toml`` (Fig. 10 Monte Carlo,
each run logged to MCAP), into a fresh folder per repetition.  The configurations take turns,
after a warm-up round (the local forkserver and the Dask workers start once, as in a long
session); the timings include everything else: worker processes, FMU shipping and opening,
logs, journal and summary.  Prints medians over ``REPEATS`` and one table with the speed-up
over one worker and the Dask overhead relative to the local executor with 2 workers.

Run: ``python benchmarks/batch.py [N_RUNS] [REPEATS]`` (defaults 200 and 3).
"""

from __future__ import annotations

import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from wmr.apps.batch import BatchSpec, load_batch, run_batch
from wmr.apps.run import default_fmu
from wmr.infra.paths import scenarios_dir


def _timed(batch: BatchSpec, go: Callable[[BatchSpec, Path], None]) -> float:
    """Runs per second of one batch by ``go`` into a fresh folder."""
    folder = Path(tempfile.mkdtemp(prefix="wmr-bench-batch-"))
    try:
        t0 = time.perf_counter()
        go(batch, folder)
        return len(batch.runs) / (time.perf_counter() - t0)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def main(argv: list[str]) -> None:
    """Measure and print the table.

    The configurations take turns (one batch each per round, after a warm-up round), so that
    a load that comes and goes on the machine falls on all of them alike.
    """
    from distributed import Client, LocalCluster

    n_runs = int(argv[0]) if argv else 200
    repeats = int(argv[1]) if len(argv) > 1 else 3
    full = load_batch(scenarios_dir() / "mc_fig10.toml")
    batch = replace(full, runs=full.runs[:n_runs])
    fmu = default_fmu()

    def local(workers: int) -> Callable[[BatchSpec, Path], None]:
        def go(b: BatchSpec, out: Path) -> None:
            result = run_batch(b, out, workers=workers, fmu_path=fmu, progress=False)
            assert len(result.executed) == len(b.runs)
        return go

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster, Client(cluster) as client:
        def on_dask(b: BatchSpec, out: Path) -> None:
            result = run_batch(b, out, client=client, fmu_path=fmu, progress=False)
            assert len(result.executed) == len(b.runs)

        configs = {"local, 1 worker": local(1), "local, 2 workers": local(2),
                   "Dask, 2 workers": on_dask}
        samples: dict[str, list[float]] = {name: [] for name in configs}
        for round_ in range(repeats + 1):
            for name, go in configs.items():
                rate = _timed(batch, go)
                if round_:
                    samples[name].append(rate)
    rates = {name: statistics.median(v) for name, v in samples.items()}
    one, two = rates["local, 1 worker"], rates["local, 2 workers"]
    print(f"batch throughput: {n_runs} runs of mc_fig10 per batch, median of {repeats}")
    print(f"{'executor':<18} {'runs/s':>8} {'speed-up vs 1':>14} {'overhead vs local 2':>20}")
    for name, rate in rates.items():
        overhead = f"{100.0 * (two / rate - 1.0):+.1f} %" if name != "local, 1 worker" else ""
        print(f"{name:<18} {rate:>8.1f} {rate / one:>14.2f} {overhead:>20}")


if __name__ == "__main__":
    main(sys.argv[1:])
