"""``wmr tune``: a controller's gains tuned by Nelder-Mead on a scenario set or a batch spec."""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from wmr.cli.shared import add_fmu_options, fmu_path, json_line, progress_line
from wmr.infra.errors import ConfigError

if TYPE_CHECKING:
    from wmr.core.closedloop import LoopOutcome



class _TuneProgress:
    """``tune``'s progress: the first evaluation, then one line at least every
    ``interval_s`` (each evaluation runs every case), and the last."""

    def __init__(self, controller: str, budget: int, cases: int,
                 interval_s: float = 5.0) -> None:
        import time

        self.controller, self.budget, self.cases = controller, budget, cases
        self.interval_s = interval_s
        self.clock = time.monotonic
        self.last = -math.inf
        progress_line(f"tune {controller}: up to {budget} evaluations of {cases} runs each")

    def __call__(self, evaluation: int, cost_s: float, best_s: float) -> None:
        now = self.clock()
        if now - self.last >= self.interval_s or evaluation >= self.budget:
            self.last = now
            progress_line(f"tune {self.controller}: evaluation {evaluation}/{self.budget}, "
                      f"objective {cost_s:.3f} s (best {best_s:.3f} s)")


#: A spec's tuning prints its runs one a line up to this many (then their summary only).
_LISTED_RUNS = 20


def _draw_summary(results: Sequence[LoopOutcome | None]) -> dict[str, Any]:
    """The converged count and the mean time to goal (s, of the converged runs) of a tuning's
    runs at its gains."""
    times = [r.time_to_goal_s for r in results
             if r is not None and r.status == "converged" and r.time_to_goal_s is not None]
    return {"converged": len(times),
            "mean_time_to_goal_s": sum(times) / len(times) if times else math.nan}


def _cmd_tune(args: argparse.Namespace) -> int:
    from wmr.adapters.fmi.robot import FmuPlant
    from wmr.apps.benchmark import run_optimal
    from wmr.apps.tune import (
        DEFAULT_BUDGET,
        batch_cases,
        default_cases,
        tunable_gains,
        tunable_names,
        tune,
    )
    from wmr.config.scenario import load_scenario
    from wmr.core.runspec import RunSpec
    from wmr.infra.outputs import check_output

    budget = DEFAULT_BUDGET if args.budget is None else args.budget
    if budget < 1:
        raise ConfigError("--budget", f"must be an integer >= 1, got {budget}",
                          f"give e.g. --budget {DEFAULT_BUDGET}")
    if args.save:
        check_output(args.save, "--save")
    specs: list[RunSpec] = []
    if args.spec is not None:
        if args.scenarios:
            raise ConfigError("--spec", "given with scenarios; a tuning set is one or the other",
                              "drop the scenarios, or --spec")
        specs = batch_cases(args.spec, args.runs)
        if not args.no_optimal:  # one OCP per draw would cost more than the tuning itself
            progress_line("tune: no optimal reference times for a spec's runs (a batch with "
                      "optimal = \"time\" gives them)")
            args.no_optimal = True
    elif args.runs is not None:
        raise ConfigError("--runs", "given without --spec", "add --spec SPEC.toml")
    elif args.scenarios:
        for s in args.scenarios:
            specs.extend(load_scenario(s).runs)
    else:
        specs = default_cases()
    controllers = tunable_names() if args.controller == "all" else [args.controller]
    for c in controllers:  # before the FMU and the optimal times: an unknown name fails fast
        tunable_gains(c)
    saved: dict[str, dict[str, float]] = {}
    out: list[dict[str, Any]] = []
    with FmuPlant(fmu_path(args)) as plant:
        opt_times: list[float | None] = []
        if not args.no_optimal:
            for i, s in enumerate(specs, 1):
                progress_line(f"tune: the optimal time of {s.name} ({i}/{len(specs)})")
                o = run_optimal(s, plant, None)
                opt_times.append(o.final_time_s)
        for c in controllers:
            res = tune(c, specs, plant, budget=budget,
                       progress=_TuneProgress(c, budget, len(specs)))
            saved[c] = res.gains
            gains = ", ".join(f"{k} = {v:.4g}" for k, v in res.gains.items())
            start = ", ".join(f"{k} = {v:.4g}" for k, v in res.start_gains.items())
            print(f"{c}: objective {res.start_cost_s:.3f} s -> {res.cost_s:.3f} s in "
                  f"{res.evaluations} evaluations ({res.wall_time_s:.0f} s)")
            print(f"  start: {start}")
            print(f"  tuned: {gains}")
            ratios = []
            per_run = args.spec is None or len(specs) <= _LISTED_RUNS
            for s, r, t_opt in zip(specs, res.results, opt_times or [None] * len(specs),
                                   strict=True):
                t = r.time_to_goal_s if r is not None else None
                ratio = t / t_opt if t is not None and t_opt else None
                if ratio is not None:
                    ratios.append(ratio)
                line = (f"    {s.name:22s} {r.status if r else 'rejected':9s} t = "
                        + (f"{t:7.2f} s" if t is not None else "      - s"))
                if not args.no_optimal:  # without the optimum there is nothing to compare
                    line += ("  optimal " + (f"{t_opt:7.2f} s" if t_opt is not None
                                             else "      - s")
                             + "  ratio " + (f"{ratio:.3f}" if ratio is not None else "-"))
                if per_run:
                    print(line)
            extra: dict[str, Any] = {}
            if args.spec is not None:
                extra = _draw_summary(res.results)
                print(f"  on {len(specs)} runs of {args.spec}: {extra['converged']} converged, "
                      f"their mean time to goal {extra['mean_time_to_goal_s']:.2f} s")
                extra.update(spec=str(args.spec), runs=len(specs))
            if ratios:
                print(f"  time / optimal time: mean {sum(ratios) / len(ratios):.3f}, "
                      f"max {max(ratios):.3f}")
            out.append({"controller": c, "gains": res.gains, "start_gains": res.start_gains,
                        "start_objective_s": res.start_cost_s, "objective_s": res.cost_s,
                        "evaluations": res.evaluations,
                        "mean_time_ratio": sum(ratios) / len(ratios) if ratios else None,
                        **extra})
    if args.save:
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)
        Path(args.save).write_text(json.dumps(saved, indent=2) + "\n", encoding="utf-8")
        print(f"tuned gains saved to {args.save} (use: wmr benchmark --tuned {args.save})")
    if args.json:
        print(json_line(out if len(out) > 1 else out[0]))
    return 0



def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``tune`` sub-command."""
    t = sub.add_parser(
        "tune", help="tune a controller's gains by Nelder-Mead on a scenario set",
        description="Tune the gains of the PI (or a peer) to minimise the mean time to goal "
                    "over a scenario set, with penalties for timeouts, failures and heading "
                    "error; print the gains and the times against the optimal times.")
    t.add_argument("scenarios", nargs="*", metavar="SCENARIO",
                   help="scenario names or TOML files (default: a subset of fig9 + fig10)")
    from wmr.core.control.registry import BUILTIN_NAMES

    t.add_argument("--controller", metavar="NAME", default="pi",
                   help=f"controller to tune: {', '.join(BUILTIN_NAMES)} (default pi), an "
                        "installed plug-in's (docs/plugins.md), or all (every one with gains to "
                        "tune)")
    t.add_argument("--budget", type=int, default=None, metavar="N",
                   help="objective evaluations per controller (default 60)")
    t.add_argument("--spec", metavar="SPEC.toml",
                   help="tune on the runs of this batch spec instead (robust tuning: its "
                        "random robots, limits and starts, the same draws for every candidate)")
    t.add_argument("--runs", type=int, metavar="N",
                   help="with --spec: its first N runs (default all)")
    t.add_argument("--save", metavar="FILE.json", help="write the tuned gains here")
    t.add_argument("--no-optimal", action="store_true", help="skip the optimal reference times")
    t.add_argument("--json", action="store_true", help="the result as JSON on the last line")
    add_fmu_options(t)
    t.set_defaults(handler=_cmd_tune)
