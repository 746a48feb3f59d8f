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

import contextlib
import hashlib
import logging
import secrets
import threading
import time
from collections.abc import Iterator
from concurrent.futures import CancelledError
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Literal

from distributed.diagnostics.plugin import WorkerPlugin

from wmr.adapters.fmi.varmap import VariableMap
from wmr.apps.batch import worker as _worker
from wmr.apps.batch.local import DIED_TWICE, Killed
from wmr.apps.batch.worker import (
    TOKEN_FILE,
    Attachment,
    Block,
    BlockResult,
    RetryResult,
    TaskSource,
    dask_run_block,
)
from wmr.infra.errors import ClusterError

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


#: Dask tasks in flight per worker thread (each a range of runs): enough to keep every
#: thread busy while results travel back, few enough that a million-run batch is not all
#: submitted at once.
WINDOW: Final = 4
#: Seconds to fetch a finished task's result.  A worker that dies after finishing a task takes
#: the result with it; Dask then computes the task again, but a fetch that started before the
#: death was seen to wait for ever while the other workers kept dying.  Past this wait the
#: task's runs are treated as those of a dead worker: one more try each, under a new key.
RESULT_WAIT_S: Final = 30.0
#: Seconds each finished task's result is still waited for, at least, once its group's fetch
#: has used up :data:`RESULT_WAIT_S`: a result that is there comes in well under it, and a
#: group's wait stays about :data:`RESULT_WAIT_S`, not that once more for each of its tasks
#: (all the workers gone mid-fetch must still stop the batch in bounded time).
RESULT_FLOOR_S: Final = 1.0
#: Most runs in one Dask task (a range: the worker draws its runs and returns their journal
#: lines and summary rows in one piece).  A task costs the scheduler, the client and the
#: worker the same whatever it holds (Dask's own cost is 0.2 to 1 ms a task, the client's
#: about 1 ms), and a run of ``mc_fig10`` takes a worker about 2.5 ms: with 1,024 runs a
#: task the client spends about 1 us a run on Dask; a dead worker loses at most its range's
#: work (its runs are run again).
MAX_CHUNK: Final = 1024
#: Seconds a batch waits for its scheduler to have a worker before it stops, saying it has
#: none: a worker started with the batch joins within a few seconds; a batch sent to a
#: scheduler without workers waited for ever.
WORKER_WAIT_S: Final = 30.0
#: Seconds between two looks at the scheduler's workers while the batch waits for its tasks:
#: when every worker left mid-batch, the tasks would wait for ever.
WORKER_POLL_S: Final = 1.0


def task_runs(n_runs: int, threads: int) -> int:
    """Runs per Dask task for ``n_runs`` runs on ``threads`` worker threads.

    Each thread gets at least 8 tasks (the last ones share out evenly), of at most
    :data:`MAX_CHUNK` runs; but a task holds at least as many runs as there are threads
    (while each thread still gets one): the client spends about 1 to 5 ms of CPU on each
    task (submitting it, fetching its result, writing its rows and lines), and a cluster of
    ``threads`` threads finishes one every ``runs x w / threads`` seconds (``w`` a run's time,
    2.5 ms for ``mc_fig10``), so that with as many runs a task as threads the client has a
    run's time for each task, however large the cluster (10^6 runs on 1,000 threads: 1,000
    tasks of 1,000 runs, not 8,000 of 125)."""
    threads = max(1, threads)
    return max(1, min(MAX_CHUNK, max(n_runs // (8 * threads),
                                     min(threads, n_runs // threads))))


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
        Runs per Dask task; default: :func:`task_runs` (up to :data:`MAX_CHUNK`; fewer,
        longer tasks cost the scheduler and the client less).
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

    def run(self, tasks: TaskSource) -> Iterator[list[BlockResult | Killed]]:
        """Submit ``tasks``, one Dask task per range of runs; yield, as they finish, each
        range's :class:`~wmr.apps.batch.worker.BlockResult` and a :class:`Killed` for each run
        whose task failed: in lists, the tasks that finished together (their results fetched
        at once, made durable together by the caller).

        At most :data:`WINDOW` tasks per worker thread are submitted at a time, the next as one
        finishes: the client holds, and the scheduler tracks, a window of a large batch, not
        all of it.  Closing the iterator early cancels the runs not finished.

        Raises
        ------
        ClusterError
            The scheduler went away or cannot be reached, or has no worker within
            :data:`WORKER_WAIT_S`: the runs not yielded are not results (none is made up).
        """
        from distributed import Client

        # the local files first: an error reading them is not the cluster's
        plugin = FmuPlugin(self.fmu_path.name, self.fmu_path.read_bytes())
        att: Any = None
        if self.attachment is not None:
            # by value in each task (a spec is a few kB), not scattered: scattered data
            # dies with the workers that hold it, and every task needing it is then
            # cancelled instead of rescheduled when a worker process dies
            att = Attachment(self.attachment.name, self.attachment.read_bytes())
        token = secrets.token_hex(16)
        if not self.ship_logs:
            (self.out_dir / TOKEN_FILE).write_text(token)
        address = self.scheduler or _address(self.client)
        own = self.client is None
        with _cluster_errors(address, None, "cannot be reached"):
            client = self.client if self.client is not None else Client(self.scheduler,
                                                                         timeout="20s")
        futures: dict[Any, Block] = {}
        lost = False
        try:
            yield from self._run(client, address, tasks, plugin, att, token, futures)
        except ClusterError:
            lost = True
            raise
        finally:
            # never a call on a client that lost its scheduler: it raises (ClosedClientError)
            # over the error that says so
            if futures and not lost and client.status == "running":
                with contextlib.suppress(Exception):
                    client.cancel(list(futures))
            if own:
                with contextlib.suppress(Exception), _quiet(lost):
                    client.close()

    def _run(self, client: Client, address: str, tasks: TaskSource, plugin: FmuPlugin,
             att: Attachment | None, token: str, futures: dict[Any, Block]
             ) -> Iterator[list[BlockResult | Killed]]:
        """:meth:`run` on ``client``; ``futures`` holds the tasks in flight (the caller
        cancels them)."""
        from distributed import as_completed

        with _cluster_errors(address, client):
            client.register_plugin(plugin, name=f"wmr-fmu-{plugin.sha256[:16]}")
            try:
                client.wait_for_workers(1, timeout=WORKER_WAIT_S)
            except TimeoutError as exc:
                if client.status != "running":
                    raise
                raise _starved(address, "has no workers",
                               f"none joined within {WORKER_WAIT_S:g} s") from exc
            threads = sum(client.nthreads().values()) or 1
            watch = _WorkerWatch(client, futures)
        out = str(self.out_dir.resolve())
        size = self.chunk or task_runs(len(tasks), threads)

        def submit(block: Block, tag: str) -> Any:
            fut = client.submit(dask_run_block, block, plugin.sha256, att, out, token,
                                self.var_map, pure=False, retries=0,
                                key=f"wmr-runs-{block.indices[0]}-{token[:8]}{tag}")
            futures[fut] = block
            return fut

        source = tasks.blocks(size)

        def submit_next() -> Any:
            block = next(source, None)
            return submit(block, "") if block is not None else None

        try:
            with _cluster_errors(address, client):
                for _ in range(WINDOW * threads):
                    if submit_next() is None:
                        break
                retried: set[int] = set()
                # Not as_completed(with_results=True): it gathers each result inside its own
                # tracking task, and a worker that dies during that gather raises KilledWorker
                # there; the future is then never yielded and the batch waits for ever (seen with
                # workers killed mid-run).  Waiting only for completion, then asking for the
                # finished futures' results here (_results: with a bounded wait), cannot lose one.
                done = as_completed(list(futures))
                for finished in done.batches():  # every task finished meanwhile, at once
                    blocks = [futures.pop(fut) for fut in finished]
                    for _ in finished:
                        more = submit_next()
                        if more is not None:
                            done.add(more)
                    group: list[BlockResult | Killed] = []
                    for fut, block, result in zip(finished, blocks, _results(client, finished),
                                                  strict=True):
                        if isinstance(result, RetryResult):  # each died alone: its own run
                            group += result.results
                            group += [Killed(i, "failed", DIED_TWICE, 0.0) for i in result.died]
                            continue
                        if not isinstance(result, BaseException):
                            group.append(result)
                            continue
                        how = task_failure(result, fut.status, client.status)
                        if how == "cluster":  # its runs were not run, or their results are
                            # lost with the connection: none is journalled, a resume runs them
                            if group:
                                yield group  # those that came back are kept
                            if watch.starved.is_set():
                                raise _starved(address, "has no workers left",
                                               f"none for {WORKER_WAIT_S:g} s")
                            raise _lost(address, result)
                        if isinstance(result, TimeoutError):  # the result died with its worker
                            fut.cancel()
                        died = how == "worker"
                        # the rule of the local pool: a run whose worker died gets one more
                        # try, alone (the others of its range too: they died with it, and
                        # which one killed it is not known): the range's runs once more, in a
                        # process of the worker's own that costs a run that dies only itself
                        again = [i for i in block.indices if died and i not in retried]
                        if again:
                            retried.update(again)
                            done.add(submit(replace(block, indices=again, retry=True), "-retry"))
                        group += [Killed(index, "failed", DIED_TWICE if died else
                                         f"the Dask task failed: {type(result).__name__}: "
                                         f"{result}", 0.0)
                                  for index in block.indices if index not in again]
                    if group:
                        yield group
        finally:
            watch.stop()


def _results(client: Client, finished: list[Any]) -> list[Any]:
    """The results of the finished futures ``finished``, in their order (an exception for a
    future whose result could not be had): several in one ``gather`` (one round trip through
    the scheduler for all, not one each: a client that fell behind catches up), with a
    bounded wait; if that fails (a task's error, a worker that died with a result, a lost
    connection) or takes longer than :data:`RESULT_WAIT_S`, each is asked for alone, as one
    alone always is, and its failure said for it; the group's wait is bounded as one's is
    (each alone then waits what is left of it, or :data:`RESULT_FLOOR_S`)."""
    deadline = time.monotonic() + RESULT_WAIT_S
    if len(finished) > 1:
        with contextlib.suppress(Exception):
            return list(client.sync(client._gather, finished,
                                    callback_timeout=RESULT_WAIT_S))
    got: list[Any] = []
    for fut in finished:
        try:
            got.append(fut.result(timeout=max(RESULT_FLOOR_S, deadline - time.monotonic())))
        except Exception as exc:  # KilledWorker, CancelledError, TimeoutError, its own
            got.append(exc)
    return got


class _WorkerWatch:
    """Watches the workers of ``client``'s scheduler while a batch waits for its tasks: once
    it has had none for :data:`WORKER_WAIT_S` s (all left mid-batch), sets :attr:`starved`
    and cancels the tasks in ``futures``, which would wait for ever (the batch then stops,
    saying so).

    A look every :data:`WORKER_POLL_S` s can miss a worker that a nanny restarts and that
    dies again in between (a run that crashes every worker it is given): from the first look
    that finds none, each worker that joins is an event of the scheduler's topic ``all``, and
    one joined since the last look counts as one seen.  Not before: the scheduler sends a
    client subscribed to ``all`` an event for every ``gather`` too, one per task, which cost
    the client about 0.2 ms of CPU a task.  (A caller's own handler of that topic on the
    same client is replaced while the batch has no workers.)
    """

    def __init__(self, client: Client, futures: dict[Any, Block]) -> None:
        self.client = client
        self.futures = futures
        self.starved = threading.Event()
        self._stop = threading.Event()
        self._joined = 0
        self._subscribed = False
        threading.Thread(target=self._watch, name="wmr-dask-workers", daemon=True).start()

    def _event(self, event: tuple[float, Any]) -> None:
        msg = event[1]
        if isinstance(msg, dict) and msg.get("action") == "add-worker":
            self._joined += 1

    def _watch(self) -> None:
        idle_since: float | None = None
        joined = self._joined
        while not self._stop.wait(WORKER_POLL_S):
            try:
                workers = self.client.nthreads()
                if not workers and not self._subscribed:  # the joins from now on count
                    self._subscribed = True
                    self.client.subscribe_topic("all", self._event)
            except Exception:  # the connection's loss: the tasks' futures say it
                return
            now = time.monotonic()
            if workers or self._joined != joined:
                idle_since, joined = None, self._joined
                continue
            if idle_since is None:
                idle_since = now
            if now - idle_since < WORKER_WAIT_S:
                continue
            self.starved.set()
            while True:
                try:
                    pending = list(self.futures)
                    break
                except RuntimeError:  # the batch changed it meanwhile
                    continue
            with contextlib.suppress(Exception):
                self.client.cancel(pending, reason="no-workers")
            return

    def stop(self) -> None:
        """Stop watching (the client may have lost its scheduler: then no call on it)."""
        self._stop.set()
        if self._subscribed and self.client.status == "running":
            with contextlib.suppress(Exception):
                self.client.unsubscribe_topic("all")


def task_failure(exc: BaseException, future_status: str | None, client_status: str
                 ) -> Literal["run", "worker", "cluster"]:
    """Whose failure ``exc`` is, raised asking a Dask task for its result (or asking the
    client anything).

    Parameters
    ----------
    exc
        What was raised.
    future_status
        The task's future's status then (``"error"`` when the task raised or its workers
        died; ``None`` when no task was asked).
    client_status
        The client's status then (``"running"`` while it is connected to its scheduler).

    Returns
    -------
    str
        ``"run"``: the task's runs failed (they raised): each is a ``failed`` row.
        ``"worker"``: the worker running them died (``KilledWorker``), or took their result
        with it (no result within :data:`RESULT_WAIT_S`): each gets one more try.
        ``"cluster"``: the scheduler or the connection to it went away (a cancelled future,
        a closed comm or client, a connection that timed out, anything while the client is
        not connected): the runs were not run, or their results never came back; none of
        them is a result.
    """
    from distributed.comm.core import CommClosedError

    if client_status not in ("running", "newly-created"):
        return "cluster"
    if isinstance(exc, CancelledError | CommClosedError) \
            or type(exc).__name__ == "ClosedClientError":
        return "cluster"
    if type(exc).__name__ == "KilledWorker":
        return "worker"
    if future_status == "error":
        return "run"
    if future_status is None:  # not a task's: only a connection's error is the cluster's
        return "cluster" if isinstance(exc, OSError) else "run"
    if isinstance(exc, TimeoutError):
        return "worker"
    return "run" if future_status == "finished" else "cluster"


@contextlib.contextmanager
def _cluster_errors(address: str, client: Client | None, what: str = "went away"
                    ) -> Iterator[None]:
    """Inside: an error that :func:`task_failure` calls the cluster's (a submit or a call on
    a client that lost its scheduler at ``address``; ``client`` None: while connecting)
    becomes one :class:`ClusterError`, the scheduler that ``what``; any other passes."""
    try:
        yield
    except ClusterError:
        raise
    except Exception as exc:
        if task_failure(exc, None, "running" if client is None else client.status) \
                != "cluster":
            raise
        raise _lost(address, exc, what) from None


def _address(client: Client | None) -> str:
    """The scheduler address of ``client``, for messages."""
    scheduler = getattr(client, "scheduler", None)
    return str(getattr(scheduler, "address", None) or "of the given client")


def _lost(address: str, exc: BaseException, what: str = "went away") -> ClusterError:
    """The :class:`ClusterError` of a scheduler at ``address`` that ``what`` (``exc`` says
    how), in one line."""
    how = str(exc).strip().splitlines()
    return ClusterError(f"the Dask scheduler {address} {what}",
                        "start it (dask scheduler, dask worker) and run the same command "
                        "again", type(exc).__name__ + (f": {_cut(how[0])}" if how else ""))


@contextlib.contextmanager
def _quiet(lost: bool) -> Iterator[None]:
    """Inside: no ``distributed.client`` log lines if the client ``lost`` its scheduler
    (closing it logs the reconnection it gives up, with a traceback): the batch's own error
    line says what happened."""
    logger = logging.getLogger("distributed.client")
    level = logger.level
    if lost:
        logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


def _starved(address: str, what: str, cause: str) -> ClusterError:
    """The :class:`ClusterError` of a scheduler at ``address`` without workers."""
    return ClusterError(f"the Dask scheduler {address} {what}",
                        f"start some (dask worker {address}) and run the same command again",
                        cause)


def _cut(text: str, limit: int = 120) -> str:
    return text if len(text) <= limit else text[:limit] + "..."


__all__ = ["DaskExecutor", "FmuPlugin", "task_failure", "task_runs"]
