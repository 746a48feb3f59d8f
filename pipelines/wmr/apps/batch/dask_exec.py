"""Execution on a Dask cluster (``wmr batch --scheduler ADDRESS``).

The FMU's bytes go to each worker once, in a :class:`FmuPlugin` (a worker that joins later gets
it too); each worker thread keeps one :class:`~wmr.adapters.fmi.robot.FmuPlant` for all its runs.
A worker that sees the batch folder (same host, or a shared file system) writes each log there
directly; any other returns the log's bytes, which the client writes under ``OUT/runs``: the
workers need the ``wmr`` package, not a file system shared with the client.

A run past its wall-clock limit is stopped by its own progress callback (every 100 control
steps).  A hang inside the FMU's C code cannot be interrupted in a Dask worker thread; the
local executor kills such a worker, the Dask one only reports it when its future finishes.
"""

from __future__ import annotations

import hashlib
import itertools
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from distributed.diagnostics.plugin import WorkerPlugin

from wmr.adapters.fmi.varmap import VariableMap
from wmr.apps.batch import worker as _worker
from wmr.apps.batch.local import DIED_TWICE, Outcome, made_up_record
from wmr.apps.batch.worker import TOKEN_FILE, Attachment, Task, TaskSource, dask_run_many

if TYPE_CHECKING:
    from distributed import Client


class FmuPlugin(WorkerPlugin):
    """Writes the FMU once per Dask worker and registers it by SHA-256.

    Parameters
    ----------
    name
        The FMU's file name (kept: the logs record it).
    data
        Its bytes.
    """

    def __init__(self, name: str, data: bytes) -> None:
        self.name = name
        self.data = data
        self.sha256 = hashlib.sha256(data).hexdigest()

    def setup(self, worker: Any) -> None:
        _worker._FMUS[self.sha256] = _worker.materialise(self.name, self.data)

    def teardown(self, worker: Any) -> None:
        _worker._FMUS.pop(self.sha256, None)


#: Dask tasks in flight per worker thread (each of ``chunk`` runs): enough to keep every
#: thread busy while results travel back, few enough that a million-run batch is not all
#: submitted (and made) at once.
WINDOW: Final = 4
#: Seconds to fetch a finished task's result.  A worker that dies after finishing a task takes
#: the result with it; Dask then computes the task again, but a fetch that started before the
#: death was seen to wait for ever while the other workers kept dying.  Past this wait the
#: task's runs are treated as those of a dead worker: one more try each, under a new key.
RESULT_WAIT_S: Final = 30.0
#: Most runs in one Dask task.  A task costs the scheduler, the client and the worker the same
#: whatever it holds, and a run of ``mc_fig10`` takes a worker 3 ms (19 with its full log):
#: with 8 runs a task Dask was 16 % slower than the local pool on 10,000 runs, with 32 it is
#: 13 % faster (failed-only) and 11 % slower (full logs) (docs/batch.md); a dead worker loses
#: at most 32 runs' work.
MAX_CHUNK: Final = 32


class DaskExecutor:
    """Runs on a Dask cluster.

    Parameters
    ----------
    fmu_path
        The FMU, built once by the caller; its bytes are shipped.
    scheduler
        Scheduler address (``tcp://host:8786``); ignored when ``client`` is given.
    client
        An existing client (left open).
    out_dir
        The batch folder.
    attachment
        File attached to every log (the spec).
    ship_logs
        Send every log back to the client, even from workers that see ``out_dir``.
    chunk
        Runs per Dask task; default: up to :data:`MAX_CHUNK`, so that each worker thread gets
        at least 8 tasks (fewer, longer tasks cost the scheduler, which shares the cores, less).
    """

    def __init__(self, fmu_path: Path, out_dir: Path, *, scheduler: str | None = None,
                 client: Client | None = None, attachment: Path | None = None,
                 ship_logs: bool = False, chunk: int | None = None,
                 var_map: VariableMap | None = None) -> None:
        self.chunk = chunk
        self.var_map = var_map
        self.fmu_path = fmu_path
        self.out_dir = out_dir
        self.ship_logs = ship_logs
        self.scheduler = scheduler
        self.client = client
        self.attachment = attachment

    def run(self, tasks: TaskSource) -> Iterator[Outcome]:
        """Submit ``tasks``; yield each :class:`Outcome` as it finishes.

        At most :data:`WINDOW` tasks per worker thread are submitted at a time, the next as one
        finishes: the client holds, and the scheduler tracks, a window of a large batch, not
        all of it.  Closing the iterator early cancels the runs not finished.
        """
        from distributed import Client, as_completed

        own = self.client is None
        client = self.client if self.client is not None else Client(self.scheduler,
                                                                     timeout="20s")
        futures: dict[Any, list[Task]] = {}
        try:
            plugin = FmuPlugin(self.fmu_path.name, self.fmu_path.read_bytes())
            client.register_plugin(plugin, name=f"wmr-fmu-{plugin.sha256[:16]}")
            att: Any = None
            if self.attachment is not None:
                # by value in each task (a spec is a few kB), not scattered: scattered data
                # dies with the workers that hold it, and every task needing it is then
                # cancelled instead of rescheduled when a worker process dies
                att = Attachment(self.attachment.name, self.attachment.read_bytes())
            token = secrets.token_hex(16)
            if not self.ship_logs:
                (self.out_dir / TOKEN_FILE).write_text(token)
            out = str(self.out_dir.resolve())
            threads = sum(client.nthreads().values()) or 1
            size = self.chunk or max(1, min(MAX_CHUNK, len(tasks) // (8 * threads)))
            def submit(chunk: list[Task], tag: str) -> Any:
                fut = client.submit(dask_run_many, chunk, plugin.sha256, att, out, token,
                                    self.var_map, pure=False, retries=0,
                                    key=f"wmr-runs-{chunk[0].run_id}-{token[:8]}{tag}")
                futures[fut] = chunk
                return fut

            source = iter(tasks)

            def submit_next() -> Any:
                chunk = list(itertools.islice(source, size))
                return submit(chunk, "") if chunk else None

            for _ in range(WINDOW * threads):
                if submit_next() is None:
                    break
            retried: set[str] = set()
            # Not as_completed(with_results=True): it gathers each result inside its own
            # tracking task, and a worker that dies during that gather raises KilledWorker
            # there; the future is then never yielded and the batch waits for ever (seen with
            # workers killed mid-run).  Waiting only for completion, then asking the finished
            # future for its result here, cannot lose one.
            done = as_completed(list(futures))
            for fut in done:
                chunk = futures.pop(fut)
                more = submit_next()
                if more is not None:
                    done.add(more)
                try:
                    result = fut.result(timeout=RESULT_WAIT_S)
                except Exception as exc:  # KilledWorker, CancelledError, TimeoutError, its own
                    result = exc
                if isinstance(result, BaseException):
                    lost = isinstance(result, TimeoutError)  # the result died with its worker
                    if lost:
                        fut.cancel()
                    died = lost or type(result).__name__ == "KilledWorker"
                    # the rule of the local pool: a run whose worker died gets one more
                    # try, alone (the others of its chunk too: they died with it)
                    again = [t for t in chunk if died and t.run_id not in retried]
                    for task in again:
                        retried.add(task.run_id)
                        done.add(submit([task], "-retry"))
                    for task in chunk:
                        if task in again:
                            continue
                        yield Outcome(task.run_id, made_up_record(
                            task.run_id, "failed", DIED_TWICE if died else
                            f"the Dask task failed: {type(result).__name__}: {result}"),
                            0.0, killed=True)
                    continue
                for run_id, record, data, wall in result:
                    yield Outcome(run_id, record, wall, log=data)
        finally:
            if futures:
                client.cancel(list(futures))
            if own:
                client.close()


__all__ = ["DaskExecutor", "FmuPlugin"]
