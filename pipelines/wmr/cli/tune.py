"""``wmr tune``: a controller's gains tuned by Nelder-Mead on a scenario set or a batch spec."""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING

from wmr.cli.shared import add_fmu_options, errors_as_options, json_line, progress_line

if TYPE_CHECKING:
    from wmr.apps.tuning import Tuned, TuneRequest



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

#: ``wmr tune``'s options by the field of the request (and of its errors) they fill.
TUNE_OPTIONS: dict[str, str] = {
    "controller": "--controller", "budget": "--budget", "spec": "--spec", "runs": "--runs",
    "save": "--save", "fmi": "--fmi", "fmu": "--fmu",
}


def _print_tuned(tuned: Tuned, request: TuneRequest) -> None:
    """One controller's tuning: its objective, gains and (a spec's up to
    :data:`_LISTED_RUNS`) runs against the optimum."""
    res, c = tuned.result, tuned.summary["controller"]
    gains = ", ".join(f"{k} = {v:.4g}" for k, v in res.gains.items())
    start = ", ".join(f"{k} = {v:.4g}" for k, v in res.start_gains.items())
    print(f"{c}: objective {res.start_cost_s:.3f} s -> {res.cost_s:.3f} s in "
          f"{res.evaluations} evaluations ({res.wall_time_s:.0f} s)")
    print(f"  start: {start}")
    print(f"  tuned: {gains}")
    optimal = request.optimal and request.spec is None
    if request.spec is None or len(tuned.cases) <= _LISTED_RUNS:
        for case in tuned.cases:
            t, t_opt, ratio = case.time_to_goal_s, case.optimal_time_s, case.ratio
            line = (f"    {case.name:22s} {case.status:9s} t = "
                    + (f"{t:7.2f} s" if t is not None else "      - s"))
            if optimal:  # without the optimum there is nothing to compare
                line += ("  optimal " + (f"{t_opt:7.2f} s" if t_opt is not None
                                         else "      - s")
                         + "  ratio " + (f"{ratio:.3f}" if ratio is not None else "-"))
            print(line)
    summary = tuned.summary
    if request.spec is not None:
        print(f"  on {summary['runs']} runs of {request.spec}: {summary['converged']} "
              f"converged, their mean time to goal {summary['mean_time_to_goal_s']:.2f} s")
    ratios = [case.ratio for case in tuned.cases if case.ratio is not None]
    if ratios:
        print(f"  time / optimal time: mean {sum(ratios) / len(ratios):.3f}, "
              f"max {max(ratios):.3f}")


def _cmd_tune(args: argparse.Namespace) -> int:
    from wmr.apps.tuning import TuneRequest, tune_command

    request = TuneRequest(args.scenarios, controller=args.controller, budget=args.budget,
                          spec=args.spec, runs=args.runs, save=args.save,
                          optimal=not args.no_optimal, fmi=args.fmi, fmu=args.fmu)
    with errors_as_options(TUNE_OPTIONS):
        done = tune_command(request, progress_line, _TuneProgress,
                            lambda tuned: _print_tuned(tuned, request))
    if args.save:
        print(f"tuned gains saved to {args.save} (use: wmr benchmark --tuned {args.save})")
    if args.json:
        out = [tuned.summary for tuned in done]
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
