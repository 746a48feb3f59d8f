"""``wmr batch`` and ``wmr report``: spec expansion, executors, resume, failures, report."""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import os
import shutil
import signal
import struct
import subprocess
import sys
import time
import tomllib
import tracemalloc
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st

import wmr.apps.batch.runner as runner_module
from wmr.adapters.mcap import read_run
from wmr.apps.batch import BatchOptions, BatchSpec, load_batch, parse_batch, run_batch
from wmr.apps.batch.journal import Journal, line_check, log_complete
from wmr.apps.batch.report import write_report
from wmr.apps.batch.runner import _test_hooks
from wmr.apps.batch.spec import RunList, run_index
from wmr.apps.batch.summary import SummaryRow, summary_table, write_summary
from wmr.cli import main
from wmr.infra.errors import ConfigError

# 20 short runs (about 25 ms each): 2 list entries x 10 random samples, starts 0.5-1.5 m away.
SPEC20 = """
name = "t20"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 15.0
[random]
seed = 3
n = 10
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


def _write(tmp: Path, text: str, name: str = "spec.toml") -> Path:
    path = tmp / name
    path.write_text(text, encoding="utf-8")
    return path


def _parse(text: str) -> BatchSpec:
    return parse_batch(tomllib.loads(text))


def _gains_grid(n: int) -> str:
    """A spec of n x n runs: a grid of n K_ps by n K_is values (more [grid.*] may follow)."""
    values = ", ".join(f"{0.1 + 0.01 * i:.2f}" for i in range(n))
    return ('start = [1.0, 0.0, 0.0]\ngoal = [0.0, 0.0, 0.0]\n'
            f"[grid.gains]\nK_ps = [{values}]\nK_is = [{values}]\n")


def _summary_bytes(out: Path) -> tuple[bytes, bytes]:
    return (out / "summary.csv").read_bytes(), (out / "summary.parquet").read_bytes()


def _journal_ids(out: Path) -> list[str]:
    return [json.loads(line)["run_id"]
            for line in (out / "journal.jsonl").read_text().splitlines() if line.strip()]


# -- spec expansion ------------------------------------------------------------------------------

def test_plain_scenario_is_a_spec_with_its_run_names() -> None:
    batch = load_batch("fig9")
    assert len(batch.runs) == 13
    assert [r.spec.name for r in batch.runs][:2] == ["fig9-thd-090", "fig9-thd-075"]
    ids = [r.run_id for r in batch.runs]
    assert ids == sorted(ids) and len(set(ids)) == 13
    assert ids == [r.run_id for r in load_batch("fig9").runs]  # stable


def test_grid_list_random_expand_to_their_product() -> None:
    batch = _parse("""
        start = [0.0, 0.0, 0.0]
        goal = [5.0, 0.0, 0.0]
        [grid]
        max_time_s = [10.0, 20.0]
        [grid.gains]
        K_ps = [0.3, 0.5, 0.8]
        [[list]]
        name = "light"
        params = { m = 20.0 }
        [[list]]
        name = "heavy"
        params = { m = 40.0 }
        goal = [6.0, 1.0, 90.0]
        [random]
        seed = 7
        n = 2
        [random.params]
        l = { dist = "uniform", low = 0.3, high = 0.4 }
    """)
    assert len(batch.runs) == 2 * 3 * 2 * 2
    first, last = batch.runs[0], batch.runs[-1]
    assert (first.spec.t_max_s, first.spec.gains.K_ps, first.spec.params.m) == (10.0, 0.3, 20.0)
    assert (last.spec.t_max_s, last.spec.gains.K_ps, last.spec.params.m) == (20.0, 0.8, 40.0)
    assert last.variant == "heavy" and last.spec.goal.x_m == 6.0
    assert last.spec.goal.heading_rad == pytest.approx(math.pi / 2)
    assert all(0.3 <= r.spec.params.l <= 0.4 for r in batch.runs)
    for col in ("max_time_s", "gains.K_ps", "params.m", "params.l"):
        assert col in batch.input_columns
    assert len({r.run_id for r in batch.runs}) == len(batch.runs)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 3), max_size=3), st.integers(0, 3), st.integers(0, 3),
       st.integers(0, 2))
def test_lazy_runs_are_the_product_in_index_order(axes: list[int], n_list: int,
                                                  n_random: int, extra_bases: int) -> None:
    """Run ``i`` made from ``i`` alone is the ``i``-th of an eager product (a second
    implementation: itertools.product over the raw values, base slowest, sample fastest)."""
    fields = ("max_time_s", "gains.K_ps", "params.m")[:len(axes)]
    values = {f: [10.0 + 10.0 * k + j for j in range(n)] for k, (f, n) in
              enumerate(zip(fields, axes, strict=True))}
    text = 'name = "p"\nstart = [1.0, 0.0, 0.0]\ngoal = [0.0, 0.0, 0.0]\n'
    if extra_bases:
        text += "".join(f'[[runs]]\nname = "b{k}"\n' for k in range(extra_bases + 1))
    if values:
        text += "[grid]\n" + "".join(f"{f} = {v}\n" for f, v in values.items() if "." not in f)
        for f, v in values.items():
            if "." in f:
                group, name = f.split(".")
                text += f"[grid.{group}]\n{name} = {v}\n"
    entries = [{"name": f"e{k}", "l": 0.3 + 0.01 * k} for k in range(n_list)]
    text += "".join(f'[[list]]\nname = "{e["name"]}"\nparams = {{ l = {e["l"]} }}\n'
                    for e in entries)
    if n_random:
        text += (f"[random]\nseed = 5\nn = {n_random}\n"
                 '[random.limits]\ntorque_max_nm = { dist = "uniform", low = 5.0, high = 9.0 }\n')
    runs = _parse(text).runs
    bases = [f"b{k}" for k in range(extra_bases + 1)] if extra_bases else ["p"]
    expected = list(itertools.product(bases, *values.values(), entries or [None],
                                      range(n_random or 1)))
    assert len(runs) == len(expected)
    made = list(runs)
    assert [r.run_id for r in made] == [runs[i].run_id for i in range(len(runs))]
    for i, (run, combo) in enumerate(zip(made, expected, strict=True)):
        base, *grid_values, entry, _ = combo
        assert run.base == base and run_index(run.run_id) == i
        got = {"max_time_s": run.spec.t_max_s, "gains.K_ps": run.spec.gains.K_ps,
               "params.m": run.spec.params.m}
        assert [got[f] for f in fields] == grid_values
        assert run.variant == (entry["name"] if entry else "")
        if entry:
            assert run.spec.params.l == entry["l"]
    assert runs[-1] == made[-1] and runs[1:3] == made[1:3]
    with pytest.raises(IndexError):
        runs[len(runs)]


def test_a_million_run_spec_loads_lazily(monkeypatch: pytest.MonkeyPatch) -> None:
    made: list[int] = []
    original = RunList._make

    def spy(self: RunList, index: int) -> Any:
        made.append(index)
        return original(self, index)

    monkeypatch.setattr(RunList, "_make", spy)
    masses = ", ".join(f"{20.0 + 0.1 * i:.1f}" for i in range(100))
    text = _gains_grid(100) + f"[grid.params]\nm = [{masses}]\n"
    tracemalloc.start()
    try:
        batch = _parse(text)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(batch.runs) == 1_000_000
    assert len(made) == 298 and peak < 20e6  # the probes: each grid value once, not the product
    last = batch.runs[-1]
    assert last.run_id.startswith("999999-") and last.spec.params.m == 29.9
    assert (last.spec.gains.K_ps, last.spec.gains.K_is) == (1.09, 1.09)


def test_a_bad_grid_value_of_a_large_spec_is_found_at_load() -> None:
    values = ", ".join(f"{0.1 + 0.01 * i:.2f}" for i in range(100))
    with pytest.raises(ConfigError, match=r"grid\.params\.m: must be > 0.*\(run 19,"):
        _parse(f"""
            start = [1.0, 0.0, 0.0]
            goal = [0.0, 0.0, 0.0]
            [grid.gains]
            K_ps = [{values}]
            [grid.params]
            m = [{", ".join(["25.0"] * 19)}, -1.0]
        """)


def test_a_run_invalid_only_in_combination_stops_its_batch_and_the_fix_resumes(
        tmp_path: Path, fmu3: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The probes try each grid value with the first of the others: a combination of two
    valid values (a long period with a stiff wheel servo) is found when the batch makes it."""
    import wmr.apps.batch.spec as spec_module

    monkeypatch.setattr(spec_module, "CHECK_ALL_RUNS", 0)  # probe this 4-run spec as if large
    text = """
        name = "combo"
        start = [0.3, 0.0, 0.0]
        goal = [0.0, 0.0, 0.0]
        max_time_s = 3.0
        [grid]
        control_period_s = [0.01, 0.05]
        [grid.gains]
        K_pw = [7.0, 14.0]
    """
    spec = _write(tmp_path, text)
    out = tmp_path / "out"
    assert main(["batch", str(spec), "--check", "--no-progress"]) == 1
    assert "grid.control_period_s" in capsys.readouterr().err
    with pytest.raises(ConfigError, match=r"grid\.control_period_s.*run 3, combo-0003") as info:
        run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert "rerun the same command" in info.value.fix
    assert len(_journal_ids(out)) == 3  # the runs before it are kept ...
    assert pq.read_table(out / "summary.parquet").num_rows == 3  # ... and summarised
    spec.write_text(text.replace("K_pw = [7.0, 14.0]", "K_pw = [7.0, 10.0]"), encoding="utf-8")
    assert main(["batch", str(spec), "--check", "--no-progress"]) == 0
    assert "4 runs, all valid" in capsys.readouterr().err
    again = run_batch(load_batch(spec), out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.skipped == 2 and len(again.executed) == 2 and again.finished == 4


def test_random_samples_are_reproducible_and_keep_their_values_when_n_grows() -> None:
    five, ten = _parse(SPEC20.replace("n = 10", "n = 5")), _parse(SPEC20)
    assert [r.spec for r in five.runs[:5]] == [r.spec for r in ten.runs[:5]]
    assert len({r.spec.params.m for r in ten.runs[:10]}) == 10
    other_seed = _parse(SPEC20.replace("seed = 3", "seed = 4"))
    assert other_seed.runs[0].spec.params.m != five.runs[0].spec.params.m


def test_polar_start_and_the_fig10_heading_rule() -> None:
    batch = _parse(SPEC20)
    for run in batch.runs:
        s, g = run.spec.start, run.spec.goal
        assert math.hypot(s.x_m, s.y_m) == pytest.approx(run.inputs["start.r_m"])
        assert 0.5 <= run.inputs["start.r_m"] <= 1.5
        assert math.degrees(g.heading_rad) == (180.0 if s.x_m >= 0.0 else 0.0)
        assert 18.0 <= run.spec.params.m <= 32.0


@pytest.mark.parametrize(("snippet", "field"), [
    ("[grid.gains]\nK_px = [1.0]", "grid.gains.K_px"),
    ("[grid.params]\nm = []", "grid.params.m"),
    ("[grid.params]\nm = [25.0, -1.0]", "grid.params.m"),
    ("[grid]\nstart = [[0, 0]]", "grid.start[0]"),
    ("[grid]\nspeed = [1.0]", "grid.speed"),
    ("[[list]]\nparams = { m = -5.0 }", "list[0].params.m"),
    ("[[list]]\nname = 3", "list[0].name"),
    ("[random]\nseed = 1\nn = 0\n[random.params]\nm = { dist = 'uniform', low = 1, high = 2 }",
     "random.n"),
    ("[random]\nn = 3\n[random.params]\nm = { dist = 'uniform', low = 1, high = 2 }",
     "random.seed"),
    ("[random]\nseed = 1\nn = 3\n[random.params]\nm = { dist = 'normal', mean = 25, std = -1 }",
     "random.params.m.std"),
    ("[random]\nseed = 1\nn = 3\n[random.params]\nm = { dist = 'gauss', mean = 25, std = 1 }",
     "random.params.m.dist"),
    ("[random]\nseed = 1\nn = 3\n[random.params]\nm = { dist = 'uniform', low = 30, high = 20 }",
     "random.params.m.high"),
    ("[random]\nseed = 1\nn = 3\n[random.params]\nm = { dist = 'uniform', low = 1 }",
     "random.params.m.high"),
    ("[random]\nseed = 1\nn = 3\n[random.goal]\nx_m = { dist = 'along_x' }",
     "random.goal.x_m.dist"),
    ("[random]\nseed = 1\nn = 3\n[random.params]\nm = { dist = 'uniform', low = -9, high = -1 }",
     "random.params.m"),
    ("[grid]\nmax_time_s = [1.0]\n[sweep]\nstop_radius_m = [0.1]", "sweep"),
    ("[gains]\nK_ps = 'fast'", "gains.K_ps"),
])
def test_bad_fields_are_named(snippet: str, field: str) -> None:
    text = "start = [0.0, 0.0, 0.0]\ngoal = [5.0, 0.0, 0.0]\n" + snippet
    with pytest.raises(ConfigError) as err:
        _parse(text)
    assert err.value.field == field, str(err.value)


def test_missing_spec_file_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as err:
        load_batch(tmp_path / "nope.toml")
    assert err.value.field == "spec"


# -- execution -----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def spec20(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _write(tmp_path_factory.mktemp("spec"), SPEC20, "t20.toml")


@pytest.fixture(scope="module")
def reference(spec20: Path, fmu3: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The 20-run batch on one worker."""
    out = tmp_path_factory.mktemp("ref")
    result = run_batch(load_batch(spec20), out, BatchOptions(workers=1, fmu_path=fmu3),
                       progress=False)
    assert not result.interrupted and len(result.executed) == 20
    return out


def test_reference_summary_has_one_row_per_run(reference: Path, spec20: Path) -> None:
    table = pq.read_table(reference / "summary.parquet")
    ids = [r.run_id for r in load_batch(spec20).runs]
    assert table.column("run_id").to_pylist() == ids
    assert set(table.column("status").to_pylist()) == {"converged"}
    assert table.column("mcap").to_pylist()[0] == f"runs/{ids[0]}.mcap"
    for col in ("start.r_m", "params.m", "gains.K_ps", "time_to_goal_s", "path_length_m"):
        assert col in table.column_names
    assert "wall_s" not in table.column_names
    assert all(log_complete(reference / "runs" / f"{i}.mcap") for i in ids)
    log = read_run(reference / "runs" / f"{ids[3]}.mcap")
    assert json.loads(log.metadata["result"]["steps"]) == table.column("steps")[3].as_py()


#: The summary of SPEC20 as written before the log policies and the sharded layout (CSV: its
#: bytes do not depend on the Parquet library's version); 1 worker, 2 workers and Dask must
#: still write it byte for byte (the tests below compare them with ``reference``).
REFERENCE_CSV = Path(__file__).parent / "data" / "batch_t20_summary.csv"


def test_reference_summary_is_the_one_kept(reference: Path) -> None:
    assert (reference / "summary.csv").read_bytes() == REFERENCE_CSV.read_bytes()


#: The summary of the first 48 runs of ``scenarios/mc_failures.toml`` (42 converge, 6 time out
#: and keep their logs), written by the code of before workers drew their own runs (the parent
#: drew each run and handed it out alone; ``--workers 2 --log failed``).
REFERENCE_MC_CSV = Path(__file__).parent / "data" / "batch_mc_failures48_summary.csv"


def test_workers_drawing_their_ranges_write_the_summary_of_before(fmu3: Path,
                                                                  tmp_path: Path) -> None:
    """docs/batch.md, "Execution": each worker draws the runs of its range from the spec and
    their indices, and their summary rows and journal lines come back a range at a time; the
    inputs, results and log paths are those of before, bit for bit (here ranges of 3 runs on
    2 workers, and 1 worker in ranges of 6)."""
    from wmr.apps.run import LogPolicy
    from wmr.infra.paths import scenarios_dir

    text = (scenarios_dir() / "mc_failures.toml").read_text(encoding="utf-8")
    spec = _write(tmp_path, text.replace("n = 800", "n = 48"), "mc_failures.toml")
    batch = load_batch(spec)
    for workers in (2, 1):
        blocks = runner_module._Blocks(batch, runner_module._Ledger(48), None, {},
                                       LogPolicy("failed"), "f")
        assert blocks.block_runs(workers) == 6 // workers  # ranges, not runs one by one
        out = tmp_path / f"w{workers}"
        result = run_batch(batch, out,
                           BatchOptions(workers=workers, fmu_path=fmu3, log=LogPolicy("failed")),
                           progress=False)
        assert result.counts == {"converged": 42, "timeout": 6, "failed": 0}
        assert (out / "summary.csv").read_bytes() == REFERENCE_MC_CSV.read_bytes()
        assert result.logs_kept == 6 and all(
            log_complete(out / row["mcap"]) for row in pq.read_table(
                out / "summary.parquet").to_pylist() if row["mcap"] is not None)


def test_a_range_whose_worker_dies_costs_only_its_run_and_holes_resume(
        reference: Path, spec20: Path, fmu3: Path, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/batch.md, "A crash, a hang": in ranges of 4 runs, a worker that dies on a run of
    its range loses the range's results, yet only that run is retried (then ``failed``); the
    range's other runs are run again and their rows are the reference's.  A resume whose missing
    runs are not consecutive gets them in one range of those runs (not a ``range``)."""
    from wmr.apps.batch.local import DIED_TWICE

    monkeypatch.setattr(runner_module._Blocks, "block_runs", lambda self, workers: 4)
    batch = load_batch(spec20)
    dead, once = batch.runs[5].run_id, batch.runs[9].run_id  # 2nd run of their ranges
    with _test_hooks(faults={dead: "crash", once: "crash-once"}):
        result = run_batch(batch, tmp_path, BatchOptions(workers=2, fmu_path=fmu3), progress=False)
    assert len(result.executed) == 20 and result.counts["failed"] == 1
    rows = {r["run_id"]: r for r in pq.read_table(tmp_path / "summary.parquet").to_pylist()}
    ref = {r["run_id"]: r for r in pq.read_table(reference / "summary.parquet").to_pylist()}
    assert rows[dead]["status"] == "failed" and rows[dead]["message"] == DIED_TWICE
    assert {k: v for k, v in rows.items() if k != dead} == \
        {k: v for k, v in ref.items() if k != dead}
    journal = tmp_path / "journal.jsonl"
    holes = {batch.runs[i].run_id for i in (2, 7, 8, 13)}
    journal.write_text("".join(line + "\n" for line in journal.read_text().splitlines()
                               if json.loads(line)["run_id"] not in holes))
    blocks = []
    real = runner_module._Blocks._block

    def seen(self: Any, indices: list[int]) -> Any:
        blocks.append(list(indices))
        return real(self, indices)

    monkeypatch.setattr(runner_module._Blocks, "_block", seen)
    again = run_batch(batch, tmp_path, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert sorted(again.executed) == sorted(holes) and blocks == [[2, 7, 8, 13]]
    assert pq.read_table(tmp_path / "summary.parquet").to_pylist() == list(rows.values())


def test_two_workers_give_the_same_summary_bit_for_bit(reference: Path, spec20: Path,
                                                       fmu3: Path, tmp_path: Path) -> None:
    result = run_batch(load_batch(spec20), tmp_path, BatchOptions(workers=2, fmu_path=fmu3),
                       progress=False)
    assert len(result.executed) == 20
    assert {j.get("worker") for j in map(json.loads, (tmp_path / "journal.jsonl")
                                         .read_text().splitlines())} != {""}
    assert _summary_bytes(tmp_path) == _summary_bytes(reference)


@pytest.mark.parametrize("ship_logs", [False, True], ids=["shared-folder", "logs-shipped"])
def test_dask_gives_the_same_summary_and_logs(reference: Path, spec20: Path, fmu3: Path,
                                              tmp_path: Path, ship_logs: bool) -> None:
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        result = run_batch(load_batch(spec20), tmp_path,
                           BatchOptions(client=client, dask_ship_logs=ship_logs, fmu_path=fmu3),
                           progress=False)
    assert len(result.executed) == 20 and result.counts["converged"] == 20
    assert _summary_bytes(tmp_path) == _summary_bytes(reference)
    # every log: the worker's two threads share the process's row encoder (a thread's rows
    # were written into another's log, test_mcaplog; seen in clean-clone CI: with a cold
    # cache, test_api's documented wmr.run wrote its log before the stepper was built and left
    # the numpy encoder to the whole process, then this test in the same worker failed)
    differ = {}
    for log in sorted((reference / "runs").glob("*.mcap")):
        here, there = read_run(tmp_path / "runs" / log.name), read_run(log)
        assert here.metadata["run"] == there.metadata["run"]  # same FMU file name and hash
        assert here.attachments == there.attachments
        signals = [k for k in here.signals
                   if not np.array_equal(here.signals[k], there.signals[k], equal_nan=True)]
        if signals:
            differ[log.name] = signals[:4]
    assert differ == {}


@pytest.mark.slow
def test_dask_scheduler_address_with_worker_processes(reference: Path, spec20: Path,
                                                      fmu3: Path, tmp_path: Path) -> None:
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      host="127.0.0.1", dashboard_address=None) as cluster:
        assert main(["batch", str(spec20), "--out", str(tmp_path), "--fmu", str(fmu3),
                     "--scheduler", cluster.scheduler_address, "--no-progress"]) == 0
    assert _summary_bytes(tmp_path) == _summary_bytes(reference)


def test_interrupted_batch_resumes_with_only_the_missing_runs(reference: Path, spec20: Path,
                                                              fmu3: Path, tmp_path: Path) -> None:
    batch = load_batch(spec20)
    with _test_hooks(stop_after=7):
        first = run_batch(batch, tmp_path, BatchOptions(workers=2, fmu_path=fmu3), progress=False)
    assert first.interrupted and len(first.executed) == 7
    assert pq.read_table(tmp_path / "summary.parquet").num_rows == 7
    # a run killed mid-write: a half log without its journal line; and a finished run whose
    # log was cut afterwards
    todo = [r.run_id for r in batch.runs if r.run_id not in first.executed]
    half = tmp_path / "runs" / f"{todo[0]}.mcap"
    half.write_bytes((reference / "runs" / half.name).read_bytes()[:3000])
    cut = tmp_path / "runs" / f"{first.executed[0]}.mcap"
    cut.write_bytes(cut.read_bytes()[:-100])
    second = run_batch(batch, tmp_path, BatchOptions(workers=2, fmu_path=fmu3), progress=False)
    assert not second.interrupted and second.skipped == 6
    assert sorted(second.executed) == sorted([*todo, first.executed[0]])
    assert _summary_bytes(tmp_path) == _summary_bytes(reference)
    third = run_batch(batch, tmp_path, BatchOptions(workers=2, fmu_path=fmu3), progress=False)
    assert third.executed == [] and third.skipped == 20
    assert len(Journal(tmp_path / "journal.jsonl").load()) == 20
    ids = _journal_ids(tmp_path)
    assert len(ids) == 21 and len(set(ids)) == 20  # only the cut log's run twice in the journal


def test_a_range_stopped_midway_keeps_the_rows_and_lines_of_the_same_runs(
        reference: Path, spec20: Path, fmu3: Path, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/batch.md, "Execution": a range comes back as its rows and its lines, and the
    parent keeps the same runs of both.  Stopped after 6 runs, in the middle of the second
    range of 4, the batch journals the first 6 runs, and its summary holds exactly their rows
    (not the 2 others of the range, which have no line); the resume runs the other 14 and
    ends with the reference's summary."""
    monkeypatch.setattr(runner_module._Blocks, "block_runs", lambda self, workers: 4)
    batch = load_batch(spec20)
    with _test_hooks(stop_after=6):
        first = run_batch(batch, tmp_path, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    journalled = _journal_ids(tmp_path)
    assert first.interrupted and journalled == list(first.executed) \
        == [r.run_id for r in batch.runs[:6]]
    assert pq.read_table(tmp_path / "summary.parquet")["run_id"].to_pylist() == journalled
    again = run_batch(batch, tmp_path, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.skipped == 6 and len(again.executed) == 14
    assert _summary_bytes(tmp_path) == _summary_bytes(reference)


def test_a_parts_file_cut_or_damaged_gives_back_its_whole_frames_only(tmp_path: Path) -> None:
    """docs/batch.md, "Execution": each range's rows are a frame appended to the invocation's
    parts file.  A batch killed during an append leaves a cut last frame, and a disk may
    damage one: a resume reads every whole frame, skips the damaged one (its runs are run
    again) and takes nothing of the cut one."""
    parts = runner_module._Parts(tmp_path, 4)
    ids = [f"{i:04d}-0000000{i}" for i in range(4)]
    for i, run_id in enumerate(ids):
        row = SummaryRow(run_id, "n", "b", "", {"gains.K_ps": 0.5 + i}, "pi", i)
        parts.add(summary_table([row], ["gains.K_ps"], {run_id: {"status": "converged",
                                                                 "steps": 3 + i}}), [i])
    parts.close()
    frames = _part_frames(tmp_path)
    assert len(frames) == 4
    data = bytearray(parts.path.read_bytes())
    data[frames[1][0] + len(frames[1][1]) // 2] ^= 0xFF  # the second frame damaged
    parts.path.write_bytes(bytes(data[:frames[3][0] + len(frames[3][1]) // 2]))  # the last cut
    again = runner_module._Parts(tmp_path, 4)
    got = [t["run_id"].to_pylist() for t in again.read(again.leftovers())]
    assert got == [[ids[0]], [ids[2]]]


def test_parts_frames_of_before_are_read_and_an_overlong_one_is_not(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/batch.md, "Execution": a frame's payload is an Arrow IPC stream compressed whole
    with zstd; the frame a batch of before left (the stream's buffers compressed one by one)
    is still read on resume, and a zstd frame that says it holds more than a frame may is
    skipped unread (its runs are run again) rather than decompressed."""
    ids = [f"{i:04d}-0000000{i}" for i in range(3)]
    tables = [summary_table([SummaryRow(run_id, "n", "b", "", {"gains.K_ps": 0.5 + i}, "pi",
                                        i)], ["gains.K_ps"],
                            {run_id: {"status": "converged", "steps": 3 + i}})
              for i, run_id in enumerate(ids)]
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, tables[0].schema,
                           options=pa.ipc.IpcWriteOptions(compression="zstd")) as writer:
        writer.write_table(tables[0])
    before = sink.getvalue().to_pybytes()
    now = runner_module.table_bytes(tables[1])
    assert now[:4] == b"\x28\xb5\x2f\xfd" and _payload_table(now).equals(tables[1])
    # the longest a frame may be, made just shorter than this one's stream of three rows
    huge = runner_module.table_bytes(pa.concat_tables(tables))
    monkeypatch.setattr(runner_module, "MAX_PART_BYTES",
                        len(zstandard.ZstdDecompressor().decompress(huge)) - 1)
    (tmp_path / ".parts").mkdir()
    with open(tmp_path / ".parts" / "1-0.arrows", "wb") as part:
        for payload in (before, huge, runner_module.table_bytes(tables[2])):
            part.write(struct.pack("<4sII", b"WMRp", len(payload), zlib.crc32(payload))
                       + payload)
    parts = runner_module._Parts(tmp_path, 3)
    got = [t["run_id"].to_pylist() for t in parts.read(parts.leftovers())]
    assert got == [[ids[0]], [ids[2]]]


def test_a_cut_journal_line_is_ignored_and_redone(spec20: Path, fmu3: Path,
                                                  tmp_path: Path) -> None:
    batch = load_batch(spec20)
    with _test_hooks(stop_after=3):
        run_batch(batch, tmp_path, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    journal = tmp_path / "journal.jsonl"
    journal.write_bytes(journal.read_bytes()[:-40])  # the third line is cut
    assert len(Journal(journal).load()) == 2
    again = run_batch(batch, tmp_path, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert len(again.executed) == 18 and again.finished == 20
    assert len(Journal(journal).load()) == 20


def test_the_summary_is_read_back_from_the_journal_in_blocks(
        reference: Path, spec20: Path, fmu3: Path, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch, journal_of_before: Callable[[Path, Any], None]
        ) -> None:
    """Blocks of 3 rows (7 blocks), journal lines written before lines held their rows or
    were sealed, and lines whose row or record is damaged (made again from the spec and the
    log) give the reference's summary byte for byte."""
    out = tmp_path / "copy"
    shutil.copytree(reference, out)
    journal_of_before(out, load_batch(spec20).runs)  # lines that hold their records
    journal = out / "journal.jsonl"
    lines = [json.loads(line) for line in journal.read_text().splitlines()]
    # lines of now hold no summary row (its inputs are drawn again from the spec); those of
    # before did, sealed with it: the odd lines are made such
    assert not any("row" in line for line in lines)
    runs = load_batch(spec20).runs
    for line in lines[1::2]:
        line["row"] = runner_module._row_json(runs[int(line["run_id"][:4])])
        line["check"] = line_check(line)
    lines[1]["row"] = "garbled"  # rows a hand or a disk damaged are made again, not trusted
    lines[3]["row"]["inputs"] = 5
    lines[5]["row"]["inputs"]["params.m"] = [1.0]
    del lines[7]["check"]  # written before lines were sealed
    lines[9]["record"]["status"] = "failed"  # the log says converged
    journal.write_text("".join(json.dumps(line) + "\n" for line in lines))
    for name in ("summary.csv", "summary.parquet"):
        (out / name).unlink()
    monkeypatch.setattr(runner_module, "SUMMARY_BLOCK", 3)
    again = run_batch(load_batch(spec20), out, BatchOptions(workers=1, fmu_path=fmu3),
                      progress=False)
    assert again.executed == [] and again.skipped == 20 and again.counts["converged"] == 20
    assert (out / "summary.csv").read_bytes() == (reference / "summary.csv").read_bytes()
    assert pq.read_table(out / "summary.parquet").equals(
        pq.read_table(reference / "summary.parquet"))


def test_an_edit_that_keeps_the_runs_keeps_them_and_fills_the_new_column(
        reference: Path, spec20: Path, fmu3: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str], journal_of_before: Callable[[Path, Any], None]
        ) -> None:
    """A one-value grid axis equal to the base's value changes no run (same ids, nothing
    redone) but adds a column: the rows read back from the journal must fill it, and the
    lines of before, which held their rows, are made again with the spec's rows (said once,
    naming why: docs/reliability.md); lines of now hold none: nothing to make again."""
    edited = _write(tmp_path, SPEC20 + "[grid]\nmax_time_s = [15.0]\n", "t20.toml")
    batch = load_batch(edited)
    assert [r.run_id for r in batch.runs] == [r.run_id for r in load_batch(spec20).runs]
    now = tmp_path / "now"
    shutil.copytree(reference, now, copy_function=shutil.copy2)
    capsys.readouterr()
    again = run_batch(batch, now, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.skipped == 20 and again.executed == []
    table = pq.read_table(now / "summary.parquet")
    assert table.column("max_time_s").to_pylist() == [15.0] * 20
    assert capsys.readouterr().err == ""
    out = tmp_path / "copy"  # its lines as a batch of before wrote them: with their rows
    shutil.copytree(reference, out, copy_function=shutil.copy2)
    journal_of_before(out, load_batch(spec20).runs)
    journal = out / "journal.jsonl"
    before = [json.loads(line) for line in journal.read_text().splitlines()]
    runs = load_batch(spec20).runs
    for line in before:
        line["row"] = runner_module._row_json(runs[int(line["run_id"][:4])])
        line["check"] = line_check(line)
    journal.write_text("".join(json.dumps(line) + "\n" for line in before))
    again = run_batch(batch, out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.skipped == 20 and again.executed == []
    table = pq.read_table(out / "summary.parquet")
    assert table.column("max_time_s").to_pylist() == [15.0] * 20
    assert capsys.readouterr().err == (
        f"wmr: {out / 'journal.jsonl'}: 20 lines did not match the spec or the run's log "
        f"(first: run {batch.runs[0].run_id}, row (the spec's input columns changed)): made "
        "again from them, not trusted\n")
    lines = Journal(out / "journal.jsonl").load()
    assert all(lines[run.run_id]["row"] == runner_module._row_json(run) for run in batch.runs)


def test_resume_trusts_a_stamped_log_only_while_it_is_unchanged(
        reference: Path, spec20: Path, fmu3: Path, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch, journal_of_before: Callable[[Path, Any], None]
        ) -> None:
    """A log with the size and time journalled for it, still ending with the MCAP magic, is
    not parsed again; one zeroed in place (what a crash before the data reached the disk can
    leave), its time put back, is read, found unfinished, and its run done again.  A line
    whose seal broke, of a log touched since, is made again from the log with the log's new
    stamp: the next resume trusts it without parsing it."""
    import mcap.reader

    out = tmp_path / "copy"
    shutil.copytree(reference, out, copy_function=shutil.copy2)  # keeps the times
    batch = load_batch(spec20)
    journal_of_before(out, batch.runs)  # lines of before hold their log's stamp
    with monkeypatch.context() as m:
        m.setattr(mcap.reader, "make_reader", lambda *a, **k: pytest.fail("a log was parsed"))
        again = run_batch(batch, out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert again.skipped == 20 and again.executed == []
    victim = out / "runs" / f"{batch.runs[4].run_id}.mcap"
    st = victim.stat()
    victim.write_bytes(bytes(st.st_size))
    os.utime(victim, ns=(st.st_atime_ns, st.st_mtime_ns))
    third = run_batch(batch, out, BatchOptions(workers=1, fmu_path=fmu3), progress=False)
    assert third.executed == [batch.runs[4].run_id] and third.skipped == 19
    assert _summary_bytes(out) == _summary_bytes(reference)
    touched = out / "runs" / f"{batch.runs[6].run_id}.mcap"
    os.utime(touched, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    journal = out / "journal.jsonl"
    lines = journal.read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if batch.runs[6].run_id in line)
    lines[at] = lines[at].replace('"check":"', '"check":"0')  # the seal broken
    journal.write_text("\n".join(lines) + "\n")
    one = BatchOptions(workers=1, fmu_path=fmu3)
    assert run_batch(batch, out, one, progress=False).skipped == 20
    real = mcap.reader.make_reader

    def not_the_touched_log(stream: Any, *args: Any, **kwargs: Any) -> Any:
        # (run 4's first line, superseded, is still checked against its new log: parsed)
        assert stream.name != str(touched), "the log made again was parsed again"
        return real(stream, *args, **kwargs)

    with monkeypatch.context() as m:
        m.setattr(mcap.reader, "make_reader", not_the_touched_log)
        assert run_batch(batch, out, one, progress=False).skipped == 20


def test_a_batch_stopped_before_its_first_run_writes_an_empty_summary(
        spec20: Path, tmp_path: Path) -> None:
    """No run finished, so there is no journal: the summary is its header alone."""
    batch = load_batch(spec20)
    ledger = runner_module._Ledger(len(batch.runs))
    chunks = runner_module._summary_chunks(batch, Journal(tmp_path / "journal.jsonl"), ledger)
    write_summary(chunks, tmp_path)
    assert pq.read_table(tmp_path / "summary.parquet").num_rows == 0
    header = (tmp_path / "summary.csv").read_text().splitlines()
    assert len(header) == 1 and header[0].startswith("run_id,name,base,variant,start.x_m")


def test_a_formula_in_a_summary_cell_is_text_in_the_csv_and_kept_in_parquet(
        tmp_path: Path) -> None:
    # issue 28 item 11: a run named '=HYPERLINK(...)' was a live formula in summary.csv
    names = ["=HYPERLINK(\"http://x\",\"y\")", "+1", "-cmd", "@SUM(A1)", "\tt", "ok", "\rr"]
    rows = [SummaryRow(f"{i:04d}-00000000", n, n, "", {"gains.K_ps": -0.5}, "pi", 0)
            for i, n in enumerate(names)]
    records = {r.run_id: {"status": "converged", "message": "-x", "steps": 3} for r in rows}
    write_summary(summary_table(rows, ["gains.K_ps"], records), tmp_path)
    text = (tmp_path / "summary.csv").read_bytes().decode("utf-8")
    # Python's csv module quotes no CR (with lineterminator '\n'): that row is checked as text
    text, cr_row = text.split("\n0006-")
    assert cr_row.startswith("00000000,'\rr,'\rr,,")
    table = list(csv.DictReader(io.StringIO(text, newline="")))
    assert [r["name"] for r in table] == [f"'{n}" for n in names[:4]] + ["'\tt", "ok"]
    assert {r["base"] for r in table} == {r["name"] for r in table}
    assert {(r["message"], r["gains.K_ps"], r["steps"]) for r in table} == {("'-x", "-0.5", "3")}
    assert pq.read_table(tmp_path / "summary.parquet").column("name").to_pylist() == names


def test_a_resumed_batch_keeps_9_bytes_a_finished_run(tmp_path: Path) -> None:
    """The parent's state of a finished run is its journal offset and status (the records
    stay in the journal): checked on 5,000 journalled runs of a 10,000-run spec."""
    batch = _parse(_gains_grid(100))
    journal = Journal(tmp_path / "journal.jsonl")
    record = {"status": "timeout", "message": "m" * 100,
              **{f"value_{k}": 0.5 + k for k in range(12)}}
    for run in batch.runs[:5000]:
        journal.append({"run_id": run.run_id, "digest": run.digest, "fmu_sha256": "f",
                        "killed": True, "record": record})
    runner_module._resume(batch, journal, "f", tmp_path, progress=False)  # imports, caches
    tracemalloc.start()
    try:
        ledger = runner_module._resume(batch, journal, "f", tmp_path, progress=False)
        kept, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert ledger.n_done == 5000 and ledger.counts()["timeout"] == 5000
    # 90 kB of offsets and status codes (and what other tests left cached); the records
    # themselves would be about 8 MB
    assert kept < 1_000_000


def _killed_line(batch: BatchSpec, index: int, **fields: Any) -> dict[str, Any]:
    """The journal line of run ``index`` of ``batch`` killed by its executor (FMU ``"f"``)."""
    run = batch.runs[index]
    return {"run_id": run.run_id, "digest": run.digest, "fmu_sha256": "f", "killed": True,
            "record": {"status": "failed"}, "row": runner_module._row_json(run), **fields}


def test_resume_redoes_a_run_whose_line_without_a_log_was_edited(tmp_path: Path) -> None:
    """docs/reliability.md: a killed run's line, or a line without a log (its policy kept none),
    counts only while its seal holds: edited by hand (the record's status), the run is done
    again, even though the status it now says is a valid one; so is a sealed line naming a log
    that is not followed."""
    batch = _parse(_gains_grid(2))
    journal = Journal(tmp_path / "journal.jsonl")
    journal.append(_killed_line(batch, 0))
    journal.append(_killed_line(batch, 1, killed=False, path=None))
    journal.append(_killed_line(batch, 2))
    journal.append(_killed_line(batch, 3, killed=False, path=None))
    ledger = runner_module._resume(batch, journal, "f", tmp_path, progress=False)
    assert ledger.n_done == 4  # as written: every seal holds
    lines = journal.path.read_text().splitlines()
    for i in (2, 3):  # a hand's edit: the status, not the seal
        lines[i] = lines[i].replace('"status":"failed"', '"status":"timeout"')
    journal.path.write_text("\n".join(lines) + "\n")
    ledger = runner_module._resume(batch, journal, "f", tmp_path, progress=False)
    assert [i for i, _ in ledger.finished()] == [0, 1]
    # sealed, but naming a log that is not followed (outside runs/, not a path): done again
    journal.path.unlink()
    for index, path in enumerate(("runs/../../x.mcap", "/etc/x.mcap", 5, ["runs/x.mcap"])):
        journal.append(_killed_line(batch, index, killed=False, path=path))
    assert runner_module._resume(batch, journal, "f", tmp_path, progress=False).n_done == 0


def test_resume_takes_the_last_line_of_a_run_and_ignores_runs_past_the_spec(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The last journal line of a run wins: an earlier line that would be made again (its row
    differs from the spec's) is dropped when a later line of the run holds as it is, or says
    the run must be done again (another FMU); a line of a run past the spec's last one (a
    spec cut to fewer runs) is ignored.  Nothing is appended, nothing reported."""
    batch = _parse(_gains_grid(2))
    runs = batch.runs
    journal = Journal(tmp_path / "journal.jsonl")

    def killed(index: int, **fields: Any) -> dict[str, Any]:
        return _killed_line(batch, index, **fields)

    journal.append(killed(0, row="stale"))
    journal.append(killed(0, fmu_sha256="another FMU"))  # the last line: redo run 0
    journal.append(killed(1, row="stale"))
    last = journal.append(killed(1))  # the last line: run 1 done, as it is
    journal.append({**killed(3), "run_id": f"{len(runs):04d}-00000000"})  # past the spec
    size = journal.path.stat().st_size
    ledger = runner_module._resume(batch, journal, "f", tmp_path, progress=False)
    assert list(ledger.finished()) == [(1, last)] and ledger.n_done == 1
    assert journal.path.stat().st_size == size
    assert capsys.readouterr() == ("", "")
    # last lines made again (docs/reliability.md), a killed run's and one without a log: said
    # once on stderr, naming the first run in the journal and the field that differed
    for stale, lines in (([2], "1 line"), ([3, 2], "2 lines")):
        for index in stale:
            journal.append(killed(index, row="stale") if index == 2 else
                           killed(index, row="stale", killed=False, path=None))
        size = journal.path.stat().st_size
        ledger = runner_module._resume(batch, journal, "f", tmp_path, progress=False)
        assert sorted(i for i, _ in ledger.finished()) == sorted({1, 2, *stale})
        assert min(ledger.offsets[i] for i in stale) >= size  # their lines made again ...
        for index, line in zip(stale, journal.read_at(ledger.offsets[i] for i in stale),
                               strict=True):  # ... with the spec's row, sealed
            assert line["row"] == runner_module._row_json(runs[index]) != "stale"
            assert line["check"] == line_check(line)
        assert capsys.readouterr() == ("", f"wmr: {journal.path}: {lines} did not match the spec "
                                           f"or the run's log (first: run {runs[stale[0]].run_id}, "
                                           "row): made again from them, not trusted\n")


def test_resume_checks_a_journal_of_10_mb_or_more_under_its_own_bar(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The resume's check of a journal of 10,000,000 bytes or more (about 10,000 runs, 2 s)
    gets its own bar in bytes, named, shown as ``--progress`` says and removed when the check
    ends; a smaller journal gets none.  Lines of 100,000 bytes for runs of no spec."""
    import tqdm

    bars: list[tuple[float | None, float]] = []

    class Recorded(tqdm.tqdm):
        def close(self) -> None:
            if not self.disable:  # closed once (again by __del__, then disabled)
                bars.append((self.total, self.n))
            super().close()

    monkeypatch.setattr(tqdm, "tqdm", Recorded)
    batch = _parse(_gains_grid(2))
    journal = Journal(tmp_path / "journal.jsonl")

    def line(n_bytes: int) -> bytes:
        return b'{"run_id": "x", "record": {}, "pad": "' + b"a" * (n_bytes - 41) + b'"}\n'

    for short, progress, shown in ((0, True, True), (1, True, False), (0, False, False),
                                   (0, None, False)):  # None: on a terminal only (not here)
        journal.path.write_bytes(line(100_000) * 99 + line(100_000 - short))
        bars.clear()
        runner_module._resume(batch, journal, "f", tmp_path, progress=progress)
        err = capsys.readouterr().err
        assert bool(err) == shown, (short, progress, err)
        if shown:
            assert err.startswith("\rchecking the journal:   0%|          | 0.00/10.0M "
                                  "[00:00<?, ?B/s]")
            assert err.endswith("\r") and not err.rsplit("\r", 2)[-2].strip(), "bar left"
            ((total, n),) = bars
            assert total == 10_000_000 and 9_900_000 <= n <= 10_000_000  # the last line read


FAILING = """
name = "bad"
start = [1.0, 0.0, 0.0]
goal = [0.0, 0.0, 180.0]
max_time_s = 15.0
[[list]]
name = "ok"
[[list]]
name = "singular"                     # valid fields, but the FMU cannot integrate them
params = { m = 1e-300, Ig = 0.0, Iwm = 0.0 }
gains = { K_pw = 0.0 }                # (no servo gain that the period check would refuse)
[[list]]
name = "weak"                         # 0.01 N m cannot move the robot in 2 s
limits = { torque_max_nm = 0.01 }
max_time_s = 2.0
[[list]]
name = "slow"                         # would take seconds: the wall clock stops it
limits = { torque_max_nm = 0.01 }
max_time_s = 30000.0
[[list]]
name = "hang"
[[list]]
name = "crash"
[[list]]
name = "ok2"
start = [0.0, 1.0, 0.0]
"""


def test_failures_timeouts_hangs_and_crashes_are_rows(fmu3: Path, tmp_path: Path) -> None:
    batch = load_batch(_write(tmp_path, FAILING))
    by_variant = {r.variant: r.run_id for r in batch.runs}
    out = tmp_path / "out"
    # 2 s of wall clock: the short runs finish well inside it on a loaded machine, "slow" (3 million
    # steps) cannot
    with _test_hooks(faults={by_variant["hang"]: "hang", by_variant["crash"]: "crash"}):
        result = run_batch(batch, out, BatchOptions(workers=2, run_timeout_s=2.0, fmu_path=fmu3),
                           progress=False)
    assert not result.interrupted and result.finished == 7
    table = pq.read_table(out / "summary.parquet").to_pylist()
    rows = {row["variant"]: row for row in table}
    assert rows["ok"]["status"] == rows["ok2"]["status"] == "converged"
    assert rows["singular"]["status"] == "failed"
    assert "DoStep returned Error" in rows["singular"]["message"]
    assert rows["weak"]["status"] == "timeout"
    assert "max_time_s" in rows["weak"]["message"]
    assert rows["slow"]["status"] == "timeout"
    assert "wall-clock limit" in rows["slow"]["message"]
    assert log_complete(out / "runs" / f"{by_variant['slow']}.mcap")  # stopped cleanly
    assert rows["hang"]["status"] == "timeout"
    assert "wall-clock limit" in rows["hang"]["message"] and "killed" in rows["hang"]["message"]
    assert rows["crash"]["status"] == "failed" and "died" in rows["crash"]["message"]
    assert rows["crash"]["time_to_goal_s"] is None
    assert result.counts == {"converged": 2, "timeout": 3, "failed": 2}
    # killed runs are final: a rerun does nothing
    again = run_batch(batch, out, BatchOptions(workers=2, run_timeout_s=2.0, fmu_path=fmu3),
                      progress=False)
    assert again.executed == []


def test_a_run_past_its_wall_clock_limit_only_at_its_end_is_a_timeout(
        fmu3: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The worker's clock passes the deadline only at the loop's last report, after its last
    block: the run is ``timeout`` with the limit's message and its log closed ``failed``.  The
    exception escaped the loop there: the record said ``failed``, ``WallClockLimit: ...``, and
    a resumed batch ran the run again (1 batch in 6 of test_hostile_inputs'
    test_records_made_again_from_logs_are_the_journalled_ones, on CI too)."""
    import types

    import wmr.apps.batch.worker as worker
    from wmr.apps.batch.worker import PlantHolder, Task, wall_limit_message
    from wmr.config.scenario import load_scenario

    spec = load_scenario("fig11").runs[0]
    reads = [0]
    late_from = [math.inf]

    def monotonic() -> float:  # 0 s, then far past any limit from the read late_from on
        reads[0] += 1
        return 1e9 if reads[0] >= late_from[0] else 0.0

    monkeypatch.setattr(worker, "time", types.SimpleNamespace(monotonic=monotonic,
                                                              sleep=time.sleep))
    holder = PlantHolder(fmu3)
    try:
        task = Task("r", spec, wall_limit_s=1.0)
        first = holder.run(task, tmp_path / "a.mcap", None)
        assert first["status"] == "converged"
        late_from[0], reads[0] = reads[0], 0  # the last read: the report after the loop
        record = holder.run(task, tmp_path / "b.mcap", None)
    finally:
        holder.close()
    assert (record["status"], record["message"]) == ("timeout", wall_limit_message(1.0))
    result = read_run(tmp_path / "b.mcap").metadata["result"]
    assert result["status"] == "failed" and result["message"].startswith("WallClockLimit at t = ")


def test_cli_exit_codes_and_messages(spec20: Path, fmu3: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    bad = _write(tmp_path, "start = [0.0, 0.0, 0.0]\ngoal = [1.0, 0.0, 0.0]\n"
                           "[grid.gains]\nK_ps = [0.5, 'x']\n", "bad.toml")
    assert main(["batch", str(bad), "--out", str(tmp_path / "b")]) == 1
    assert "grid.gains.K_ps[1]" in capsys.readouterr().err
    assert main(["batch", str(spec20), "--out", str(tmp_path / "o"), "--fmu", str(fmu3),
                 "--workers", "0"]) == 1
    assert "--workers" in capsys.readouterr().err
    assert main(["batch", str(spec20), "--out", str(tmp_path / "o"), "--fmu", str(fmu3),
                 "--workers", "2", "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert captured.out.strip() == str(tmp_path / "o" / "summary.parquet")
    assert "20 converged" in captured.err


def test_report_from_a_sweep(reference: Path, tmp_path: Path,
                             capsys: pytest.CaptureFixture[str]) -> None:
    path = write_report(reference)
    text = path.read_text()
    assert path == reference / "report" / "report.md"
    assert "Success rate: 100.0 %" in text
    for png in ("status.png", "spread.png", "vs_params_m.png", "vs_gains_K_ps.png"):
        assert (reference / "report" / png).stat().st_size > 1000
        assert png in text
    assert main(["report", str(reference)]) == 0
    assert capsys.readouterr().out.strip() == str(path)
    assert main(["report", str(tmp_path)]) == 1
    assert "summary.parquet" in capsys.readouterr().err


@pytest.mark.slow
def test_ctrl_c_stops_cleanly_and_the_rerun_finishes(spec20: Path, fmu3: Path,
                                                     tmp_path: Path) -> None:
    slow = _write(tmp_path, SPEC20.replace("n = 10", "n = 40").replace("seed = 3", "seed = 5"),
                  "t80.toml")
    cmd = [sys.executable, "-m", "wmr.cli", "batch", str(slow), "--out", str(tmp_path / "o"),
           "--fmu", str(fmu3), "--workers", "2", "--no-progress"]
    env = dict(os.environ)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                            start_new_session=True)
    journal = tmp_path / "o" / "journal.jsonl"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (
            not journal.exists() or len(journal.read_text().splitlines()) < 5):
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal does: the whole process group
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    done = set(_journal_ids(tmp_path / "o"))
    assert 5 <= len(done) < 80
    rows = pq.read_table(tmp_path / "o" / "summary.parquet").column("run_id").to_pylist()
    assert set(rows) == done
    rerun = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    assert rerun.returncode == 0, rerun.stderr
    assert f"{80 - len(done)} run now, {len(done)} done before" in rerun.stderr
    ids = _journal_ids(tmp_path / "o")
    assert len(ids) == len(set(ids)) == 80


def _rows(out: Path) -> list[dict[str, Any]]:
    return pq.read_table(out / "summary.parquet").to_pylist()


def test_each_batch_log_attaches_its_own_run_not_the_spec(reference: Path, spec20: Path) -> None:
    from wmr.config.scenario import parse_scenario

    runs = load_batch(spec20).runs
    for r in (runs[0], runs[7]):
        log = read_run(reference / "runs" / f"{r.run_id}.mcap")
        tomls = [n for n in log.attachments if n.endswith(".toml")]
        assert tomls == [f"{r.spec.name}.toml"]
        back = parse_scenario(tomllib.loads(log.attachments[tomls[0]].decode())).runs
        assert back == (r.spec,)


_KILLED_BETWEEN_WRITES = """
import os, signal, sys
from pathlib import Path
from wmr.apps.batch import BatchOptions, load_batch, run_batch
from wmr.apps.batch.runner import _test_hooks

calls = []

def kill_at_the_third_range(run_ids):
    calls.append(run_ids)
    if len(calls) == 3:  # ranges 1 and 2 journalled, range 3's rows written, not its lines
        os.kill(os.getpid(), signal.SIGKILL)

with _test_hooks(between_writes=kill_at_the_third_range):
    run_batch(load_batch(sys.argv[1]), sys.argv[2],
              BatchOptions(workers=1, fmu_path=sys.argv[3]), progress=False)
"""


def _part_frames(out: Path) -> list[tuple[int, bytes]]:
    """The frames of the batch's one parts file, as docs/batch.md describes them (read here
    with ``struct``, not with the batch's reader): each payload's offset and bytes."""
    (path,) = (out / ".parts").glob("*.arrows")
    data, at, frames = path.read_bytes(), 0, []
    while at < len(data):
        magic, length, crc = struct.unpack_from("<4sII", data, at)
        payload = data[at + 12:at + 12 + length]
        assert magic == b"WMRp" and len(payload) == length and zlib.crc32(payload) == crc
        frames.append((at + 12, payload))
        at += 12 + length
    return frames


def _payload_table(payload: bytes) -> pa.Table:
    """A parts frame's payload as docs/batch.md describes it (an Arrow IPC stream compressed
    whole with zstd), read with zstandard and pyarrow, not with the batch's reader."""
    return pa.ipc.open_stream(zstandard.ZstdDecompressor().decompress(payload)).read_all()


def _killed_between_writes(spec20: Path, fmu3: Path, out: Path) -> list[str]:
    """The 20-run batch (ranges of 2 runs on one worker) killed with SIGKILL after its third
    range's summary rows are on disk and before that range's journal lines; the ids of the
    runs journalled."""
    proc = subprocess.run([sys.executable, "-c", _KILLED_BETWEEN_WRITES, str(spec20),
                           str(out), str(fmu3)], capture_output=True, text=True, timeout=120,
                          env=dict(os.environ))
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert not (out / "summary.parquet").exists()  # killed: no summary, the parts are all
    return _journal_ids(out)


@pytest.mark.slow
def test_a_batch_killed_between_a_ranges_rows_and_its_lines_resumes_to_the_same_summary(
        reference: Path, spec20: Path, fmu3: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """docs/reliability.md: a range's summary rows are on disk (fsynced) before its journal
    lines, so every journalled run has its row: killed between the two writes, the resume
    keeps every journalled run (none run again, nothing said) and runs the rest; the summary
    is the uninterrupted batch's byte for byte."""
    out = tmp_path / "o"
    journalled = _killed_between_writes(spec20, fmu3, out)
    on_disk = {r for _, payload in _part_frames(out)
               for r in _payload_table(payload)["run_id"].to_pylist()}
    assert set(journalled) <= on_disk, "a journalled run without its summary row on disk"
    assert len(journalled) == 4 and len(on_disk) == 6
    capsys.readouterr()
    again = run_batch(load_batch(spec20), out, BatchOptions(workers=1, fmu_path=fmu3),
                      progress=False)
    assert again.skipped == len(journalled) and len(again.executed) == 20 - len(journalled)
    assert not set(again.executed) & set(journalled)
    assert capsys.readouterr().err == ""
    assert _summary_bytes(out) == _summary_bytes(reference)
    assert not (out / ".parts").exists()


def test_ranges_that_finish_together_are_made_durable_together_rows_before_lines(
        reference: Path, spec20: Path, fmu3: Path, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/batch.md, "Execution": ranges that finish together (here the executor's ranges
    of 2 runs handed over in pairs) are settled together: their rows appended and made
    durable with one ``fdatasync``, then their journal lines in one write (a journal line
    always has its row on disk); the summary is the uninterrupted batch's byte for byte."""
    from wmr.apps.batch.local import LocalPool

    events: list[str] = []
    run = LocalPool.run

    def in_pairs(self: LocalPool, tasks: Any, block_runs: int = 1) -> Any:
        held: list[Any] = []
        for group in run(self, tasks, block_runs):
            held.extend(group)
            if len(held) >= 2:
                yield held
                held = []
        if held:
            yield held

    sync, append = runner_module._datasync, Journal.append_lines
    monkeypatch.setattr(LocalPool, "run", in_pairs)
    monkeypatch.setattr(runner_module._Blocks, "block_runs", lambda self, workers: 2)
    monkeypatch.setattr(runner_module, "_datasync",
                        lambda fd: (events.append("sync"), sync(fd))[1])
    monkeypatch.setattr(Journal, "append_lines",
                        lambda self, data: (events.append(f"lines {len(data.splitlines())}"),
                                            append(self, data))[1])
    groups: list[Sequence[str]] = []
    with _test_hooks(between_writes=groups.append):
        done = run_batch(load_batch(spec20), tmp_path, BatchOptions(workers=1, fmu_path=fmu3),
                         progress=False)
    assert len(done.executed) == 20
    assert [len(ids) for ids in groups] == [4] * 5  # two ranges of 2 runs each time
    assert events == ["sync", "lines 4"] * 5
    assert _summary_bytes(tmp_path) == _summary_bytes(reference)


def test_a_batch_stopped_between_a_range_s_rows_and_its_lines_keeps_no_row_without_a_line(
        spec20: Path, fmu3: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A full disk when the third range's lines are to be written (its rows already in the
    parts file): the batch stops with its summary, which holds the rows of the journalled
    runs only, not the third range's (a summary row without a journal line is a result the
    journal does not know: a resume runs it again, and the two disagree until then)."""
    from wmr.infra.errors import DiskFullError

    monkeypatch.setattr(runner_module._Blocks, "block_runs", lambda self, workers: 2)
    calls: list[int] = []

    def full_at_the_third(ids: Sequence[str]) -> None:
        calls.append(len(ids))
        if len(calls) == 3:
            raise DiskFullError("no space left on / while writing journal.jsonl")

    with _test_hooks(between_writes=full_at_the_third), pytest.raises(DiskFullError):
        run_batch(load_batch(spec20), tmp_path, BatchOptions(workers=1, fmu_path=fmu3),
                  progress=False)
    journalled = [json.loads(line)["run_id"]
                  for line in (tmp_path / "journal.jsonl").read_text().splitlines()]
    rows = pq.read_table(tmp_path / "summary.parquet").column("run_id").to_pylist()
    assert len(journalled) == 4 and rows == journalled


@pytest.mark.slow
def test_a_part_lost_after_its_journal_lines_reruns_its_runs_saying_so(
        reference: Path, spec20: Path, fmu3: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A range's summary rows removed after its journal lines were written (the batch killed
    before its summary): the journal says done, but there is no row to trust, so the resume
    runs those runs again, saying so in one line; the summary is the uninterrupted batch's."""
    out = tmp_path / "o"
    journalled = _killed_between_writes(spec20, fmu3, out)
    first = journalled[0]
    (lost,) = [(at, payload) for at, payload in _part_frames(out)
               if _payload_table(payload)["run_id"][0].as_py() == first]
    with open(next((out / ".parts").glob("*.arrows")), "r+b") as part:
        part.seek(lost[0])
        part.write(bytes(len(lost[1])))  # the part of runs 0 and 1 zeroed on disk
    capsys.readouterr()
    again = run_batch(load_batch(spec20), out, BatchOptions(workers=1, fmu_path=fmu3),
                      progress=False)
    assert again.skipped == len(journalled) - 2
    assert set(journalled[:2]) <= set(again.executed)
    assert capsys.readouterr().err == (
        f"wmr: {out / 'journal.jsonl'}: 2 journalled runs had no summary row matching its "
        f"line, or no finished log (first: run {first}): run again\n")
    assert _summary_bytes(out) == _summary_bytes(reference)
