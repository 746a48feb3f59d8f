"""Local execution: a pool of worker processes, one FMU instance each.

Not :class:`concurrent.futures.ProcessPoolExecutor`: a run that hangs must be killable on its
own, and a worker that dies (a crash in the FMU's C code, the OOM killer) must cost its run
only, not the pool: the run is given once more to a fresh worker, then recorded ``failed``.
Each worker has its own pipe; the parent hands out a range of runs at a time (a
:class:`~wmr.apps.batch.worker.Block`: the worker draws each run itself and sends back the
range's journal lines and summary rows in one message), reads from a word of shared memory
which run each worker is on and since when, kills a worker whose run passes the hard
wall-clock limit, and starts a new one in its place.  Workers come from a
``forkserver`` that has imported the simulation code once, so a replacement starts in
milliseconds and no worker inherits the parent's threads.  Workers ignore SIGINT and SIGTERM:
the parent alone stops them; and they end as soon as it is gone, even killed outright.

Workers never import the user's script: multiprocessing would run it again in each worker
(as ``__mp_main__``) to find its functions, repeating a top-level ``wmr.batch`` call inside
the batch; a worker needs only :mod:`wmr` (its target and every task it is sent are wmr's
own), so the worker's start data leaves the main module out (:class:`_WorkerProcess`).
"""

from __future__ import annotations

import multiprocessing as mp
import multiprocessing.context
import multiprocessing.popen_forkserver
import multiprocessing.spawn
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, replace
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

import wmr.apps.run  # noqa: F401 - preloaded by the forkserver, so that workers start fast
from wmr.adapters.fmi.varmap import VariableMap
from wmr.apps.batch.worker import (
    Block,
    BlockResult,
    PlantHolder,
    Task,
    TaskSource,
    run_block,
    wall_limit_message,
)
from wmr.core.energy import ENERGY_KEYS
from wmr.infra.durable import open_own
from wmr.infra.errors import FmuError, WmrError
from wmr.infra.orphans import die_with

#: Exit code of a worker that could not open the FMU (one whose batch process is gone:
#: :data:`wmr.infra.orphans.ORPHANED`).
_INIT_FAILED = 3


#: Open files a batch needs besides its workers' (standard streams, the journal and its lock,
#: the module being imported, a log being recovered, the forkserver's sockets and a fork
#: request's descriptors, a worker's FMU, log and pidfd): each process has the same limit.
_FDS_SPARE = 16
#: Open files per worker: its pipe and its process sentinel in the batch process, its exit
#: status pipe in the forkserver.
_FDS_PER_WORKER = 3


def open_files_needed(workers: int) -> int:
    """About how many files a batch of ``workers`` local workers keeps open in its process:
    those open now (at least the standard streams), 3 per worker, and a spare of 16."""
    try:
        open_now = len(os.listdir("/proc/self/fd"))
    except OSError:  # not Linux: assume few
        open_now = 16
    return max(open_now, 16) + _FDS_PER_WORKER * workers + _FDS_SPARE


def check_open_files(workers: int) -> None:
    """Make sure ``workers`` local workers can open what they need, before any is started:
    the soft open-file limit is raised to what is needed when the hard limit allows it, else
    one :class:`WmrError` says the limit and how to fix it (below it, the forkserver died with a
    traceback, or a worker could not be started)."""
    try:
        import resource
    except ImportError:  # not POSIX
        return
    need = open_files_needed(workers)
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or soft >= need:
        return
    if hard == resource.RLIM_INFINITY or hard >= need:
        resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
        return
    fewer = max((k for k in range(1, workers) if open_files_needed(k) <= soft), default=0)
    who = "1 worker needs" if workers == 1 else f"{workers} workers need"
    raise WmrError(f"the open-file limit (ulimit -n) is {soft}, and {who} about {need} open "
                   f"files: raise it (e.g. "
                   f"ulimit -n {max(256, need)})"
                   + (f", or run --workers {fewer}" if fewer else ""))


@dataclass
class Outcome:
    """A finished run as :func:`wmr.apps.batch.run_batch` reports it to its ``on_outcome``.

    Attributes
    ----------
    run_id
        The run.
    record
        Its result record (:func:`wmr.apps.run.run_to_log`), or one made up by the executor when the
        worker was killed or died.
    wall_s
        Wall time of the run on its worker, s.
    killed
        The executor stopped the run from outside (its log has no ``result`` record).
    log
        The log's bytes when the worker sent them back (Dask), else ``None``.
    worker
        Who ran it (process id or Dask worker address).
    """

    run_id: str
    record: dict[str, Any]
    wall_s: float
    killed: bool = False
    log: bytes | None = None
    worker: str = ""


@dataclass(frozen=True)
class Killed:
    """A run that its executor stopped or lost (a hang past the hard limit, a worker that died
    on it twice, a Dask task that failed): its record is made up (:func:`made_up_record`).

    Attributes
    ----------
    index
        The run's index in the spec.
    status, message
        Its made-up record's.
    wall_s
        How long it ran, s.
    worker
        Who ran it.
    """

    index: int
    status: str
    message: str
    wall_s: float
    worker: str = ""


#: Message of a run whose worker process died on it twice (the same on every executor).
DIED_TWICE = "the worker process died during the run, and again when it was retried"


def made_up_record(run_id: str, status: str, message: str) -> dict[str, Any]:
    """The result record of a run that produced none (killed, or its worker died)."""
    return {"name": run_id, "status": status, "message": message,
            "final_position_error_m": None, "final_heading_error_rad": None,
            "time_to_goal_s": None, "path_length_m": None,
            **dict.fromkeys(ENERGY_KEYS),
            "torque_sq_integral_n2m2s": None, "peak_torque_nm": None, "steps": None,
            "mcap": None}


def _worker_main(conn: Connection, fmu_path: str, runs_dir: str, attachment: str | None,
                 log_file: str | None, batch_pid: int,
                 var_map: VariableMap | None = None, where: Any = None) -> None:
    """A worker process: open the FMU once, then run the blocks the pipe brings until ``None``.

    ``where`` is shared memory of two doubles: the index of the run it starts and when
    (``time.monotonic``, the same clock in every process), written before each run.
    """
    die_with(batch_pid)
    # Ctrl-C and SIGTERM reach the whole process group: the parent alone decides what stops
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if log_file is not None:  # the FMU's own messages go to a file, not over the progress bar
        try:
            fd = open_own(log_file, os.O_WRONLY | os.O_CREAT | os.O_APPEND, "worker log")
        except WmrError as exc:  # the batch folder removed, unwritable or planted with a link
            conn.send(("setup_error", f"{exc} (was the batch folder removed or changed?)"))
            conn.close()
            os._exit(_INIT_FAILED)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        os.close(fd)
    try:
        holder = PlantHolder(Path(fmu_path), var_map)
    except Exception as exc:
        conn.send(("init_error", f"{type(exc).__name__}: {exc}"))
        conn.close()
        os._exit(_INIT_FAILED)
    conn.send(("ready",))
    att = Path(attachment) if attachment else None
    runs = Path(runs_dir)
    me = str(os.getpid())

    def starting(index: int) -> None:
        if where is not None:
            where[1] = time.monotonic()
            where[0] = float(index)

    def run_one(task: Task) -> tuple[dict[str, Any], bytes | None]:
        return holder.run(task, runs / task.log_relpath, att), None

    try:
        while True:
            try:
                block: Block | None = conn.recv()
            except EOFError:
                break
            if block is None:
                break
            conn.send(("done", run_block(block, run_one, runs.parent, me, starting)))
    finally:
        holder.close()
        conn.close()


#: Held while a worker's start data is made without the main module (one launch at a time).
_LAUNCH_LOCK = threading.Lock()


class _PopenWithoutMain(multiprocessing.popen_forkserver.Popen):
    """A forkserver child started without the parent's main module: its start data has no
    ``init_main_from_path`` (a script) or ``init_main_from_name`` (``python -m``), which the
    child would run again as ``__mp_main__`` before its target."""

    def _launch(self, process_obj: Any) -> None:
        # the stdlib reads the start data from one function of multiprocessing.spawn; it is
        # wrapped for the length of this launch only, under a lock, and restored
        with _LAUNCH_LOCK:
            made = multiprocessing.spawn.get_preparation_data

            def without_main(name: str) -> dict[str, Any]:
                data: dict[str, Any] = made(name)
                data.pop("init_main_from_path", None)
                data.pop("init_main_from_name", None)
                return data

            multiprocessing.spawn.get_preparation_data = without_main
            try:
                super()._launch(process_obj)  # type: ignore[misc]  # not in typeshed
            finally:
                multiprocessing.spawn.get_preparation_data = made


class _WorkerProcess(multiprocessing.context.ForkServerProcess):
    """A batch worker: a forkserver process that does not import the user's script."""

    @staticmethod
    def _Popen(process_obj: Any) -> _PopenWithoutMain:  # the stdlib calls it by this name
        return _PopenWithoutMain(process_obj)


def _start_problem(exc: BaseException) -> str:
    """Why a worker could not be started, and what to do."""
    import errno

    if isinstance(exc, OSError) and exc.errno in (errno.EMFILE, errno.ENFILE):
        return f"{exc.strerror} (raise ulimit -n, or run fewer --workers)"
    if isinstance(exc, MemoryError) or (isinstance(exc, OSError)
                                        and exc.errno in (errno.ENOMEM, errno.EAGAIN)):
        return "out of memory or processes (raise ulimit -v or ulimit -u, or run fewer --workers)"
    if isinstance(exc, EOFError):
        return "the process that starts workers ended (too few open files or too little memory?)"
    return f"{type(exc).__name__}: {exc}"


@dataclass
class _Slot:
    number: int
    proc: BaseProcess
    conn: Connection
    #: [index of the run it is on (-1: none yet), when it started (time.monotonic)]
    where: Any
    block: Block | None = None
    ready: bool = False

    def give(self, block: Block) -> None:
        """Send ``block`` (its first run counts as started now: a worker that never reads it
        is caught by the hard limit too)."""
        self.block = block
        self.where[0], self.where[1] = -1.0, time.monotonic()
        try:
            self.conn.send(block)
        except OSError:  # the worker is gone: wait() reports it
            pass

    def current(self) -> tuple[int, float]:
        """The run it is on (its index) and since when (``time.monotonic``)."""
        assert self.block is not None
        index, since = int(self.where[0]), float(self.where[1])
        return (index if index >= 0 else self.block.indices[0]), since


class LocalPool:
    """Worker processes on this machine.

    Parameters
    ----------
    fmu_path
        The FMU, built once by the caller.
    runs_dir
        Where the workers write ``<run_id>.mcap``.
    workers
        Number of processes.
    hard_limit_s
        A run still going after this wall time is killed with its worker (``None``: never).
    attachment
        File attached to every log (the spec).
    log_dir
        Folder for the workers' stdout/stderr (``worker-<n>.log``); ``None`` keeps them on the
        terminal.
    """

    def __init__(self, fmu_path: Path, runs_dir: Path, workers: int, *,
                 hard_limit_s: float | None = None, attachment: Path | None = None,
                 log_dir: Path | None = None, var_map: VariableMap | None = None) -> None:
        self.fmu_path = fmu_path
        self.var_map = var_map
        self.runs_dir = runs_dir
        self.workers = max(1, int(workers))
        self.hard_limit_s = hard_limit_s
        self.attachment = attachment
        self.log_dir = log_dir
        self._ctx = mp.get_context("forkserver")
        self._ctx.set_forkserver_preload(["wmr.apps.batch.local"])

    def _spawn(self, number: int) -> _Slot:
        """Start worker ``number``; a pipe or a process that cannot be made (no file
        descriptors, no memory, the forkserver gone) is one :class:`WmrError`."""
        log_file = str(self.log_dir / f"worker-{number}.log") if self.log_dir else None
        try:
            parent, child = self._ctx.Pipe(duplex=True)
        except OSError as exc:
            raise WmrError(f"cannot make the pipe of batch worker {number}: "
                           f"{_start_problem(exc)}") from None
        where = self._ctx.RawArray("d", 2)
        proc = _WorkerProcess(
            target=_worker_main, name=f"wmr-batch-{number}", daemon=True,
            args=(child, str(self.fmu_path), str(self.runs_dir),
                  str(self.attachment) if self.attachment else None, log_file, os.getpid(),
                  self.var_map, where))
        try:
            proc.start()
        except (OSError, EOFError, MemoryError) as exc:  # EOFError: the forkserver died
            parent.close()
            raise WmrError(f"cannot start batch worker {number}: {_start_problem(exc)}"
                           ) from None
        finally:
            child.close()
        return _Slot(number, proc, parent, where)

    @staticmethod
    def _stop(slot: _Slot, kill: bool) -> None:
        if kill or slot.block is not None:
            slot.proc.kill()
        else:
            try:
                slot.conn.send(None)
            except OSError:
                slot.proc.kill()
        slot.proc.join(2.0)
        if slot.proc.is_alive():
            slot.proc.kill()
            slot.proc.join(2.0)
        slot.conn.close()

    def run(self, tasks: TaskSource, block_runs: int = 1
            ) -> Iterator[list[BlockResult | Killed]]:
        """Run ``tasks`` in blocks of up to ``block_runs`` runs; yield, as they finish, the
        blocks' :class:`~wmr.apps.batch.worker.BlockResult` and a :class:`Killed` for each run
        stopped or lost with its worker: in lists, those that came in together (the caller
        makes them durable together).

        A worker that dies or is killed loses its block's results: the run it was on gets one
        more try, alone (then it is a ``failed`` :class:`Killed`), and the block's other runs
        are given again.  Closing the iterator early (Ctrl-C in the consumer) kills the
        workers.

        Raises
        ------
        FmuError
            A worker cannot open the FMU.
        """
        check_open_files(min(self.workers, len(tasks)))
        source = tasks.blocks(block_runs)  # taken as they go: nothing is made up front
        again: deque[Block] = deque()
        retried: set[int] = set()
        slots: list[_Slot] = []
        spawned = 0

        def lost(slot: _Slot, died: bool) -> Iterator[Killed]:
            """The block of ``slot``, whose worker died (``died``) or was killed at the hard
            limit: its run in flight once more or made up, the others given again."""
            block = slot.block
            assert block is not None
            index, since = slot.current()
            rest = [i for i in block.indices if i != index]
            if rest:
                again.append(replace(block, indices=rest, retry=False))
            wall = time.monotonic() - since
            if not died:
                yield Killed(index, "timeout",
                             wall_limit_message(block.wall_limit_s or self.hard_limit_s or 0.0)
                             + "; the worker was killed", wall, str(slot.proc.pid))
            elif index not in retried:  # e.g. the OOM killer: once more, then failed
                retried.add(index)
                again.appendleft(replace(block, indices=[index], retry=True))
            else:
                yield Killed(index, "failed", DIED_TWICE, wall,
                             f"{slot.proc.pid} (died, exit code {slot.proc.exitcode})")

        try:
            for _ in range(min(self.workers, len(tasks))):
                slots.append(self._spawn(spawned))
                spawned += 1
            while True:
                for slot in slots:
                    if slot.block is None:
                        block = again.popleft() if again else next(source, None)
                        if block is not None:
                            slot.give(block)
                busy = [s for s in slots if s.block is not None]
                if not busy:
                    return
                timeout = 0.5
                if self.hard_limit_s is not None:
                    first = min(s.current()[1] for s in busy) + self.hard_limit_s
                    timeout = max(0.0, min(timeout, first - time.monotonic()))
                # the process too: one gone whose pipe a child of its own (an FMU's helper)
                # keeps open never reads as EOF
                ready = wait([s.conn for s in busy] + [s.proc.sentinel for s in busy], timeout)
                group: list[BlockResult | Killed] = []
                for slot in busy:
                    if slot.conn in ready:
                        try:
                            msg = slot.conn.recv()
                        except (EOFError, OSError):
                            msg = None
                    elif slot.proc.sentinel in ready:
                        msg = None
                    else:
                        continue
                    if msg is not None and msg[0] == "ready":
                        slot.ready = True
                        continue
                    if msg is not None and msg[0] == "done":
                        slot.block = None
                        group.append(msg[1])
                        continue
                    if group:  # what finished is kept before an error below
                        yield group
                        group = []
                    if msg is not None and msg[0] == "init_error":
                        raise FmuError(f"a batch worker cannot open {self.fmu_path}: {msg[1]}")
                    if msg is not None and msg[0] == "setup_error":
                        raise WmrError(f"a batch worker could not start: {msg[1]}")
                    # the worker died during its block
                    slot.proc.join(2.0)
                    if not slot.ready:
                        log = (f"; see {self.log_dir / f'worker-{slot.number}.log'}"
                               if self.log_dir else "")
                        raise WmrError(f"a batch worker process died while starting (exit "
                                       f"code {slot.proc.exitcode}){log}")
                    self._stop(slot, kill=True)
                    group.extend(lost(slot, died=True))
                    slot.block = None
                    slots[slots.index(slot)] = self._spawn(spawned)
                    spawned += 1
                if self.hard_limit_s is not None:
                    now = time.monotonic()
                    for i, slot in enumerate(slots):
                        if slot.block is None or now - slot.current()[1] < self.hard_limit_s:
                            continue
                        self._stop(slot, kill=True)
                        group.extend(lost(slot, died=False))
                        slot.block = None
                        slots[i] = self._spawn(spawned)
                        spawned += 1
                if group:
                    yield group
        finally:
            for slot in slots:
                self._stop(slot, kill=slot.block is not None)


__all__ = ["DIED_TWICE", "Killed", "LocalPool", "Outcome", "check_open_files", "made_up_record",
           "open_files_needed"]
