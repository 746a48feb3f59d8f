"""The summary of a batch: one row per finished run, sorted by run id, as Parquet and CSV.

Nothing in it depends on the execution (no timings, no worker, no host, logs by relative path),
so the same spec gives the same bytes with any number of workers or on Dask.  Wall times go to
the journal only.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import pyarrow as pa
import pyarrow.parquet as pq

from wmr.apps.batch.spec import NAME_COLUMNS, BatchRun
from wmr.apps.optimal import OPTIMUM_COLUMNS
from wmr.infra.durable import replacing

SUMMARY_PARQUET: Final = "summary.parquet"
SUMMARY_CSV: Final = "summary.csv"
#: What identifies a run: ``controller`` is the run's controller (varied or not), ``draw`` the
#: index of its random sample (:attr:`wmr.apps.batch.spec.BatchRun.draw`): runs of one draw under
#: different controllers had the same random inputs.  These two follow the input columns: a
#: summary starts as it always did, its inputs after ``variant``.
ID_COLUMNS: Final = ("run_id", "name", "base", "variant", "controller", "draw")
#: Result columns: name -> Arrow type.
RESULT_COLUMNS: Final[dict[str, pa.DataType]] = {
    "status": pa.string(),
    "message": pa.string(),
    "final_position_error_m": pa.float64(),
    "final_heading_error_rad": pa.float64(),
    "time_to_goal_s": pa.float64(),
    "path_length_m": pa.float64(),
    "energy_net_j": pa.float64(),  # wmr.core.energy
    "energy_positive_j": pa.float64(),
    "energy_abs_j": pa.float64(),
    "torque_sq_integral_n2m2s": pa.float64(),
    "peak_torque_nm": pa.float64(),
    "steps": pa.int64(),
    "estimated_final_position_error_m": pa.float64(),
    "estimated_final_heading_error_rad": pa.float64(),
    "mcap": pa.string(),
}
STATUSES: Final = ("converged", "timeout", "failed")
#: The optimum's columns (:func:`wmr.apps.optimal.optimum_fields`), after the results, in a
#: summary of a spec with ``optimal`` only: a spec without it keeps its summary byte for byte.
OPTIMUM_RESULT_COLUMNS: Final[dict[str, pa.DataType]] = {
    c: pa.string() if kind == "string" else pa.float64() for c, kind in OPTIMUM_COLUMNS.items()}

#: ``optimal_message`` of a run without an optimum (killed by its executor: a hang, a crash).
UNSOLVED: Final = "not solved: the run's worker was killed before the optimum"


#: A batch of more runs than this keeps its logs in shards of this many runs each,
#: ``runs/<shard>/<run_id>.mcap``: no folder of a million-run batch holds more than a
#: thousand logs.  A smaller batch keeps them in ``runs/`` itself, as batches always did.
SHARD_RUNS: Final = 1000


def log_relpath(run_id: str, n_runs: int = 0, shard_runs: int | None = None) -> str:
    """A run's log, relative to the batch folder.

    ``runs/<run_id>.mcap`` in a batch of at most :data:`SHARD_RUNS` runs;
    ``runs/<shard>/<run_id>.mcap`` in a larger one, the shard being the run's index
    (:func:`wmr.apps.batch.spec.run_index`) divided by :data:`SHARD_RUNS`, with at least three
    digits (``runs/012/012345-1f2e3d4c.mcap``), so that the shards sort as their runs do.
    """
    shard = SHARD_RUNS if shard_runs is None else shard_runs
    if n_runs <= shard:
        return f"runs/{run_id}.mcap"
    head = run_id.partition("-")[0]
    width = max(3, len(str((n_runs - 1) // shard)))
    return f"runs/{int(head) // shard:0{width}d}/{run_id}.mcap"


def _float(value: object) -> float | None:
    if value is None or isinstance(value, bool) or not isinstance(value, int | float):
        return None
    v = float(value)
    return v if math.isfinite(v) else None


@dataclass(frozen=True)
class SummaryRow:
    """What the summary says of a run besides its result: a :class:`BatchRun` without its
    :class:`~wmr.core.runspec.RunSpec` (the summary of a large batch holds many)."""

    run_id: str
    name: str
    base: str
    variant: str
    inputs: Mapping[str, float | str]
    controller: str
    draw: int

    @classmethod
    def of(cls, run: BatchRun) -> SummaryRow:
        return cls(run.run_id, run.spec.name, run.base, run.variant, run.inputs,
                   run.controller, run.draw)


def summary_table(runs: Iterable[BatchRun | SummaryRow], input_columns: Sequence[str],
                  records: Mapping[str, Mapping[str, Any]],
                  logs: Mapping[str, str | None] | None = None,
                  optimal: bool = False) -> pa.Table:
    """The summary of the runs of ``runs`` that have a record, sorted by run id.

    Parameters
    ----------
    runs
        The batch's runs, or the summary rows of some of them (at least those with a record).
    input_columns
        Input columns (:attr:`wmr.apps.batch.spec.BatchSpec.input_columns`).
    records
        Result records (:func:`wmr.apps.run.run_to_log`) by run id.
    logs
        Each run's log relative to the batch folder, ``None`` for a run without a log (its
        log policy kept none); a run missing here has :func:`log_relpath` (every run, when
        ``logs`` is ``None``).
    optimal
        Add :data:`OPTIMUM_RESULT_COLUMNS` (the spec has ``optimal``); a record without them
        (its worker was killed before the solve) has ``optimal_status`` ``none`` and the
        message :data:`UNSOLVED`.
    """
    results = {**RESULT_COLUMNS, **(OPTIMUM_RESULT_COLUMNS if optimal else {})}
    done = sorted((r for r in runs if r.run_id in records), key=lambda r: r.run_id)
    cols: dict[str, list[Any]] = {c: [] for c in (*ID_COLUMNS, *input_columns, *results)}
    for run in done:
        rec = records[run.run_id]
        if optimal and not rec.get("optimal_status"):  # its worker died before the solve
            rec = {**rec, "optimal_status": "none", "optimal_message": UNSOLVED}
        cols["run_id"].append(run.run_id)
        cols["name"].append(run.name)
        cols["base"].append(run.base)
        cols["variant"].append(run.variant)
        cols["controller"].append(run.controller)
        cols["draw"].append(run.draw)
        for c in input_columns:
            v = run.inputs.get(c, math.nan)
            cols[c].append(v if isinstance(v, str) else None if math.isnan(v) else v)
        for c, kind in results.items():
            if c == "mcap":
                cols[c].append(log_relpath(run.run_id) if logs is None or run.run_id not in logs
                               else logs[run.run_id])
            elif kind == pa.string():
                cols[c].append(str(rec.get(c) or ""))
            elif kind == pa.int64():
                steps = rec.get(c)
                cols[c].append(int(steps) if isinstance(steps, int) else None)
            else:
                cols[c].append(_float(rec.get(c)))
    fields = [pa.field(c, pa.string(), nullable=False) for c in ID_COLUMNS[:4]]
    fields += [pa.field(c, pa.string() if c in NAME_COLUMNS else pa.float64())
               for c in input_columns]
    fields += [pa.field("controller", pa.string(), nullable=False),
               pa.field("draw", pa.int64(), nullable=False)]
    fields += [pa.field(c, t) for c, t in results.items()]
    schema = pa.schema(fields)
    return pa.table({f.name: pa.array(cols[f.name], f.type) for f in fields}, schema=schema)


def result_rows(table: pa.Table) -> list[dict[str, Any]]:
    """Each row's result columns (:data:`RESULT_COLUMNS`, and the optimum's when the table
    has them), name -> value: what a compact journal line seals
    (:func:`wmr.apps.batch.journal.compact_line`)."""
    names = [c for c in table.column_names
             if c in RESULT_COLUMNS or c in OPTIMUM_RESULT_COLUMNS]
    return table.select(names).to_pylist()


#: What a spreadsheet takes for the start of a formula (OWASP, "CSV Injection").
FORMULA_STARTS: Final = ("=", "+", "-", "@", "\t", "\r")


def _csv_cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)  # shortest text that reads back to the same double (-1.5 stays)
    if isinstance(value, str) and value.startswith(FORMULA_STARTS):
        # a run named '=HYPERLINK(...)' must not become a formula where the CSV is opened: a
        # quote first makes it text, as OWASP recommends (only here: Parquet keeps the name)
        return f"'{value}"
    return str(value)


#: A batch of more runs than this writes its summary as Parquet only: the CSV of a
#: ``mc_fig10`` run is about 480 bytes (every float as its shortest exact decimal) against
#: 160 in Parquet, and writing it costs the parent about 15 µs a run.  Read a larger one with
#: ``pandas.read_parquet`` (or ``.to_csv`` it).
CSV_MAX_RUNS: Final = 1000


def write_summary(tables: pa.Table | Iterable[pa.Table], out_dir: Path, csv_too: bool = True
                  ) -> tuple[Path, Path | None]:
    """Write the summary, a table or the consecutive blocks of one (one schema, the first
    block maybe empty), as ``summary.parquet`` and (``csv_too``) ``summary.csv``, each
    atomically and a block at a time: the summary of a million runs is never whole in memory.
    Without ``csv_too`` a ``summary.csv`` of before is removed (it would be stale).

    Returns
    -------
    tuple of Path
        The Parquet and the CSV file (``None`` without ``csv_too``).
    """
    blocks = iter([tables] if isinstance(tables, pa.Table) else tables)
    first = next(blocks)
    parquet, csv_path = out_dir / SUMMARY_PARQUET, out_dir / SUMMARY_CSV
    # each under a new random name beside it (a planted 'summary.csv.tmp' link is never
    # followed), renamed into place: the summary before stays until both are whole
    with ExitStack() as stack:
        # fsynced: once it is written the parts are removed, and it holds the only results
        parquet_file = stack.enter_context(replacing(parquet, durable=True))
        writer = None
        if csv_too:
            csv_file = stack.enter_context(replacing(csv_path))
            stream = io.TextIOWrapper(csv_file, encoding="utf-8", newline="")
            writer = csv.writer(stream, lineterminator="\n")
            writer.writerow(first.column_names)
        # no dictionary pages: a summary's columns are mostly distinct floats and ids, for
        # which Arrow builds a dictionary and gives it up; plain pages and zstd cost the
        # parent half the CPU (2.0 against 0.9 us a run of mc_fig10) and 18 % fewer bytes
        # (194 against 158 a run; repeated values compress as well under zstd)
        with pq.ParquetWriter(parquet_file, first.schema, compression="zstd",
                              write_statistics=False, use_dictionary=False) as pw:
            for table in itertools.chain([first], blocks):
                if table.num_rows:
                    # one chunk a column: a block merged from a frame a range (78 chunks of
                    # 128 rows) cost Parquet's writer 0.84 us a run written as it is, 0.55
                    # combined first (mc_fig10, 10,240 rows)
                    pw.write_table(table.combine_chunks())
                if writer is not None:
                    columns = [table.column(i).to_pylist() for i in range(table.num_columns)]
                    writer.writerows([_csv_cell(v) for v in row]
                                     for row in zip(*columns, strict=True))
        if writer is not None:
            stream.flush()
            stream.detach()  # replacing() closes the file itself
    if not csv_too:
        csv_path.unlink(missing_ok=True)
        return parquet, None
    return parquet, csv_path


def read_summary(out_dir: Path) -> pa.Table:
    """The summary table of a batch folder (Parquet)."""
    return pq.read_table(out_dir / SUMMARY_PARQUET)


__all__ = [
    "CSV_MAX_RUNS",
    "FORMULA_STARTS",
    "OPTIMUM_RESULT_COLUMNS",
    "RESULT_COLUMNS",
    "SHARD_RUNS",
    "SUMMARY_CSV",
    "SUMMARY_PARQUET",
    "SummaryRow",
    "log_relpath",
    "read_summary",
    "result_rows",
    "summary_table",
    "write_summary",
]
