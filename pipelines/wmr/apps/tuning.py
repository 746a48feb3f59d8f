"""``wmr tune``'s command (:func:`tune_command`): the request, its cases and their optimal
times, the tuning of each controller (:func:`wmr.apps.tune.tune`) on one FMU, the saved gains.

Above :mod:`wmr.apps.tune` and :mod:`wmr.apps.benchmark` (the optimal times), which use each
other's parts in one direction only.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wmr.apps.tune import (
    DEFAULT_BUDGET,
    TuneResult,
    batch_cases,
    default_cases,
    tunable_gains,
    tunable_names,
    tune,
)
from wmr.config.scenario import load_scenario
from wmr.core.closedloop import LoopOutcome
from wmr.core.runspec import RunSpec
from wmr.infra.errors import ConfigError


@dataclass(frozen=True)
class TuneRequest:
    """A tuning, as ``wmr tune`` asks for it; errors name its fields (``budget``, ``runs``,
    ``controller``), the command line its options.

    Attributes
    ----------
    scenarios
        Scenario names or TOML files (default :data:`DEFAULT_CASES`).
    controller
        The controller to tune, or ``all`` (every one with gains to tune).
    budget
        Objective evaluations per controller (default :data:`DEFAULT_BUDGET`).
    spec, runs
        Tune on the first ``runs`` runs of this batch spec instead (:func:`batch_cases`).
    save
        Write the tuned gains here (JSON, for ``wmr benchmark --tuned``).
    optimal
        Also solve each case's minimum time, to compare (never for a spec's runs).
    fmi, fmu
        The project's FMI 2 or 3 build, or another robot FMU.
    """

    scenarios: Sequence[str] = ()
    controller: str = "pi"
    budget: int | None = None
    spec: str | Path | None = None
    runs: int | None = None
    save: str | Path | None = None
    optimal: bool = True
    fmi: int = 3
    fmu: str | Path | None = None


@dataclass(frozen=True)
class TunedCase:
    """One case of a tuning at the tuned gains: its status (``rejected``: gains outside their
    admissible set), time to goal and the optimum's, s, and their ratio (None when missing)."""

    name: str
    status: str
    time_to_goal_s: float | None
    optimal_time_s: float | None
    ratio: float | None


@dataclass(frozen=True)
class Tuned:
    """One controller tuned by :func:`tune_command`: the tuning, its cases, and the summary
    (the JSON object of ``wmr tune --json``)."""

    result: TuneResult
    cases: list[TunedCase]
    summary: dict[str, Any]


def _draw_summary(results: Sequence[LoopOutcome | None]) -> dict[str, Any]:
    """The converged count and the mean time to goal (s, of the converged runs) of a tuning's
    runs at its gains."""
    times = [r.time_to_goal_s for r in results
             if r is not None and r.status == "converged" and r.time_to_goal_s is not None]
    return {"converged": len(times),
            "mean_time_to_goal_s": sum(times) / len(times) if times else math.nan}


#: ``evaluations(controller, budget, cases)``: the progress callback of one tuning.
EvaluationProgress = Callable[[str, int, int], Callable[[int, float, float], None]]


def tune_command(request: TuneRequest, progress: Callable[[str], None] | None = None,
                 evaluations: EvaluationProgress | None = None,
                 on_tuned: Callable[[Tuned], None] | None = None) -> list[Tuned]:
    """What ``wmr tune`` does: check the request, load the cases, solve their optimal times,
    tune each controller (:func:`tune`) on one FMU, and save the gains.

    ``progress`` receives a line per step (an optimal time, a note); ``evaluations`` makes the
    progress callback of each tuning; ``on_tuned`` is told of each controller as it is done.
    """
    import json

    from wmr.apps.benchmark import run_optimal
    from wmr.apps.run import default_fmu
    from wmr.infra.outputs import check_output

    def say(line: str) -> None:
        if progress is not None:
            progress(line)

    r = request
    budget = DEFAULT_BUDGET if r.budget is None else r.budget
    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
        raise ConfigError("budget", f"must be an integer >= 1, got {budget}",
                          f"give e.g. budget={DEFAULT_BUDGET}")
    if r.save:
        check_output(r.save, "save")
    optimal = r.optimal
    specs: list[RunSpec] = []
    if r.spec is not None:
        if r.scenarios:
            raise ConfigError("spec", "given with scenarios; a tuning set is one or the other",
                              "drop the scenarios, or the spec")
        specs = batch_cases(r.spec, r.runs)
        if optimal:  # one OCP per draw would cost more than the tuning itself
            say("tune: no optimal reference times for a spec's runs (a batch with "
                "optimal = \"time\" gives them)")
            optimal = False
    elif r.runs is not None:
        raise ConfigError("runs", "given without spec", "add spec=SPEC.toml")
    elif r.scenarios:
        for scenario in r.scenarios:
            specs.extend(load_scenario(scenario).runs)
    else:
        specs = default_cases()
    controllers = tunable_names() if r.controller == "all" else [r.controller]
    for c in controllers:  # before the FMU and the optimal times: an unknown name fails fast
        tunable_gains(c)
    from wmr.adapters.fmi.robot import FmuPlant

    saved: dict[str, dict[str, float]] = {}
    done: list[Tuned] = []
    with FmuPlant(Path(r.fmu) if r.fmu else default_fmu(r.fmi)) as plant:
        opt_times: list[float | None] = [None] * len(specs)
        if optimal:
            for i, case in enumerate(specs, 1):
                say(f"tune: the optimal time of {case.name} ({i}/{len(specs)})")
                opt_times[i - 1] = run_optimal(case, plant, None).final_time_s
        for c in controllers:
            res = tune(c, specs, plant, budget=budget,
                       progress=None if evaluations is None
                       else evaluations(c, budget, len(specs)))
            saved[c] = res.gains
            cases = []
            for spec, run, t_opt in zip(specs, res.results, opt_times, strict=True):
                t = run.time_to_goal_s if run is not None else None
                cases.append(TunedCase(spec.name, run.status if run else "rejected", t, t_opt,
                                       t / t_opt if t is not None and t_opt else None))
            ratios = [case.ratio for case in cases if case.ratio is not None]
            extra: dict[str, Any] = {}
            if r.spec is not None:
                extra = {**_draw_summary(res.results), "spec": str(r.spec), "runs": len(specs)}
            tuned = Tuned(res, cases, {
                "controller": c, "gains": res.gains, "start_gains": res.start_gains,
                "start_objective_s": res.start_cost_s, "objective_s": res.cost_s,
                "evaluations": res.evaluations,
                "mean_time_ratio": sum(ratios) / len(ratios) if ratios else None, **extra})
            done.append(tuned)
            if on_tuned is not None:
                on_tuned(tuned)
    if r.save:
        Path(r.save).parent.mkdir(parents=True, exist_ok=True)
        Path(r.save).write_text(json.dumps(saved, indent=2) + "\n", encoding="utf-8")
    return done


__all__ = ["EvaluationProgress", "TuneRequest", "Tuned", "TunedCase", "tune_command"]
