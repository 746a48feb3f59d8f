"""The sensing study: success rate and true final errors against the GPS noise sigma and the stop
radius epsilon (``scenarios/sensing_fig10.toml``, ``docs/sensing.md``).

``wmr report DIR`` adds this section (:func:`sensing_section`) to the report of any batch whose
summary varies both ``sensors.gps_sigma_m`` and ``stop_radius_m``: one heat map per variant (the
``[[list]]`` entry, e.g. ``tuned-ekf``) of the success rate, the median true final position
error and the median true final heading error of the converged runs, and the table of the
smallest epsilon that reaches the success target for each sigma.

A run **succeeds** when it converged (on its estimate) and its true final position error is
within the stop radius: the robot really stopped where it believes it did.  Converged runs that
stopped outside epsilon count as converged but not as successes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt
import pyarrow as pa

SIGMA: Final = "sensors.gps_sigma_m"
EPSILON: Final = "stop_radius_m"
#: The success rate epsilon must reach (the issue's 99 %).
TARGET: Final = 0.99


@dataclass(frozen=True)
class Cell:
    """The runs of one variant at one (sigma, epsilon)."""

    runs: int
    converged: int
    succeeded: int  # converged and truly within epsilon
    position_error_m: float  # median true final position error of the converged runs
    heading_error_deg: float  # median true final heading error of the converged runs

    @property
    def rate(self) -> float:
        """Success rate (0 to 1), NaN without runs."""
        return self.succeeded / self.runs if self.runs else math.nan


@dataclass(frozen=True)
class Study:
    """The cells of a sensing batch, by variant, sigma and epsilon."""

    variants: tuple[str, ...]
    sigmas_m: tuple[float, ...]
    epsilons_m: tuple[float, ...]
    cells: dict[tuple[str, float, float], Cell]

    def epsilon_for(self, variant: str, sigma_m: float, target: float = TARGET) -> float | None:
        """The smallest epsilon from which on every larger one reaches ``target``; None: none."""
        best: float | None = None
        for eps in reversed(self.epsilons_m):
            cell = self.cells.get((variant, sigma_m, eps))
            if cell is None or not cell.rate >= target:
                break
            best = eps
        return best


def _column(table: pa.Table, name: str) -> npt.NDArray[np.float64]:
    return np.array([math.nan if v is None else float(v)
                     for v in table.column(name).to_pylist()], dtype=np.float64)


def study(table: pa.Table) -> Study | None:
    """The study of a batch summary; ``None`` unless it varies sigma and epsilon."""
    names = set(table.column_names)
    if SIGMA not in names or EPSILON not in names or table.num_rows == 0:
        return None
    sigma = _column(table, SIGMA)
    eps = _column(table, EPSILON)
    if len(np.unique(sigma[np.isfinite(sigma)])) < 2 or len(np.unique(eps)) < 2:
        return None
    labels = [str(v) for v in table.column("variant").to_pylist()]
    if "sensors.estimator" in names and not any(labels):
        labels = [str(v) for v in table.column("sensors.estimator").to_pylist()]
    ok = np.array([s == "converged" for s in table.column("status").to_pylist()])
    pos = _column(table, "final_position_error_m")
    head = np.degrees(_column(table, "final_heading_error_rad"))
    variants = tuple(dict.fromkeys(labels))
    lab = np.array(labels)
    cells: dict[tuple[str, float, float], Cell] = {}
    for v in variants:
        for s in np.unique(sigma[np.isfinite(sigma)]):
            for e in np.unique(eps):
                m = (lab == v) & (sigma == s) & (eps == e)
                if not m.any():
                    continue
                good = m & ok
                cells[(v, float(s), float(e))] = Cell(
                    int(m.sum()), int(good.sum()), int((good & (pos <= e)).sum()),
                    float(np.median(pos[good])) if good.any() else math.nan,
                    float(np.median(head[good])) if good.any() else math.nan)
    return Study(variants, tuple(float(s) for s in np.unique(sigma[np.isfinite(sigma)])),
                 tuple(float(e) for e in np.unique(eps)), cells)


def plot_study(st: Study, path: Path) -> None:
    """Heat maps: rows success rate, position error, heading error; a column per variant."""
    import matplotlib

    matplotlib.use("Agg")  # a file, never a window (as wmr report)
    import matplotlib.pyplot as plt

    rows = (("success rate, %", lambda c: 100.0 * c.rate, "RdYlGn", (0.0, 100.0)),
            ("median true final position error, mm", lambda c: 1000.0 * c.position_error_m,
             "viridis", None),
            ("median true final heading error, deg", lambda c: c.heading_error_deg,
             "magma", None))
    n = len(st.variants)
    fig, axes = plt.subplots(3, n, figsize=(3.2 * n + 1.0, 8.4), squeeze=False,
                             constrained_layout=True)
    for r, (label, value, cmap, limits) in enumerate(rows):
        grids = []
        for v in st.variants:
            g = np.full((len(st.sigmas_m), len(st.epsilons_m)), math.nan)
            for i, s in enumerate(st.sigmas_m):
                for j, e in enumerate(st.epsilons_m):
                    cell = st.cells.get((v, s, e))
                    if cell is not None and (cell.converged or r == 0):
                        g[i, j] = value(cell)
            grids.append(g)
        finite = np.concatenate([g[np.isfinite(g)] for g in grids])
        lo, hi = limits if limits else ((float(finite.min()), float(finite.max()))
                                        if len(finite) else (0.0, 1.0))
        for k, (v, g) in enumerate(zip(st.variants, grids, strict=True)):
            ax = axes[r][k]
            im = ax.imshow(g, origin="lower", cmap=cmap, vmin=lo, vmax=hi, aspect="auto")
            for i in range(g.shape[0]):
                for j in range(g.shape[1]):
                    if np.isfinite(g[i, j]):
                        # white on the dark ends of viridis and magma
                        dark = r > 0 and (g[i, j] - lo) < 0.4 * (hi - lo)
                        ax.text(j, i, f"{g[i, j]:.0f}" if r == 0 else f"{g[i, j]:.3g}",
                                ha="center", va="center", fontsize=7,
                                color="white" if dark else "black")
            ax.set_xticks(range(len(st.epsilons_m)), [f"{e:g}" for e in st.epsilons_m])
            ax.set_yticks(range(len(st.sigmas_m)), [f"{s:g}" for s in st.sigmas_m])
            if r == 0:
                ax.set_title(v)
            if r == 2:
                ax.set_xlabel("stop radius epsilon, m")
            if k == 0:
                ax.set_ylabel("GPS sigma, m")
        fig.colorbar(im, ax=list(axes[r]), label=label, shrink=0.9)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def epsilon_table(st: Study, target: float = TARGET) -> list[str]:
    """Markdown: the smallest epsilon reaching ``target`` per sigma (rows) and variant."""
    runs = {c.runs for c in st.cells.values()}
    lines = ["| GPS sigma, m | " + " | ".join(st.variants) + " |",
             "|---:|" + "---:|" * len(st.variants)]
    for s in st.sigmas_m:
        row = []
        for v in st.variants:
            eps = st.epsilon_for(v, s, target)
            row.append("none tried" if eps is None else f"{eps:g}")
        lines.append(f"| {s:g} | " + " | ".join(row) + " |")
    lines += ["", f"Epsilon (m) from which on every larger epsilon tried succeeded (converged, "
              f"and truly within epsilon) in at least {100 * target:g} % of its runs "
              f"({'/'.join(str(r) for r in sorted(runs))} runs per cell); 'none tried': not "
              "even the largest."]
    return lines


def sensing_section(table: pa.Table, out_dir: Path) -> list[str]:
    """The report's sensing section (Markdown lines, the figure written to ``out_dir``);
    empty when the batch is not a sensing study."""
    st = study(table)
    if st is None:
        return []
    plot_study(st, out_dir / "sensing.png")
    return ["## Sensing: sigma against epsilon", "", *epsilon_table(st), "",
            "![sensing](sensing.png)", ""]


__all__ = ["Cell", "Study", "epsilon_table", "plot_study", "sensing_section", "study"]
