"""The numbers of ``wmr report DIR``: every table of the report as one JSON-ready object.

:func:`report_data` reads the batch's summary and writes nothing; ``wmr report DIR --json``
prints what it returns, and :func:`wmr.apps.batch.report.write_report` renders the same object
as Markdown with plots.  The fields are described in docs/batch.md ("Report").
"""

from __future__ import annotations

import math
import shlex
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from wmr.apps.batch.sensitivity import Ranking, is_full_grid, plain_line, rank_inputs
from wmr.apps.batch.spec import POSE_COLUMNS
from wmr.apps.batch.summary import ID_COLUMNS, RESULT_COLUMNS, STATUSES, SUMMARY_PARQUET
from wmr.apps.optimal import OPTIMUM_COLUMNS
from wmr.infra.errors import ConfigError, LogError
from wmr.infra.inputs import open_input

#: Inputs with at most this many distinct values are grouped per value, others in bins.
DISCRETE_MAX: Final = 12
BINS: Final = 10
#: The metrics whose spread over the converged runs the report gives: column, label, scale
#: from the column's unit to the label's.
SPREAD: Final = (("time_to_goal_s", "time to goal, s", 1.0),
                 ("path_length_m", "path length, m", 1.0),
                 ("final_position_error_m", "final position error, mm", 1000.0),
                 ("final_heading_error_rad", "final heading error, deg", 180.0 / math.pi),
                 ("peak_torque_nm", "peak torque, N m", 1.0),
                 ("torque_sq_integral_n2m2s", "integral of torque^2, N^2 m^2 s", 1.0))
#: The optimality gaps a batch with the optimum has (``optimal = "time"|"energy"`` in its spec):
#: column, label; each is the run's value over the optimal one (1 is the optimum).
GAPS: Final = (("time_gap", "time to goal / optimal time"),
               ("energy_gap", "energy / optimal energy"))
#: The energy outcome: the positive energy when the summary has it, else the effort metric
#: every summary has had.
ENERGY_COLUMNS: Final = ("energy_positive_j", "torque_sq_integral_n2m2s")
#: The summary's column naming a run's controller (a batch may compare several).
CONTROLLER: Final = "controller"
#: Two-sided 95 % quantile of the normal distribution, for the Wilson interval.
Z95: Final = 1.959963984540054
#: Default number of worst runs per metric.
WORST: Final = 10
#: Columns a summary must have for a report; the rest (metrics, ``mcap``) may be missing, as in
#: a summary written by another version or by hand, and are then read as empty.
_REQUIRED: Final = ("run_id", "status", "message")
#: Start columns that follow from the spec's polar start (``start.r_m``, ``start.bearing_deg``)
#: rather than being given by it.
_POLAR: Final = ("start.r_m", "start.bearing_deg")
_FROM_POLAR: Final = ("start.x_m", "start.y_m")


def floats(table: pa.Table, name: str) -> NDArray[np.float64]:
    """Column ``name`` as floats, NaN for a null."""
    return np.array([math.nan if v is None else float(v)
                     for v in table.column(name).to_pylist()], dtype=np.float64)


#: The most ``wmr report`` reads of a summary (10^6 runs make about 200 MB).
MAX_SUMMARY_BYTES: Final = 2048 * (1 << 20)


def read_checked(path: Path) -> pa.Table:
    """The summary at ``path``, checked: a file that is not Parquet, or lacks a required
    column, is one line naming the file (a batch folder may come from anyone)."""
    import pyarrow.parquet as pq

    try:
        # a FIFO there blocked the report for ever: opened as every input is
        with open_input(path, "DIR", max_bytes=MAX_SUMMARY_BYTES, what="a batch summary",
                        fix="give the --out folder of a 'wmr batch'") as stream:
            table = pq.read_table(stream)
    except (pa.ArrowException, OSError) as exc:
        detail = " ".join(str(exc).split())[:200]  # Arrow's messages run over several lines
        raise LogError(f"{path}: not a readable Parquet summary ({detail}); "
                       "run 'wmr batch' on its spec again to write it anew") from None
    missing = [c for c in _REQUIRED if c not in table.column_names]
    if missing:
        raise LogError(f"{path}: the summary has no column {', '.join(missing)}; "
                       "run 'wmr batch' on its spec again to write it anew")
    for name in (*(c for c, _, _ in SPREAD), "mcap"):
        if name not in table.column_names:
            table = table.append_column(name, pa.nulls(table.num_rows, pa.string()
                                                       if name == "mcap" else pa.float64()))
    return table


def derived_inputs(columns: Sequence[str]) -> set[str]:
    """The input columns that follow from others rather than from the spec: the start's x and
    y when the spec gives the start as a distance and bearing about the goal."""
    return set(_FROM_POLAR) if any(c in columns for c in _POLAR) else set()


def varied_inputs(table: pa.Table) -> list[str]:
    """Input columns with more than one distinct value: the spec's own fields first (the
    others, then the poses it gives), the columns that follow from them last."""
    # the optimum's columns are results (of the OCP), not inputs: ranked as inputs they would
    # "explain" the outcomes they follow from
    result = set(RESULT_COLUMNS) | set(OPTIMUM_COLUMNS)
    derived = derived_inputs(table.column_names)
    out = []
    for name in table.column_names:
        if name in ID_COLUMNS or name in result \
                or pa.types.is_string(table.schema.field(name).type):  # a name, e.g. estimator
            continue
        x = floats(table, name)
        if len(np.unique(x[np.isfinite(x)])) > 1:
            out.append(name)
    return sorted(out, key=lambda c: (c in derived, c in POSE_COLUMNS))


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a proportion ``k / n`` (95 % by default); ``(nan, nan)``
    for no runs.  Unlike the normal approximation it stays within [0, 1] and is not empty
    at 0 or n successes."""
    if n <= 0:
        return math.nan, math.nan
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def groups(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], list[NDArray[np.bool_]], bool]:
    """Group the runs by value (few values) or in equal-width bins: centres, masks, binned."""
    values = np.unique(x[np.isfinite(x)])
    if len(values) <= DISCRETE_MAX:
        return values, [x == v for v in values], False
    edges = np.linspace(values[0], values[-1], BINS + 1)
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, BINS - 1)
    centres = 0.5 * (edges[:-1] + edges[1:])
    return centres, [(idx == i) & np.isfinite(x) for i in range(BINS)], True


def rerun_command(batch_dir: Path | str, run_id: str) -> str:
    """The command that runs one run of a batch again with its full log."""
    return f"wmr rerun {shlex.quote(str(batch_dir))} {shlex.quote(run_id)}"


def _num(v: float) -> float | None:
    """A JSON number: ``None`` for NaN or an infinity (JSON has neither)."""
    return float(v) if math.isfinite(v) else None


def _rate(k: int, n: int) -> dict[str, Any]:
    lo, hi = wilson(k, n)
    return {"runs": n, "converged": k, "rate": _num(k / n) if n else None,
            "ci95": [_num(lo), _num(hi)]}


def energy_column(table: pa.Table) -> str:
    """The energy outcome of this summary (:data:`ENERGY_COLUMNS`): the first with a value."""
    for name in ENERGY_COLUMNS:
        if name in table.column_names and table.column(name).null_count < table.num_rows:
            return name
    return ENERGY_COLUMNS[-1]


class Summary:
    """A summary read once: its columns as arrays, for the report's numbers and plots."""

    def __init__(self, batch_dir: Path) -> None:
        self.batch_dir = batch_dir
        self.path = batch_dir / SUMMARY_PARQUET
        if not self.path.exists():
            raise ConfigError("DIR", f"no {SUMMARY_PARQUET} in {batch_dir}",
                              "give the --out folder of a 'wmr batch'")
        self.table = read_checked(self.path)
        self.n = self.table.num_rows
        self.status = [str(s) for s in self.table.column("status").to_pylist()]
        self.ok = np.array([s == "converged" for s in self.status], dtype=bool)
        self.ids = [str(r) for r in self.table.column("run_id").to_pylist()]
        self.energy = energy_column(self.table)
        self.gaps = [c for c, _ in GAPS if c in self.table.column_names]
        self.cols = {c: floats(self.table, c) for c in
                     {*(c for c, _, _ in SPREAD), self.energy, *self.gaps}}
        self.varied = varied_inputs(self.table)
        self.derived = derived_inputs(self.varied)
        self.x = {c: floats(self.table, c) for c in self.varied}

    def counts(self) -> dict[str, int]:
        """Runs per status: the three statuses, then any other a summary holds."""
        # one pass: the count of each status per run was quadratic (10^10 steps at 10^5 runs)
        seen = Counter(self.status)
        return {**{s: seen[s] for s in STATUSES}, **seen}

    def is_grid(self) -> bool:
        """The spec's own varied inputs form a full grid."""
        own = [c for c in self.varied if c not in self.derived]
        return bool(own) and is_full_grid(np.column_stack([self.x[c] for c in own]))

    def rankings(self) -> list[Ranking]:
        """Every varied input ranked for convergence, time to goal and energy."""
        if not self.varied:
            return []
        x = np.column_stack([self.x[c] for c in self.varied])
        grid = self.is_grid()
        out = [rank_inputs("converged", self.varied, x, self.ok.astype(np.float64), grid)]
        for col in ("time_to_goal_s", self.energy):
            y = np.where(self.ok, self.cols[col], math.nan)
            out.append(rank_inputs(col, self.varied, x, y, grid))
        return out

    def inputs_of(self, i: int) -> dict[str, float | None]:
        """Run ``i``'s varied inputs."""
        return {c: _num(float(self.x[c][i])) for c in self.varied}

    def run_entry(self, i: int) -> dict[str, Any]:
        """What the report says of run ``i``: its status, message, log, varied inputs, metrics
        and the command that reruns it."""
        mcap = self.table.column("mcap")[i].as_py()
        entry: dict[str, Any] = {
            "run_id": self.ids[i], "status": self.status[i],
            "message": str(self.table.column("message")[i].as_py()),
            "mcap": mcap, "inputs": self.inputs_of(i),
            "rerun": rerun_command(self.batch_dir, self.ids[i])}
        if CONTROLLER in self.table.column_names:
            entry[CONTROLLER] = self.table.column(CONTROLLER)[i].as_py()
        entry.update({c: _num(float(self.cols[c][i]))
                      for c in ("time_to_goal_s", "final_position_error_m", self.energy)})
        return entry

    def worst(self, metric: str, n: int) -> list[int]:
        """The ``n`` runs with the largest finite ``metric``, largest first (ties by run id)."""
        y = self.cols[metric]
        have = np.flatnonzero(np.isfinite(y))
        order = sorted(have.tolist(), key=lambda i: (-y[i], self.ids[i]))
        return order[:n]

    def not_converged(self) -> list[int]:
        """Every run that failed or timed out: failed first, then by run id."""
        rank = {s: k for k, s in enumerate(("failed", "timeout"))}
        bad = [i for i, s in enumerate(self.status) if s != "converged"]
        return sorted(bad, key=lambda i: (rank.get(self.status[i], len(rank)), self.ids[i]))

    def grid_map(self, rankings: Sequence[Ranking] = ()) -> dict[str, Any] | None:
        """Success rate and median time to goal over two inputs: the spec's own two when they
        form a full grid (per value); otherwise, in a sampled design with runs that did not
        converge, the two inputs that matter most for convergence (per value, or in 10 bins
        over 12 values), where the 1-D plots cannot show two inputs acting together.
        ``None`` for any other design."""
        own = [c for c in self.varied if c not in self.derived]
        sampled = False
        if len(own) == 2 and self.is_grid():
            a, b = own
        else:
            conv = next((r for r in rankings if r.outcome == "converged"), None)
            if conv is None or len(conv.ranked) < 2 or self.is_grid():
                return None
            a, b = conv.ranked[0].input, conv.ranked[1].input
            sampled = True
        (ca, ma, ba), (cb, mb, bb) = groups(self.x[a]), groups(self.x[b])
        rate = np.full((len(cb), len(ca)), math.nan)
        med = np.full_like(rate, math.nan)
        runs = np.zeros(rate.shape, dtype=np.int64)
        ttg = self.cols["time_to_goal_s"]
        for j, mj in enumerate(mb):
            for i, mi in enumerate(ma):
                m = mi & mj
                runs[j, i] = int(m.sum())
                if runs[j, i]:
                    rate[j, i] = self.ok[m].mean()
                t = ttg[m & self.ok]
                t = t[np.isfinite(t)]
                med[j, i] = float(np.median(t)) if t.size else math.nan
        return {"x": a, "y": b, "design": "sampled" if sampled else "grid", "binned": ba or bb,
                "x_values": [_num(v) for v in ca], "y_values": [_num(v) for v in cb],
                "runs": runs.tolist(),
                "success_rate": [[_num(v) for v in row] for row in rate],
                "median_time_to_goal_s": [[_num(v) for v in row] for row in med]}


def _spread(s: Summary) -> list[dict[str, Any]]:
    out = []
    for col in (*(c for c, _, _ in SPREAD), *s.gaps):
        y = s.cols[col][s.ok]
        y = y[np.isfinite(y)]
        if not len(y):
            continue
        q = np.percentile(y, [0, 5, 50, 95, 100])
        out.append({"metric": col, "runs": len(y), "min": _num(q[0]), "p5": _num(q[1]),
                    "median": _num(q[2]), "p95": _num(q[3]), "max": _num(q[4]),
                    "mean": _num(float(y.mean())), "std": _num(float(y.std()))})
    return out


def _against(s: Summary) -> dict[str, Any]:
    out = {}
    for name in s.varied:
        centres, masks, binned = groups(s.x[name])
        out[name] = {"binned": binned, "groups": [
            {"value": _num(float(c)), **_rate(int(s.ok[m].sum()), int(m.sum()))}
            for c, m in zip(centres, masks, strict=True) if m.any()]}
    return out


def _controllers(s: Summary) -> list[dict[str, Any]]:
    if CONTROLLER not in s.table.column_names:
        return []
    names = [str(v) for v in s.table.column(CONTROLLER).to_pylist()]
    out = []
    for name in sorted(set(names)):
        m = np.array([v == name for v in names], dtype=bool)
        row: dict[str, Any] = {CONTROLLER: name, **_rate(int(s.ok[m].sum()), int(m.sum()))}
        for col in ("time_to_goal_s", s.energy, *s.gaps):
            y = s.cols[col][m & s.ok]
            y = y[np.isfinite(y)]
            row[f"median_{col}"] = _num(float(np.median(y))) if y.size else None
        out.append(row)
    return out


def report_data(batch_dir: Path, worst: int = WORST, summary: Summary | None = None
                ) -> dict[str, Any]:
    """Every number of the report of ``batch_dir``, as one JSON-ready object.

    Parameters
    ----------
    batch_dir
        A folder written by ``wmr batch``.
    worst
        How many of the worst runs per metric.
    summary
        The summary already read (the Markdown report reads it once for both).

    Returns
    -------
    dict
        The fields of docs/batch.md ("Report"); a NaN is ``None``.

    Raises
    ------
    ConfigError
        No summary in ``batch_dir``, or ``worst`` below 0.
    LogError
        A summary that is not Parquet or lacks a required column.
    """
    if worst < 0:
        raise ConfigError("--worst", f"must be >= 0, got {worst}",
                          "give e.g. --worst 10, or 0 for no table of worst runs")
    s = summary or Summary(batch_dir)
    counts = s.counts()
    rankings = s.rankings()
    bad = s.not_converged()
    return {
        "batch": str(batch_dir), "summary": str(s.path), "runs": s.n,
        "logs_kept": s.n - s.table.column("mcap").null_count,
        "success": {**_rate(int(s.ok.sum()), s.n), "interval": "Wilson, 95 %"},
        "status": [{"status": k, "runs": c, "share": _num(c / s.n) if s.n else None,
                    "ci95": [_num(v) for v in wilson(c, s.n)]} for k, c in counts.items()],
        "controllers": _controllers(s),
        "spread": _spread(s),
        "inputs": [{"input": c, "derived": c in s.derived,
                    "values": len(np.unique(s.x[c][np.isfinite(s.x[c])]))}
                   for c in s.varied],
        "design": "grid" if s.is_grid() else "sampled",
        "against": _against(s),
        "sensitivity": {r.outcome: [k.as_dict() for k in r.ranked] for r in rankings},
        "sensitivity_notes": {r.outcome: r.note for r in rankings if r.note},
        "sensitivity_runs": {r.outcome: r.runs for r in rankings},
        "sensitivity_line": plain_line(rankings),
        "worst": {m: [s.run_entry(i) for i in s.worst(m, worst)]
                  for m in ("time_to_goal_s", "final_position_error_m", s.energy)},
        "not_converged": [s.run_entry(i) for i in bad],
        "grid_map": s.grid_map(rankings),
    }


__all__ = ["CONTROLLER", "DISCRETE_MAX", "GAPS", "SPREAD", "Summary", "derived_inputs", "floats",
           "groups", "read_checked", "report_data", "rerun_command", "varied_inputs",
           "wilson"]
