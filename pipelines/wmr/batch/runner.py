"""``wmr batch``: run every run of a spec, resumably, locally or on Dask.

Layout of the output folder::

    OUT/runs/<run_id>.mcap   one log per run
    OUT/journal.jsonl        one line per finished run (with its wall time and worker)
    OUT/summary.parquet      one row per finished run, sorted by run id (see summary.py)
    OUT/summary.csv          the same as CSV
    OUT/batch.json           counts and timings of the last invocation
    OUT/logs/worker-<n>.log  the FMU's messages (local workers)

Rerunning the same command skips the runs that are done (:mod:`wmr.batch.journal`) and redoes
the others, half-written logs included; a run is never reported twice.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from wmr.batch.journal import JOURNAL, Journal, log_complete
from wmr.batch.local import LocalPool, Outcome
from wmr.batch.spec import BatchSpec, spec_digest
from wmr.batch.summary import SummaryRow, status_counts, summary_table, write_summary
from wmr.batch.worker import DISK_FULL, FAULTS, Task
from wmr.durable import AtomicFile, partial_path, storage_error
from wmr.errors import ConfigError, DiskFullError, WmrError
from wmr.fmu.archive import file_sha256
from wmr.fmu.varmap import VariableMap, load_map

#: Default per-run wall-clock limit, s: generous (a 120 s simulated run takes about 1 s).
DEFAULT_RUN_TIMEOUT_S: Final = 600.0
#: A batch whose first runs (this many, or all) fail before their first step stops: the FMU
#: or the setup is broken, not the runs.
EARLY_STOP_RUNS: Final = 4


@dataclass
class BatchOutcome:
    """What :func:`run_batch` did.

    Attributes
    ----------
    out_dir
        The batch folder.
    total
        Runs in the spec.
    skipped
        Runs already done by an earlier invocation.
    executed
        Run ids executed by this invocation, in finishing order.
    counts
        Runs per status over the whole summary (done earlier or now).
    interrupted
        Stopped early (Ctrl-C or ``stop_after``); the summary holds the finished runs.
    wall_s
        Wall time of this invocation, s.
    """

    out_dir: Path
    total: int
    skipped: int
    executed: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    interrupted: bool = False
    wall_s: float = 0.0

    @property
    def finished(self) -> int:
        """Runs in the summary."""
        return sum(self.counts.values())


class _Lock:
    """An exclusive lock on the batch folder: two batches must not share a journal."""

    def __init__(self, out_dir: Path) -> None:
        self._fd = os.open(out_dir / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(self._fd)
            raise ConfigError("--out", f"another batch is running in {out_dir}",
                              "wait for it or give another --out folder") from None

    def release(self) -> None:
        fcntl.flock(self._fd, fcntl.LOCK_UN)
        os.close(self._fd)


def _write_atomic(path: Path, data: bytes) -> None:
    """Write ``path`` whole or not at all (fsynced; a full disk is a DiskFullError)."""
    out = AtomicFile(path, "file")
    try:
        out.write(data)
        out.commit()
    finally:
        out.abandon()


def run_batch(batch: BatchSpec, out_dir: str | os.PathLike[str], *,
              workers: int | None = None, scheduler: str | None = None, client: Any = None,
              run_timeout_s: float | None = DEFAULT_RUN_TIMEOUT_S,
              fmu_path: str | os.PathLike[str] | None = None, fmi_version: int = 3,
              progress: bool | None = None, stop_after: int | None = None,
              faults: Mapping[str, str] | None = None, dask_ship_logs: bool = False,
              var_map: VariableMap | None = None,
              on_outcome: Callable[[Outcome], None] | None = None) -> BatchOutcome:
    """Run the runs of ``batch`` not done yet into ``out_dir``; write the summary.

    Parameters
    ----------
    batch
        The expanded spec (:func:`wmr.batch.load_batch`).
    out_dir
        The batch folder (created).
    workers
        Local worker processes (default: one per core).  Ignored on Dask.
    scheduler, client
        A Dask scheduler address, or a :class:`distributed.Client`: run there.
    run_timeout_s
        Wall-clock limit per run, s; a run past it is a ``timeout`` row ("wall-clock limit").
        Local workers still busy ``max(1 s, 10 %)`` later are killed.  ``None``: no limit.
    fmu_path, fmi_version
        The FMU to drive; by default the spec's ``fmu``, else the project's own, built (or
        reused) once, here.
    var_map
        The FMU's variable map (:mod:`wmr.fmu.varmap`); by default the spec's ``fmu_map``.
    progress
        tqdm bar on stderr: ``None`` shows it on a terminal only.
    stop_after
        Test hook: behave as if Ctrl-C came after this many runs of this invocation.
    faults
        Test hook: run id -> ``"hang"`` or ``"crash"``.
    dask_ship_logs
        On Dask, have every worker send its logs back, as workers on other hosts do.
    on_outcome
        Called with each finished run (after its journal line is written).

    Returns
    -------
    BatchOutcome
        Counts and run ids; ``interrupted`` when Ctrl-C (or ``stop_after``) stopped it.

    Raises
    ------
    ConfigError
        Bad arguments, or the folder is in use by another batch.
    FmuError
        The workers cannot open the FMU.
    """
    from tqdm import tqdm

    from wmr.run import default_fmu

    t0 = time.perf_counter()
    if workers is not None and workers < 1:
        raise ConfigError("--workers", f"must be >= 1, got {workers}", "give e.g. --workers 2")
    if run_timeout_s is not None and not run_timeout_s > 0:
        raise ConfigError("--run-timeout", f"must be > 0, got {run_timeout_s}",
                          "give seconds, e.g. --run-timeout 600")
    for run_id, fault in (faults or {}).items():
        if fault not in FAULTS:
            raise ConfigError("faults", f"{run_id}: unknown fault {fault!r}",
                              f"use one of {FAULTS}")
    out = Path(out_dir)
    runs_dir = out / "runs"
    try:
        runs_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError("--out", f"cannot create {runs_dir}: {exc.strerror}",
                          "give a writable folder") from None
    fmu = Path(fmu_path) if fmu_path is not None else batch.fmu or default_fmu(fmi_version)
    if var_map is None and batch.fmu_map is not None:
        var_map = load_map(batch.fmu_map)
    fmu_sha = file_sha256(fmu)
    if var_map is not None:
        # a run through another map is another run: the journal must not reuse it
        fmu_sha += "+map:" + hashlib.sha256(
            json.dumps(var_map.as_dict(), sort_keys=True).encode()).hexdigest()[:16]
    lock = _Lock(out)
    try:
        journal = Journal(out / JOURNAL)
        records, rows = _resume(batch, journal.load(), fmu_sha, runs_dir, progress)
        result = BatchOutcome(out_dir=out, total=len(batch.runs), skipped=len(records))
        attachment = None
        if batch.path is not None and batch.source:
            attachment = out / f"spec-{batch.path.name}"
            if not attachment.exists() or attachment.read_bytes() != batch.source:
                _write_atomic(attachment, batch.source)
        tasks = _Tasks(batch, records, rows, run_timeout_s, faults or {})
        if not tasks:
            stream: Iterator[Outcome] = iter(())
        elif scheduler is not None or client is not None:
            from wmr.batch.dask_exec import DaskExecutor

            stream = DaskExecutor(fmu, out, scheduler=scheduler, client=client,
                                  attachment=attachment, ship_logs=dask_ship_logs,
                                  var_map=var_map).run(tasks)
        else:
            n = workers if workers is not None else (os.cpu_count() or 1)
            (out / "logs").mkdir(exist_ok=True)
            hard = None if run_timeout_s is None else run_timeout_s + max(1.0,
                                                                          0.1 * run_timeout_s)
            stream = LocalPool(fmu, runs_dir, n, hard_limit_s=hard, attachment=attachment,
                               log_dir=out / "logs", var_map=var_map).run(tasks)
        statuses = [str(r.get("status")) for r in records.values()]
        bar = tqdm(total=len(batch.runs), initial=len(records), unit="run", file=sys.stderr,
                   disable=_bar_off(progress), smoothing=0.05,
                   dynamic_ncols=True, desc=batch.name)
        counts = status_counts(statuses)

        def show() -> None:
            bar.set_postfix_str(f"ok {counts['converged']}, timeout {counts['timeout']}, "
                                f"failed {counts['failed']}", refresh=False)

        show()
        full: DiskFullError | None = None
        started = False  # a run of this invocation got past its first step
        unstarted = 0  # runs of this invocation that failed before it
        try:
            for outcome in stream:
                if outcome.record.get(DISK_FULL):
                    raise DiskFullError(str(outcome.record.get("message")))
                if outcome.log is not None:
                    _write_atomic(runs_dir / f"{outcome.run_id}.mcap", outcome.log)
                elif outcome.killed:
                    _recover_partial(runs_dir / f"{outcome.run_id}.mcap")
                journal.append({"run_id": outcome.run_id,
                                "digest": tasks.digests.pop(outcome.run_id),
                                "fmu_sha256": fmu_sha, "killed": outcome.killed,
                                "wall_s": round(outcome.wall_s, 6), "worker": outcome.worker,
                                "record": outcome.record})
                records[outcome.run_id] = outcome.record
                result.executed.append(outcome.run_id)
                if outcome.record.get("status") != "failed" or outcome.record.get("steps"):
                    started = True
                elif not outcome.killed:
                    unstarted += 1
                    if not started and unstarted >= min(EARLY_STOP_RUNS, len(tasks)):
                        raise WmrError(
                            f"the first {unstarted} runs all failed before their first step, "
                            f"stopping the batch: {outcome.record.get('message')}")
                status = str(outcome.record.get("status"))
                counts[status] = counts.get(status, 0) + 1
                show()
                bar.update(1)
                if on_outcome is not None:
                    on_outcome(outcome)
                if stop_after is not None and len(result.executed) >= stop_after \
                        and len(records) < len(batch.runs):
                    raise KeyboardInterrupt
        except KeyboardInterrupt:
            result.interrupted = True
        except DiskFullError as exc:
            full = exc
        finally:
            close = getattr(stream, "close", None)
            if close is not None:
                close()  # stops the workers
            bar.close()
            table = summary_table(rows.values(), batch.input_columns, records)
            result.counts = status_counts(table.column("status").to_pylist())
            result.wall_s = time.perf_counter() - t0
            try:
                _finish(out, table, result, batch, scheduler, client, workers, fmu, fmu_sha)
            except DiskFullError as exc:
                full = full or exc
        if full is not None:
            raise DiskFullError(f"{full}; {result.finished} of {result.total} runs finished "
                                "and are in the journal; free some space and rerun the same "
                                "command to finish the batch") from full
    finally:
        lock.release()
    return result


def _resume(batch: BatchSpec, journal: Mapping[str, Mapping[str, Any]], fmu_sha: str,
            runs_dir: Path, progress: bool | None
            ) -> tuple[dict[str, dict[str, Any]], dict[str, SummaryRow]]:
    """The journal's records still valid for ``batch``, and their summary rows, by run id.

    A line counts when its run is the spec's run of that id (same inputs: same digest), was
    run by the same FMU, and was killed by its executor or has a complete log.  Each line's
    run is made again to compare its digest (about 0.1 ms a run): only the runs done are
    made, not the spec.
    """
    from tqdm import tqdm

    runs = batch.runs
    index_of = getattr(runs, "index_of", None)
    records: dict[str, dict[str, Any]] = {}
    rows: dict[str, SummaryRow] = {}
    quick = len(journal) < 10_000  # under 2 s: no bar
    for run_id, line in tqdm(journal.items(), desc="checking the journal", unit="run",
                             file=sys.stderr, leave=False,
                             disable=True if quick else _bar_off(progress)):
        digest = line.get("digest")
        if line.get("fmu_sha256") != fmu_sha or not isinstance(digest, str) \
                or not run_id.endswith("-" + digest[:8]):
            continue
        if index_of is not None:
            i = index_of(run_id)
        else:  # any sequence of runs: ids start with their index
            head = run_id.partition("-")[0]
            i = int(head) if head.isdigit() and int(head) < len(runs) else None
        if i is None:
            continue
        run = runs[i]
        if run.run_id != run_id or (run.digest or spec_digest(run.spec)) != digest:
            continue
        if line.get("killed") or log_complete(runs_dir / f"{run_id}.mcap"):
            records[run_id] = dict(line["record"])
            rows[run_id] = SummaryRow.of(run)
    return records, rows


def _bar_off(progress: bool | None) -> bool | None:
    """tqdm's ``disable``: ``None`` shows the bar on a terminal only."""
    return None if progress is None else not progress


class _Tasks:
    """The runs of ``batch`` not in ``records``, made one by one as the executor asks.

    Each made run's summary row goes into ``rows`` and its digest into :attr:`digests` (until
    its journal line is written), so that nothing is made twice.
    """

    def __init__(self, batch: BatchSpec, records: Mapping[str, Any],
                 rows: dict[str, SummaryRow], run_timeout_s: float | None,
                 faults: Mapping[str, str]) -> None:
        self._runs = batch.runs
        self._done = {int(run_id.partition("-")[0]) for run_id in records}
        self._rows = rows
        self._timeout, self._faults = run_timeout_s, faults
        self.digests: dict[str, str] = {}

    def __len__(self) -> int:
        return len(self._runs) - len(self._done)

    def __iter__(self) -> Iterator[Task]:
        for i in range(len(self._runs)):
            if i in self._done:
                continue
            try:
                run = self._runs[i]
            except ConfigError as exc:  # a run made late, e.g. a sample drawn out of range
                raise ConfigError(exc.field, exc.problem, f"{exc.fix}; the runs finished are "
                                  "kept: rerun the same command after the fix") from None
            self.digests[run.run_id] = run.digest or spec_digest(run.spec)
            self._rows[run.run_id] = SummaryRow.of(run)
            yield Task(run.run_id, run.spec, self._timeout, self._faults.get(run.run_id))


def _recover_partial(log: Path) -> None:
    """A run killed by its executor leaves ``<id>.mcap.partial``: make it a finished log
    (what was lost is recorded in it), so that every tool reads the run's last seconds."""
    from wmr.mcaplog.recover import recover_log

    partial = partial_path(log)
    killed = log.with_name(log.name + ".killed")  # out of the way of the recovered log's own
    try:
        os.replace(partial, killed)
    except FileNotFoundError:
        return
    try:
        recover_log(killed, log, overwrite=True)
    except WmrError:  # nothing readable: the journal line says the run was killed
        return
    killed.unlink()


def _finish(out: Path, table: Any, result: BatchOutcome, batch: BatchSpec, scheduler: str | None,
            client: Any, workers: int | None, fmu: Path, fmu_sha: str) -> None:
    """Write the summary and ``batch.json``; a full disk is one :class:`DiskFullError`."""
    try:
        write_summary(table, out)
        _write_atomic(out / "batch.json", (json.dumps({
                "spec": str(batch.path) if batch.path else batch.name, "total": result.total,
                "finished": result.finished, "skipped": result.skipped,
                "executed": len(result.executed), "counts": result.counts,
                "interrupted": result.interrupted, "wall_s": round(result.wall_s, 3),
                "executor": (f"dask {scheduler or 'client'}" if scheduler or client
                             else f"local, {workers or os.cpu_count()} workers"),
                "fmu": fmu.name, "fmu_sha256": fmu_sha}, indent=1) + "\n").encode())
    except OSError as exc:
        raise storage_error(exc, out) from exc


__all__ = ["DEFAULT_RUN_TIMEOUT_S", "BatchOutcome", "run_batch"]
