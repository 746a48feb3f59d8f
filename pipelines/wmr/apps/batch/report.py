"""``wmr report DIR``: a batch's summary as ``DIR/report/report.md`` plus PNG plots.

The numbers come from :func:`wmr.apps.batch.report_data.report_data` (what ``--json`` prints);
this module renders them.  Sections: the outcome (runs per status, the success rate with its
95 % Wilson interval, per controller when the batch has several); which input matters
(:mod:`wmr.apps.batch.sensitivity`: every varied input ranked for convergence, time to goal and
energy, and one plain-language line); the worst runs and every run that did not converge, each
with its inputs and the command that reruns it; the spread of the metrics over the converged
runs; a 2-D map of a 2-D grid; the region of attraction when the start varies
(:func:`wmr.apps.figures.roa_figure`); the success rate, time to goal and path length against
each varied input; and the sensing study of a batch that varies the GPS noise and the stop
radius (:mod:`wmr.apps.sensing_study`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np
from numpy.typing import NDArray

from wmr.apps.batch.report_data import (
    CONTROLLER,
    DISCRETE_MAX,
    GAPS,
    SPREAD,
    WORST,
    Summary,
    groups,
    report_data,
    varied_inputs,
    wilson,
)
from wmr.apps.batch.summary import SUMMARY_PARQUET
from wmr.config.naming import plural
from wmr.infra.errors import ConfigError, WmrError
from wmr.infra.outputs import refuse_special

if TYPE_CHECKING:
    from wmr.apps.figures import RoaResult

_COLOURS: Final = {"converged": "tab:green", "timeout": "tab:orange", "failed": "tab:red"}
#: Runs that did not converge listed in the Markdown (all of them are in the JSON).
LISTED_BAD: Final = 50
#: Points of one status drawn in a scatter at most (the medians and rates use every run).
SCATTER_MAX: Final = 2000
#: A region of attraction from sampled starts: cells per axis, and heading sectors.
_ROA_CELLS: Final = 12
_ROA_SECTORS: Final = 4
#: Labels of the worst-run tables, by metric.
_WORST_LABELS: Final = {"time_to_goal_s": "time to goal, s",
                        "final_position_error_m": "final position error, m",
                        "energy_positive_j": "positive energy, J",
                        "torque_sq_integral_n2m2s": "integral of torque^2, N^2 m^2 s"}


def _fmt(v: float | None, digits: int = 4) -> str:
    return "–" if v is None or not math.isfinite(v) else f"{v:.{digits}g}"


def _save(fig: Any, path: Path) -> None:
    """Save ``fig`` as ``path`` (PNG), which must not be a device or a FIFO: one would block
    the save, the other be written."""
    refuse_special(path)
    fig.savefig(path, dpi=110)


def _pct(v: float | None) -> str:
    return "–" if v is None else f"{100.0 * v:.1f} %"


def _ci(ci: Sequence[float | None]) -> str:
    return f"{_pct(ci[0])} to {_pct(ci[1])}"


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]+", "_", name)


def _cell(text: object) -> str:
    """A Markdown table cell: no ``|`` or line break of a message breaks the table."""
    return " ".join(str(text).replace("|", "/").split())


def _status_legend(ax: Any, names: Sequence[str]) -> None:
    from matplotlib.patches import Patch

    ax.legend(handles=[Patch(color=_COLOURS.get(n, "tab:gray"), label=n) for n in names],
              fontsize=7)


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
    _status_legend(ax, names)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _shown(mask: NDArray[np.bool_], label: str) -> tuple[NDArray[np.bool_], str]:
    """At most :data:`SCATTER_MAX` of the runs of ``mask``, drawn with a fixed seed, and the
    legend label saying so: a scatter of 10^5 points took 4 s a plot and shows no more."""
    k = int(mask.sum())
    if k <= SCATTER_MAX:
        return mask, label
    pick = np.zeros_like(mask)
    pick[np.random.default_rng(0).choice(np.flatnonzero(mask), SCATTER_MAX, replace=False)] = True
    return pick, f"{label} ({SCATTER_MAX} of {k} drawn)"


def _plot_against(name: str, x: NDArray[np.float64], ok: NDArray[np.bool_],
                  status: Sequence[str], ttg: NDArray[np.float64], path_len: NDArray[np.float64],
                  path: Path) -> list[tuple[float, int, float]]:
    """Success rate (with its Wilson interval), time to goal and path length against input
    ``name``, a legend in each panel; the runs without a time to goal (timeouts, failures)
    are marked along the top of the time panel.  Returns the rate per group."""
    import matplotlib.pyplot as plt
    from matplotlib.transforms import blended_transform_factory

    centres, masks, binned = groups(x)
    rates = [(float(c), int(m.sum()), float(ok[m].mean()) if m.any() else math.nan)
             for c, m in zip(centres, masks, strict=True)]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
    band = np.array([wilson(int(ok[m].sum()), int(m.sum())) for m in masks])
    axes[0].plot(centres, [100.0 * r for _, _, r in rates], "o-", color="tab:blue",
                 label="converged, % of the runs" + (" (per bin)" if binned else ""))
    axes[0].fill_between(centres, 100.0 * band[:, 0], 100.0 * band[:, 1], color="tab:blue",
                         alpha=0.2, label="95 % Wilson interval")
    axes[0].set_ylim(-5, 105)
    axes[0].set_ylabel("converged, %")
    axes[0].legend(fontsize=7)
    st = np.array(status)
    kinds = list(dict.fromkeys(status))
    for ax, y, label in ((axes[1], ttg, "time to goal, s"), (axes[2], path_len,
                                                              "path length, m")):
        for kind in kinds:
            fin, label_of = _shown((st == kind) & np.isfinite(y) & np.isfinite(x), kind)
            if fin.any():
                ax.scatter(x[fin], y[fin], s=6, alpha=0.5, color=_COLOURS.get(kind, "tab:gray"),
                           label=label_of)
        if y is ttg:  # no time to goal: shown at the top, or they vanish from the panel
            top = blended_transform_factory(ax.transData, ax.transAxes)
            for kind in kinds:
                miss, label_of = _shown((st == kind) & ~np.isfinite(y) & np.isfinite(x),
                                        f"{kind}: no time to goal (at the top)")
                if miss.any():
                    ax.scatter(x[miss], np.full(int(miss.sum()), 0.97), s=14, marker="^",
                               color=_COLOURS.get(kind, "tab:gray"), transform=top,
                               label=label_of)
        med = [float(np.median(y[m & ok])) if (m & ok & np.isfinite(y)).any() else math.nan
               for m in masks]
        ax.plot(centres, med, "k-", lw=1.5, label="median (converged)")
        ax.set_ylabel(label)
        ax.legend(fontsize=7)
    for ax in axes:
        ax.set_xlabel(name)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return rates


def _plot_spread(columns: Mapping[str, NDArray[np.float64]], ok: NDArray[np.bool_],
                 path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5))
    for ax, (col, label, scale) in zip(axes.flat, SPREAD, strict=True):
        y = columns[col][ok] * scale
        y = y[np.isfinite(y)]
        if len(y):
            ax.hist(y, bins=min(40, max(5, len(y) // 10)), color="tab:blue", alpha=0.8,
                    label="converged runs")
            for q, style, name in ((5, ":", "5 and 95 %"), (50, "-", "median"),
                                   (95, ":", None)):
                ax.axvline(float(np.percentile(y, q)), color="k", ls=style, lw=1, label=name)
            ax.legend(fontsize=7)
        ax.set_xlabel(label)
        ax.set_ylabel("runs")
    fig.suptitle(f"spread over the {int(ok.sum())} converged runs (median, 5 and 95 %)")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _plot_gaps(s: Summary, path: Path) -> None:
    """Histograms of the optimality gaps over the converged runs, one per controller when the
    batch compares several."""
    import matplotlib.pyplot as plt

    names = ([str(v) for v in s.table.column(CONTROLLER).to_pylist()]
             if CONTROLLER in s.table.column_names else [""] * s.n)
    fig, axes = plt.subplots(1, len(s.gaps), figsize=(6 * len(s.gaps), 3.6), squeeze=False)
    for ax, col in zip(axes[0], s.gaps, strict=True):
        for name in sorted(set(names)):
            m = s.ok & np.array([v == name for v in names]) & np.isfinite(s.cols[col])
            if m.any():
                ax.hist(s.cols[col][m], bins=min(40, max(5, int(m.sum()) // 10)), alpha=0.6,
                        label=f"{name or 'all runs'} (median {np.median(s.cols[col][m]):.3g})")
        ax.axvline(1.0, color="k", lw=1, label="the optimum")
        ax.set_xlabel(dict(GAPS)[col])
        ax.set_ylabel("converged runs")
        ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _plot_grid_map(grid: Mapping[str, Any], path: Path) -> None:
    """Success rate and median time to goal over a 2-D grid, each cell labelled."""
    import matplotlib.pyplot as plt

    xs, ys = grid["x_values"], grid["y_values"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    for ax, key, label, cmap, fmt in (
            (axes[0], "success_rate", "converged, %", "RdYlGn", "{:.0f}"),
            (axes[1], "median_time_to_goal_s", "median time to goal (converged), s",
             "viridis", "{:.3g}")):
        z = np.array([[math.nan if v is None else v for v in row] for row in grid[key]],
                     dtype=np.float64)
        if key == "success_rate":
            z = 100.0 * z
        img = ax.imshow(np.ma.masked_invalid(z), origin="lower", aspect="auto", cmap=cmap,
                        vmin=0.0 if key == "success_rate" else None,
                        vmax=100.0 if key == "success_rate" else None)
        for j in range(len(ys)):
            for i in range(len(xs)):
                ax.text(i, j, "none" if not math.isfinite(z[j, i]) else fmt.format(z[j, i]),
                        ha="center", va="center", fontsize=7)
        ax.set_xticks(range(len(xs)), [_fmt(v, 3) for v in xs])
        ax.set_yticks(range(len(ys)), [_fmt(v, 3) for v in ys])
        ax.set_xlabel(grid["x"])
        ax.set_ylabel(grid["y"])
        fig.colorbar(img, ax=ax, label=label)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _axis(v: NDArray[np.float64], cells: int) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Centres and each value's cell: the distinct values when few, else equal bins."""
    values = np.unique(v)
    if len(values) <= cells:
        return values, np.searchsorted(values, v)
    edges = np.linspace(values[0], values[-1], cells + 1)
    return 0.5 * (edges[:-1] + edges[1:]), np.clip(
        np.searchsorted(edges, v, side="right") - 1, 0, cells - 1)


def roa_of(s: Summary) -> RoaResult | None:
    """The region of attraction of a batch whose start varies, as a
    :class:`~wmr.apps.figures.RoaResult`: start positions in the goal's frame (goal at the
    origin heading along x) and start headings relative to the goal's; a cell is marked with
    the most common status of its runs and coloured by their median time to goal (converged).
    ``None`` when the start does not vary or the summary lacks the pose columns."""
    from wmr.apps.figures import RoaResult
    from wmr.core.plant import Pose

    cols = ("start.x_m", "start.y_m", "start.heading_deg", "goal.x_m", "goal.y_m",
            "goal.heading_deg")
    if not all(c in s.table.column_names for c in cols) \
            or not {"start.x_m", "start.y_m"} & set(s.varied):
        return None
    from wmr.apps.batch.report_data import floats

    sx, sy, sh, gx, gy, gh = (floats(s.table, c) for c in cols)
    g = np.radians(gh)
    dx, dy = sx - gx, sy - gy
    xr, yr = np.cos(g) * dx + np.sin(g) * dy, -np.sin(g) * dx + np.cos(g) * dy
    hr = np.degrees(np.angle(np.exp(1j * np.radians(sh - gh))))  # wrapped to (-180, 180]
    keep = np.isfinite(xr) & np.isfinite(yr) & np.isfinite(hr)
    if not keep.any():
        return None
    xs, ix = _axis(xr[keep], _ROA_CELLS)
    ys, iy = _axis(yr[keep], _ROA_CELLS)
    hs = np.unique(hr[keep])
    if len(hs) > 2 * _ROA_SECTORS:  # sampled headings: sectors centred on 0, 90, 180, 270
        width = 360.0 / _ROA_SECTORS
        ih = np.round(np.mod(hr[keep], 360.0) / width).astype(np.intp) % _ROA_SECTORS
        hs = np.arange(_ROA_SECTORS) * width
    else:
        ih = np.searchsorted(hs, hr[keep])
    ttg = np.full((len(hs), len(ys), len(xs)), math.nan)
    status = np.full(ttg.shape, "", dtype="<U9")
    st = np.array(s.status)[keep]
    time = s.cols["time_to_goal_s"][keep]
    cell = (ih * len(ys) + iy) * len(xs) + ix
    for c in np.unique(cell):
        m = cell == c
        k, rest = divmod(int(c), len(ys) * len(xs))
        j, i = divmod(rest, len(xs))
        kinds, counts = np.unique(st[m], return_counts=True)
        status[k, j, i] = str(kinds[int(np.argmax(counts))])
        t = time[m & (st == "converged") & np.isfinite(time)]
        ttg[k, j, i] = float(np.median(t)) if t.size else math.nan
    limit = floats(s.table, "max_time_s") if "max_time_s" in s.table.column_names else None
    t_max = float(np.nanmax(limit)) if limit is not None and np.isfinite(limit).any() \
        else math.nan
    return RoaResult(xs=xs, ys=ys, headings_rad=np.radians(hs), time_to_goal_s=ttg,
                     status=status, goal=Pose(0.0, 0.0, 0.0), t_max_s=t_max, wall_s=0.0)


def _logs_line(batch_dir: Path, kept: int, n: int) -> str:
    """What was logged: the runs with a log (the summary's ``mcap`` column) and the log policy
    of the last invocation (``batch.json``, when it says)."""
    import json

    policy = ""
    try:
        log = json.loads((batch_dir / "batch.json").read_text(encoding="utf-8")).get("log")
        from wmr.apps.run import LogPolicy

        policy = f" (last run with {LogPolicy(log['keep'], log['every_k_steps']).describe()})"
    except (OSError, ValueError, TypeError, KeyError, AttributeError, WmrError):
        pass  # an older batch folder, or one whose batch.json is gone: the count is enough
    return f"Logs: {kept} of {plural(n, 'run')} kept one{policy}."


def _silent(line: str) -> None:
    """The progress receiver of a report nobody watches."""


def _runs_table(entries: Sequence[Mapping[str, Any]], inputs: Sequence[str],
                value: str | None = None) -> list[str]:
    """Markdown rows of runs: id, status, [value], inputs, message, log, rerun command."""
    head = ["run", "status", *([value] if value else []), *inputs, "message", "log", "rerun"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for e in entries:
        cells = [f"`{_cell(e['run_id'])}`", e["status"],
                 *([_fmt(e[value])] if value else []),
                 *(_fmt(e["inputs"][c]) for c in inputs), _cell(e["message"]),
                 "–" if e["mcap"] is None else f"`{_cell(e['mcap'])}`", f"`{e['rerun']}`"]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _sensitivity_section(data: Mapping[str, Any]) -> list[str]:
    sens: Mapping[str, list[dict[str, Any]]] = data["sensitivity"]
    if not sens:
        return []
    notes: Mapping[str, str] = data["sensitivity_notes"]
    outcomes = list(sens)
    methods = sorted({k["method"] for ranked in sens.values() for k in ranked})
    lines = ["## Which input matters", "",
             f"**{data['sensitivity_line']}**", "",
             "First-order index of each varied input (the share of the outcome's variance it "
             "explains alone, 0 to 1), from the most influential down; convergence is 1 for a "
             "converged run and 0 for the others, time to goal and energy are over the "
             f"converged runs. Design: {data['design']}; method: "
             f"{', '.join(methods) or 'none'} (docs/batch.md, \"Report\")."]
    for o in outcomes:
        if notes.get(o):
            lines.append(f"* `{o}`: {notes[o]} ({plural(data['sensitivity_runs'][o], 'run')}).")
    lines.append("")
    for k in sens.get("converged", [])[:2]:  # what the index means, in runs
        g = [e for e in data["against"][k["input"]]["groups"] if e["rate"] is not None]
        if len(g) > 1:
            lo, hi = g[0], g[-1]
            lines.append(f"* Not converged against `{k['input']}`: {_pct(1.0 - lo['rate'])} "
                         f"at {_fmt(lo['value'], 3)}, {_pct(1.0 - hi['rate'])} at "
                         f"{_fmt(hi['value'], 3)} (lowest and highest "
                         f"{'bin' if data['against'][k['input']]['binned'] else 'value'}).")
    ranked = {o: sens[o] for o in outcomes if sens[o]}
    if ranked:
        if lines[-1]:  # a table right after a list is taken into its last item
            lines.append("")
        lines += ["| rank | " + " | ".join(f"{o}: input | index" for o in ranked) + " |",
                  "|---:|" + "---|---:|" * len(ranked)]
        for r in range(max(len(v) for v in ranked.values())):
            cells = []
            for v in ranked.values():
                if r >= len(v):
                    cells += ["", ""]
                    continue
                e = v[r]
                cells += [e["input"], f"{e['index']:.3f}"
                          + (f" ± {e['conf']:.3f}" if e.get("conf") is not None else "")]
            lines.append(f"| {r + 1} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def write_report(batch_dir: Path, max_plots: int = 8,
                 progress: Callable[[str], None] = _silent, worst: int = WORST) -> Path:
    """Write ``batch_dir/report/report.md`` and its plots from the batch's summary.

    Parameters
    ----------
    batch_dir
        A folder written by ``wmr batch``.
    max_plots
        Plot at most this many varied inputs (the spec's own fields before the columns that
        follow from them).
    progress
        Called with a line before each step (reading the summary, each plot): a report with
        many plots takes seconds.
    worst
        List this many of the worst runs per metric.

    Returns
    -------
    Path
        The report.

    Raises
    ------
    ConfigError
        No summary in ``batch_dir``, or ``worst`` below 0.
    """
    if worst < 0:
        raise ConfigError("--worst", f"must be >= 0, got {worst}",
                          "give e.g. --worst 10, or 0 for no table of worst runs")
    progress(f"report: reading {batch_dir / SUMMARY_PARQUET}")
    import matplotlib

    matplotlib.use("Agg")
    s = Summary(batch_dir)
    out = batch_dir / "report"
    out.mkdir(exist_ok=True)
    n = s.n
    lines = [f"# Batch report: {batch_dir.name}", "",
             f"Summary: `{s.path}`, {plural(n, 'run')}.", ""]
    if n == 0:
        lines.append("No finished runs.")
        path = out / "report.md"
        refuse_special(path)
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
        return path
    progress("report: ranking the inputs")
    data = report_data(batch_dir, worst=worst, summary=s)
    lines += [_logs_line(batch_dir, data["logs_kept"], n), ""]
    counts = s.counts()
    success = data["success"]
    lines += ["## Outcome", "", "| status | runs | share | 95 % interval (Wilson) |",
              "|---|---:|---:|---|"]
    lines += [f"| {e['status']} | {e['runs']} | {_pct(e['share'])} | {_ci(e['ci95'])} |"
              for e in data["status"]]
    lines += ["", f"**Success rate: {100.0 * s.ok.mean():.1f} %** ({int(s.ok.sum())}/{n} "
              f"converged; 95 % Wilson interval {_ci(success['ci95'])}).", "",
              "![runs per status](status.png)", ""]
    progress("report: plotting the runs per status")
    _plot_status(counts, out / "status.png")
    if data["controllers"]:
        lines += ["## Per controller", "",
                  "| controller | runs | converged | success | 95 % interval | "
                  "median time to goal, s | median energy |"
                  + "".join(f" median {g} |" for g in s.gaps),
                  "|---|---:|---:|---:|---|---:|---:|" + "---:|" * len(s.gaps)]
        lines += [f"| {_cell(c[CONTROLLER])} | {c['runs']} | {c['converged']} | "
                  f"{_pct(c['rate'])} | {_ci(c['ci95'])} | {_fmt(c['median_time_to_goal_s'])}"
                  f" | {_fmt(c[f'median_{s.energy}'])} |"
                  + "".join(f" {_fmt(c[f'median_{g}'])} |" for g in s.gaps)
                  for c in data["controllers"]]
        lines.append("")
    lines += _sensitivity_section(data)
    own = [c for c in s.varied if c not in s.derived]
    lines += [f"## The worst runs (up to {worst} per metric)", ""]
    for metric, entries in data["worst"].items():
        label = _WORST_LABELS.get(metric, metric)
        if not entries:
            lines += [f"No run has a {label.split(',')[0]}.", ""]
            continue
        lines += [f"### By {label}", "", *_runs_table(entries, own, metric), ""]
    bad = data["not_converged"]
    if bad:
        shown = bad[:LISTED_BAD]
        lines += ["## Runs that did not converge", "",
                  f"{plural(len(bad), 'run')} failed or timed out"
                  + (f"; the first {len(shown)} (failed first, then by run id), all of them in "
                     "`wmr report --json`" if len(bad) > len(shown) else "") + ".", "",
                  *_runs_table(shown, own), ""]
        if len(bad) > len(shown):
            lines += [f"... and {len(bad) - len(shown)} more.", ""]

    lines += ["## Spread over the converged runs", "",
              "| metric | min | 5 % | median | 95 % | max | mean | std |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]
    scales = {c: (label, scale) for c, label, scale in SPREAD}
    for e in data["spread"]:
        if e["metric"] not in scales:  # an optimality gap: its own section
            continue
        label, scale = scales[e["metric"]]
        lines.append(f"| {label} | " + " | ".join(
            _fmt(e[k] * scale) for k in ("min", "p5", "median", "p95", "max", "mean", "std"))
            + " |")
    lines += ["", "![spread](spread.png)", ""]
    progress("report: plotting the spread of the metrics")
    _plot_spread(s.cols, s.ok, out / "spread.png")

    gaps = [e for e in data["spread"] if e["metric"] in dict(GAPS)]
    if gaps:
        progress("report: plotting the optimality gaps")
        _plot_gaps(s, out / "optimality_gap.png")
        lines += ["## Against the optimum", "",
                  "Each converged run's value over the optimal one (1 is the optimum).", "",
                  "| gap | runs | min | 5 % | median | 95 % | max |",
                  "|---|---:|---:|---:|---:|---:|---:|"]
        lines += [f"| {dict(GAPS)[e['metric']]} | {e['runs']} | " + " | ".join(
            _fmt(e[k]) for k in ("min", "p5", "median", "p95", "max")) + " |" for e in gaps]
        lines += ["", "![optimality gap](optimality_gap.png)", ""]
    if data["grid_map"] is not None:
        progress("report: the map over two inputs")
        _plot_grid_map(data["grid_map"], out / "grid_map.png")
        g = data["grid_map"]
        lines += ["## Over the grid" if g["design"] == "grid" else
                  "## Where runs fail: the two inputs that matter most for convergence", "",
                  f"Success rate and median time to goal (converged) over {g['x']} and "
                  f"{g['y']}" + (" (bin centres)" if g["binned"] else "") + ".", "",
                  "![grid map](grid_map.png)", ""]
    roa = roa_of(s)
    if roa is not None:
        from wmr.apps.figures import roa_figure

        progress("report: the region of attraction of the start poses")
        fig = roa_figure(roa)
        fig.suptitle("Region of attraction of the batch: median time to goal (converged) by "
                     "start position in the goal's frame,\none panel per start heading "
                     "relative to the goal's; a cell is marked with its runs' most common "
                     "status", fontsize=9)
        _save(fig, out / "roa.png")
        lines += ["## Region of attraction", "",
                  "Start positions relative to the goal (goal at the origin, heading along x), "
                  "one panel per start heading relative to the goal's.", "",
                  "![region of attraction](roa.png)", ""]

    varied = s.varied
    if varied:
        lines += ["## Against the varied inputs", ""]
        shown_inputs = varied[:max_plots]
        for i, name in enumerate(shown_inputs, 1):
            progress(f"report: plotting against {name} ({i}/{len(shown_inputs)})")
            x = s.x[name]
            png = f"vs_{_safe(name)}.png"
            rates = _plot_against(name, x, s.ok, s.status, s.cols["time_to_goal_s"],
                                  s.cols["path_length_m"], out / png)
            binned = len(np.unique(x[np.isfinite(x)])) > DISCRETE_MAX
            cells = ", ".join(f"{_fmt(c, 3)}: {100.0 * r:.0f} % of {k}" for c, k, r in rates
                              if k)
            lines += [f"### {name}" + (" (follows from the spec's fields)"
                                       if name in s.derived else ""), "",
                      f"Success rate {'per bin (centre)' if binned else 'per value'}: {cells}.",
                      "", f"![{name}]({png})", ""]
        if len(varied) > max_plots:
            lines += [f"Not plotted (over --max-plots): {', '.join(varied[max_plots:])}.", ""]
    from wmr.apps.sensing_study import sensing_section

    progress("report: the sensing study, if the batch varies the sensors")
    lines += sensing_section(s.table, out)
    path = out / "report.md"
    refuse_special(path)
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


__all__ = ["LISTED_BAD", "roa_of", "varied_inputs", "write_report"]
