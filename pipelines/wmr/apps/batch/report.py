"""``wmr report DIR``: a batch's summary as ``DIR/report/report.md`` plus PNG plots.

Plots: the runs per status; for each varied input (a column of the summary's inputs with more
than one value), the success rate, the time to goal and the path length against it; and the
spread of the metrics over the converged runs as histograms.  A batch that varies the GPS noise
and the stop radius also gets the sensing study (:mod:`wmr.apps.sensing_study`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Final

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from wmr.apps.batch.spec import POSE_COLUMNS
from wmr.apps.batch.summary import ID_COLUMNS, RESULT_COLUMNS, STATUSES, SUMMARY_PARQUET
from wmr.config.naming import plural
from wmr.infra.errors import ConfigError, LogError, WmrError
from wmr.infra.inputs import open_input
from wmr.infra.outputs import refuse_special

#: Inputs with at most this many distinct values are plotted per value, others in bins.
DISCRETE_MAX: Final = 12
_BINS: Final = 10
_SPREAD: Final = (("time_to_goal_s", "time to goal, s", 1.0),
                  ("path_length_m", "path length, m", 1.0),
                  ("final_position_error_m", "final position error, mm", 1000.0),
                  ("final_heading_error_rad", "final heading error, deg", 180.0 / math.pi),
                  ("peak_torque_nm", "peak torque, N m", 1.0),
                  ("torque_sq_integral_n2m2s", "integral of torque^2, N^2 m^2 s", 1.0))
_COLOURS: Final = {"converged": "tab:green", "timeout": "tab:orange", "failed": "tab:red"}


def _floats(table: pa.Table, name: str) -> NDArray[np.float64]:
    return np.array([math.nan if v is None else float(v)
                     for v in table.column(name).to_pylist()], dtype=np.float64)


#: Columns a summary must have for a report; the rest (metrics, ``mcap``) may be missing, as in
#: a summary written by another version or by hand, and are then read as empty.
_REQUIRED: Final = ("run_id", "status", "message")
#: The most ``wmr report`` reads of a summary (10^6 runs make about 200 MB).
MAX_SUMMARY_BYTES: Final = 2048 * (1 << 20)


def _read_summary(path: Path) -> pa.Table:
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
    for name in (*(c for c, _, _ in _SPREAD), "mcap"):
        if name not in table.column_names:
            table = table.append_column(name, pa.nulls(table.num_rows, pa.string()
                                                       if name == "mcap" else pa.float64()))
    return table


def varied_inputs(table: pa.Table) -> list[str]:
    """Input columns with more than one distinct value: the spec's varied fields first, then
    the pose columns that follow from them."""
    result = set(RESULT_COLUMNS)
    out = []
    for name in table.column_names:
        if name in ID_COLUMNS or name in result \
                or pa.types.is_string(table.schema.field(name).type):  # a name, e.g. estimator
            continue
        x = _floats(table, name)
        if len(np.unique(x[np.isfinite(x)])) > 1:
            out.append(name)
    return sorted(out, key=lambda c: c in POSE_COLUMNS)


def _groups(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], list[NDArray[np.bool_]], bool]:
    """Group the runs by value (few values) or in equal-width bins: centres, masks, binned."""
    values = np.unique(x[np.isfinite(x)])
    if len(values) <= DISCRETE_MAX:
        return values, [x == v for v in values], False
    edges = np.linspace(values[0], values[-1], _BINS + 1)
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, _BINS - 1)
    centres = 0.5 * (edges[:-1] + edges[1:])
    return centres, [(idx == i) & np.isfinite(x) for i in range(_BINS)], True


def _fmt(v: float, digits: int = 4) -> str:
    return "–" if not math.isfinite(v) else f"{v:.{digits}g}"


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]+", "_", name)


def _plot_status(counts: dict[str, int], path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3))
    total = max(1, sum(counts.values()))
    names = list(counts)
    bars = ax.bar(names, [counts[n] for n in names],
                  color=[_COLOURS.get(n, "tab:gray") for n in names])
    for bar, n in zip(bars, names, strict=True):
        ax.annotate(f"{100.0 * counts[n] / total:.1f} %", (bar.get_x() + bar.get_width() / 2,
                    bar.get_height()), ha="center", va="bottom", fontsize=8)
    ax.set_ylabel("runs")
    converged_pct = 100.0 * counts.get("converged", 0) / total
    ax.set_title(f"{plural(total, 'run')}: {converged_pct:.1f} % converged")
    fig.tight_layout()
    refuse_special(path)  # a FIFO there would block the save, a device be written
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_against(name: str, x: NDArray[np.float64], ok: NDArray[np.bool_],
                  status: Sequence[str], ttg: NDArray[np.float64], path_len: NDArray[np.float64],
                  path: Path) -> list[tuple[float, int, float]]:
    """Success rate, time to goal and path length against input ``name``; the rate per group."""
    import matplotlib.pyplot as plt

    centres, masks, binned = _groups(x)
    rates = [(float(c), int(m.sum()), float(ok[m].mean()) if m.any() else math.nan)
             for c, m in zip(centres, masks, strict=True)]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
    axes[0].plot(centres, [100.0 * r for _, _, r in rates], "o-")
    axes[0].set_ylim(-5, 105)
    axes[0].set_ylabel("converged, %" + (" (binned)" if binned else ""))
    colours = [_COLOURS.get(s, "tab:gray") for s in status]
    for ax, y, label in ((axes[1], ttg, "time to goal, s"), (axes[2], path_len,
                                                              "path length, m")):
        fin = np.isfinite(y) & np.isfinite(x)
        ax.scatter(x[fin], y[fin], s=6, alpha=0.5,
                   c=[colours[i] for i in np.flatnonzero(fin)])
        med = [float(np.median(y[m & ok])) if (m & ok).any() else math.nan for m in masks]
        ax.plot(centres, med, "k-", lw=1.5, label="median (converged)")
        ax.set_ylabel(label)
        ax.legend(fontsize=7)
    for ax in axes:
        ax.set_xlabel(name)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    refuse_special(path)  # a FIFO there would block the save, a device be written
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return rates


def _plot_spread(columns: dict[str, NDArray[np.float64]], ok: NDArray[np.bool_],
                 path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5))
    for ax, (col, label, scale) in zip(axes.flat, _SPREAD, strict=True):
        y = columns[col][ok] * scale
        y = y[np.isfinite(y)]
        if len(y):
            ax.hist(y, bins=min(40, max(5, len(y) // 10)), color="tab:blue", alpha=0.8)
            for q, style in ((5, ":"), (50, "-"), (95, ":")):
                ax.axvline(float(np.percentile(y, q)), color="k", ls=style, lw=1)
        ax.set_xlabel(label)
        ax.set_ylabel("runs")
    fig.suptitle(f"spread over the {int(ok.sum())} converged runs (median, 5 and 95 %)")
    fig.tight_layout()
    refuse_special(path)  # a FIFO there would block the save, a device be written
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _logs_line(batch_dir: Path, table: pa.Table) -> str:
    """What was logged: the runs with a log (the summary's ``mcap`` column) and the log policy
    of the last invocation (``batch.json``, when it says)."""
    import json

    kept = table.num_rows - table.column("mcap").null_count
    policy = ""
    try:
        log = json.loads((batch_dir / "batch.json").read_text(encoding="utf-8")).get("log")
        from wmr.apps.run import LogPolicy

        policy = f" (last run with {LogPolicy(log['keep'], log['every_k_steps']).describe()})"
    except (OSError, ValueError, TypeError, KeyError, AttributeError, WmrError):
        pass  # an older batch folder, or one whose batch.json is gone: the count is enough
    return f"Logs: {kept} of {plural(table.num_rows, 'run')} kept one{policy}."


def _silent(line: str) -> None:
    """The progress receiver of a report nobody watches."""


def write_report(batch_dir: Path, max_plots: int = 8,
                 progress: Callable[[str], None] = _silent) -> Path:
    """Write ``batch_dir/report/report.md`` and its plots from the batch's summary.

    Parameters
    ----------
    batch_dir
        A folder written by ``wmr batch``.
    max_plots
        Plot at most this many varied inputs.
    progress
        Called with a line before each step (reading the summary, each plot): a report with
        many plots takes seconds.

    Returns
    -------
    Path
        The report.

    Raises
    ------
    ConfigError
        No summary in ``batch_dir``.
    """
    progress(f"report: reading {batch_dir / SUMMARY_PARQUET}")
    import matplotlib

    matplotlib.use("Agg")
    summary = batch_dir / SUMMARY_PARQUET
    if not summary.exists():
        raise ConfigError("DIR", f"no {SUMMARY_PARQUET} in {batch_dir}",
                          "give the --out folder of a 'wmr batch'")
    table = _read_summary(summary)
    out = batch_dir / "report"
    out.mkdir(exist_ok=True)
    n = table.num_rows
    status = [str(s) for s in table.column("status").to_pylist()]
    counts = {s: status.count(s) for s in STATUSES}
    for s in status:
        counts.setdefault(s, status.count(s))
    ok = np.array([s == "converged" for s in status], dtype=bool)
    cols = {c: _floats(table, c) for c, _, _ in _SPREAD}
    lines = [f"# Batch report: {batch_dir.name}", "",
             f"Summary: `{summary}`, {plural(n, 'run')}.", ""]
    if n:
        lines += [_logs_line(batch_dir, table), ""]
    if n == 0:
        lines.append("No finished runs.")
        path = out / "report.md"
        refuse_special(path)
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
        return path
    rate = 100.0 * ok.mean()
    lines += ["## Outcome", "", "| status | runs | share |", "|---|---:|---:|"]
    lines += [f"| {s} | {c} | {100.0 * c / n:.1f} % |" for s, c in counts.items()]
    lines += ["", f"**Success rate: {rate:.1f} %** ({int(ok.sum())}/{n} converged).", "",
              "![runs per status](status.png)", ""]
    progress("report: plotting the runs per status")
    _plot_status(counts, out / "status.png")

    lines += ["## Spread over the converged runs", "",
              "| metric | min | 5 % | median | 95 % | max | mean | std |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for col, label, scale in _SPREAD:
        y = cols[col][ok] * scale
        y = y[np.isfinite(y)]
        if not len(y):
            continue
        q = np.percentile(y, [0, 5, 50, 95, 100])
        lines.append(f"| {label} | " + " | ".join(_fmt(float(v)) for v in q)
                     + f" | {_fmt(float(y.mean()))} | {_fmt(float(y.std()))} |")
    lines += ["", "![spread](spread.png)", ""]
    progress("report: plotting the spread of the metrics")
    _plot_spread(cols, ok, out / "spread.png")

    varied = varied_inputs(table)
    if varied:
        lines += ["## Against the varied inputs", ""]
        shown = varied[:max_plots]
        for i, name in enumerate(shown, 1):
            progress(f"report: plotting against {name} ({i}/{len(shown)})")
            x = _floats(table, name)
            png = f"vs_{_safe(name)}.png"
            rates = _plot_against(name, x, ok, status, cols["time_to_goal_s"],
                                  cols["path_length_m"], out / png)
            binned = len(np.unique(x[np.isfinite(x)])) > DISCRETE_MAX
            cells = ", ".join(f"{_fmt(c, 3)}: {100.0 * r:.0f} % of {k}" for c, k, r in rates
                              if k)
            lines += [f"### {name}", "",
                      f"Success rate {'per bin (centre)' if binned else 'per value'}: {cells}.",
                      "", f"![{name}]({png})", ""]
        if len(varied) > max_plots:
            lines += [f"Not plotted (over --max-plots): {', '.join(varied[max_plots:])}.", ""]
    from wmr.apps.sensing_study import sensing_section

    progress("report: the sensing study, if the batch varies the sensors")
    lines += sensing_section(table, out)
    bad = [i for i, s in enumerate(status) if s != "converged"]
    if bad:
        ids = table.column("run_id").to_pylist()
        msgs = table.column("message").to_pylist()
        logs = table.column("mcap").to_pylist()
        lines += ["## Runs that did not converge", "", "| run | status | message | log |",
                  "|---|---|---|---|"]
        lines += [f"| {ids[i]} | {status[i]} | {str(msgs[i]).replace('|', '/')} | "
                  f"{'–' if logs[i] is None else f'`{logs[i]}`'} |" for i in bad[:20]]
        if len(bad) > 20:
            lines.append(f"| ... | | {len(bad) - 20} more in the summary |")
        lines.append("")
    path = out / "report.md"
    refuse_special(path)
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


__all__ = ["varied_inputs", "write_report"]
