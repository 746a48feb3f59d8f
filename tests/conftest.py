"""Shared fixtures: the FMUs are built once per test session (and shared across xdist workers)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from wmr.adapters.fmi.robot import FmuPlant
from wmr.build.fmus import BuildResult, build_fmus
from wmr.infra import paths

os.environ.setdefault("MPLBACKEND", "Agg")  # headless: no figure ever opens a window


@pytest.fixture(scope="session", autouse=True)
def fmu_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """One build folder for the whole session; xdist workers share it (the build is locked).

    ``WMR_CACHE_DIR`` points there too, so that everything that builds or reuses the
    project's FMUs (``wmr run`` and its subprocesses included) finds this build, and no test
    writes into the user's cache.
    """
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    old = os.environ.get("WMR_CACHE_DIR")
    os.environ["WMR_CACHE_DIR"] = str(root / "cache")
    yield paths.default_fmu_dir()
    if old is None:
        os.environ.pop("WMR_CACHE_DIR", None)
    else:
        os.environ["WMR_CACHE_DIR"] = old


@pytest.fixture(scope="session")
def built(fmu_dir: Path) -> BuildResult:
    return build_fmus(fmu_dir)


@pytest.fixture(scope="session")
def fmu2(built: BuildResult) -> Path:
    return built.fmus[2]


@pytest.fixture(scope="session")
def fmu3(built: BuildResult) -> Path:
    return built.fmus[3]


@pytest.fixture(scope="module")
def fmu3_plant(fmu3: Path) -> Iterator[FmuPlant]:
    """One plant of the FMI 3 FMU for a test module, its runs one after another (reset per
    run).  Per module, not per session: a module's tests may change its parameters or leave it
    after a failed run, and no other module should see that."""
    with FmuPlant(fmu3) as plant:
        yield plant


@pytest.fixture(scope="module")
def fig11_log(tmp_path_factory: pytest.TempPathFactory, fmu3_plant: FmuPlant) -> Path:
    """The log of the scenario ``fig11`` (its one run, on the FMI 3 plant), once per test
    module; tests read it or copy it, never change it."""
    from wmr.apps.run import run_to_log
    from wmr.config.scenario import load_scenario

    path = tmp_path_factory.mktemp("logs") / "fig11.mcap"
    record = run_to_log(load_scenario("fig11").runs[0], path, fmu3_plant)
    assert record["status"] == "converged"
    return path


@pytest.fixture(params=[2, 3], ids=["fmi2", "fmi3"])
def plant(request: pytest.FixtureRequest, built: BuildResult) -> Iterator[FmuPlant]:
    with FmuPlant(built.fmus[request.param]) as p:
        yield p


def _journal_of_before(out: Path, runs: Any) -> None:
    """Rewrite the journal of the batch folder ``out`` as batches wrote it before compact
    lines (docs/batch.md, "Journal lines of before"): each line the run's whole record (made
    again from its log's ``result`` record, else from its summary row), the run's own digest,
    the FMU's, the log's path and stamp, sealed with ``line_check``.  ``runs`` is the spec's
    run list; the FMU's digest is ``batch.json``'s.  Such a journal must still resume."""
    import json

    import pyarrow.parquet as pq

    from wmr.apps.batch.journal import JOURNAL, Journal, log_stamp, logged_record, sealed_line
    from wmr.apps.batch.local import made_up_record
    from wmr.apps.batch.spec import run_index
    from wmr.apps.batch.summary import OPTIMUM_RESULT_COLUMNS, RESULT_COLUMNS

    fmu_sha = json.loads((out / "batch.json").read_text())["fmu_sha256"]
    rows = {r["run_id"]: r for r in pq.read_table(out / "summary.parquet").to_pylist()}
    data = b""
    for _, line in Journal(out / JOURNAL).scan():
        run_id = str(line["run_id"])
        row, run = rows[run_id], runs[run_index(run_id)]
        rel, killed = row["mcap"], bool(line.get("killed"))
        record = None
        if killed:
            record = made_up_record(run_id, row["status"], row["message"])
        elif rel is not None:
            record = logged_record(out / rel)
        if record is None:
            record = {"name": row["name"], **{
                c: row[c] for c in (*RESULT_COLUMNS, *OPTIMUM_RESULT_COLUMNS)
                if c in row and c != "mcap" and row[c] is not None}}
            record["mcap"] = None
        data += sealed_line({
            "run_id": run_id, "digest": run.digest, "fmu_sha256": fmu_sha, "killed": killed,
            "wall_s": 0.5, "worker": "1", "path": rel,
            "log": log_stamp(out / rel) if rel is not None else None, "record": record})
    (out / JOURNAL).write_bytes(data)


@pytest.fixture
def journal_of_before() -> Callable[[Path, Any], None]:
    """:func:`_journal_of_before`: a batch folder's journal as older batches wrote it."""
    return _journal_of_before
