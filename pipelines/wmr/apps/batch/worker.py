"""The worker side of a batch: one :class:`~wmr.adapters.fmi.robot.FmuPlant` per process (or
thread), reused for every run it is given.

Both executors call :func:`execute`: the local pool from its worker processes, Dask from its
worker threads (:func:`dask_run`, with the FMU shipped once per worker by
:class:`wmr.apps.batch.dask_exec.FmuPlugin`).
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import shutil
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Final, Protocol

from wmr.adapters.fmi.archive import file_sha256
from wmr.adapters.fmi.compiled_law import law_library
from wmr.adapters.fmi.robot import FmuPlant
from wmr.adapters.fmi.varmap import VariableMap
from wmr.apps.batch.journal import WallClockLimit, compact_line, run_digest
from wmr.apps.batch.spec import BatchRun
from wmr.apps.batch.summary import (
    SHARD_RUNS,
    SummaryRow,
    log_relpath,
    result_rows,
    summary_table,
)
from wmr.apps.run import FULL_LOGS, LogPolicy
from wmr.config.scenario import RunSpec
from wmr.infra.errors import ConfigError, DiskFullError

#: Key of a result record whose log could not be written for lack of space.
DISK_FULL = "disk_full"
#: ``fault`` values understood by :func:`execute`, for tests of the executors only.
FAULTS = ("hang", "crash", "crash-once", "crash-keeping-pipe")


@dataclass(frozen=True)
class Task:
    """One run as sent to a worker.

    Attributes
    ----------
    run_id
        The run's id.
    spec
        The run.
    wall_limit_s
        Wall-clock limit of the run, s (checked every 100 control steps), ``None``: none.
    fault
        Test hook: ``"hang"`` sleeps for ever, ``"crash"`` kills the worker process,
        ``"crash-once"`` kills it on the first attempt only, ``"crash-keeping-pipe"`` kills
        it after starting a process that keeps its pipe open for 60 s (its pid in
        ``<run_id>.helpers``).
    log_name
        Its log, relative to the batch's ``runs`` folder (``<shard>/<run_id>.mcap``, see
        :func:`wmr.apps.batch.summary.log_relpath`); ``""``: ``<run_id>.mcap``.
    log
        Which runs keep a log, and how much of it.
    optimal
        The batch's ``optimal`` (``"time"``, ``"energy"``): the optimum solved after the run,
        its fields added to the record (:func:`wmr.apps.optimal.optimum_fields`); ``None``:
        none.
    """

    run_id: str
    spec: RunSpec
    wall_limit_s: float | None = None
    fault: str | None = None
    log_name: str = ""
    log: LogPolicy = FULL_LOGS
    optimal: str | None = None

    @property
    def log_relpath(self) -> str:
        """The log's path relative to the ``runs`` folder."""
        return self.log_name or f"{self.run_id}.mcap"


@dataclass(frozen=True)
class Block:
    """A range of a batch's runs, as sent to a worker: the worker draws each run from the spec
    and its index (the parent makes none), runs it, and returns the range's journal lines and
    summary rows in one piece (:class:`BlockResult`).

    Attributes
    ----------
    indices
        The runs' indices, increasing (a ``range``, or the runs of one not done yet).
    runs
        Where the runs are drawn from: the spec's :class:`~wmr.apps.batch.spec.RunList` (a few
        kB: bases, axes and distributions), or the block's runs by index for a spec given as
        a list.
    n_runs
        Runs in the spec (their logs are in shards beyond :data:`~wmr.apps.batch.summary.
        SHARD_RUNS`).
    input_columns
        The summary's input columns.
    fmu_sha256
        The FMU's digest (:func:`fmu_digest`), journalled with each run.
    wall_limit_s, log, optimal
        As :class:`Task`'s.
    faults
        Test hooks by run id (:data:`FAULTS`).
    retry
        The block's runs are given once more after their worker died (one run, locally; a
        Dask task's runs, each alone in a process of its own: :func:`run_alone`).
    """

    indices: Sequence[int]
    runs: Sequence[BatchRun] | Mapping[int, BatchRun]
    n_runs: int
    input_columns: tuple[str, ...]
    fmu_sha256: str
    wall_limit_s: float | None = None
    log: LogPolicy = FULL_LOGS
    optimal: str | None = None
    faults: Mapping[str, str] = field(default_factory=dict)
    retry: bool = False
    #: Runs per shard of logs (:data:`~wmr.apps.batch.summary.SHARD_RUNS`, the parent's).
    shard_runs: int = SHARD_RUNS
    #: Send each run's record and wall time back (:attr:`BlockResult.outcomes`: the API's
    #: ``on_outcome`` wants them; without it, no Python object a run crosses the pipe).
    outcomes: bool = False

    def __len__(self) -> int:
        return len(self.indices)

    def log_relpath(self, run_id: str) -> str:
        """A run's log relative to the batch folder (:func:`~wmr.apps.batch.summary.
        log_relpath`)."""
        return log_relpath(run_id, self.n_runs, self.shard_runs)

    def task(self, run: BatchRun) -> Task:
        """The :class:`Task` of ``run``, one of the block's."""
        return Task(run.run_id, run.spec, self.wall_limit_s, self.faults.get(run.run_id),
                    log_name=self.log_relpath(run.run_id).removeprefix("runs/"),
                    log=self.log, optimal=self.optimal)


#: A finished run's status as one byte of :attr:`BlockResult.codes` (0: none of these).
STATUS_CODES: Final = {"converged": 1, "timeout": 2, "failed": 3}
#: The status bits of a code.
STATUS_MASK: Final = 3
#: Bit of a code: the run got past its first step (a batch whose first runs all fail before
#: it stops).
STARTED: Final = 4
#: Bit of a code: the run kept a log.
KEPT: Final = 8


@dataclass
class BlockResult:
    """What a worker returns for a :class:`Block`: its finished runs as a few byte strings,
    one of each kind for the whole range, never a Python object per run (a range crosses a
    pipe or the network, and the parent does per range what it did per run).

    Attributes
    ----------
    indices
        The runs finished, in index order: the block's first ``len(indices)`` (a ``range``
        when they are consecutive).
    ids
        Their run ids, each followed by a newline (ASCII).
    lines
        Their sealed journal lines (:func:`~wmr.apps.batch.journal.compact_line`), in the
        same order, each ending with a newline: written with one ``write``.
    codes
        One byte a run: its status (:data:`STATUS_CODES`), with :data:`STARTED` and
        :data:`KEPT`.
    table
        Their summary rows, an Arrow IPC stream (zstd), ``b""`` when none.
    logs
        ``(k, path, bytes)`` of each log sent back (a worker that does not see the batch
        folder): the ``k``-th run's, which the parent writes at ``path`` (relative to the
        batch folder) before the lines.
    outcomes
        ``(record, wall_s)`` of each run when the block asked for them (:attr:`Block.
        outcomes`: the API's ``on_outcome``), else ``None``.
    worker
        Who ran them.
    killed
        Their executor stopped them from outside (their records are made up).
    stop
        Why the block stopped early, if it did: ``("disk_full", message)`` (the run that
        found the disk full is not among them) or ``("config", field, problem, fix)`` (a run
        could not be made).
    """

    indices: Sequence[int] = ()
    ids: bytes = b""
    lines: bytes = b""
    codes: bytes = b""
    table: bytes = b""
    logs: tuple[tuple[int, str, bytes], ...] = ()
    outcomes: tuple[tuple[dict[str, Any], float], ...] | None = None
    worker: str = ""
    killed: bool = False
    stop: tuple[str, ...] | None = None

    def __len__(self) -> int:
        return len(self.indices)

    def run_ids(self) -> list[str]:
        """The run ids, as strings."""
        return self.ids.decode("ascii").split("\n")[:-1]


def run_code(status: str, started: bool, kept: bool) -> int:
    """A run's byte of :attr:`BlockResult.codes`."""
    return STATUS_CODES.get(status, 0) | (STARTED if started else 0) | (KEPT if kept else 0)


def line_ends(lines: bytes) -> Any:
    """Where each line of ``lines`` ends (the offset after its newline), as a numpy array."""
    import numpy as np

    return np.flatnonzero(np.frombuffer(lines, np.uint8) == 0x0A) + 1


class TaskSource(Protocol):
    """The runs for an executor: their count at once, the blocks of them as it takes them
    (of ``size`` runs at most: the executor knows its workers)."""

    def __len__(self) -> int: ...

    def blocks(self, size: int) -> Iterator[Block]: ...


def block_lines(table: Any, digests: Mapping[str, str], killed: bool = False
                ) -> dict[str, bytes]:
    """The compact journal lines (:func:`~wmr.apps.batch.journal.compact_line`) of the runs
    of ``table`` (their summary rows; ``digests`` their
    :func:`~wmr.apps.batch.journal.run_digest` by run id), by run id: each sealed over its
    row's results."""
    ids = table["run_id"].to_pylist()
    return {run_id: compact_line(run_id, str(row["status"]), digests[run_id], row, killed)
            for run_id, row in zip(ids, result_rows(table), strict=True)}


#: The first bytes of a zstd frame: a range's rows as :func:`table_bytes` makes them.  An
#: Arrow IPC stream (a range's rows as a batch of before sent them) starts otherwise.
ZSTD_MAGIC: Final = b"\x28\xb5\x2f\xfd"


def table_bytes(table: Any) -> bytes:
    """An Arrow table as an IPC stream, compressed whole with zstd (level 1).

    Whole, not buffer by buffer (Arrow's ``IpcWriteOptions(compression="zstd")``, as before):
    a summary row has some 34 columns, and zstd's cost per buffer made a 128-run range's
    stream cost about 0.8 ms to write and 0.6 ms to read back (the parent's, at the merge)
    where it now costs about 0.08 and 0.05 ms, in fewer bytes (186 a run against 221).
    Compressed at all, because a range's rows wait on disk until the summary is written
    (about 330 bytes a run as they are)."""
    import pyarrow as pa
    import zstandard

    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, table.schema) as writer:
        writer.write_table(table)
    return zstandard.ZstdCompressor(level=1).compress(sink.getvalue())


def table_of(payload: bytes | bytearray, max_bytes: int) -> Any:
    """The Arrow table of ``payload``, made by :func:`table_bytes` or, for rows a batch of
    before left, an IPC stream whose buffers are compressed.

    Raises
    ------
    pyarrow.ArrowInvalid
        ``payload`` is damaged, or its stream would be longer than ``max_bytes`` (the
        decompressed size is checked before any is made).
    """
    import pyarrow as pa
    import zstandard

    if payload[:4] == ZSTD_MAGIC:
        try:
            size = zstandard.frame_content_size(payload)
            if not 0 <= size <= max_bytes:  # -1: not recorded; a frame of ours records it
                raise pa.ArrowInvalid(f"a summary part of {size} bytes (at most {max_bytes})")
            payload = zstandard.ZstdDecompressor().decompress(payload, max_output_size=size)
        except zstandard.ZstdError as exc:
            raise pa.ArrowInvalid(f"a damaged summary part: {exc}") from None
    return pa.ipc.open_stream(payload).read_all()


def run_block(block: Block, run_one: Callable[[Task], tuple[dict[str, Any], bytes | None]],
              out_dir: Path | None, worker: str,
              starting: Callable[[int], None] | None = None) -> BlockResult:
    """Draw, run and journal the runs of ``block``, one after the other.

    Parameters
    ----------
    block
        The runs.
    run_one
        Runs a task; returns its record and, when the worker does not see the batch folder,
        its log's bytes (``None`` otherwise: the log, if kept, is in place).
    out_dir
        The batch folder as this worker sees it (the journal lines' stamps), ``None`` when
        logs go back as bytes.
    worker
        Who runs them (the journal's ``worker``).
    starting
        Called with each run's index before it starts (the local pool's parent learns from
        it which run a worker that died or hung was on).
    """
    done: list[tuple[BatchRun, bool, float, dict[str, Any]]] = []
    shipped: list[tuple[int, str, bytes]] = []
    logs: dict[str, str | None] = {}
    stop: tuple[str, ...] | None = None
    for index in block.indices:
        if starting is not None:
            starting(index)
        try:
            run = block.runs[index]
        except ConfigError as exc:  # a run made late, e.g. a sample drawn out of range
            stop = ("config", exc.field, exc.problem, exc.fix)
            break
        t0 = time.perf_counter()
        record, data = run_one(block.task(run))
        wall = time.perf_counter() - t0
        if record.get(DISK_FULL):
            stop = ("disk_full", str(record.get("message")))
            break
        rel = block.log_relpath(run.run_id)
        if out_dir is None:  # the parent writes the log
            kept = data is not None and record.get("mcap") is not None
            if kept and data is not None:
                shipped.append((len(done), rel, data))
        else:
            kept = record.get("mcap") is not None and (out_dir / rel).is_file()
        done.append((run, kept, wall, record))
        logs[run.run_id] = rel if kept else None
    if not done:
        return BlockResult(stop=stop, worker=worker)
    records = {run.run_id: record for run, _, _, record in done}
    table = summary_table([SummaryRow.of(run) for run, *_ in done], block.input_columns,
                          records, logs, optimal=block.optimal is not None)
    lines = block_lines(table, {run.run_id: run_digest(run.digest, block.fmu_sha256)
                                for run, *_ in done})
    codes = bytes(run_code(str(record.get("status")),
                           record.get("status") != "failed" or bool(record.get("steps")), kept)
                  for _, kept, _, record in done)
    indices = block.indices[:len(done)]
    return BlockResult(
        indices=range(indices[0], indices[-1] + 1)
        if indices[-1] - indices[0] + 1 == len(indices) else tuple(indices),
        ids="".join(f"{run.run_id}\n" for run, *_ in done).encode("ascii"),
        lines=b"".join(lines[run.run_id] for run, *_ in done), codes=codes,
        table=table_bytes(table), logs=tuple(shipped),
        outcomes=tuple((record, wall) for _, _, wall, record in done) if block.outcomes
        else None, worker=worker, stop=stop)


@dataclass(frozen=True)
class Attachment:
    """The spec file, attached to every run's log (name and bytes, so that remote workers
    need no shared file system)."""

    name: str
    data: bytes


def fmu_digest(fmu: Path, var_map: VariableMap | None = None) -> str:
    """The identity of the FMU a batch runs, as its journal and ``batch.json`` record it: the
    file's SHA-256, plus a hash of its variable map when it has one (a run through another map
    is another run: the journal must not reuse it)."""
    digest = file_sha256(fmu)
    if var_map is not None:
        digest += "+map:" + hashlib.sha256(
            json.dumps(var_map.as_dict(), sort_keys=True).encode()).hexdigest()[:16]
    return digest


def wall_limit_message(limit_s: float) -> str:
    """The message of a run stopped by its wall-clock limit."""
    return f"wall-clock limit of {limit_s:g} s exceeded"


_TMP = threading.Lock()
_files: dict[str, Path] = {}


def materialise(name: str, data: bytes) -> Path:
    """Write ``data`` once per process to a private temp folder as ``name``; return the path.

    Keeps the file's own name, which the logs record (``fmu_file``), so that a log written
    by a Dask worker records the FMU as one written locally does.
    """
    digest = hashlib.sha256(data).hexdigest()
    key = f"{digest}/{name}"
    with _TMP:
        path = _files.get(key)
        if path is None or not path.exists():
            folder = Path(tempfile.mkdtemp(prefix=f"wmr-batch-{digest[:12]}-"))
            path = folder / name
            path.write_bytes(data)
            _files[key] = path
        return path


def execute(task: Task, plant: FmuPlant, mcap_path: Path,
            attachment: Path | None, location: Path | None = None) -> dict[str, Any]:
    """Run ``task`` on ``plant`` into ``mcap_path``; return the result record of
    :func:`wmr.apps.run.run_to_log`.  ``location``: where the log is moved once finished,
    if not ``mcap_path`` (its ``mcap`` field, in the record and in the log).

    A run past its wall-clock limit ends with status ``timeout`` and the message of
    :func:`wall_limit_message` (its log says ``failed``: it was stopped from outside the loop).
    """
    from wmr.adapters.mcap import McapOpener
    from wmr.apps.run import run_to_log

    if task.fault == "crash":
        os._exit(70)
    if task.fault == "crash-once":  # dies on the first attempt only (a marker beside the log)
        marker = mcap_path.with_name(f"{task.run_id}.crashed")
        if not marker.exists():
            marker.touch()
            os._exit(70)
        # the marker stays: Dask's scheduler may run a dead worker's task again more than
        # once, and a third attempt must not die as the first did
    if task.fault == "crash-keeping-pipe":  # an FMU whose helper process outlives it
        helper = os.fork()
        if helper == 0:  # holds every descriptor the worker had, its pipe to the batch too
            time.sleep(60)
            os._exit(0)
        with open(mcap_path.with_name(f"{task.run_id}.helpers"), "a") as f:
            f.write(f"{helper}\n")
        os._exit(70)
    if task.fault == "hang":
        while True:
            time.sleep(3600)
    progress = None
    limit = task.wall_limit_s
    if limit is not None:
        deadline = time.monotonic() + limit

        def progress(t_s: float, t_max_s: float) -> None:
            if time.monotonic() > deadline:
                raise WallClockLimit(wall_limit_message(limit))

    with ExitStack() as stack:
        ctrl = None
        if task.spec.controller_fmu is not None:  # the scenario key controller_fmu
            from wmr.adapters.fmi.controller import FmuController
            from wmr.apps.run import default_controller_fmu

            ctrl_path = task.spec.controller_fmu or default_controller_fmu(
                int(plant.fmi_version[0]))
            ctrl = stack.enter_context(FmuController(ctrl_path))
        # no fsync per log: the resume checks every log, and redoes one a power loss damaged
        record = run_to_log(task.spec, McapOpener(mcap_path, durable=False,
                                                  location=location), plant,
                            scenario_file=attachment, progress=progress, controller_fmu=ctrl,
                            log=task.log)
    if limit is not None and record["status"] == "failed" \
            and str(record["message"]).startswith(WallClockLimit.__name__):
        record["status"] = "timeout"
        record["message"] = wall_limit_message(limit)
    return record


class PlantHolder:
    """An :class:`FmuPlant` reopened after a failed run (an FMU left in its error state may
    refuse the next reset)."""

    def __init__(self, fmu_path: Path, var_map: VariableMap | None = None) -> None:
        self.fmu_path = fmu_path
        self.var_map = var_map
        self.plant = FmuPlant(fmu_path, var_map=var_map)
        # the compiled law's one check in this process, before any run's wall clock starts
        law_library()
        #: The last optimum this worker solved: the next one's warm start.
        self.previous_optimum: Any = None

    def run(self, task: Task, mcap_path: Path, attachment: Path | None,
            location: Path | None = None) -> dict[str, Any]:
        """:func:`execute` on the held plant; a fresh plant after a failure.

        An exception outside the run itself (the log cannot be created, ...) is a ``failed``
        record, never the end of the worker.
        """
        try:
            record = execute(task, self.plant, mcap_path, attachment, location)
        except DiskFullError as exc:  # not the run's fault: the batch stops, the run is redone
            return {"name": task.spec.name, "status": "failed", "message": str(exc),
                    "mcap": str(location or mcap_path), DISK_FULL: True}
        except Exception as exc:
            record = {"name": task.spec.name, "status": "failed",
                      "message": f"{type(exc).__name__}: {exc}",
                      "mcap": str(location or mcap_path)}
        if record["status"] == "failed":
            self.plant.close()
            self.plant = FmuPlant(self.fmu_path, var_map=self.var_map)
        if task.optimal is not None:
            # after the run, outside its wall clock; in the record, so that the journal keeps
            # it and a resumed batch never solves it again
            from wmr.apps.optimal import optimum_fields

            fields, solved = optimum_fields(task.spec, task.optimal, record,
                                            self.previous_optimum)
            record.update(fields)
            if solved is not None:
                self.previous_optimum = solved
        return record

    def close(self) -> None:
        self.plant.close()


# -- Dask --------------------------------------------------------------------------------------

#: FMU files shipped by :class:`wmr.apps.batch.dask_exec.FmuPlugin`, by SHA-256 (one per worker).
_FMUS: dict[str, Path] = {}
_local = threading.local()


def _holder(sha256: str, path: Path, var_map: VariableMap | None = None) -> PlantHolder:
    """This thread's plant of the FMU ``sha256`` at ``path`` (FmuPlant is not thread-safe)."""
    holders: dict[tuple[str, str], PlantHolder] | None = getattr(_local, "holders", None)
    if holders is None:
        holders = _local.holders = {}
    key = (sha256, "" if var_map is None else json.dumps(var_map.as_dict(), sort_keys=True))
    holder = holders.get(key)
    if holder is None:
        holder = holders[key] = PlantHolder(path, var_map)
    return holder


_shared: dict[tuple[str, str], bool] = {}


def sees_folder(out_dir: str, token: str) -> bool:
    """Whether this process sees the client's batch folder (it holds the client's token)."""
    key = (out_dir, token)
    if key not in _shared:
        try:
            _shared[key] = (Path(out_dir) / TOKEN_FILE).read_text() == token
        except OSError:
            _shared[key] = False
    return _shared[key]


#: File of the batch folder that tells a worker it shares the client's file system.
TOKEN_FILE = ".dask-token"


@dataclass
class RetryResult:
    """What a Dask task's retry returns (:func:`run_alone`): a result for each of its runs that
    finished, and the runs that died again, each alone in its process.

    Attributes
    ----------
    results
        One :class:`BlockResult` a finished run, in index order (the last may say the batch
        must stop: ``stop``).
    died
        The runs whose process died while each was the one running.
    """

    results: list[BlockResult]
    died: list[int]


#: Bytes of the length before each result a retry's process writes (little-endian).
_FRAME_HEAD: Final = 8


def dask_run_block(block: Block, fmu_sha256: str, attachment: Attachment | None,
                   out_dir: str, token: str, var_map: VariableMap | None = None
                   ) -> BlockResult | RetryResult:
    """A Dask task: the runs of ``block`` (:func:`run_block`), one task per range.

    A worker that sees the batch folder (same host or shared file system: it holds the
    client's ``token``) writes each log there, atomically, and the journal lines; any other
    writes each log to a private temp file and sends its bytes back for the client to write.

    A retry (``block.retry``: the runs of a task whose worker died) runs in a process of its
    own (:func:`run_alone`: a :class:`RetryResult`), as the local pool's retry runs alone in
    a fresh worker: a run that crashes every process again takes only that one with it.  In
    the worker itself it killed the worker again, and Dask counts every task queued on a
    worker that dies as a suspect (``allowed-failures``) and loses the results still held
    there: the retry of another run queued beside it was seen to end "died twice" though it
    never failed.
    """
    path = _FMUS.get(fmu_sha256)
    if path is None:
        raise RuntimeError(f"FMU {fmu_sha256[:12]} was not shipped to this worker "
                           "(FmuPlugin not registered)")
    att = materialise(attachment.name, attachment.data) if attachment is not None else None
    shared = sees_folder(out_dir, token)
    if block.retry:
        return run_alone(block, path, att, out_dir if shared else None, var_map, out_dir)
    return block_on(_holder(fmu_sha256, path, var_map), block, att,
                    out_dir if shared else None, out_dir)


def block_on(holder: PlantHolder, block: Block, attachment: Path | None,
             out_dir: str | None, batch_dir: str | None = None) -> BlockResult:
    """The runs of ``block`` on ``holder``'s plant: each log written in ``out_dir``'s
    ``runs`` folder, atomically, or, ``out_dir`` None, to a private temp file whose bytes go
    back in the result, for the client to write in its batch folder ``batch_dir``.  Either
    way the log's result record names where it is kept (the log written under a name of its
    own and moved there, or sent there)."""

    root = out_dir if out_dir is not None else batch_dir  # where the logs are kept

    def run_one(task: Task) -> tuple[dict[str, Any], bytes | None]:
        # the record's mcap field, and the log's own, name this (run_to_log: its location)
        kept = None if root is None else Path(root) / "runs" / task.log_relpath
        if out_dir is not None and kept is not None:
            part = kept.with_name(f"{kept.name}.{os.getpid()}.{threading.get_ident()}.part")
            try:
                record = holder.run(task, part, attachment, location=kept)
                if record.get("mcap") is not None and part.exists():  # kept (the log policy)
                    os.replace(part, kept)
            finally:
                part.unlink(missing_ok=True)
            return record, None
        folder = Path(tempfile.mkdtemp(prefix="wmr-run-"))
        try:
            path = folder / f"{task.run_id}.mcap"
            record = holder.run(task, path, attachment, location=kept)
            data = path.read_bytes() if record.get("mcap") is not None and path.exists() \
                else None
        finally:
            shutil.rmtree(folder, ignore_errors=True)
        return record, data

    return run_block(block, run_one, Path(out_dir) if out_dir is not None else None, "")


def run_alone(block: Block, fmu_path: Path, attachment: Path | None, out_dir: str | None,
              var_map: VariableMap | None, batch_dir: str | None = None) -> RetryResult:
    """The runs of ``block`` one after the other in a new Python process
    (``python -m wmr.apps.batch.retry PID``) on its own plant of ``fmu_path``, each as
    :func:`block_on` runs it; a process that dies costs only the run it was on, and a new one
    takes the runs after it.  It ends with this process, even one killed outright.

    The process writes each run's result, pickled (it is this one's child, running this
    package), to a file of a private temp folder as the run ends, a length before it: the
    results whole in the file are those of the runs that finished, and the run after them is
    the one the process died on.  A process per range, not per run: one costs about 0.6 s to
    start, and a range whose worker died is given again whole.  ``out_dir`` and
    ``batch_dir`` are :func:`block_on`'s.
    """
    import subprocess
    import sys

    import wmr

    env = dict(os.environ)
    # the package this process runs, whatever put it on its path
    package_root = str(Path(wmr.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (package_root, env.get("PYTHONPATH")) if p)
    pending = list(block.indices)
    done = RetryResult([], [])
    folder = Path(tempfile.mkdtemp(prefix="wmr-retry-"))
    try:
        while pending:
            out = folder / f"results-{len(done.died)}"
            job = pickle.dumps((replace(block, indices=pending), str(fmu_path),
                                None if attachment is None else str(attachment), out_dir,
                                var_map, str(out), batch_dir))
            proc = subprocess.run([sys.executable, "-m", "wmr.apps.batch.retry",
                                   str(os.getpid())], input=job, env=env, check=False)
            results = read_frames(out) if out.exists() else []
            done.results += results
            if results and results[-1].stop is not None:
                break  # the batch stops: the runs after are not results
            finished = sum(len(r.indices) for r in results)
            if finished >= len(pending):
                break
            if proc.returncode == 0:
                raise RuntimeError(f"the process of a retry ended without the results of "
                                   f"{len(pending) - finished} of its runs")
            died = pending[finished]
            done.died.append(died)
            pending = pending[finished + 1:]
        return done
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def write_frame(f: Any, result: BlockResult) -> None:
    """Append ``result`` to the results file of a retry's process (:func:`run_alone`)."""
    data = pickle.dumps(result)
    f.write(len(data).to_bytes(_FRAME_HEAD, "little") + data)
    f.flush()


def read_frames(path: Path) -> list[BlockResult]:
    """The results whole in ``path``, the results file of a retry's process: one cut by its
    death is not one."""
    data = path.read_bytes()
    results: list[BlockResult] = []
    at = 0
    while at + _FRAME_HEAD <= len(data):
        size = int.from_bytes(data[at:at + _FRAME_HEAD], "little")
        if at + _FRAME_HEAD + size > len(data):
            break
        results.append(pickle.loads(data[at + _FRAME_HEAD:at + _FRAME_HEAD + size]))
        at += _FRAME_HEAD + size
    return results


__all__ = ["FAULTS", "KEPT", "STARTED", "STATUS_CODES", "STATUS_MASK", "Attachment", "Block",
           "BlockResult", "PlantHolder", "RetryResult", "Task", "WallClockLimit",
           "block_lines", "block_on", "dask_run_block", "execute", "fmu_digest",
           "line_ends", "materialise", "read_frames", "run_alone", "run_block", "run_code",
           "table_bytes", "table_of", "wall_limit_message", "write_frame"]
