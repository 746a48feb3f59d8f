"""Batch throughput and where a run's time goes, on the Fig. 10 Monte Carlo (``mc_fig10``).

Three measurements, each printed as a table:

``python benchmarks/batch.py executors [N_RUNS] [REPEATS]`` (defaults 200 and 3)
    Runs per second with 1 and 2 local workers and on a 2-worker Dask cluster (LocalCluster
    of processes), each run logged.  The configurations take turns, after a warm-up round (the
    local forkserver and the Dask workers start once, as in a long session); the timings
    include everything else: worker processes, FMU shipping and opening, logs, journal and
    summary.  Medians over ``REPEATS``; speed-up over one worker and the Dask overhead
    relative to the local executor with 2 workers.

``python benchmarks/batch.py phases [N_RUNS]`` (default 50)
    Where the time of one run goes, in one process, per run (medians over the first
    ``N_RUNS`` runs, wall and CPU time): opening the FMU (once per worker), resetting it, the
    control loop without a log, the loop holding its rows (the failed-only policy's cost for
    a run that converges), the loop writing its full log, and appending its journal line.

``python benchmarks/batch.py scaling N_RUNS [--dask] [--repeats R] [--policy P]``
    The scaling table: one batch of ``N_RUNS`` runs of ``mc_fig10`` (failed-only logs by
    default) per configuration, side by side, the configurations taking turns ``R`` times
    (default 1; medians): 1 and 2 local workers (and 4 and 8 where the machine has that many
    cores; ``--workers K``, repeated, chooses) and, with ``--dask``, a Dask cluster of 2
    worker processes of one thread started with ``dask scheduler`` and ``dask worker``.  Per
    configuration: runs per second, the speed-up over the first, the CPU time of the batch's
    own process per run (``resource.getrusage(RUSAGE_SELF)``: the parent, or the Dask
    client, alone; its workers are other processes) and the bytes per run of its journal
    and summary.

``python benchmarks/batch.py costs N_RUNS [--dask] [--repeats R] [--workers K]``
    The parent's (or the Dask client's) CPU split into what it spends per range (a Dask
    task) and per run, from which docs/batch.md projects where the client becomes the bound:
    three batches of ``mc_fig10`` (failed-only logs) per executor, the configurations taking
    turns ``R`` times (default 2; medians): ``N_RUNS`` runs in ranges of 1,024, the same in
    ranges of 128, and ``N_RUNS / 4`` in ranges of 128 (the range size set by patching the
    executors' largest range; ``N_RUNS`` at least 8 x 1,024 x the worker threads, so that
    the large ranges are whole).  With C(runs, size) the CPU of the batch's own process
    (``RUSAGE_SELF``), the cost of a range is (C(N, 128) - C(N, 1024)) / (N/128 - N/1024),
    that of a run (C(N, 128) - C(N/4, 128)) / (3N/4) less a range's share, and the rest the
    fixed cost (imports done, the FMU's digest, workers or client, the summary's merge).
    The Dask client also spends CPU per second whatever it runs (its heartbeats, the
    batch's look at the workers every second), which a batch of 2 workers would count as a
    cost per run: it is measured alone (a client and the batch's worker watch, idle for
    5 s), printed, and its share (per second x the batch's wall time) taken out of each C
    first.  (The local parent's is nil: it sleeps between its workers' messages.)  The
    last column is the CPU of the summary's merge at the end (the parts read back, the
    summary written: ``runner._finish``, timed), per run, included in the others: the part
    of the cost a run that comes after the workers are done, not while they run.

``python benchmarks/batch.py backlog N_RUNS [--runs-a-task K ...] [--repeats R]``
    The Dask client at the pace of a large cluster: ``N_RUNS`` runs of ``mc_fig10``
    (failed-only) on a Dask cluster of 2 worker processes in tasks of ``K`` runs (repeat;
    default 2 and 1,024), the configurations taking turns ``R`` times (default 3; medians).
    With tasks of 2 runs, 2 workers finish a task every 1 to 2 ms, as 1,000 worker threads
    do with tasks of 1,000 runs: the client then spends its CPU per task at the rate it
    must keep up with there.  Per configuration: tasks, wall time, runs per second, and the
    client's CPU (``RUSAGE_SELF``, its per second share, measured idle, taken out) per task.

``python benchmarks/batch.py rows N_RUNS [--repeats R]``
    What the summary rows crossing to the Dask client cost it: ``N_RUNS`` runs of
    ``mc_fig10`` (failed-only) on a Dask cluster of 2 worker processes in tasks of 1,024
    runs, as shipped and with each task's rows dropped by its worker (a worker plugin
    empties :attr:`~wmr.apps.batch.worker.BlockResult.table`: a batch without a summary,
    measured only), in turn ``R`` times (default 3; medians).  The difference is what the
    client would save if the workers wrote the rows into the batch folder themselves, the
    journal lines alone crossing (the next step of docs/batch.md's projection).  The
    client's CPU (``RUSAGE_SELF``) with its idle share and the summary's merge at the end
    (``runner._finish``, timed) taken out: what it spends while the workers run.

``python benchmarks/batch.py policies N_RUNS [--dask] [--policy P ...]``
    One batch of ``N_RUNS`` runs of ``mc_fig10`` (its ``n`` raised to ``N_RUNS``) per log
    policy (``full``, ``failed``, ``none``; default all three), on 2 local workers and, with
    ``--dask``, on a Dask cluster of 2 worker processes started with ``dask scheduler`` and
    ``dask worker`` (not in-process), the configurations taking turns: wall time, runs per
    second, the disk the batch folder takes and the parent's peak memory.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

from wmr.apps.batch import BatchOptions, BatchSpec, load_batch, run_batch
from wmr.apps.batch.spec import RunList
from wmr.apps.run import LogPolicy, default_fmu
from wmr.infra.paths import scenarios_dir


def _mc_fig10(n_runs: int) -> BatchSpec:
    """``mc_fig10`` with ``n_runs`` samples (the first 1000 are those of the scenario)."""
    path = scenarios_dir() / "mc_fig10.toml"
    text = path.read_text(encoding="utf-8").replace("n = 1000", f"n = {max(n_runs, 1000)}")
    folder = Path(tempfile.mkdtemp(prefix="wmr-bench-spec-"))
    spec = folder / "mc_fig10.toml"
    spec.write_text(text, encoding="utf-8")
    batch = load_batch(spec)
    runs = batch.runs
    assert isinstance(runs, RunList)
    # a list made on demand, as the spec's own: the workers draw their runs from it
    return batch if len(runs) == n_runs else replace(batch, runs=runs.head(n_runs))


def _folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def executors(n_runs: int, repeats: int) -> None:
    """Runs per second of the local pool (1 and 2 workers) and of Dask (2 processes)."""
    from distributed import Client, LocalCluster

    batch = _mc_fig10(n_runs)
    fmu = default_fmu()

    def timed(go: Callable[[Path], None]) -> float:
        folder = Path(tempfile.mkdtemp(prefix="wmr-bench-batch-"))
        try:
            t0 = time.perf_counter()
            go(folder)
            return n_runs / (time.perf_counter() - t0)
        finally:
            shutil.rmtree(folder, ignore_errors=True)

    def local(workers: int) -> Callable[[Path], None]:
        def go(out: Path) -> None:
            result = run_batch(batch, out, BatchOptions(workers=workers, fmu_path=fmu),
                               progress=False)
            assert len(result.executed) == n_runs
        return go

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster, Client(cluster) as client:
        def on_dask(out: Path) -> None:
            result = run_batch(batch, out, BatchOptions(client=client, fmu_path=fmu),
                               progress=False)
            assert len(result.executed) == n_runs

        configs = {"local, 1 worker": local(1), "local, 2 workers": local(2),
                   "Dask, 2 workers": on_dask}
        samples: dict[str, list[float]] = {name: [] for name in configs}
        for round_ in range(repeats + 1):  # round 0 warms up
            for name, go in configs.items():
                rate = timed(go)
                if round_:
                    samples[name].append(rate)
    rates = {name: statistics.median(v) for name, v in samples.items()}
    one, two = rates["local, 1 worker"], rates["local, 2 workers"]
    print(f"batch throughput: {n_runs} runs of mc_fig10 per batch, median of {repeats}")
    print(f"{'executor':<18} {'runs/s':>8} {'speed-up vs 1':>14} {'overhead vs local 2':>20}")
    for name, rate in rates.items():
        overhead = f"{100.0 * (two / rate - 1.0):+.1f} %" if name != "local, 1 worker" else ""
        print(f"{name:<18} {rate:>8.1f} {rate / one:>14.2f} {overhead:>20}")


def phases(n_runs: int) -> None:
    """Where a run's time goes, in one process (no pool, no pipes)."""
    from wmr.adapters.fmi.compiled_law import CompiledLawController
    from wmr.adapters.fmi.robot import FmuPlant
    from wmr.adapters.mcap import McapOpener
    from wmr.apps.batch.journal import Journal
    from wmr.apps.run import run_to_log
    from wmr.core.closedloop import run_closed_loop

    batch = _mc_fig10(n_runs)
    fmu = default_fmu()
    folder = Path(tempfile.mkdtemp(prefix="wmr-bench-phases-"))
    times: dict[str, list[tuple[float, float]]] = {k: [] for k in (
        "FMU reset", "loop, no log", "loop, rows held (failed-only, converged)",
        "loop, full log", "journal line")}
    steps: list[int] = []

    def timed(name: str, fun: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """``fun(*args, **kwargs)``, its wall and CPU time (this process's) kept under
        ``name``."""
        wall, cpu = time.perf_counter(), time.process_time()
        out = fun(*args, **kwargs)
        times[name].append((time.perf_counter() - wall, time.process_time() - cpu))
        return out

    try:
        t0 = time.perf_counter()
        plant = FmuPlant(fmu)
        opened_s = time.perf_counter() - t0
        journal = Journal(folder / "journal.jsonl")
        with plant:
            for i, run in enumerate(batch.runs):
                timed("FMU reset", plant.reset, run.spec.params, run.spec.start)
                result = timed("loop, no log", run_closed_loop, run.spec, plant,
                               controller=CompiledLawController())
                steps.append(result.steps)
                # the three variants take turns on each run: a load that comes and goes
                # falls on all of them alike
                timed("loop, rows held (failed-only, converged)", run_to_log, run.spec,
                      McapOpener(folder / "held.mcap", durable=False), plant,
                      log=LogPolicy("failed"))
                # a new file per run, as in a batch (a rename over an existing file makes
                # ext4 write the new one out first)
                log = folder / f"full-{i}.mcap"
                record = timed("loop, full log", run_to_log, run.spec,
                               McapOpener(log, durable=False), plant)
                log.unlink()
                timed("journal line", journal.append, {
                    "run_id": run.run_id, "digest": run.digest, "fmu_sha256": "x",
                    "killed": False, "wall_s": 0.1, "worker": "1", "row": {},
                    "path": "runs/x.mcap", "log": {"size": 1, "mtime_ns": 1},
                    "record": record})
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    wall = {k: statistics.median(w for w, _ in v) for k, v in times.items()}
    cpu = {k: statistics.median(c for _, c in v) for k, v in times.items()}
    print(f"where a run's time goes: {n_runs} runs of mc_fig10, median per run "
          f"({statistics.median(steps):.0f} control steps), wall and CPU time of this process")
    print(f"{'phase':<42} {'ms wall':>8} {'ms CPU':>8} {'CPU vs loop':>12}")
    print(f"{'open the FMU (once per worker)':<42} {1e3 * opened_s:>8.1f}")
    for name in times:
        print(f"{name:<42} {1e3 * wall[name]:>8.2f} {1e3 * cpu[name]:>8.2f} "
              f"{cpu[name] / cpu['loop, no log']:>12.2f}")


@contextmanager
def dask_cluster(workers: int) -> Iterator[str]:
    """A Dask scheduler and ``workers`` worker processes (one thread each), started with the
    ``dask`` command line as a user would; yields the scheduler's address."""
    folder = Path(tempfile.mkdtemp(prefix="wmr-bench-dask-"))
    info = folder / "scheduler.json"
    dask = str(Path(sys.executable).with_name("dask"))
    scheduler = subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0",
                                  "--dashboard-address", ":0", "--scheduler-file", str(info)],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    worker = None
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        worker = subprocess.Popen([dask, "worker", "--scheduler-file", str(info),
                                   "--nworkers", str(workers), "--nthreads", "1",
                                   "--no-dashboard", "--local-directory", str(folder)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        from distributed import Client

        address = json.loads(info.read_text())["address"]
        with Client(address, timeout="60s") as client:
            client.wait_for_workers(workers, timeout=120)
        yield address
    finally:
        for proc in (worker, scheduler):
            if proc is not None:
                proc.terminate()
                proc.wait(30)
        shutil.rmtree(folder, ignore_errors=True)


def policies(n_runs: int, names: list[str], with_dask: bool) -> None:
    """One batch per log policy (and executor), side by side."""
    batch = _mc_fig10(n_runs)
    fmu = default_fmu()
    rows = []
    with dask_cluster(2) if with_dask else _nothing() as address:
        executors_: dict[str, dict[str, Any]] = {"local, 2 workers": {"workers": 2}}
        if address:
            executors_["Dask, 2 worker processes"] = {"scheduler": address}
        for name in names:
            for label, how in executors_.items():
                folder = Path(tempfile.mkdtemp(prefix="wmr-bench-policy-", dir=os.getcwd()))
                try:
                    t0 = time.perf_counter()
                    result = run_batch(batch, folder,
                                       BatchOptions(fmu_path=fmu, log=LogPolicy(name), **how),
                                       progress=False)
                    wall = time.perf_counter() - t0
                    assert len(result.executed) == n_runs
                    rows.append((name, label, wall, n_runs / wall, _folder_bytes(folder),
                                 result.logs_kept, dict(result.counts)))
                    print(*rows[-1], file=sys.stderr, flush=True)  # as they come: a long job
                finally:
                    shutil.rmtree(folder, ignore_errors=True)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{n_runs} runs of mc_fig10 per batch (parent's peak RSS over all: {peak_mb:.0f} MB)")
    print(f"{'log':<7} {'executor':<26} {'wall s':>8} {'runs/s':>8} {'disk MB':>9} "
          f"{'logs':>6}  counts")
    for name, label, wall, rate, disk, kept, counts in rows:
        print(f"{name:<7} {label:<26} {wall:>8.1f} {rate:>8.1f} {disk / 1e6:>9.1f} "
              f"{kept:>6}  {counts}")


#: The files of a batch folder counted as "journal and summary" (the logs are not).
RECORD_FILES = ("journal.jsonl", "summary.parquet", "summary.csv", "batch.json")


def scaling(n_runs: int, with_dask: bool, repeats: int, policy: str,
            workers: list[int] | None = None) -> None:
    """Runs per second, the parent's CPU per run and the bytes per run, per executor."""
    batch = _mc_fig10(n_runs)
    fmu = default_fmu()
    cores = os.cpu_count() or 1
    configs: dict[str, dict[str, Any]] = {
        f"local, {k} worker{'s' if k > 1 else ''}": {"workers": k}
        for k in (workers or [k for k in (1, 2, 4, 8) if k <= max(2, cores)])}
    samples: dict[str, list[tuple[float, float, float]]] = {name: [] for name in configs}
    with dask_cluster(2) if with_dask else _nothing() as address:
        if address:
            configs["Dask, 2 worker processes"] = {"scheduler": address}
            samples["Dask, 2 worker processes"] = []
        warm = replace(batch, runs=batch.runs.head(50)) if isinstance(batch.runs, RunList) \
            else batch
        for how in configs.values():  # imports, the forkserver, the Dask workers' FMU: once
            folder = Path(tempfile.mkdtemp(prefix="wmr-bench-warm-"))
            run_batch(warm, folder, BatchOptions(fmu_path=fmu, log=LogPolicy(policy), **how),
                      progress=False)
            shutil.rmtree(folder, ignore_errors=True)
        for _ in range(repeats):
            for name, how in configs.items():
                folder = Path(tempfile.mkdtemp(prefix="wmr-bench-scaling-", dir=os.getcwd()))
                try:
                    before = resource.getrusage(resource.RUSAGE_SELF)
                    t0 = time.perf_counter()
                    result = run_batch(batch, folder,
                                       BatchOptions(fmu_path=fmu, log=LogPolicy(policy), **how),
                                       progress=False)
                    wall = time.perf_counter() - t0
                    after = resource.getrusage(resource.RUSAGE_SELF)
                    assert len(result.executed) == n_runs
                    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
                    disk = sum((folder / f).stat().st_size for f in RECORD_FILES
                               if (folder / f).exists())
                    samples[name].append((n_runs / wall, cpu / n_runs, disk / n_runs))
                    print(name, *samples[name][-1], file=sys.stderr, flush=True)
                finally:
                    shutil.rmtree(folder, ignore_errors=True)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    med = {name: tuple(statistics.median(x[k] for x in v) for k in range(3))
           for name, v in samples.items()}
    one = next(iter(med.values()))[0]
    print(f"scaling: {n_runs} runs of mc_fig10 per batch, log {policy}, median of {repeats} "
          f"(configurations in turn; {cores} cores; load {os.getloadavg()[0]:.1f}; parent's "
          f"peak RSS {peak_mb:.0f} MB)")
    print(f"{'executor':<26} {'runs/s':>8} {'vs first':>8} {'parent CPU us/run':>18} "
          f"{'journal+summary B/run':>22}")
    for name, (runs_s, cpu_s, bytes_run) in med.items():
        print(f"{name:<26} {runs_s:>8.1f} {runs_s / one:>8.2f} {1e6 * cpu_s:>18.1f} "
              f"{bytes_run:>22.0f}")


def _idle_client_cpu(address: str, seconds: float = 5.0) -> float:
    """CPU seconds per second of this process with a Dask client of ``address`` connected and
    a batch's worker watch running, idle."""
    from distributed import Client

    from wmr.apps.batch.dask_exec import _WorkerWatch

    with Client(address, timeout="60s") as client:
        watch = _WorkerWatch(client, {})
        time.sleep(1.0)
        before = resource.getrusage(resource.RUSAGE_SELF)
        time.sleep(seconds)
        after = resource.getrusage(resource.RUSAGE_SELF)
        watch.stop()
    return ((after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)) / seconds


#: Range sizes of the ``costs`` measurement: large and small.
COST_RANGES = (1024, 128)


def costs(n_runs: int, with_dask: bool, repeats: int, workers: int) -> None:
    """The CPU of the batch's own process per range and per run, per executor."""
    import wmr.apps.batch.dask_exec as dask_exec
    import wmr.apps.batch.runner as runner

    big, small = COST_RANGES
    batch = _mc_fig10(n_runs)
    quarter = replace(batch, runs=batch.runs.head(n_runs // 4)) \
        if isinstance(batch.runs, RunList) else batch
    fmu = default_fmu()
    executors_: dict[str, dict[str, Any]] = {f"local, {workers} workers": {"workers": workers}}
    #: (runs, range size) -> CPU seconds, per executor
    samples: dict[str, dict[tuple[int, int], list[float]]] = {}
    #: the CPU of the summary's merge at the end (the parts read back, the summary written),
    #: per run, per executor; ``merges`` the last one's seconds
    merged: dict[str, list[float]] = {}
    merges: list[float] = []
    with dask_cluster(workers) if with_dask else _nothing() as address:
        if address:
            executors_[f"Dask, {workers} worker processes"] = {"scheduler": address}
        if n_runs < 8 * big * workers:
            raise SystemExit(f"costs: give at least {8 * big * workers} runs (8 ranges of "
                             f"{big} a worker)")
        warm = replace(batch, runs=batch.runs.head(50)) if isinstance(batch.runs, RunList) \
            else batch
        for how in executors_.values():  # imports, the forkserver, the Dask workers' FMU
            folder = Path(tempfile.mkdtemp(prefix="wmr-bench-warm-"))
            run_batch(warm, folder, BatchOptions(fmu_path=fmu, log=LogPolicy("failed"), **how),
                      progress=False)
            shutil.rmtree(folder, ignore_errors=True)
        per_s = {name: 0.0 for name in executors_}
        if address:
            per_s[f"Dask, {workers} worker processes"] = _idle_client_cpu(address)
        points = ((batch, big), (batch, small), (quarter, small))
        for _ in range(repeats):
            for name, how in executors_.items():
                for spec, size in points:
                    folder = Path(tempfile.mkdtemp(prefix="wmr-bench-costs-", dir=os.getcwd()))
                    saved = runner.MAX_BLOCK, dask_exec.MAX_CHUNK, runner._finish
                    runner.MAX_BLOCK = dask_exec.MAX_CHUNK = size  # type: ignore[misc]
                    runner._finish = _timed(runner._finish, merges)
                    try:
                        before = resource.getrusage(resource.RUSAGE_SELF)
                        t0 = time.perf_counter()
                        result = run_batch(spec, folder, BatchOptions(
                            fmu_path=fmu, log=LogPolicy("failed"), **how), progress=False)
                        wall = time.perf_counter() - t0
                        after = resource.getrusage(resource.RUSAGE_SELF)
                    finally:
                        runner.MAX_BLOCK, dask_exec.MAX_CHUNK, runner._finish = saved  # type: ignore[misc]
                        shutil.rmtree(folder, ignore_errors=True)
                    merged.setdefault(name, []).append(merges.pop() / len(spec.runs))
                    assert len(result.executed) == len(spec.runs)
                    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime
                                                                - before.ru_stime)
                    key = (len(spec.runs), size)
                    samples.setdefault(name, {}).setdefault(key, []).append(
                        cpu - per_s[name] * wall)
                    print(name, *key, f"{cpu:.3f} s CPU, {wall:.1f} s wall", file=sys.stderr,
                          flush=True)
    print(f"costs: the CPU of the batch's own process (the parent, or the Dask client), "
          f"mc_fig10, failed-only, median of {repeats} (configurations in turn; "
          f"{os.cpu_count()} cores; load {os.getloadavg()[0]:.1f})")
    print(f"{'executor':<26} {'ms/s':>5} {'C(N,1024) s':>11} {'C(N,128) s':>10} "
          f"{'C(N/4,128) s':>12} {'us/range':>9} {'us/run':>7} {'fixed s':>8} "
          f"{'us/run at 1024':>15} {'merge us/run':>13}")
    for name, by in samples.items():
        med = {k: statistics.median(v) for k, v in by.items()}
        c_big, c_small, c_quarter = (med[(n_runs, big)], med[(n_runs, small)],
                                     med[(n_runs // 4, small)])
        per_range = (c_small - c_big) / (n_runs / small - n_runs / big)
        per_run = (c_small - c_quarter) / (n_runs - n_runs // 4) - per_range / small
        fixed = c_big - n_runs * per_run - n_runs / big * per_range
        print(f"{name:<26} {1e3 * per_s[name]:>5.2f} {c_big:>11.3f} {c_small:>10.3f} "
              f"{c_quarter:>12.3f} "
              f"{1e6 * per_range:>9.0f} {1e6 * per_run:>7.2f} {fixed:>8.3f} "
              f"{1e6 * (per_run + per_range / big):>15.2f} "
              f"{1e6 * statistics.median(merged[name]):>13.2f}")


def backlog(n_runs: int, sizes: list[int], repeats: int) -> None:
    """The Dask client's CPU per task when tasks finish every few milliseconds."""
    import wmr.apps.batch.dask_exec as dask_exec

    batch = _mc_fig10(n_runs)
    fmu = default_fmu()
    samples: dict[int, list[tuple[float, float]]] = {size: [] for size in sizes}
    with dask_cluster(2) as address:
        per_s = _warm_client(batch, fmu, address)
        for _ in range(repeats):
            for size in sizes:
                saved = dask_exec.MAX_CHUNK
                dask_exec.MAX_CHUNK = size  # type: ignore[misc]  # as costs does
                try:
                    wall, cpu = _client_batch(batch, fmu, address, "backlog")
                finally:
                    dask_exec.MAX_CHUNK = saved  # type: ignore[misc]
                samples[size].append((wall, cpu - per_s * wall))
                print(size, f"{cpu:.3f} s CPU, {wall:.1f} s wall", file=sys.stderr, flush=True)
    print(f"backlog: {n_runs} runs of mc_fig10, failed-only, Dask, 2 worker processes, median "
          f"of {repeats} (configurations in turn; {os.cpu_count()} cores; load "
          f"{os.getloadavg()[0]:.1f}; the client idle {1e3 * per_s:.2f} ms/s, taken out)")
    print(f"{'runs a task':>11} {'tasks':>6} {'wall s':>7} {'runs/s':>7} {'ms a task':>10} "
          f"{'client CPU ms/task':>19}")
    for size, got in samples.items():
        wall = statistics.median(w for w, _ in got)
        cpu = statistics.median(c for _, c in got)
        tasks = -(-n_runs // min(size, dask_exec.task_runs(n_runs, 2)))  # 8 a thread at least
        print(f"{size:>11} {tasks:>6} {wall:>7.1f} {n_runs / wall:>7.0f} "
              f"{1e3 * wall / tasks:>10.2f} {1e3 * cpu / tasks:>19.3f}")


class _DropRows(WorkerPlugin):
    """Makes the worker's ranges return no summary rows (``drop``), or restores them."""

    def __init__(self, drop: bool) -> None:
        self.drop = drop

    def setup(self, worker: Any) -> None:
        import wmr.apps.batch.worker as batch_worker

        shipped = getattr(batch_worker, "_shipped_block_on", batch_worker.block_on)
        batch_worker._shipped_block_on = shipped  # type: ignore[attr-defined]

        def rowless(*args: Any, **kwargs: Any) -> Any:
            return replace(shipped(*args, **kwargs), table=b"")

        batch_worker.block_on = rowless if self.drop else shipped


def rows(n_runs: int, repeats: int) -> None:
    """The Dask client's CPU while its workers run, with and without the rows crossing."""
    from distributed import Client

    import wmr.apps.batch.runner as runner

    batch = _mc_fig10(n_runs)
    fmu = default_fmu()
    merges: list[float] = []
    finish = runner._finish
    runner._finish = _timed(finish, merges)
    samples: dict[bool, list[float]] = {False: [], True: []}
    try:
        with dask_cluster(2) as address, Client(address, timeout="60s") as client:
            per_s = _warm_client(batch, fmu, address)
            for _ in range(repeats):
                for drop in (False, True):
                    client.register_plugin(_DropRows(drop), name="wmr-bench-rows")
                    wall, cpu = _client_batch(batch, fmu, address, "rows")
                    samples[drop].append(cpu - per_s * wall - merges[-1])
                    print("rows dropped" if drop else "as shipped", f"{cpu:.3f} s CPU, "
                          f"merge {merges[-1]:.3f} s, {wall:.1f} s wall", file=sys.stderr,
                          flush=True)
    finally:
        runner._finish = finish
    tasks = -(-n_runs // 1024)
    print(f"rows: {n_runs} runs of mc_fig10, failed-only, Dask, 2 worker processes, {tasks} "
          f"tasks of 1,024 runs, median of {repeats} (in turn; load "
          f"{os.getloadavg()[0]:.1f}; the client idle {1e3 * per_s:.2f} ms/s and the merge "
          "taken out)")
    print(f"{'':<24} {'client CPU s':>12} {'ms a task':>10} {'us a run':>9}")
    for drop, got in samples.items():
        cpu = statistics.median(got)
        print(f"{'rows dropped' if drop else 'as shipped':<24} {cpu:>12.3f} "
              f"{1e3 * cpu / tasks:>10.2f} {1e6 * cpu / n_runs:>9.2f}")
    saved = statistics.median(samples[False]) - statistics.median(samples[True])
    print(f"{'the rows crossing':<24} {saved:>12.3f} {1e3 * saved / tasks:>10.2f} "
          f"{1e6 * saved / n_runs:>9.2f}")


def _warm_client(batch: BatchSpec, fmu: Path, address: str) -> float:
    """Warm the Dask cluster at ``address`` up with 50 runs of ``batch`` (the workers' FMU,
    imports); return the client's idle CPU per second (:func:`_idle_client_cpu`)."""
    warm = replace(batch, runs=batch.runs.head(50)) if isinstance(batch.runs, RunList) \
        else batch
    folder = Path(tempfile.mkdtemp(prefix="wmr-bench-warm-"))
    run_batch(warm, folder, BatchOptions(fmu_path=fmu, log=LogPolicy("failed"),
                                         scheduler=address), progress=False)
    shutil.rmtree(folder, ignore_errors=True)
    return _idle_client_cpu(address)


def _client_batch(batch: BatchSpec, fmu: Path, address: str, what: str
                  ) -> tuple[float, float]:
    """``batch``, failed-only, on the Dask cluster at ``address``, in a folder of the current
    one (removed after); its wall time and the CPU of this process (the client), seconds."""
    folder = Path(tempfile.mkdtemp(prefix=f"wmr-bench-{what}-", dir=os.getcwd()))
    try:
        before = resource.getrusage(resource.RUSAGE_SELF)
        t0 = time.perf_counter()
        result = run_batch(batch, folder, BatchOptions(fmu_path=fmu, log=LogPolicy("failed"),
                                                       scheduler=address), progress=False)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_SELF)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    assert len(result.executed) == len(batch.runs)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _timed(fun: Callable[..., Any], into: list[float]) -> Callable[..., Any]:
    """``fun``, appending the CPU time (this process's) of each call to ``into``."""
    def timed(*args: Any, **kwargs: Any) -> Any:
        before = time.process_time()
        try:
            return fun(*args, **kwargs)
        finally:
            into.append(time.process_time() - before)
    return timed


@contextmanager
def _nothing() -> Iterator[str]:
    yield ""


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what")
    e = sub.add_parser("executors")
    e.add_argument("n_runs", nargs="?", type=int, default=200)
    e.add_argument("repeats", nargs="?", type=int, default=3)
    ph = sub.add_parser("phases")
    ph.add_argument("n_runs", nargs="?", type=int, default=50)
    sc = sub.add_parser("scaling")
    sc.add_argument("n_runs", type=int)
    sc.add_argument("--dask", action="store_true")
    sc.add_argument("--repeats", type=int, default=1)
    sc.add_argument("--policy", default="failed", choices=("full", "failed", "none"))
    sc.add_argument("--workers", type=int, action="append",
                    help="local workers of a configuration (repeat; default 1, 2, 4, 8 up to "
                    "the cores)")
    co = sub.add_parser("costs")
    co.add_argument("n_runs", type=int)
    co.add_argument("--dask", action="store_true")
    co.add_argument("--repeats", type=int, default=2)
    co.add_argument("--workers", type=int, default=2)
    bl = sub.add_parser("backlog")
    bl.add_argument("n_runs", type=int)
    bl.add_argument("--runs-a-task", type=int, action="append")
    bl.add_argument("--repeats", type=int, default=3)
    ro = sub.add_parser("rows")
    ro.add_argument("n_runs", type=int)
    ro.add_argument("--repeats", type=int, default=3)
    po = sub.add_parser("policies")
    po.add_argument("n_runs", type=int)
    po.add_argument("--dask", action="store_true")
    po.add_argument("--policy", action="append", choices=("full", "failed", "none"))
    args = parser.parse_args(argv or ["executors"])
    if args.what == "phases":
        phases(args.n_runs)
    elif args.what == "scaling":
        scaling(args.n_runs, args.dask, args.repeats, args.policy, args.workers)
    elif args.what == "costs":
        costs(args.n_runs, args.dask, args.repeats, args.workers)
    elif args.what == "backlog":
        backlog(args.n_runs, args.runs_a_task or [2, 1024], args.repeats)
    elif args.what == "rows":
        rows(args.n_runs, args.repeats)
    elif args.what == "policies":
        policies(args.n_runs, args.policy or ["full", "failed", "none"], args.dask)
    else:
        executors(args.n_runs, args.repeats)


if __name__ == "__main__":
    main(sys.argv[1:])
