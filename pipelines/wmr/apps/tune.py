r"""Gain tuning of the PI stabiliser and of the peers by numerical optimisation (``wmr tune``).

The objective is the mean cost of a scenario set, every run on the same FMU plant:

.. math::

    J(k) = \frac1N \sum_{i=1}^N c_i(k),\qquad
    c_i = \begin{cases}
        t_{goal,i} + w_\theta |\Delta\theta_i| & \text{converged}\\
        t_{max,i} + w_r \Delta r_i + w_\theta |\Delta\theta_i| + P & \text{timeout}\\
        2 t_{max,i} + P & \text{failed, or gains outside their admissible set}
    \end{cases}

with :math:`t_{goal}` the time to convergence (stop radius, 0.5 deg heading, at rest), s;
:math:`w_\theta` = 10 s/rad, :math:`w_r` = 10 s/m, :math:`P` = 100 s.

Search: Nelder-Mead (``scipy.optimize.minimize``) in the logarithm of the gains' magnitudes
(every tuned gain keeps its sign; steps are relative), from the default gains, with an initial
simplex of +30 % steps in each gain and a budget of objective evaluations.  Nelder-Mead is
deterministic, so a tuning is reproducible; the best point seen is returned, hence the tuned
objective is never worse than the starting one.

The default scenario set (:data:`DEFAULT_CASES`) is a subset of Figs. 9 and 10 that spans the
headings and the start directions, to keep a tuning to about a minute.  A robust tuning
(``wmr tune --spec SPEC.toml --runs N``, :func:`batch_cases`) takes instead the first runs of a
batch spec: its random draws of robots, frictions, limits and starts, drawn once, so every
candidate gains are scored on the same draws (common random numbers: the objective's
differences are the gains', not the draws').
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Final

import numpy as np
from scipy.optimize import minimize

from wmr.config.scenario import Overrides, load_scenario, with_overrides
from wmr.core.closedloop import LoopOutcome, run_closed_loop
from wmr.core.control import registry
from wmr.core.control.from_spec import SpecController
from wmr.core.plant import Plant
from wmr.core.runspec import RunSpec
from wmr.infra.errors import ConfigError

#: Default tuning set: Fig. 9 with theta_d = -90, -45, 0, 45, 90 deg and Fig. 10 from 0, 60,
#: 120, 240 and 270 deg (the set is mirror-symmetric about the x axis otherwise).
DEFAULT_CASES: Final = (
    ("fig9", "fig9-thd-090"), ("fig9", "fig9-thd-045"), ("fig9", "fig9-thd+000"),
    ("fig9", "fig9-thd+045"), ("fig9", "fig9-thd+090"),
    ("fig10", "fig10-from000deg"), ("fig10", "fig10-from060deg"),
    ("fig10", "fig10-from120deg"), ("fig10", "fig10-from240deg"),
    ("fig10", "fig10-from270deg"),
)
DEFAULT_BUDGET: Final = 60
W_HEADING_S_PER_RAD: Final = 10.0
W_DISTANCE_S_PER_M: Final = 10.0
PENALTY_S: Final = 100.0

def default_cases() -> list[RunSpec]:
    """The runs of :data:`DEFAULT_CASES`, loaded from the shipped scenarios."""
    loaded: dict[str, dict[str, RunSpec]] = {}
    out = []
    for scen, name in DEFAULT_CASES:
        if scen not in loaded:
            loaded[scen] = {r.name: r for r in load_scenario(scen).runs}
        out.append(loaded[scen][name])
    return out


def batch_cases(spec: str | Path, runs: int | None = None) -> list[RunSpec]:
    """The first ``runs`` runs of the batch spec ``spec``, expanded as ``wmr batch`` expands it.

    The draws are made here once; :func:`tune` scores every candidate on this same list.

    Parameters
    ----------
    spec
        A batch spec (name or TOML file, as ``wmr batch`` takes it).
    runs
        How many of its runs, from the first (default: all).

    Raises
    ------
    ConfigError
        A bad spec (its field named), ``runs`` < 1 or more than the spec has, or a run driven
        by a controller FMU (the tuning runs the Python controllers).
    """
    # here: the batch package brings its runner and executors, which a default tuning never needs
    from wmr.apps.batch.spec import load_batch

    if runs is not None and (isinstance(runs, bool) or not isinstance(runs, int) or runs < 1):
        raise ConfigError("runs", f"must be an integer >= 1, got {runs!r}",
                          "give e.g. runs=40")
    batch = load_batch(spec)
    if runs is not None and runs > len(batch.runs):
        raise ConfigError("runs", f"{runs} runs asked, the spec {batch.name} has "
                          f"{len(batch.runs)}", f"give runs={len(batch.runs)} or fewer, or "
                          "raise the spec's [random] n")
    chosen = [r.spec for r in batch.runs[:len(batch.runs) if runs is None else runs]]
    for s in chosen:
        if s.controller_fmu is not None:
            raise ConfigError("controller_fmu", f"run {s.name} of {batch.name} is driven by a "
                              "controller FMU, which wmr tune does not tune",
                              "drop controller_fmu from the spec to tune the Python controller")
    return chosen


def tunable_names() -> list[str]:
    """Every registered controller with gains to tune (``wmr tune --controller all``); a
    plug-in that does not load is named in a one-line error."""
    return [n for n in registry.names() if registry.get(n, "controller").tunable()]


def tunable_gains(controller: str) -> tuple[registry.Gain, ...]:
    """The gains of ``controller`` that ``wmr tune`` searches, with their bounds.

    Raises
    ------
    ConfigError
        ``controller``: an unknown controller, a plug-in that does not load, or one without
        gains to tune.
    """
    table = registry.get(controller, "controller").tunable()
    if not table:
        raise ConfigError("controller", f"{controller} declares no gain with bounds to tune",
                          f"tune one of: {', '.join(tunable_names())}")
    return table


def with_gains(spec: RunSpec, controller: str, gains: Mapping[str, float]) -> RunSpec:
    """``spec`` run by ``controller`` with ``gains`` (the PI's go to ``[gains]``).

    Raises
    ------
    ConfigError
        Unknown controller or gain, or gains outside their admissible set.
    """
    if registry.get(controller).gains_table == registry.RUN_GAINS:  # the PI's: [gains]
        return with_overrides(replace(spec, controller=controller, controller_gains=()),
                              Overrides(gains=dict(gains)))
    return with_overrides(spec, Overrides(controller=controller, controller_gains=dict(gains)))


def case_cost(result: LoopOutcome, spec: RunSpec) -> float:
    r"""Cost :math:`c_i` of one run, s (module docstring)."""
    head = result.final_heading_error_rad
    head = 0.0 if not math.isfinite(head) else head
    if result.status == "converged" and result.time_to_goal_s is not None:
        return result.time_to_goal_s + W_HEADING_S_PER_RAD * head
    if result.status == "timeout":
        dist = result.final_position_error_m
        dist = 1e3 if not math.isfinite(dist) else dist
        return spec.t_max_s + W_DISTANCE_S_PER_M * dist + W_HEADING_S_PER_RAD * head + PENALTY_S
    return 2.0 * spec.t_max_s + PENALTY_S


def evaluate(controller: str, gains: Mapping[str, float], specs: Sequence[RunSpec],
             plant: Plant) -> tuple[float, list[LoopOutcome | None]]:
    """Objective :math:`J` (s) of ``gains`` over ``specs`` and the run results.

    Gains outside the admissible set (a ``ConfigError``) cost :math:`2 t_{max} + P` per run
    and give ``None`` results.
    """
    try:
        tuned = [with_gains(s, controller, gains) for s in specs]
    except ConfigError:
        return float(np.mean([2.0 * s.t_max_s + PENALTY_S for s in specs])), [None] * len(specs)
    results: list[LoopOutcome | None] = []
    costs = []
    for s in tuned:
        r = run_closed_loop(s, plant, controller=SpecController())
        results.append(r)
        costs.append(case_cost(r, s))
    return float(np.mean(costs)), results


@dataclass
class TuneResult:
    """Outcome of a tuning.

    Attributes
    ----------
    controller
        Its name (:mod:`wmr.core.control.registry`).
    start_gains, gains
        Initial and tuned gains by name.
    start_cost_s, cost_s
        Objective J at the start and at the tuned gains, s.
    evaluations
        Objective evaluations used (each = one run per case).
    wall_time_s
        Wall time of the tuning, s.
    results
        The runs at the tuned gains, one per case.
    """

    controller: str
    start_gains: dict[str, float]
    gains: dict[str, float]
    start_cost_s: float
    cost_s: float
    evaluations: int
    wall_time_s: float
    results: list[LoopOutcome | None] = field(default_factory=list)


def tune(controller: str, specs: Sequence[RunSpec], plant: Plant,
         budget: int = DEFAULT_BUDGET, start: Mapping[str, float] | None = None,
         progress: Callable[[int, float, float], None] | None = None) -> TuneResult:
    r"""Tune ``controller``'s gains on ``specs`` by Nelder-Mead in :math:`\log|k|`.

    Parameters
    ----------
    controller
        A controller of :mod:`wmr.core.control.registry` with gains to tune (bounds).
    specs
        The scenario set (their own ``controller`` fields are overridden).
    plant
        One plant for every run (the FMU).
    budget
        Maximum objective evaluations (>= 1; the first is the starting point).
    start
        Initial gains (default: the controller's declared defaults).
    progress
        ``progress(evaluation, cost_s, best_cost_s)`` after each evaluation.

    Returns
    -------
    TuneResult
        The best gains seen (never worse than ``start``).
    """
    table = tunable_gains(controller)
    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
        raise ConfigError("budget", f"must be an integer >= 1, got {budget!r}",
                          f"give e.g. budget={DEFAULT_BUDGET}")
    if not specs:
        raise ConfigError("scenarios", "the tuning set is empty", "give a scenario with runs")
    names = [g.name for g in table]
    x_start = {g.name: float(g.default) for g in table}
    if start:
        unknown = set(start) - set(names)
        if unknown:
            raise ConfigError("start", f"not tunable for {controller}: {sorted(unknown)}",
                              f"tunable: {', '.join(names)}")
        x_start.update({k: float(v) for k, v in start.items()})
    signs = np.array([math.copysign(1.0, x_start[n]) for n in names])
    bounds = [g.bounds for g in table if g.bounds is not None]
    lo = np.log(np.array([min(abs(b[0]), abs(b[1])) for b in bounds]))
    hi = np.log(np.array([max(abs(b[0]), abs(b[1])) for b in bounds]))
    z0 = np.log(np.array([abs(x_start[n]) for n in names]))

    def gains_of(z: np.ndarray) -> dict[str, float]:
        return {n: float(s * math.exp(v)) for n, s, v in zip(names, signs, z, strict=True)}

    t0 = time.perf_counter()
    best: dict[str, Any] = {"cost": math.inf, "z": z0, "n": 0, "results": []}
    first: list[float] = []

    def f(z: np.ndarray) -> float:
        if best["n"] >= budget:  # hard budget: Nelder-Mead may overshoot maxfev by a few
            return math.inf
        best["n"] += 1
        zc = np.clip(z, lo, hi)
        cost, results = evaluate(controller, gains_of(zc), specs, plant)
        cost += 10.0 * float(np.sum(np.abs(z - zc)))  # leave the box: pay for it
        if not first:
            first.append(cost)
        if cost < best["cost"]:
            best.update(cost=cost, z=zc, results=results)
        if progress is not None:
            progress(best["n"], cost, best["cost"])
        return cost

    f(z0)
    if budget > 1:
        simplex = np.vstack([z0] + [z0 + 0.262 * np.eye(len(names))[i]
                                    for i in range(len(names))])  # +30 % per gain
        minimize(f, z0, method="Nelder-Mead",
                 options={"maxfev": budget - 1, "initial_simplex": simplex,
                          "xatol": 1e-3, "fatol": 1e-3})
    return TuneResult(controller=controller, start_gains=gains_of(z0),
                      gains=gains_of(best["z"]), start_cost_s=first[0], cost_s=best["cost"],
                      evaluations=best["n"], wall_time_s=time.perf_counter() - t0,
                      results=best["results"])


__all__ = [
    "DEFAULT_BUDGET",
    "DEFAULT_CASES",
    "TuneResult",
    "batch_cases",
    "case_cost",
    "default_cases",
    "evaluate",
    "tunable_gains",
    "tunable_names",
    "tune",
    "with_gains",
]
