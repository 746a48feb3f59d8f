"""``wmr batch --scheduler``: a Dask cluster that goes away (its scheduler killed, no worker,
a killed worker), with real ``dask scheduler`` and ``dask worker`` processes.

A scheduler that goes away is not a result: the runs it had are not journalled, the batch
stops with one line naming the scheduler and the command to resume, and the resume, on a
restarted cluster, runs exactly the missing runs and ends with the local batch's summary.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest
from distributed.client import ClosedClientError, FutureCancelledError
from distributed.comm.core import CommClosedError
from distributed.scheduler import KilledWorker

from wmr.adapters.mcap import read_run
from wmr.apps.batch import BatchOptions, dask_exec, load_batch, run_batch
from wmr.apps.batch.dask_exec import task_failure, task_runs
from wmr.apps.batch.runner import _test_hooks
from wmr.cli import main

#: 40 short runs (about 25 ms each): 2 list entries x 20 random samples.
SPEC40 = """
name = "t40"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 15.0
[random]
seed = 3
n = 20
[random.start]
r_m = { dist = "uniform", low = 0.5, high = 1.5 }
bearing_deg = { dist = "uniform", low = -180.0, high = 180.0 }
[random.goal]
heading_deg = { dist = "along_x" }
[random.params]
m = { dist = "normal", mean = 25.0, std = 3.0, low = 18.0, high = 32.0 }
[[list]]
name = "a"
[[list]]
name = "b"
gains = { K_ps = 0.8 }
"""

#: The venv's ``dask`` command (the one beside this interpreter).
DASK = shutil.which("dask", path=str(Path(sys.executable).parent)) or "dask"


# -- which failures are the cluster's ---------------------------------------------------------

@pytest.mark.parametrize(("exc", "future_status", "client_status", "whose"), [
    # the infrastructure went away: never a result
    (FutureCancelledError("k", "scheduler-connection-lost"), "cancelled", "running", "cluster"),
    (FutureCancelledError("k", None), "cancelled", "running", "cluster"),
    (CommClosedError("in <TCP (closed)>: Stream is closed"), "pending", "running", "cluster"),
    (CommClosedError("Stream is closed"), None, "running", "cluster"),
    (ClosedClientError(), None, "running", "cluster"),
    (OSError("Timed out trying to connect to tcp://127.0.0.1:1 after 20 s"), None, "running",
     "cluster"),
    (TimeoutError("no result"), "pending", "connecting", "cluster"),
    (TimeoutError("no result"), "finished", "closed", "cluster"),
    (ValueError("anything"), "error", "connecting", "cluster"),
    # the worker died (or took the result with it): one more try
    (KilledWorker("k", cast(Any, "tcp://127.0.0.1:2"), 3), "error", "running", "worker"),
    (TimeoutError("no result for k within 30 s"), "finished", "running", "worker"),
    (TimeoutError("no result for k within 30 s"), "lost", "running", "worker"),
    # the run's own failure: a failed row
    (RuntimeError("FMU not shipped"), "error", "running", "run"),
    (TimeoutError("raised by the task itself"), "error", "running", "run"),
    (OSError("raised by the task itself"), "error", "running", "run"),
    (ValueError("not a connection's"), None, "running", "run"),
], ids=lambda v: v if isinstance(v, str | None) else type(v).__name__)
def test_a_failure_is_the_run_s_its_worker_s_or_the_cluster_s(
        exc: BaseException, future_status: str | None, client_status: str, whose: str) -> None:
    assert task_failure(exc, future_status, client_status) == whose


ALONE = """
import sys
from pathlib import Path

from wmr.apps.batch import worker
from wmr.apps.batch.spec import BatchRun
from wmr.config.scenario import load_scenario

spec = load_scenario("fig11").runs[0]
out = Path(sys.argv[2])
worker._FMUS["f"] = Path(sys.argv[1])
(out / "runs").mkdir(parents=True)
(out / worker.TOKEN_FILE).write_text("t")
runs = {i: BatchRun(f"000{i}-x", spec, spec.name, "", {}, "x") for i in range(3)}
again = worker.Block([0, 1, 2], runs, 3, (), "f", faults={"0001-x": "crash"}, retry=True)
done = worker.dask_run_block(again, "f", None, str(out), "t")
print("died alone:", done.died)
print("ran alone:", [list(r.indices) for r in done.results])
"""


def test_a_dask_retry_runs_alone_and_its_crash_leaves_the_worker(fmu3: Path,
                                                                tmp_path: Path) -> None:
    """A retry crashed the worker it ran in again: Dask counted the tasks queued there as
    suspects and lost the results held there, and the retry of a run queued beside one that
    crashes every time ended "died twice" (test_robustness'
    test_dask_retries_a_dead_worker_s_run_like_the_local_pool, 1 CI in 3).  Now a range's
    retry runs in a process of its own, one run after the other: a run that crashes it costs
    only itself, the runs after it run in a new one, and the worker (here this script) lives
    on."""
    proc = subprocess.run([sys.executable, "-c", ALONE, str(fmu3), str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "died alone: [1]" in proc.stdout
    assert "ran alone: [[0], [2]]" in proc.stdout
    logs = sorted(p.name for p in (tmp_path / "out" / "runs").iterdir())
    assert logs == ["0000-x.mcap", "0002-x.mcap"]


def test_a_dask_retry_s_process_ends_with_its_killed_worker(fmu3: Path, tmp_path: Path) -> None:
    """A worker killed outright (kill -9) while its retry runs alone leaves no orphan to go
    on writing into the batch folder."""
    hang = ALONE.replace('"crash"', '"hang"')
    worker_proc = subprocess.Popen([sys.executable, "-c", hang, str(fmu3), str(tmp_path / "out")],
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        children = Path(f"/proc/{worker_proc.pid}/task/{worker_proc.pid}/children")
        deadline = time.monotonic() + 60
        pids: list[int] = []
        while not pids and time.monotonic() < deadline:
            pids = [int(x) for x in children.read_text().split()]
            time.sleep(0.05)
        assert pids, "the retry's process never started"
        (alone,) = pids
        worker_proc.kill()
        worker_proc.wait()
        deadline = time.monotonic() + 10
        while Path(f"/proc/{alone}").exists() and time.monotonic() < deadline:
            with contextlib.suppress(ChildProcessError):
                os.waitpid(alone, os.WNOHANG)
            time.sleep(0.05)
        stat = Path(f"/proc/{alone}/stat")
        assert not stat.exists() or stat.read_text().split(")")[1].split()[0] == "Z", \
            "the retry's process outlived its worker"
    finally:
        worker_proc.kill()


def test_the_retry_s_process_runs_its_job_and_watches_its_worker(
        fmu3: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``python -m wmr.apps.batch.retry PID``'s main, in this process: it watches the worker
    ``PID``, runs the job's block and leaves its result, as the worker's own run of it."""
    import io
    import pickle

    from wmr.apps.batch import retry
    from wmr.apps.batch.spec import BatchRun
    from wmr.apps.batch.worker import Block, PlantHolder, block_on, read_frames
    from wmr.config.scenario import load_scenario

    spec = load_scenario("fig11").runs[0]
    block = Block([0], {0: BatchRun("0000-x", spec, spec.name, "", {}, "x")}, 1, (), "f",
                  retry=True)
    watched: list[int] = []
    monkeypatch.setattr(retry, "die_with", watched.append)
    result = tmp_path / "result.pickle"
    batch_dir = str(tmp_path / "batch")
    job = pickle.dumps((block, str(fmu3), None, None, None, str(result), batch_dir))
    retry.main(["retry", "4242"], io.BytesIO(job))
    assert watched == [4242]
    (done,) = read_frames(result)
    holder = PlantHolder(fmu3)
    try:
        here = block_on(holder, block, None, None, batch_dir)
    finally:
        holder.close()
    assert (done.indices, done.ids, done.codes) == (here.indices, here.ids, here.codes)
    (a, b) = (tmp_path / "alone.mcap", tmp_path / "here.mcap")
    a.write_bytes(done.logs[0][2])  # the log's bytes come back
    b.write_bytes(here.logs[0][2])
    np.testing.assert_array_equal(read_run(a).block(), read_run(b).block())
    # each names where the client keeps it, as a local worker's log does
    kept = str(Path(batch_dir) / block.log_relpath("0000-x"))
    assert _logged_mcap(a) == _logged_mcap(b) == kept


def test_a_dask_worker_s_log_names_where_it_is_kept(fmu3: Path, tmp_path: Path) -> None:
    """A Dask worker that sees the batch folder writes each log under a name of its own
    (two tries of a run never share a file) and moves it into place: the log's own result
    record names the place, not the name it was written under, as the journal does."""
    from wmr.apps.batch.spec import BatchRun
    from wmr.apps.batch.worker import Block, PlantHolder, block_on
    from wmr.config.scenario import load_scenario

    spec = load_scenario("fig11").runs[0]
    block = Block([0], {0: BatchRun("0000-x", spec, spec.name, "", {}, "x")}, 1, (), "f")
    out = tmp_path / "batch"
    holder = PlantHolder(fmu3)
    try:
        done = block_on(holder, block, None, str(out), str(out))
    finally:
        holder.close()
    final = out / block.log_relpath("0000-x")
    assert not done.logs and sorted(p.name for p in final.parent.iterdir()) == [final.name]
    assert _logged_mcap(final) == str(final)


def _logged_mcap(log: Path) -> str:
    """The ``mcap`` field of the finished log's own ``result`` record."""
    from wmr.adapters.mcap.reader import finished_result

    result = finished_result(log)
    assert result is not None, f"{log} is not a finished log"
    return result["mcap"]


def test_a_result_cut_by_its_process_s_death_is_not_one(tmp_path: Path) -> None:
    """The results file of a retry's process: a result whose bytes are not all there (the
    process died writing it) is not read, and what comes before it is."""
    from wmr.apps.batch.worker import BlockResult, read_frames, write_frame

    path = tmp_path / "results"
    with open(path, "ab") as f:
        for i in range(2):
            write_frame(f, BlockResult(indices=[i], ids=f"{i:04d}-x\n".encode()))
    whole = path.read_bytes()
    for cut in (len(whole), len(whole) - 1, len(whole) // 2 + 4, 3):
        path.write_bytes(whole[:cut])
        got = [list(r.indices) for r in read_frames(path)]
        assert got == ([[0], [1]] if cut == len(whole) else [[0]] if cut > len(whole) // 2
                       else []), cut


class _FakeClient:
    """What :class:`dask_exec._WorkerWatch` asks of a client: a scheduler that never has a
    worker when looked at, and, with ``restarts``, one that a nanny restarts (and that dies at
    once) every 0.05 s, between the looks."""

    status = "running"

    def __init__(self, restarts: bool) -> None:
        self.restarts = restarts
        self.cancelled: list[tuple[list[object], str]] = []
        self.handler: Callable[[tuple[float, object]], None] | None = None
        self._stop = threading.Event()

    def nthreads(self) -> dict[str, int]:
        return {}

    def subscribe_topic(self, topic: str, handler: Callable[[tuple[float, object]], None]
                        ) -> None:
        assert topic == "all"
        self.handler = handler
        threading.Thread(target=self._restarts, daemon=True).start()

    def _restarts(self) -> None:
        while self.restarts and not self._stop.wait(0.05):
            assert self.handler is not None
            self.handler((time.time(), {"action": "gather", "count": 1}))
            self.handler((time.time(), {"action": "add-worker", "worker": "tcp://w:1"}))

    def unsubscribe_topic(self, topic: str) -> None:
        self._stop.set()

    def cancel(self, futures: list[object], reason: str | None = None) -> None:
        self.cancelled.append((futures, str(reason)))


@pytest.mark.parametrize("restarts", [False, True], ids=["workers-gone", "workers-restarting"])
def test_the_worker_watch_tells_no_workers_from_workers_restarting(
        restarts: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """A worker restarted and dead again between two looks is a worker: only a scheduler that
    no worker joined for WORKER_WAIT_S is one without workers (a run crashing every worker it
    was given made the looks alone stop a batch that was going on)."""
    monkeypatch.setattr(dask_exec, "WORKER_WAIT_S", 0.6)
    monkeypatch.setattr(dask_exec, "WORKER_POLL_S", 0.1)
    client = _FakeClient(restarts)
    futures: dict[Any, list[Any]] = {"f1": [], "f2": []}
    watch = dask_exec._WorkerWatch(client, futures)  # type: ignore[arg-type]
    try:
        starved = watch.starved.wait(2.0)
    finally:
        watch.stop()
    assert starved is not restarts
    assert client.cancelled == ([] if restarts else [(["f1", "f2"], "no-workers")])


def test_the_worker_watch_hears_no_event_while_the_scheduler_has_workers(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The scheduler sends a client subscribed to its topic ``all`` an event for every
    ``gather`` (one a task: about 0.2 ms of the client's CPU each): the watch subscribes only
    once a look finds no worker, and then hears the joins."""
    monkeypatch.setattr(dask_exec, "WORKER_POLL_S", 0.05)

    class Busy(_FakeClient):
        workers: dict[str, int]

        def nthreads(self) -> dict[str, int]:
            return self.workers

    client = Busy(restarts=True)
    client.workers = {"tcp://w:1": 1}
    watch = dask_exec._WorkerWatch(client, {})  # type: ignore[arg-type]
    try:
        time.sleep(0.3)  # several looks, each finding a worker
        assert client.handler is None
        client.workers = {}
        deadline = time.monotonic() + 5.0
        while client.handler is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert client.handler is not None
    finally:
        watch.stop()
    assert not watch.starved.is_set()


def test_results_of_tasks_finished_together_come_in_one_fetch_or_each_alone() -> None:
    """Several finished tasks' results are fetched in one gather, with a bounded wait; when
    that fails (here a dead worker's result, which alone would time out), each is asked for
    alone, as one alone always is, and only the lost one's failure is its own."""
    from distributed.scheduler import KilledWorker

    class Fut:
        def __init__(self, key: str, lost: bool = False) -> None:
            self.key, self.lost, self.asked = key, lost, 0

        def result(self, timeout: float | None = None) -> object:
            assert timeout is not None and 0 < timeout <= dask_exec.RESULT_WAIT_S
            self.asked += 1
            if self.lost:
                raise KilledWorker(self.key, "tcp://w:1", 3)
            return f"rows of {self.key}"

    class Client:
        def __init__(self) -> None:
            self.gathers: list[list[str]] = []

        async def _gather(self, futures: list[Fut]) -> list[object]:
            raise AssertionError("called through sync only")

        def sync(self, func: object, futures: list[Fut], callback_timeout: float) -> object:
            assert callback_timeout == dask_exec.RESULT_WAIT_S
            self.gathers.append([f.key for f in futures])
            if any(f.lost for f in futures):
                raise TimeoutError("no result within the wait")
            return [f"rows of {f.key}" for f in futures]

    client = Client()
    together = [Fut("a"), Fut("b"), Fut("c")]
    assert dask_exec._results(client, together) == ["rows of a", "rows of b",  # type: ignore[arg-type]
                                                    "rows of c"]
    assert client.gathers == [["a", "b", "c"]] and not any(f.asked for f in together)
    one_lost = [Fut("d"), Fut("e", lost=True), Fut("f")]
    got = dask_exec._results(client, one_lost)  # type: ignore[arg-type]
    assert got[0] == "rows of d" and got[2] == "rows of f" and isinstance(got[1], KilledWorker)
    assert [f.asked for f in one_lost] == [1, 1, 1]
    alone = [Fut("g")]
    assert dask_exec._results(client, alone) == ["rows of g"]  # type: ignore[arg-type]
    assert len(client.gathers) == 2 and alone[0].asked == 1


def test_a_group_whose_fetch_used_up_the_wait_asks_each_alone_only_briefly(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """When every worker died holding finished tasks' results, their group's fetch waits
    RESULT_WAIT_S and fails; each is then asked for alone with what is left of that wait (at
    least RESULT_FLOOR_S), not RESULT_WAIT_S again each: the batch stops in about one wait
    (`test_workers_all_gone_mid_batch_stop_it_in_bounded_time_and_it_resumes` took 90 s, over
    its 60, with 30 s each)."""
    monkeypatch.setattr(dask_exec, "RESULT_WAIT_S", 0.3)
    monkeypatch.setattr(dask_exec, "RESULT_FLOOR_S", 0.01)
    waits: list[float] = []

    class Fut:
        def result(self, timeout: float | None = None) -> object:
            assert timeout is not None
            waits.append(timeout)
            raise TimeoutError("the result died with its worker")

    class Client:
        async def _gather(self, futures: list[Fut]) -> list[object]:
            raise AssertionError("called through sync only")

        def sync(self, func: object, futures: list[Fut], callback_timeout: float) -> object:
            time.sleep(callback_timeout)  # the whole wait, then nothing
            raise TimeoutError("no result within the wait")

    got = dask_exec._results(Client(), [Fut() for _ in range(8)])  # type: ignore[arg-type]
    assert all(isinstance(r, TimeoutError) for r in got) and len(waits) == 8
    assert max(waits) <= 0.05, waits


def test_worker_threads_read_model_descriptions_one_at_a_time(
        fmu3: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each thread of a Dask worker opens its own FmuPlant: fmpy's schema check of the model
    description must not run in two threads at once (libxml2 can break for the rest of the
    process: a fresh two-thread worker failed every run, 'unreadable model description:
    ... xmlSchemaPValAttrNodeValue, the given type is not a built-in type')."""
    import fmpy

    from wmr.adapters.fmi.robot import FmuPlant

    real = fmpy.read_model_description
    inside: list[int] = []
    most = [0]
    guard = threading.Lock()

    def read(*args: object, **kwargs: object) -> object:
        with guard:
            inside.append(1)
            most[0] = max(most[0], len(inside))
        time.sleep(0.05)  # long enough for the other threads to come in, if they may
        try:
            return real(*args, **kwargs)
        finally:
            with guard:
                inside.pop()

    monkeypatch.setattr(fmpy, "read_model_description", read)
    start = threading.Barrier(4)
    made: list[str] = []

    def open_plant() -> None:
        start.wait()
        with FmuPlant(fmu3) as plant:
            made.append(plant.fmi_version)

    threads = [threading.Thread(target=open_plant) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert made == ["3.0"] * 4
    assert most[0] == 1, f"{most[0]} model descriptions read at once"


# -- real processes -----------------------------------------------------------------------------

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_for(pred: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s} s")
        time.sleep(0.05)


class _Cluster:
    """A ``dask scheduler`` on a fixed local port and ``dask worker`` processes, each in its
    own process group (killed whole, the nanny and its worker alike)."""

    def __init__(self, log_dir: Path) -> None:
        self.port = _free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.log_dir = log_dir
        self.scheduler: subprocess.Popen[bytes] | None = None
        self.workers: list[subprocess.Popen[bytes]] = []

    def _start(self, *args: str) -> subprocess.Popen[bytes]:
        log = self.log_dir / f"{args[0]}-{time.monotonic_ns()}.log"
        with open(log, "wb") as f:
            return subprocess.Popen([DASK, *args], stdout=f, stderr=subprocess.STDOUT,
                                    start_new_session=True)

    def _answers(self) -> bool:
        try:
            socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
        except OSError:
            return False
        return True

    def start_scheduler(self) -> None:
        self.scheduler = self._start("scheduler", "--host", "127.0.0.1", "--port",
                                     str(self.port), "--no-dashboard")
        _wait_for(self._answers, 60, "the scheduler")

    def start_worker(self) -> None:
        """Start a worker and wait until the scheduler has it (on a loaded machine a worker
        took more than the batch's 3 s wait to join: the batch then stopped at once, as one
        without workers, before the test could do what it tests)."""
        from distributed import Client

        self.workers.append(self._start("worker", self.address, "--nworkers", "1",
                                        "--nthreads", "2", "--no-dashboard"))
        with Client(self.address, timeout="60s") as client:
            client.wait_for_workers(1, timeout=120)

    @staticmethod
    def _kill(proc: subprocess.Popen[bytes]) -> None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=30)

    def kill_scheduler(self) -> None:
        assert self.scheduler is not None
        self._kill(self.scheduler)
        self.scheduler = None

    def kill_all(self) -> None:
        for proc in self.workers:
            self._kill(proc)
        self.workers = []
        if self.scheduler is not None:
            self.kill_scheduler()


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[_Cluster]:
    logs = tmp_path / "dask-logs"
    logs.mkdir()
    c = _Cluster(logs)
    try:
        yield c
    finally:
        c.kill_all()


@pytest.fixture
def spec40(tmp_path: Path) -> Path:
    path = tmp_path / "t40.toml"
    path.write_text(SPEC40, encoding="utf-8")
    return path


def _journal(out: Path) -> list[dict[str, object]]:
    path = out / "journal.jsonl"
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _lines(out: Path) -> int:
    try:
        return (out / "journal.jsonl").read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


@pytest.mark.timeout(300)
def test_a_scheduler_killed_mid_batch_stops_it_and_the_resume_runs_the_missing(
        tmp_path: Path, fmu3: Path, spec40: Path, cluster: _Cluster,
        capfd: pytest.CaptureFixture[str]) -> None:
    batch = load_batch(spec40)
    local = tmp_path / "local"
    run_batch(batch, local, BatchOptions(workers=2, fmu_path=fmu3), progress=False)
    out = tmp_path / "dask"
    cluster.start_scheduler()
    cluster.start_worker()
    command = ["batch", str(spec40), "--out", str(out), "--fmu", str(fmu3), "--scheduler",
               cluster.address, "--no-progress"]
    kill_at = 10

    def killer() -> None:  # the scheduler dies once 10 runs are journalled
        _wait_for(lambda: _lines(out) >= kill_at, 120, "the first runs")
        cluster.kill_scheduler()

    thread = threading.Thread(target=killer)
    capfd.readouterr()
    # the last run hangs: the batch cannot end before the scheduler is killed
    with _test_hooks(faults={batch.runs[-1].run_id: "hang"}):
        thread.start()
        t0 = time.monotonic()
        code = main(command)
        took_s = time.monotonic() - t0
    thread.join(timeout=60)
    err = capfd.readouterr().err
    assert code == 1, err
    done = _journal(out)
    n = len(done)
    assert kill_at <= n < len(batch.runs)
    assert err.count("\n") == 1, f"one line, not: {err!r}"
    assert re.fullmatch(
        rf"wmr: error: the Dask scheduler {re.escape(cluster.address)} went away after {n} "
        rf"of 40 runs \(\w+: [^\n]+\); the {n} finished are kept; start it \(dask "
        rf"scheduler, dask worker\) and run the same command again to run the {40 - n} "
        r"missing\n", err), err
    assert took_s < 60, "no wait for the client's reconnection"
    # the runs the scheduler had are not results: no made-up failed row, no record of a
    # run whose result never came back
    assert {line["status"] for line in done} == {"converged"}
    assert len({line["run_id"] for line in done}) == n

    cluster.kill_all()  # the cluster restarted: a new scheduler at the same address
    cluster.start_scheduler()
    cluster.start_worker()
    code = main(command)
    err = capfd.readouterr().err
    assert code == 0, err
    assert f"; {40 - n} run now, {n} done before;" in err
    again = _journal(out)
    assert [line["run_id"] for line in again[:n]] == [line["run_id"] for line in done]
    assert sorted(str(line["run_id"]) for line in again[n:]) == sorted(
        {r.run_id for r in batch.runs} - {str(line["run_id"]) for line in done})
    for name in ("summary.csv", "summary.parquet"):
        assert (out / name).read_bytes() == (local / name).read_bytes(), name


@pytest.mark.timeout(120)
def test_a_scheduler_without_workers_stops_the_batch_in_bounded_time(
        tmp_path: Path, fmu3: Path, spec40: Path, cluster: _Cluster,
        capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(dask_exec, "WORKER_WAIT_S", 3.0)
    cluster.start_scheduler()
    out = tmp_path / "o"
    capfd.readouterr()
    t0 = time.monotonic()
    code = main(["batch", str(spec40), "--out", str(out), "--fmu", str(fmu3), "--scheduler",
                 cluster.address, "--no-progress"])
    took_s = time.monotonic() - t0
    err = capfd.readouterr().err
    assert code == 1
    assert err == (f"wmr: error: the Dask scheduler {cluster.address} has no workers (none "
                   f"joined within 3 s); start some (dask worker {cluster.address}) and run "
                   "the same command again to run the 40 missing\n")
    assert took_s < 30
    assert _journal(out) == []


def test_a_worker_killed_mid_batch_ends_in_the_local_summary(
        tmp_path: Path, fmu3: Path, spec40: Path, cluster: _Cluster) -> None:
    """The worker process (not its nanny, which starts a new one) killed by SIGKILL mid-batch:
    the scheduler gives its tasks to the new one; nothing stops, nothing fails."""
    import psutil

    text = SPEC40.replace("n = 20", "n = 40")  # 80 runs: a batch long enough to kill into
    spec = tmp_path / "t80.toml"
    spec.write_text(text, encoding="utf-8")
    batch = load_batch(spec)
    local = tmp_path / "local"
    run_batch(batch, local, BatchOptions(workers=2, fmu_path=fmu3), progress=False)
    cluster.start_scheduler()
    cluster.start_worker()
    out = tmp_path / "dask"
    killed_at: list[int] = []

    def killer() -> None:
        _wait_for(lambda: _lines(out) >= 10, 120, "the first runs")
        nanny = psutil.Process(cluster.workers[0].pid)
        workers = nanny.children(recursive=True)
        killed_at.append(_lines(out))
        for proc in workers:
            proc.kill()

    thread = threading.Thread(target=killer)
    thread.start()
    result = run_batch(batch, out, BatchOptions(scheduler=cluster.address, fmu_path=fmu3),
                       progress=False)
    thread.join(timeout=60)
    assert killed_at and killed_at[0] < len(batch.runs), "killed before the batch ended"
    assert len(result.executed) == len(batch.runs) and result.counts["converged"] == 80
    for name in ("summary.csv", "summary.parquet"):
        assert (out / name).read_bytes() == (local / name).read_bytes(), name


@pytest.mark.timeout(300)
def test_workers_all_gone_mid_batch_stop_it_in_bounded_time_and_it_resumes(
        tmp_path: Path, fmu3: Path, spec40: Path, cluster: _Cluster,
        capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """Every worker (nanny and all) killed mid-batch: the tasks would wait for ever in the
    scheduler; after WORKER_WAIT_S the batch stops saying so, and resumes once one is back."""
    monkeypatch.setattr(dask_exec, "WORKER_WAIT_S", 3.0)
    monkeypatch.setattr(dask_exec, "WORKER_POLL_S", 0.2)
    batch = load_batch(spec40)
    local = tmp_path / "local"
    run_batch(batch, local, BatchOptions(workers=2, fmu_path=fmu3), progress=False)
    cluster.start_scheduler()
    cluster.start_worker()
    out = tmp_path / "dask"
    command = ["batch", str(spec40), "--out", str(out), "--fmu", str(fmu3), "--scheduler",
               cluster.address, "--no-progress"]

    def killer() -> None:
        _wait_for(lambda: _lines(out) >= 10, 120, "the first runs")
        for proc in cluster.workers:
            cluster._kill(proc)

    thread = threading.Thread(target=killer)
    capfd.readouterr()
    with _test_hooks(faults={batch.runs[-1].run_id: "hang"}):  # it cannot end by itself
        thread.start()
        t0 = time.monotonic()
        code = main(command)
        took_s = time.monotonic() - t0
    thread.join(timeout=60)
    err = capfd.readouterr().err
    n = len(_journal(out))
    assert code == 1, err
    assert err == (f"wmr: error: the Dask scheduler {cluster.address} has no workers left "
                   f"after {n} of 40 runs (none for 3 s); the {n} finished are kept; start "
                   f"some (dask worker {cluster.address}) and run the same command again to "
                   f"run the {40 - n} missing\n")
    assert took_s < 60
    cluster.workers = []
    cluster.start_worker()
    assert main(command) == 0
    assert f"; {40 - n} run now, {n} done before;" in capfd.readouterr().err
    for name in ("summary.csv", "summary.parquet"):
        assert (out / name).read_bytes() == (local / name).read_bytes(), name


def test_a_dask_task_holds_up_to_1024_runs_and_at_least_as_many_as_the_threads() -> None:
    """docs/batch.md, "Execution": ranges of up to 1,024 runs, at least 8 a worker thread,
    but never fewer runs a task than there are threads while each thread still gets one (the
    client spends 1 to 5 ms a task: 10^6 runs on 1,000 threads are 1,000 tasks, not 8,000)."""
    assert task_runs(10_000, 2) == 625  # 8 tasks a thread
    assert task_runs(10**6, 16) == task_runs(10**6, 64) == 1024
    assert task_runs(10**6, 1000) == 1000
    assert task_runs(20, 2) == 2 and task_runs(3, 8) == 1
    for n_runs in (1, 7, 100, 5_000, 123_457, 10**6):
        for threads in (1, 2, 16, 64, 1000):
            size = task_runs(n_runs, threads)
            tasks = -(-n_runs // size)
            assert 1 <= size <= 1024
            assert tasks >= min(n_runs, threads)  # every thread has one
            assert size >= min(threads, n_runs // threads) or tasks >= 8 * threads
