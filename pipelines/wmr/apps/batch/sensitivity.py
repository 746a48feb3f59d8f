"""Which varied input drives an outcome of a batch: every input ranked by its first-order index.

Two designs, two estimators of the same quantity, the share of the outcome's variance that one
input explains alone (:math:`S_i = \\mathrm{Var}(E[Y \\mid X_i]) / \\mathrm{Var}(Y)`, 0 to 1):

* **a full grid** (every combination of the inputs' values, each as often): the main effect,
  the variance of the outcome's mean per value of the input over the outcome's variance,
  computed exactly from the grid (``method = "main effect"``);
* **any other design** (Monte Carlo, lists, a grid crossed with random draws): RBD-FAST from
  the given runs (SALib's ``rbd_fast``, Tarantola et al. 2006 with Tissot and Prieur's bias
  correction; ``method = "RBD-FAST"``), which takes (X, Y) samples from any design.  SALib's
  delta (moment-independent) was measured and not taken: its estimator skips every class of
  runs whose outcome is constant, so a 0/1 outcome such as convergence reads as uninfluential
  (a convergence decided by one input of three gave it delta 0.01 and the two others 0.14),
  and it costs about 2 s an input on 5,000 runs where RBD-FAST takes 20 ms.

Convergence is the outcome 1 for a converged run, 0 for a failed or timed-out one; the time to
goal and the energy are taken over the converged runs (the others have no time to goal, and
their energy is that of a run cut short).  The deterministic simulation makes a grid's main
effects exact; RBD-FAST's estimates are noisy (an input that does not matter reads 0.00
+- 0.02 on 2,000 runs, bootstrap 95 %), so an index below :data:`NOISE_FLOOR` is
not named in the plain-language line, nor a sampled index within its own 95 % interval of 0.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

MAIN_EFFECT: Final = "main effect"
RBD_FAST: Final = "RBD-FAST"
#: Fewer runs than this (with a value of the outcome) are too few to rank the inputs of a
#: design other than a full grid: RBD-FAST's bias correction ``2 M / N`` (M = 10 harmonics) is
#: then over 0.2, and the 95 % half width of an input that does not matter, measured, grows
#: from 0.2 to 0.3 at 100 runs to 0.8 to 1.0 at 50 (0.01 at 2,000): the order is noise.
MIN_RUNS_SAMPLED: Final = 100
#: A full grid needs this many runs: its main effects are exact, but on fewer runs than this
#: an outcome's variance is that of a handful of numbers.
MIN_RUNS_GRID: Final = 4
#: A grid has at most this many values of one input; an input with more is a sampled one.
GRID_LEVELS_MAX: Final = 50
#: RBD-FAST uses at most this many runs, drawn with :data:`SUBSAMPLE_SEED`: its cost grows with
#: the runs (a periodogram per input and resample) and 20,000 runs already put its noise under
#: 0.01; a larger batch is subsampled, and the report says so.
SUBSAMPLE_RUNS: Final = 20_000
SUBSAMPLE_SEED: Final = 0
#: RBD-FAST's harmonics (SALib's default) and bootstrap resamples for its 95 % interval.
HARMONICS: Final = 10
RESAMPLES: Final = 20
#: Below this an index is noise for the plain-language line.
NOISE_FLOOR: Final = 0.02


@dataclass(frozen=True)
class Ranked:
    """One input's influence on one outcome.

    Attributes
    ----------
    input
        The summary column.
    index
        First-order index, 0 to 1 (a negative estimate, noise about 0, is given as 0).
    method
        :data:`MAIN_EFFECT` or :data:`RBD_FAST`.
    conf
        Half width of the 95 % bootstrap interval (RBD-FAST), ``None`` for an exact main effect.
    """

    input: str
    index: float
    method: str
    conf: float | None = None

    def as_dict(self) -> dict[str, object]:
        """``{"input", "index", "method"}`` (and ``"conf"`` for a sampled design)."""
        out: dict[str, object] = {"input": self.input, "index": round(self.index, 4),
                                  "method": self.method}
        if self.conf is not None:
            out["conf"] = round(self.conf, 4)
        return out


@dataclass(frozen=True)
class Ranking:
    """The inputs ranked for one outcome, or why they are not.

    Attributes
    ----------
    outcome
        The outcome's name (``converged``, a summary column).
    ranked
        From the most influential input down; empty when ``note`` says why.
    runs
        The runs the ranking used.
    note
        Why there is no ranking (a constant outcome, too few runs), or how it was made (a
        subsample); ``""`` otherwise.
    """

    outcome: str
    ranked: tuple[Ranked, ...]
    runs: int
    note: str = ""


def is_full_grid(x: NDArray[np.float64]) -> bool:
    """Whether the rows of ``x`` (runs by inputs) are a full grid: every combination of the
    inputs' values, each the same number of times, no input with more than
    :data:`GRID_LEVELS_MAX` values."""
    if x.ndim != 2 or x.shape[0] == 0 or x.shape[1] == 0 or not np.isfinite(x).all():
        return False
    levels = [len(np.unique(x[:, j])) for j in range(x.shape[1])]
    if max(levels) > GRID_LEVELS_MAX:
        return False
    cells, counts = np.unique(x, axis=0, return_counts=True)
    return len(cells) == math.prod(levels) and int(counts.min()) == int(counts.max())


def main_effects(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each column's main effect on ``y``: the variance of ``y``'s mean per value of the column
    (weighted by the runs per value) over the variance of ``y``."""
    total = float(np.var(y))
    out = np.zeros(x.shape[1])
    for j in range(x.shape[1]):
        _, inverse, counts = np.unique(x[:, j], return_inverse=True, return_counts=True)
        means = np.bincount(inverse, weights=y) / counts
        out[j] = float(np.sum(counts * (means - y.mean()) ** 2) / len(y)) / total
    return out


def _rbd_fast(names: Sequence[str], x: NDArray[np.float64],
              y: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """SALib's RBD-FAST first-order indices and their 95 % half widths."""
    from SALib.analyze import rbd_fast

    problem = {"num_vars": len(names), "names": list(names),
               "bounds": [[float(c.min()), float(c.max())] for c in x.T]}
    with warnings.catch_warnings():  # SALib's notes are for its console, not our stderr
        warnings.simplefilter("ignore")
        res = rbd_fast.analyze(problem, x, y, M=HARMONICS, num_resamples=RESAMPLES,
                               seed=SUBSAMPLE_SEED)
    return (np.asarray(res["S1"], dtype=np.float64),
            np.asarray(res["S1_conf"], dtype=np.float64))


def rank_inputs(outcome: str, names: Sequence[str], x: NDArray[np.float64],
                y: NDArray[np.float64], grid: bool) -> Ranking:
    """Rank the inputs ``names`` (the columns of ``x``) by their influence on ``y``.

    Parameters
    ----------
    outcome
        The outcome's name, for the notes.
    names
        The inputs, one per column of ``x``.
    x
        Runs by inputs; rows with a non-finite value or outcome are left out.
    y
        The outcome per run (0/1 for convergence).
    grid
        The design is a full grid (:func:`is_full_grid` of the spec's own inputs): main
        effects; otherwise RBD-FAST.

    Returns
    -------
    Ranking
        The inputs from the most influential down (ties in the order of ``names``).
    """
    keep = np.isfinite(y) & np.isfinite(x).all(axis=1)
    x, y = x[keep], y[keep]
    n = len(y)
    method = MAIN_EFFECT if grid else RBD_FAST
    need = MIN_RUNS_GRID if grid else MIN_RUNS_SAMPLED
    if n < need:
        return Ranking(outcome, (), n, f"too few runs to rank the inputs ({n}, {method} "
                                       f"needs {need})")
    if float(np.ptp(y)) == 0.0:
        return Ranking(outcome, (), n, f"the same in all {n} runs: no input changes it")
    note = ""
    if grid:
        index = main_effects(x, y)
        conf: NDArray[np.float64] | None = None
    else:
        if n > SUBSAMPLE_RUNS:
            pick = np.sort(np.random.default_rng(SUBSAMPLE_SEED).choice(
                n, SUBSAMPLE_RUNS, replace=False))
            # a rare outcome the subsample missed: all the runs then
            if float(np.ptp(y[pick])) > 0.0:
                x, y = x[pick], y[pick]
                note = f"{SUBSAMPLE_RUNS} of the {n} runs, drawn with seed {SUBSAMPLE_SEED}"
        index, conf = _rbd_fast(names, x, y)
    index = np.clip(np.nan_to_num(index, nan=0.0), 0.0, 1.0)
    order = sorted(range(len(names)), key=lambda j: -index[j])  # stable: ties keep names' order
    return Ranking(outcome, tuple(
        Ranked(names[j], float(index[j]), method, None if conf is None else float(conf[j]))
        for j in order), n, note)


#: How each outcome is named in the plain-language line.
_SAID: Final[Mapping[str, str]] = {"converged": "convergence",
                                   "time_to_goal_s": "time to goal",
                                   "energy_positive_j": "energy",
                                   "torque_sq_integral_n2m2s": "the integral of torque^2"}


def _clear(k: Ranked) -> bool:
    """An index the plain-language line names: over :data:`NOISE_FLOOR` and, when sampled,
    over its own 95 % half width."""
    return k.index >= NOISE_FLOOR and (k.conf is None or k.index > k.conf)


def plain_line(rankings: Sequence[Ranking], shown: int = 2) -> str:
    """One sentence naming the top inputs of each outcome, e.g. ``convergence depends most on
    limits.torque_max_nm (RBD-FAST 0.41), then params.tau_c (0.22); time to goal on ...``."""
    parts = []
    for r in rankings:
        said = _SAID.get(r.outcome, r.outcome.removesuffix("_j").replace("_", " "))
        top = [k for k in r.ranked[:shown] if _clear(k)]
        if not r.ranked:
            parts.append(f"{said}: {r.note}")
        elif not top:
            parts.append(f"{said} depends on no input alone beyond the estimate's noise")
        else:
            first = f"{top[0].input} ({top[0].method} {top[0].index:.2f})"
            rest = "".join(f", then {k.input} ({k.index:.2f})" for k in top[1:])
            parts.append(f"{said} depends most on {first}{rest}")
    if not parts:
        return ""
    line = "; ".join(parts)
    return line[0].upper() + line[1:] + "."


__all__ = ["MAIN_EFFECT", "MIN_RUNS_GRID", "MIN_RUNS_SAMPLED", "RBD_FAST", "Ranked", "Ranking",
           "is_full_grid", "main_effects", "plain_line", "rank_inputs"]
