"""``wmr batch``: run every run of a spec, resumably, locally or on Dask.

Layout of the output folder::

    OUT/runs/<run_id>.mcap   one log per run (as the log policy keeps them), in shards
                             OUT/runs/<shard>/<run_id>.mcap in a batch of over 1000 runs
    OUT/journal.jsonl        one line per finished run: id, status, digest, seal (journal.py)
    OUT/summary.parquet      one row per finished run, sorted by run id (see summary.py)
    OUT/summary.csv          the same as CSV (a batch of up to 1000 runs)
    OUT/.parts/              the summary rows of the runs finished since the last summary:
                             each range's written and fsynced before its journal lines
    OUT/batch.json           counts and timings of the last invocation
    OUT/logs/worker-<n>.log  the FMU's messages (local workers)

Rerunning the same command skips the runs that are done (:mod:`wmr.apps.batch.journal`) and redoes
the others, half-written logs included; a run is never reported twice.
"""

from __future__ import annotations

import fcntl
import itertools
import json
import math
import os
import struct
import sys
import time
import zlib
from array import array
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, overload

import numpy as np

import wmr.apps.batch.summary as summary_module
from wmr.adapters.fmi.varmap import VariableMap, load_map
from wmr.apps.batch.journal import (
    JOURNAL,
    Journal,
    body_crc,
    is_compact,
    line_check,
    log_complete,
    log_ends_whole,
    log_stamp,
    logged_record,
    row_bytes,
    run_digest,
)
from wmr.apps.batch.local import Killed, LocalPool, Outcome, check_open_files, made_up_record
from wmr.apps.batch.spec import BatchRun, BatchSpec, RunList, run_index
from wmr.apps.batch.summary import (
    CSV_MAX_RUNS,
    STATUSES,
    SUMMARY_PARQUET,
    SummaryRow,
    log_relpath,
    result_rows,
    summary_table,
    write_summary,
)
from wmr.apps.batch.worker import (
    FAULTS,
    KEPT,
    STARTED,
    STATUS_CODES,
    STATUS_MASK,
    Block,
    BlockResult,
    block_lines,
    fmu_digest,
    line_ends,
    run_code,
    table_bytes,
    table_of,
)
from wmr.apps.progress import count_progress
from wmr.apps.run import FULL_LOGS, LogPolicy
from wmr.config.naming import plural
from wmr.infra.durable import (
    AtomicFile,
    fsync_dir,
    open_own,
    partial_path,
    stop_signals_held,
    storage_error,
    write_all,
)
from wmr.infra.errors import ClusterError, ConfigError, DiskFullError, WmrError

#: Default per-run wall-clock limit, s: generous (a 120 s simulated run takes about 1 s).
DEFAULT_RUN_TIMEOUT_S: Final = 600.0
#: A batch whose first runs (this many, or all) fail before their first step stops: the FMU
#: or the setup is broken, not the runs.
EARLY_STOP_RUNS: Final = 4
#: A batch of more runs than this keeps, unless its spec or command line says otherwise, the
#: logs of its failed and timed-out runs only (``docs/batch.md``: a full log of a Fig. 10 run
#: is about 0.5 MB and a third of its run time); a smaller one keeps every log.
FULL_LOGS_MAX_RUNS: Final = 1000


def default_log_policy(n_runs: int) -> LogPolicy:
    """The log policy of a batch of ``n_runs`` runs whose spec and command line name none."""
    return LogPolicy("full" if n_runs <= FULL_LOGS_MAX_RUNS else "failed")


class RunIds(Sequence[str]):
    """Run ids in the order they were added, kept as the bytes their workers sent (each id
    followed by a newline: about 14 bytes a run, added a range at a time) rather than a Python
    string each (about 60 bytes, added one by one); made into strings when first read.

    A sequence of ``str`` (``len``, indexing, ``in``, iteration), equal to a list or tuple of
    the same ids.
    """

    def __init__(self, ids: Iterable[str] = ()) -> None:
        self._chunks: list[bytes] = []
        self._n = 0
        self._list: list[str] | None = None
        ids = list(ids)
        if ids:
            self.add("".join(f"{i}\n" for i in ids).encode("ascii"), len(ids))

    def add(self, chunk: bytes, count: int) -> None:
        """Add ``count`` ids, ``chunk`` holding each followed by a newline."""
        if count:
            self._chunks.append(chunk)
            self._n += count
            self._list = None

    def _ids(self) -> list[str]:
        if self._list is None:
            self._list = b"".join(self._chunks).decode("ascii").split("\n")[:-1]
        return self._list

    def __len__(self) -> int:
        return self._n

    @overload
    def __getitem__(self, index: int) -> str: ...

    @overload
    def __getitem__(self, index: slice) -> list[str]: ...

    def __getitem__(self, index: int | slice) -> str | list[str]:
        return self._ids()[index]

    def __iter__(self) -> Iterator[str]:
        return iter(self._ids())

    def __contains__(self, run_id: object) -> bool:
        return run_id in self._ids()

    def __eq__(self, other: object) -> bool:
        if isinstance(other, RunIds):
            return self._ids() == other._ids()
        if isinstance(other, list | tuple):
            return self._ids() == list(other)
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]  # mutable, as a list

    def __repr__(self) -> str:
        return repr(self._ids())


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
        Run ids executed by this invocation, in finishing order (a :class:`RunIds`: a
        sequence of ``str``, equal to the list of them).
    counts
        Runs per status over the whole summary (done earlier or now).
    interrupted
        Stopped early (Ctrl-C); the summary holds the finished runs.
    wall_s
        Wall time of this invocation, s.
    log
        The log policy of this invocation.
    logs_kept
        Runs of this invocation that kept a log.
    """

    out_dir: Path
    total: int
    skipped: int
    executed: RunIds = field(default_factory=RunIds)
    counts: dict[str, int] = field(default_factory=dict)
    interrupted: bool = False
    wall_s: float = 0.0
    log: LogPolicy = FULL_LOGS
    logs_kept: int = 0

    @property
    def finished(self) -> int:
        """Runs in the summary."""
        return sum(self.counts.values())


class _Lock:
    """An exclusive lock on the batch folder: two batches must not share a journal."""

    def __init__(self, out_dir: Path) -> None:
        self._fd = open_own(out_dir / ".lock", os.O_RDWR | os.O_CREAT, "batch lock")
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(self._fd)
            raise ConfigError("--out", f"another batch is running in {out_dir}",
                              "wait for it or give another --out folder") from None

    def release(self) -> None:
        fcntl.flock(self._fd, fcntl.LOCK_UN)
        os.close(self._fd)


@dataclass(frozen=True)
class _TestHooks:
    """What the executors' tests make a batch do; never set outside them (:func:`_test_hooks`).

    Attributes
    ----------
    stop_after
        Behave as if Ctrl-C came after this many runs of the invocation.
    faults
        Run id -> a fault of :data:`wmr.apps.batch.worker.FAULTS` (``"hang"``, ``"crash"``, ...).
    between_writes
        Called with the run ids of a range after its summary rows are on disk and before its
        journal lines are written (a test kills the batch there).
    """

    stop_after: int | None = None
    faults: Mapping[str, str] = field(default_factory=dict)
    between_writes: Callable[[Sequence[str]], None] | None = None


#: The hooks of the batches run in this context (a context variable: a test's hooks reach
#: neither another thread's batch nor the next test's); none outside :func:`_test_hooks`.
_HOOKS: ContextVar[_TestHooks | None] = ContextVar("wmr_batch_test_hooks", default=None)


@contextmanager
def _test_hooks(*, stop_after: int | None = None,
                faults: Mapping[str, str] | None = None,
                between_writes: Callable[[Sequence[str]], None] | None = None
                ) -> Iterator[None]:
    """Run the :func:`run_batch` calls inside the ``with`` block with test hooks.

    For the tests of the executors only (a crash, a hang, a Ctrl-C after N runs): they are
    not part of :func:`run_batch`'s signature, which is the API's.

    Raises
    ------
    ConfigError
        A fault that :data:`wmr.apps.batch.worker.FAULTS` does not know.
    """
    for run_id, fault in (faults or {}).items():
        if fault not in FAULTS:
            raise ConfigError("faults", f"{run_id}: unknown fault {fault!r}",
                              f"use one of {FAULTS}")
    token = _HOOKS.set(_TestHooks(stop_after, dict(faults or {}), between_writes))
    try:
        yield
    finally:
        _HOOKS.reset(token)


def _write_atomic(path: Path, data: bytes) -> None:
    """Write ``path`` whole or not at all (fsynced; a full disk is a DiskFullError)."""
    out = AtomicFile(path, "file")
    try:
        out.write(data)
        out.commit()
    finally:
        out.abandon()


@dataclass(frozen=True)
class BatchOptions:
    """Where and how :func:`run_batch` runs a batch: the executor, the FMU and the logs.

    Attributes
    ----------
    workers
        Local worker processes (default: one per core).  Ignored on Dask.
    scheduler, client
        A Dask scheduler address, or a :class:`distributed.Client`: run there.
    dask_ship_logs
        On Dask, have every worker send its logs back, as workers on other hosts do.
    run_timeout_s
        Wall-clock limit per run, s; a run past it is a ``timeout`` row ("wall-clock limit").
        Local workers still busy ``max(1 s, 10 %)`` later are killed.  ``None``: no limit.
    fmu_path, fmi_version
        The FMU to drive; by default the spec's ``fmu``, else the project's own, built (or
        reused) once, by :func:`run_batch`.
    var_map
        The FMU's variable map (:mod:`wmr.adapters.fmi.varmap`); by default the spec's
        ``fmu_map``.
    log
        Which runs keep a log, and how much of it; by default the spec's ``[log]``, else
        :func:`default_log_policy`.  Runs done earlier keep what they kept.
    """

    workers: int | None = None
    scheduler: str | None = None
    client: Any = None
    dask_ship_logs: bool = False
    run_timeout_s: float | None = DEFAULT_RUN_TIMEOUT_S
    fmu_path: str | os.PathLike[str] | None = None
    fmi_version: int = 3
    var_map: VariableMap | None = None
    log: LogPolicy | None = None


def run_batch(batch: BatchSpec, out_dir: str | os.PathLike[str],
              options: BatchOptions | None = None, *, progress: bool | None = None,
              on_outcome: Callable[[Outcome], None] | None = None) -> BatchOutcome:
    """Run the runs of ``batch`` not done yet into ``out_dir``; write the summary.

    Parameters
    ----------
    batch
        The expanded spec (:func:`wmr.apps.batch.load_batch`).
    out_dir
        The batch folder (created).
    options
        The executor, the FMU and the log policy (:class:`BatchOptions`); None: its defaults.
    progress
        Progress on stderr (:func:`wmr.apps.progress.count_progress`): ``None`` a tqdm bar
        on a terminal, else a line every 10 s; ``True`` also a bar in a notebook; ``False``
        nothing.
    on_outcome
        Called with each finished run (after its journal line is written).

    Returns
    -------
    BatchOutcome
        Counts and run ids; ``interrupted`` when Ctrl-C stopped it.

    Raises
    ------
    ConfigError
        Bad arguments, or the folder is in use by another batch.
    FmuError
        The workers cannot open the FMU.
    """
    o = BatchOptions() if options is None else options
    workers, scheduler, client, run_timeout_s = o.workers, o.scheduler, o.client, o.run_timeout_s
    fmu_path, fmi_version, var_map, log = o.fmu_path, o.fmi_version, o.var_map, o.log
    dask_ship_logs = o.dask_ship_logs
    from wmr.apps.run import default_fmu

    t0 = time.perf_counter()
    hooks = _HOOKS.get() or _TestHooks()
    if workers is not None and workers < 1:
        raise ConfigError("--workers", f"must be >= 1, got {workers}", "give e.g. --workers 2")
    if run_timeout_s is not None and not run_timeout_s > 0:
        raise ConfigError("--run-timeout", f"must be > 0, got {run_timeout_s}",
                          "give seconds, e.g. --run-timeout 600")
    out = Path(out_dir)
    runs_dir = out / "runs"
    try:
        runs_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError("--out", f"cannot create {runs_dir}: {exc.strerror}",
                          "give a writable folder") from None
    if scheduler is None and client is None:  # before the FMU is built (many files open)
        check_open_files(min(workers or os.cpu_count() or 1, max(1, len(batch.runs))))
    fmu = Path(fmu_path) if fmu_path is not None else batch.fmu or default_fmu(fmi_version)
    if var_map is None and batch.fmu_map is not None:
        var_map = load_map(batch.fmu_map)
    fmu_sha = fmu_digest(fmu, var_map)
    policy = log or batch.log or default_log_policy(len(batch.runs))
    lock = _Lock(out)
    journal = Journal(out / JOURNAL)
    try:
        parts = _Parts(out, len(batch.runs))
        ledger = _resume(batch, journal, fmu_sha, out, progress, parts)
        result = BatchOutcome(out_dir=out, total=len(batch.runs), skipped=ledger.n_done,
                              log=policy)
        attachment = None
        if batch.path is not None and batch.source:
            attachment = out / f"spec-{batch.path.name}"
            if not attachment.exists() or attachment.read_bytes() != batch.source:
                _write_atomic(attachment, batch.source)
        tasks = _Blocks(batch, ledger, run_timeout_s, hooks.faults, policy, fmu_sha,
                        outcomes=on_outcome is not None)
        if not tasks:
            stream: Iterator[Sequence[BlockResult | Killed]] = iter(())
        elif scheduler is not None or client is not None:
            from wmr.apps.batch.dask_exec import DaskExecutor

            stream = DaskExecutor(fmu, out, scheduler=scheduler, client=client,
                                  attachment=attachment, ship_logs=dask_ship_logs,
                                  var_map=var_map).run(tasks)
        else:
            n = workers if workers is not None else (os.cpu_count() or 1)
            (out / "logs").mkdir(exist_ok=True)
            hard = None if run_timeout_s is None else run_timeout_s + max(1.0,
                                                                          0.1 * run_timeout_s)
            stream = LocalPool(fmu, runs_dir, n, hard_limit_s=hard, attachment=attachment,
                               log_dir=out / "logs", var_map=var_map
                               ).run(tasks, block_runs=tasks.block_runs(n))
        # a bar on a terminal, a line every 10 s elsewhere, one bar in a notebook
        bar = count_progress(len(batch.runs), batch.name, "run", progress,
                             initial=ledger.n_done, smoothing=0.05, dynamic_ncols=True)
        counts = ledger.counts()

        def show() -> None:
            bar.set_postfix_str(f"ok {counts['converged']}, timeout {counts['timeout']}, "
                                f"failed {counts['failed']}", refresh=False)

        show()
        full: DiskFullError | None = None
        lost: ClusterError | None = None
        started = False  # a run of this invocation got past its first step
        unstarted = 0  # runs of this invocation that failed before it

        def settle(group: Sequence[BlockResult]) -> None:
            """Keep the summary rows of the runs some ranges finished (written and fsynced
            first, one ``fdatasync`` for the group, so that a journal line always has its row
            on disk), journal them (one write), count them: a group of ranges at a time (those
            that finished together), over their bytes (no Python work per run, unless
            ``on_outcome`` asks for each); raise when the batch must stop (its first runs all
            failed before their first step, a test's Ctrl-C) after journalling the runs up to
            the one that says so (the group's later ranges are not kept: run again on
            resume)."""
            nonlocal started, unstarted
            taken: list[tuple[BlockResult, int]] = []
            stop: BaseException | None = None
            n_taken = 0
            for res in group:
                take = len(res)
                if not take:
                    continue
                if not started:  # the first runs: do they all fail before their first step?
                    for k, code in enumerate(res.codes):
                        if code & STARTED:
                            started = True
                            break
                        if not res.killed:
                            unstarted += 1
                            if unstarted >= min(EARLY_STOP_RUNS, len(tasks)):
                                take, stop = k + 1, WmrError(
                                    f"the first {unstarted} runs all failed before their "
                                    f"first step, stopping the batch: {_message(res, k)}")
                                break
                if hooks.stop_after is not None:
                    at = max(1, hooks.stop_after - len(result.executed) - n_taken)
                    if at <= take and ledger.n_done + n_taken + at < len(batch.runs) \
                            and (stop is None or at < take):
                        take, stop = at, KeyboardInterrupt()
                taken.append((res, take))
                n_taken += take
                if stop is not None:
                    break
            # a stop signal waits until the group's rows, lines and marks agree: raised
            # between them, the summary would hold a row whose line was never written
            with stop_signals_held():
                kept: list[tuple[BlockResult, int, bytes, bytes, bytes, Any]] = []
                for res, take in taken:
                    lines, ids, codes = res.lines, res.ids, res.codes
                    ends = line_ends(lines)
                    if take < len(res):
                        lines, codes = lines[:ends[take - 1]], codes[:take]
                        ids = "".join(f"{r}\n" for r in res.run_ids()[:take]).encode("ascii")
                    kept.append((res, take, lines, ids, codes, ends))
                    for k, rel, data in res.logs:  # logs that came back as bytes: before the lines
                        if k < take:
                            (out / rel).parent.mkdir(exist_ok=True)
                            _write_atomic(out / rel, data)
                    parts.add(res.table, res.indices[:take],
                              None if take == len(res) else set(res.run_ids()[:take]),
                              durable=False)
                if not kept:
                    if stop is not None:
                        raise stop
                    return
                parts.sync()  # every row of the group on disk, before any of its lines
                if hooks.between_writes is not None:
                    hooks.between_writes([r for res, take, *_ in kept
                                          for r in res.run_ids()[:take]])
                offset = journal.append_lines(b"".join(lines for _, _, lines, *_ in kept))
                parts.commit()
                for res, take, lines, ids, codes, ends in kept:
                    ledger.mark_many(res.indices[:take],
                                     offset + np.concatenate(([0], ends[:take - 1])), codes)
                    offset += len(lines)
                    result.executed.add(ids, take)
                    flags = np.frombuffer(codes, np.uint8)
                    result.logs_kept += int(np.count_nonzero(flags & KEPT))
                    per_code = np.bincount(flags & STATUS_MASK, minlength=4)
                    for status, code in STATUS_CODES.items():
                        counts[status] += int(per_code[code])
            show()
            bar.update(n_taken)
            if on_outcome is not None:
                for res, take, *_ in kept:
                    logs = {k: data for k, _, data in res.logs}
                    assert res.outcomes is not None  # the blocks asked for them
                    for k, (run_id, (record, wall)) in enumerate(zip(res.run_ids()[:take],
                                                                     res.outcomes[:take],
                                                                     strict=True)):
                        on_outcome(Outcome(run_id, dict(record), wall, res.killed, logs.get(k),
                                           res.worker))
            if stop is not None:
                raise stop

        try:
            for items in stream:  # the ranges that finished together
                group: list[BlockResult] = []
                for item in items:
                    group.append(_killed(item, batch, out, fmu_sha) if isinstance(item, Killed)
                                 else item)
                    if group[-1].stop is not None:  # the ranges after it are not kept
                        break
                settle(group)
                last = group[-1] if group else None
                if last is not None and last.stop is not None and last.stop[0] == "disk_full":
                    raise DiskFullError(last.stop[1])
                if last is not None and last.stop is not None:  # a run made late, e.g. a
                    # sample drawn out of range
                    field_, problem, fix = last.stop[1:]
                    raise ConfigError(field_, problem, f"{fix}; the runs finished are kept: "
                                      "rerun the same command after the fix")
        except KeyboardInterrupt:
            result.interrupted = True
        except DiskFullError as exc:
            full = exc
        except ClusterError as exc:  # the runs not journalled were not run: not results
            lost = exc
        finally:
            close = getattr(stream, "close", None)
            if close is not None:
                close()  # stops the workers
            bar.close()
            result.counts = ledger.counts()
            result.wall_s = time.perf_counter() - t0
            try:
                _finish(out, _summary_chunks(batch, journal, ledger, parts), result, batch,
                        scheduler, client, workers, fmu, fmu_sha)
                parts.clear()  # only now: until the summary is written they hold the results
            except DiskFullError as exc:
                full = full or exc
        if full is not None:
            raise DiskFullError(f"{full}; {result.finished} of {result.total} runs finished "
                                "and are in the journal; free some space and rerun the same "
                                "command to finish the batch") from full
        if lost is not None:
            n = result.finished
            raise ClusterError(
                f"{lost.problem} after {n} of {plural(result.total, 'run')}" if n else
                lost.problem, (f"the {n} finished are kept; " if n else "")
                + f"{lost.fix} to run the {result.total - n} missing", lost.cause) from lost
    finally:
        journal.close()
        lock.release()
    return result


class _Ledger:
    """Which runs of a batch are finished, and where their journal lines are: 10 bytes a run
    (a million-run batch keeps 10 MB, not its records), whatever the records hold; numpy
    arrays, marked a range at a time (:meth:`mark_many`).

    A run's summary row is in the batch's parts (:class:`_Parts`), or, for a line of an older
    batch (its whole record), read back from the journal (``from_journal``,
    :func:`_summary_chunks`), a block of rows at a time.
    """

    def __init__(self, n_runs: int) -> None:
        self.offsets = np.full(n_runs, -1, np.int64)
        #: each run's status code (:data:`~wmr.apps.batch.worker.STATUS_CODES`, 0: not done)
        self._status = np.zeros(n_runs, np.uint8)
        #: 1 where the run's summary row is made from its journal line (an older batch's)
        self.from_journal = np.zeros(n_runs, np.uint8)
        self.n_done = 0

    def done(self, index: int) -> bool:
        return bool(self.offsets[index] >= 0)

    def mark(self, index: int, offset: int, status: object, from_journal: bool = False
             ) -> None:
        """Run ``index`` finished, with ``status``; its journal line starts at ``offset``
        (and holds its record when ``from_journal``)."""
        if self.offsets[index] < 0:
            self.n_done += 1
        self.offsets[index] = offset
        self._status[index] = STATUS_CODES.get(str(status), 0)
        self.from_journal[index] = from_journal

    def mark_many(self, indices: Sequence[int], offsets: Any, codes: bytes) -> None:
        """The runs ``indices`` (increasing; a ``range`` of step 1 or a sequence) finished,
        their journal lines starting at ``offsets``, with the statuses of ``codes`` (a byte
        a run, :class:`~wmr.apps.batch.worker.BlockResult`'s)."""
        where: Any = slice(indices[0], indices[-1] + 1) if isinstance(indices, range) \
            else np.asarray(indices, np.int64)
        self.n_done += int(np.count_nonzero(self.offsets[where] < 0))
        self.offsets[where] = offsets
        self._status[where] = np.frombuffer(codes, np.uint8) & STATUS_MASK
        self.from_journal[where] = 0

    def unmark(self, index: int) -> None:
        if self.offsets[index] >= 0:
            self.n_done -= 1
        self.offsets[index] = -1
        self._status[index] = 0
        self.from_journal[index] = 0

    def counts(self) -> dict[str, int]:
        """Finished runs per status (the three statuses always present)."""
        per_code = np.bincount(self._status, minlength=4)
        return {status: int(per_code[code]) for status, code in STATUS_CODES.items()}

    def todo(self, lo: int, hi: int) -> Any:
        """The indices of the runs from ``lo`` to ``hi`` (excluded) not finished, increasing
        (a numpy array)."""
        return np.flatnonzero(self.offsets[lo:hi] < 0) + lo

    def finished(self) -> Iterator[tuple[int, int]]:
        """``(index, journal offset)`` of each finished run, in index (= run id) order."""
        done = np.flatnonzero(self.offsets >= 0)
        return zip(done.tolist(), self.offsets[done].tolist(), strict=True)


def _bar_off(progress: bool | None) -> bool | None:
    """tqdm's ``disable``: ``None`` shows the bar on a terminal only."""
    return None if progress is None else not progress


def _resume(batch: BatchSpec, journal: Journal, fmu_sha: str, out: Path,
            progress: bool | None, parts: _Parts | None = None) -> _Ledger:
    """The runs of ``batch`` that the journal says are done, as a :class:`_Ledger`.

    A line counts when its run is the spec's run of that id (same inputs: same digest), was
    run by the same FMU, and was killed by its executor or has a complete log; the last line
    of a run wins.  Each line's run is made again to compare its digest (about 0.2 ms a run):
    only the runs done are made, not the spec.  A compact line (:func:`~wmr.apps.batch.
    journal.compact_line`) counts when, besides, a summary row of its run in ``parts`` (the
    ranges of a batch killed before its summary) or ``summary.parquet`` matches its seal
    (:func:`_carry`); a line of an older batch holds its record and is checked against the
    run's log (:func:`_verified`).
    """
    from tqdm import tqdm

    runs = batch.runs
    ledger = _Ledger(len(runs))
    try:
        size = journal.path.stat().st_size
    except FileNotFoundError:
        if parts is not None:
            parts.drop_leftovers()
        return ledger
    # over about 10,000 lines (2 s) the check gets its own bar
    bar = tqdm(total=size, desc="checking the journal", unit="B", unit_scale=True,
               file=sys.stderr, leave=False,
               disable=True if size < 10_000_000 else _bar_off(progress))
    remade: dict[int, tuple[dict[str, Any], str]] = {}  # by run index: the last line wins
    seals = _Seals(len(runs))
    with bar:
        for offset, line in journal.scan():
            bar.update(offset - bar.n)
            i = run_index(str(line["run_id"]))
            if i is None or i >= len(runs):
                continue
            remade.pop(i, None)
            if is_compact(line):
                run = runs[i]
                if line["run_id"] != run.run_id or line["status"] not in STATUSES \
                        or line["digest"] != run_digest(run.digest, fmu_sha):
                    ledger.unmark(i)
                else:
                    ledger.mark(i, offset, line["status"])
                    seals.keep(i, line)
                continue
            checked, differs = _verified(runs[i], line, fmu_sha, out)
            if checked is not None and batch.optimal is not None and not checked.get("killed") \
                    and not checked["record"].get("optimal_status"):
                # done before the spec asked for the optimum (or its record was made again from
                # the log, which holds the run's alone): run it again with its optimum
                checked = None
            if checked is None:
                ledger.unmark(i)
            else:
                ledger.mark(i, offset, checked["record"].get("status"), from_journal=True)
                if checked is not line:
                    remade[i] = (checked, differs)
    for i, (checked, _) in remade.items():  # written again, sealed: the summary reads them
        ledger.mark(i, journal.append(checked), checked["record"].get("status"),
                    from_journal=True)
    edited = [(runs[i].run_id, differs) for i, (_, differs) in remade.items() if differs]
    if edited:
        print(f"wmr: {journal.path}: {plural(len(edited), 'line')} did not match the spec or "
              f"the run's log (first: run {edited[0][0]}, {edited[0][1]}): made again from "
              "them, not trusted", file=sys.stderr)
    if parts is not None:
        _carry(batch, ledger, seals, out, parts)
    return ledger


class _Seals:
    """What the resume keeps of each compact journal line until it has found the run's
    summary row: the line's seal, the CRC of the rest of it, of its run id, and whether its
    executor killed the run (13 bytes a run)."""

    def __init__(self, n_runs: int) -> None:
        self.seal = array("L", [0]) * n_runs
        self.body = array("L", [0]) * n_runs
        self.run_id = array("L", [0]) * n_runs
        self.killed = bytearray(n_runs)
        self.any = False

    def keep(self, index: int, line: Mapping[str, Any]) -> None:
        self.any = True
        self.seal[index] = int(line["seal"], 16)
        self.body[index] = body_crc(line)
        self.run_id[index] = zlib.crc32(str(line["run_id"]).encode())
        self.killed[index] = bool(line.get("killed"))


def _carry(batch: BatchSpec, ledger: _Ledger, seals: _Seals, out: Path, parts: _Parts) -> None:
    """Find the summary row of each run done by a compact journal line, in the parts a killed
    batch left and in ``summary.parquet``: a row counts when its run id, status and results
    match the line's seal, and its log, if it kept one, ends whole (:func:`~wmr.apps.batch.
    journal.log_ends_whole`).  The rows found are kept
    as this invocation's parts (in the summary's columns); the runs without one are not done
    (said in one line: they are run again); the parts of before are then removed."""
    import pyarrow as pa

    runs, n_runs = batch.runs, len(batch.runs)
    optimal = batch.optimal is not None
    schema = summary_table([], batch.input_columns, {}, optimal=optimal).schema
    found = bytearray(n_runs)
    leftovers = parts.leftovers()
    for table in itertools.chain(_summary_blocks(out), parts.read(leftovers)) if seals.any \
            else ():
        ids = table["run_id"].to_pylist()
        take: list[int] = []
        took: list[int] = []  # their run indices
        for k, (run_id, res) in enumerate(zip(ids, result_rows(table), strict=True)):
            i = run_index(str(run_id))
            if i is None or i >= n_runs or found[i] or not ledger.done(i) \
                    or ledger.from_journal[i] \
                    or zlib.crc32(str(run_id).encode()) != seals.run_id[i]:
                continue
            try:
                sealed = zlib.crc32(row_bytes(res), seals.body[i]) == seals.seal[i]
            except ValueError:  # a value JSON cannot hold: not a row a worker made
                sealed = False
            if not sealed or (optimal and not seals.killed[i] and not res.get("optimal_status")):
                continue
            rel = res.get("mcap")
            if rel is not None and not seals.killed[i]:
                safe = _line_log({"run_id": run_id, "path": rel})
                if safe is None or not log_ends_whole(out / safe):
                    continue
            found[i] = 1
            take.append(k)
            took.append(i)
        if not take:
            continue
        kept = table.take(pa.array(take, pa.int64()))
        if kept.schema != schema:  # another spec's columns: made again in the summary's
            records = dict(zip(kept["run_id"].to_pylist(), result_rows(kept), strict=True))
            kept = summary_table([SummaryRow.of(runs[run_index(r) or 0]) for r in records],
                                 batch.input_columns, records,
                                 {r: rec.get("mcap") for r, rec in records.items()},
                                 optimal=optimal)
        parts.add(kept, took)
    missing = [i for i, _ in ledger.finished() if not ledger.from_journal[i] and not found[i]]
    for i in missing:
        ledger.unmark(i)
    if missing:
        print(f"wmr: {out / JOURNAL}: {plural(len(missing), 'journalled run')} had no summary "
              f"row matching its line, or no finished log (first: run {runs[missing[0]].run_id}"
              "): run again", file=sys.stderr)
    parts.drop(leftovers)


def _summary_blocks(out: Path) -> Iterator[Any]:
    """The rows of the batch's ``summary.parquet``, :data:`SUMMARY_BLOCK` at a time; none
    when it is missing or unreadable (its runs are then run again)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = out / SUMMARY_PARQUET
    if path.is_symlink() or not path.is_file():
        return
    try:
        with pq.ParquetFile(path) as source:
            for block in source.iter_batches(batch_size=SUMMARY_BLOCK):
                yield pa.Table.from_batches([block])
    except (OSError, ValueError, pa.ArrowException):  # damaged: its runs are run again
        return


def _verified(run: BatchRun, line: dict[str, Any], fmu_sha: str, out: Path
              ) -> tuple[dict[str, Any] | None, str]:
    """Journal ``line`` checked as a finished run of ``run``.

    Returns ``(line, "")`` when it holds (sealed, its row the spec's, its log unchanged);
    ``(corrected, what)`` when its row or record had to be made again from the spec and the
    log (``what`` names the first field that differed, ``""`` if only the seal was missing);
    ``(None, "")`` when the run must be done again (another run, another FMU, no finished
    log, or a killed run or one without a log whose line was edited: there is no log record
    to make it from).  The log is where the line says (``path``, relative to the batch
    folder ``out``; ``runs/<run_id>.mcap`` for a line written before lines said it, the
    layout of the batches of that time); a line without a log (``path`` null: its log policy
    kept none) counts when sealed.
    """
    if line.get("run_id") != run.run_id or line.get("fmu_sha256") != fmu_sha \
            or line.get("digest") != run.digest:
        return None, ""
    # a line of before held its summary row (its inputs); one of now has none: the inputs
    # are drawn again from the spec, as the run was just made to compare its digest
    row = _row_json(run) if "row" in line else None
    same_row = row is None or line.get("row") == row
    with_row = {**line, "row": row} if row is not None else dict(line)
    sealed = line.get("check") == line_check(line) \
        and line["record"].get("status") in STATUSES
    if line.get("killed"):
        if not sealed:
            return None, ""
        return (line, "") if same_row else (with_row, "row")
    rel = _line_log(line)
    if rel is None:  # no log: its policy kept none (the sealed line is the record), or the
        # line names a path that is not followed
        if not sealed or line.get("path", "") is not None:
            return None, ""
        return (line, "") if same_row else (with_row, "row")
    log = out / rel
    stamp = line.get("log") if sealed else None
    if sealed and log_complete(log, stamp if isinstance(stamp, dict) else None):
        if same_row:
            return line, ""
        return with_row, "row (the spec's input columns changed)"
    record = logged_record(log)
    if record is None:
        return None, ""
    corrected = {**with_row, "record": record, "log": log_stamp(log)}
    corrected.pop("check", None)
    return corrected, _first_difference(line, corrected)


def _first_difference(line: Mapping[str, Any], corrected: Mapping[str, Any]) -> str:
    """The first field of a journal line that its corrected line changes (``"row.inputs.
    gains.K_ps"``, ``"record.status"``), ``""`` when only the seal and the log's stamp do."""
    for part in ("row", "record"):
        old, new = line.get(part), corrected.get(part)
        if old == new:
            continue
        if not isinstance(old, dict) or not isinstance(new, dict):
            return part
        inner = new.get("inputs", {}) if part == "row" else {}
        for key in new:
            if key == "mcap":  # where the log was written; the summary takes the line's path
                continue
            if key == "inputs" and isinstance(old.get("inputs"), dict):
                diff = [k for k in inner if old["inputs"].get(k, ...) != inner[k]] \
                    or [k for k in old["inputs"] if k not in inner]
                if diff:
                    return f"row.inputs.{_cut(diff[0])}"
            elif old.get(key) != new[key]:
                return f"{part}.{key}"
        if set(old) - set(new):
            return f"{part}.{_cut(sorted(old)[0])}"
    return ""


def _cut(text: str, limit: int = 40) -> str:
    return text if len(text) <= limit else text[:limit] + "..."


def _line_log(line: Mapping[str, Any]) -> str | None:
    """The log of a journal line, relative to the batch folder; ``None`` when it has none, or
    a path that is not a log under ``runs/`` (a damaged or edited line is not followed)."""
    if "path" not in line:
        return log_relpath(str(line["run_id"]))
    rel = line["path"]
    if not isinstance(rel, str):
        return None
    parts = rel.split("/")
    if parts[0] != "runs" or not rel.endswith(".mcap") or any(p in ("", ".", "..")
                                                               for p in parts):
        return None
    return rel


def _row_json(run: BatchRun) -> dict[str, Any]:
    """A run's summary row as a journal line holds it (NaN as null: the journal is JSON)."""
    return {"name": run.spec.name, "base": run.base, "variant": run.variant,
            "inputs": {k: None if isinstance(v, float) and math.isnan(v) else v
                       for k, v in run.inputs.items()}}


def _row_of(index: int, line: Mapping[str, Any], batch: BatchSpec) -> SummaryRow:
    """The summary row of a journal line; made again from the spec when the line has none
    (lines leave the inputs to the spec; lines of long ago held no row either) or other input
    columns (the spec was edited without
    changing the run, e.g. a one-value grid axis added: the new column must not be empty)."""
    row = line.get("row")
    if not isinstance(row, dict) or not _row_fits(row, batch.input_columns):
        return SummaryRow.of(batch.runs[index])
    runs = batch.runs
    # the controller and draw follow from the index (the journal's lines, as before, hold
    # neither): a block of rows is not made again for them
    controller, draw = runs.label(index) if isinstance(runs, RunList) else (
        runs[index].controller, runs[index].draw)
    return SummaryRow(str(line["run_id"]), row["name"], row["base"], row["variant"],
                      {k: math.nan if v is None else v if isinstance(v, str) else float(v)
                       for k, v in row["inputs"].items()}, controller, draw)


def _row_fits(row: Mapping[str, Any], columns: Sequence[str]) -> bool:
    """Whether a journal line's summary row has the spec's input columns and sound values (an
    edited or damaged line is not trusted)."""
    inputs = row.get("inputs")
    if not isinstance(inputs, dict) or set(inputs) != set(columns):
        return False
    if not all(isinstance(row.get(k), str) for k in ("name", "base", "variant")):
        return False
    return all(v is None or isinstance(v, str)
               or (isinstance(v, int | float) and not isinstance(v, bool))
               for v in inputs.values())


def _in_order(column: Any) -> bool:
    """Whether the Arrow string ``column`` is in increasing order already (two comparisons
    over the column, not a sort: about 0.01 against 0.27 us a run)."""
    import pyarrow.compute as pc

    if len(column) < 2:
        return True
    return bool(pc.all(pc.less_equal(column.slice(0, len(column) - 1),
                                     column.slice(1))).as_py())


#: Rows of the summary built (and written) at a time.
SUMMARY_BLOCK: Final = 10_000


def _summary_chunks(batch: BatchSpec, journal: Journal, ledger: _Ledger,
                    parts: _Parts | None = None) -> Iterator[Any]:
    """The summary of the finished runs as Arrow tables of the runs ``k * SUMMARY_BLOCK`` to
    ``(k + 1) * SUMMARY_BLOCK``, in run-id order (at least one table, maybe empty): the rows
    in ``parts`` (the workers' of this invocation, those the resume found), and those of
    older journal lines read back from the journal."""
    import pyarrow as pa

    n_runs, first = len(batch.runs), True
    offsets = ledger.offsets
    for chunk, lo in enumerate(range(0, n_runs, SUMMARY_BLOCK)):
        hi = min(lo + SUMMARY_BLOCK, n_runs)
        made = parts.tables(chunk) if parts is not None else []
        older = (offsets[lo:hi] >= 0) & (ledger.from_journal[lo:hi] != 0)
        if parts is not None:  # a run with a row in the parts is not read from its line
            older &= ~parts.has[lo:hi]
        picked = np.flatnonzero(older) + lo
        block = list(zip(picked.tolist(), offsets[picked].tolist(), strict=True))
        try:
            lines = list(journal.read_at(off for _, off in block))
        except ValueError as exc:
            raise WmrError(f"{exc}: the journal changed while the batch ran; rerun the same "
                           "command to check it again and rewrite the summary") from None
        if not lines and not made and not first:
            continue
        first = False
        records = {str(line["run_id"]): line["record"] for line in lines}
        logs = {str(line["run_id"]): _line_log(line) for line in lines}
        read = summary_table([_row_of(i, line, batch) for (i, _), line in zip(block, lines,
                                                                              strict=True)],
                             batch.input_columns, records, logs,
                             optimal=batch.optimal is not None)
        if not made:
            yield read
            continue
        merged = pa.concat_tables([read, *made])
        yield merged if _in_order(merged["run_id"]) else merged.sort_by("run_id")
    if first:  # no run at all
        yield summary_table([], batch.input_columns, {}, optimal=batch.optimal is not None)


#: Most runs in a local worker's block: large enough that the parent's cost per block (a
#: message each way, one journal write, a summary part) is a few microseconds a run, small
#: enough that a block of ``mc_fig10`` takes a fraction of a second (progress, the last
#: blocks shared out evenly).
MAX_BLOCK: Final = 128


class _Blocks:
    """The runs of ``batch`` not done in ``ledger``, in blocks of consecutive indices, made as
    the executor takes them.  The parent draws no run: each block carries the spec's run list
    (a :class:`RunList`, a few kB) and its indices, and the worker draws its runs.  A block
    never crosses a multiple of :data:`SUMMARY_BLOCK` (the summary is merged that many rows at
    a time)."""

    def __init__(self, batch: BatchSpec, ledger: _Ledger, run_timeout_s: float | None,
                 faults: Mapping[str, str], log: LogPolicy, fmu_sha: str,
                 outcomes: bool = False) -> None:
        self._batch = batch
        self._ledger = ledger
        self._n = len(batch.runs) - ledger.n_done
        self._timeout, self._faults, self._log, self._fmu_sha = (run_timeout_s, faults, log,
                                                                 fmu_sha)
        self._outcomes = outcomes

    def __len__(self) -> int:
        return self._n

    def block_runs(self, workers: int) -> int:
        """Runs per block for ``workers`` workers: each gets at least 8 blocks, none more than
        :data:`MAX_BLOCK` runs (1 for a small batch: a run at a time, as it always was)."""
        return max(1, min(MAX_BLOCK, self._n // (8 * max(1, workers))))

    def blocks(self, size: int) -> Iterator[Block]:
        n_runs = len(self._batch.runs)
        for lo in range(0, n_runs, SUMMARY_BLOCK):  # the runs not done, a chunk at a time
            todo = self._ledger.todo(lo, min(lo + SUMMARY_BLOCK, n_runs))
            for k in range(0, len(todo), size):
                yield self._block(todo[k:k + size].tolist())

    def _block(self, indices: list[int]) -> Block:
        runs = self._batch.runs
        first, last = indices[0], indices[-1]
        return Block(range(first, last + 1) if last - first + 1 == len(indices)
                     else tuple(indices),
                     runs if isinstance(runs, RunList) else {i: runs[i] for i in indices},
                     len(runs), self._batch.input_columns, self._fmu_sha, self._timeout,
                     self._log, self._batch.optimal, self._faults,
                     shard_runs=summary_module.SHARD_RUNS, outcomes=self._outcomes)


def _killed(item: Killed, batch: BatchSpec, out: Path, fmu_sha: str) -> BlockResult:
    """The result of a run its executor stopped or lost: its record made up, its partial log
    recovered (the parent draws this run: it has no worker's result)."""
    run = batch.runs[item.index]
    record = made_up_record(run.run_id, item.status, item.message)
    rel = log_relpath(run.run_id, len(batch.runs))
    _recover_partial(out / rel)
    kept = (out / rel).is_file()
    table = summary_table([SummaryRow.of(run)], batch.input_columns, {run.run_id: record},
                          {run.run_id: rel if kept else None},
                          optimal=batch.optimal is not None)
    line = block_lines(table, {run.run_id: run_digest(run.digest, fmu_sha)}, killed=True)
    return BlockResult(range(item.index, item.index + 1), f"{run.run_id}\n".encode("ascii"),
                       line[run.run_id], bytes([run_code(item.status, True, kept)]),
                       table_bytes(table), outcomes=((record, item.wall_s),),
                       worker=item.worker, killed=True)


def _message(res: BlockResult, k: int) -> str | None:
    """The message of the ``k``-th run of ``res`` (its record's, else its summary row's)."""
    if res.outcomes is not None:
        return res.outcomes[k][0].get("message")

    table = table_of(res.table, MAX_PART_BYTES)
    run_id = res.run_ids()[k]
    return next((row["message"] for row in table.select(["run_id", "message"]).to_pylist()
                 if row["run_id"] == run_id), None)


#: A frame of a parts file (:class:`_Parts`): its magic, the length of its payload (an Arrow
#: IPC stream) and the payload's CRC-32, little-endian, then the payload.
PART_FRAME: Final = struct.Struct("<4sII")
PART_MAGIC: Final = b"WMRp"
#: Longest payload a parts file's frame is read with (a range of 1,024 runs is about
#: 200 kB): a longer length is damage, and the rest of the file is not read.
MAX_PART_BYTES: Final = 1 << 28
#: Suffix of a parts file (``.arrow``: a range's file, from a batch of before).
PARTS_SUFFIX: Final = ".arrows"


class _Parts:
    """The summary rows of the runs finished since the batch's summary was last written, in
    ``OUT/.parts``: one file per invocation (``<pid>-<ns>.arrows``) to which each range's rows
    are appended as a frame (:data:`PART_FRAME`: an Arrow IPC stream), made durable
    (``fdatasync``; the folder fsynced once, when the file is made) before the range's journal
    lines are written (a journal line always has its row on disk), merged into the summary at
    the end (:func:`_summary_chunks`), then removed.  A batch killed before that leaves them:
    the next one finds its runs' rows there (:func:`_carry`), keeps them as its own and
    removes the others.  (A file and two fsyncs a range, as before, cost the parent about
    0.65 ms of CPU a range; a frame appended and one ``fdatasync``, about 0.2 ms.)"""

    def __init__(self, out: Path, n_runs: int = 0) -> None:
        self.folder = out / ".parts"
        # this invocation's file never meets a killed one's
        self.path = self.folder / f"{os.getpid()}-{time.time_ns():x}{PARTS_SUFFIX}"
        self._fd: int | None = None
        self._size = 0
        #: frames written and not yet made durable; the file's name made durable
        self._unsynced = False
        self._named = False
        #: (first run index, offset, length) of each frame's payload, by SUMMARY_BLOCK of runs
        self._frames: dict[int, list[tuple[int, int, int]]] = {}
        #: 1 where the run's row is in a part of this invocation (a numpy array)
        self.has = np.zeros(n_runs, np.bool_)
        #: frames written whose runs' journal lines are not yet written (chunk, frame, runs):
        #: the summary takes a frame only once committed (:meth:`commit`): a batch stopped
        #: between its rows and its lines (a full disk, an error) holds no row without a line
        self._pending: list[tuple[int, tuple[int, int, int], Sequence[int]]] = []

    def leftovers(self) -> list[Path]:
        """The part files a batch killed before its summary left (links are not followed)."""
        try:
            return sorted(p for p in self.folder.iterdir()
                          if p.suffix in (PARTS_SUFFIX, ".arrow") and p != self.path
                          and not p.is_symlink() and p.is_file())
        except OSError:
            return []

    def read(self, paths: Sequence[Path]) -> Iterator[Any]:
        """The tables of the part files ``paths``; a damaged frame (or a damaged file of
        before) is skipped (its runs are run again), and a file is read up to a frame whose
        header is damaged (the cut end of a killed batch's)."""
        import pyarrow as pa

        for path in paths:
            try:
                if path.suffix != PARTS_SUFFIX:  # a range's file, from a batch of before
                    yield table_of(path.read_bytes(), MAX_PART_BYTES)
                    continue
                for payload in _frames(path):
                    try:
                        yield table_of(payload, MAX_PART_BYTES)
                    except pa.ArrowException:
                        continue
            except (OSError, pa.ArrowException):
                continue

    def drop(self, paths: Sequence[Path]) -> None:
        for path in paths:
            path.unlink(missing_ok=True)

    def drop_leftovers(self) -> None:
        """Remove the parts of before (a batch without a journal has no run in them)."""
        self.drop(self.leftovers())

    def add(self, table: Any, indices: Sequence[int],
            only: set[str] | None = None, durable: bool = True) -> None:
        """Keep ``table`` (a table or its IPC stream), the rows of the runs ``indices``
        (increasing, in the table's order), or, with ``only``, its rows of those run ids (the
        runs ``indices``): on disk (``fdatasync``) before this returns, or, not ``durable``,
        at the next :meth:`sync` (several ranges' frames made durable at once); a frame for
        each :data:`SUMMARY_BLOCK` of runs they fall in (a worker's range never crosses one;
        the rows a resume found may)."""
        import pyarrow as pa
        import pyarrow.compute as pc

        if not len(indices):
            return
        first, last = indices[0] // SUMMARY_BLOCK, indices[-1] // SUMMARY_BLOCK
        if only is not None or first != last:
            if isinstance(table, bytes | bytearray):
                table = table_of(table, MAX_PART_BYTES)
            if only is not None:
                table = table.filter(pc.is_in(table["run_id"], pa.array(sorted(only))))
            if first != last:  # a frame per block of runs: the summary merges them so
                at = np.asarray(indices, np.int64)
                cuts = np.searchsorted(at, np.arange(first + 1, last + 1) * SUMMARY_BLOCK)
                for lo, hi in zip([0, *cuts.tolist()], [*cuts.tolist(), len(at)],
                                  strict=True):
                    if hi > lo:
                        self.add(table.slice(lo, hi - lo), at[lo:hi].tolist(),
                                 durable=False)
                if durable:
                    self.sync()
                    self.commit()
                return
        if not isinstance(table, bytes | bytearray):
            if not table.num_rows:
                return
            table = table_bytes(table)
        if not table:
            return
        self._append(bytes(table), first, indices)
        if durable:
            self.sync()
            self.commit()

    def _append(self, payload: bytes, chunk: int, indices: Sequence[int]) -> None:
        """Append ``payload``, the rows of the runs ``indices``, as a frame (durable at the
        next :meth:`sync`, in the summary from the next :meth:`commit`; a full disk is one
        DiskFullError)."""
        try:
            if self._fd is None:
                self.folder.mkdir(exist_ok=True)
                self._fd = open_own(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL
                                    | os.O_APPEND, "batch parts")
                self._named = False
            head = PART_FRAME.pack(PART_MAGIC, len(payload), zlib.crc32(payload))
            self._unsynced = True
            write_all(self._fd, head + payload, self.path)
        except OSError as exc:
            raise storage_error(exc, self.path) from exc
        self._pending.append((chunk, (int(indices[0]), self._size + PART_FRAME.size,
                                      len(payload)), indices))
        self._size += PART_FRAME.size + len(payload)

    def commit(self) -> None:
        """The frames appended since the last commit are the summary's (their runs' journal
        lines are written)."""
        for chunk, frame, indices in self._pending:
            self._frames.setdefault(chunk, []).append(frame)
            if isinstance(indices, range):
                self.has[indices[0]:indices[-1] + 1] = True
            else:
                self.has[np.asarray(indices, np.int64)] = True
        self._pending.clear()

    def sync(self) -> None:
        """Make the frames appended since the last sync durable: one ``fdatasync`` however
        many (and the folder's, once, for the file's name)."""
        if self._fd is None or not self._unsynced:
            return
        try:
            _datasync(self._fd)
            if not self._named:
                fsync_dir(self.folder)
                self._named = True
        except OSError as exc:
            raise storage_error(exc, self.path) from exc
        self._unsynced = False

    def tables(self, chunk: int) -> list[Any]:
        """The kept tables of the runs ``chunk * SUMMARY_BLOCK`` to the next block's, in the
        order of their runs (not the order their ranges finished in: their rows are then
        usually in run-id order already, and the summary is not sorted again)."""

        frames = sorted(self._frames.get(chunk, []))
        if not frames:
            return []
        with open(self.path, "rb") as stream:
            tables = []
            for _, offset, length in frames:
                stream.seek(offset)
                tables.append(table_of(stream.read(length), MAX_PART_BYTES))
            return tables

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def clear(self) -> None:
        import shutil

        self.close()
        shutil.rmtree(self.folder, ignore_errors=True)
        self._frames.clear()

    def __del__(self) -> None:
        self.close()


#: ``fdatasync`` where the platform has it (not macOS), else ``fsync``.
_datasync: Final = getattr(os, "fdatasync", os.fsync)


def _frames(path: Path) -> Iterator[bytes]:
    """The payloads of the frames of the parts file ``path`` (a link is not followed), up to
    its first damaged header or cut frame; a frame whose CRC does not match is skipped."""
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    with os.fdopen(fd, "rb") as stream:
        while len(head := stream.read(PART_FRAME.size)) == PART_FRAME.size:
            magic, length, crc = PART_FRAME.unpack(head)
            if magic != PART_MAGIC or length > MAX_PART_BYTES:
                return
            payload = stream.read(length)
            if len(payload) < length:
                return
            if zlib.crc32(payload) == crc:
                yield payload


def _recover_partial(log: Path) -> None:
    """A run killed by its executor leaves ``<id>.mcap.partial``: make it a finished log
    (what was lost is recorded in it), so that every tool reads the run's last seconds."""
    from wmr.adapters.mcap.recover import recover_log

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


def _finish(out: Path, chunks: Iterator[Any], result: BatchOutcome, batch: BatchSpec,
            scheduler: str | None, client: Any, workers: int | None, fmu: Path,
            fmu_sha: str) -> None:
    """Write the summary and ``batch.json``; a full disk is one :class:`DiskFullError`."""
    try:
        write_summary(chunks, out, csv_too=result.total <= CSV_MAX_RUNS)
        _write_atomic(out / "batch.json", (json.dumps({
                "spec": str(batch.path) if batch.path else batch.name, "total": result.total,
                "finished": result.finished, "skipped": result.skipped,
                "executed": len(result.executed), "counts": result.counts,
                "interrupted": result.interrupted, "wall_s": round(result.wall_s, 3),
                "log": result.log.as_dict(), "logs_kept": result.logs_kept,
                "executor": (f"dask {scheduler or 'client'}" if scheduler or client
                             else f"local, {workers or os.cpu_count()} workers"),
                "fmu": fmu.name, "fmu_sha256": fmu_sha}, indent=1) + "\n").encode())
    except OSError as exc:
        raise storage_error(exc, out) from exc


__all__ = ["DEFAULT_RUN_TIMEOUT_S", "BatchOptions", "BatchOutcome", "run_batch"]
