"""``wmr optimal``, ``wmr benchmark`` and ``wmr tune``: the optimal reference, the side-by-side
benchmark of the PI stabiliser against its peers and the optimum, and gain tuning."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from wmr.infra.errors import ConfigError

if TYPE_CHECKING:
    from wmr.core.closedloop import RunResult


def _fmu_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fmi", type=int, choices=(2, 3), default=3,
                   help="FMI version of the FMU to drive (default 3)")
    p.add_argument("--fmu", metavar="FILE.fmu",
                   help="drive this FMU instead of the project's own build")


def _fmu_path(args: argparse.Namespace) -> Path:
    from wmr.apps.run import default_fmu

    return Path(args.fmu) if args.fmu else default_fmu(args.fmi)


def _progress(line: str) -> None:
    """A long step's progress line on standard error (standard output is for results)."""
    print(f"wmr: {line}", file=sys.stderr, flush=True)


def _json_line(obj: Any) -> str:
    """One line of JSON, NaN/inf as null."""

    def clean(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [clean(x) for x in v]
        return v

    return json.dumps(clean(obj), allow_nan=False)


# ---------------------------------------------------------------------------------- optimal

def _cmd_optimal(args: argparse.Namespace) -> int:
    from wmr.apps.optimal import optimal_command
    from wmr.cli.run import _key_values

    record = optimal_command(args.start, args.goal, objective=args.objective,
                             scenario=args.scenario, run=args.run,
                             params=_key_values(args.param, "--param"),
                             limits=_key_values(args.limit, "--limit"),
                             torque_limit_nm=args.torque_limit, torque_only=args.torque_only,
                             final_time_s=args.final_time, period_s=args.period,
                             out=args.out, fmi=args.fmi, fmu=args.fmu, progress=_progress,
                             command_line=True)
    out = record["mcap"]
    if args.json:
        print(_json_line(record))
    else:
        if record["status"] == "solved":
            print(f"solved: T = {record['final_time_s']:.3f} s, path "
                  f"{record['path_length_m']:.2f}"
                  f" m; FMU replay ends {record['final_position_error_m']:.4f} m and "
                  f"{math.degrees(record['final_heading_error_rad']):.3f} deg from the "
                  f"goal; log {out}")
        else:
            print(f"{record['status']}: {record['message']}")
    return {"solved": 0, "infeasible": 3}.get(record["status"], 1)


# ---------------------------------------------------------------------------------- benchmark


def _cmd_benchmark(args: argparse.Namespace) -> int:
    from wmr.adapters.fmi.robot import FmuPlant
    from wmr.apps.benchmark import (
        CONTROLLERS,
        DEFAULT_SCENARIOS,
        benchmark_specs,
        format_tables,
        load_tuned,
        run_benchmark,
        write_tables,
    )
    from wmr.apps.progress import count_progress
    from wmr.infra.outputs import check_output

    out = check_output(args.out if args.out else Path("runs") / "benchmark", "--out", "dir")
    specs = benchmark_specs(args.scenarios or list(DEFAULT_SCENARIOS))
    if args.limit_cases is not None:
        specs = specs[: args.limit_cases]
    labels = (list(CONTROLLERS) if not args.controllers
              else [c.strip() for c in args.controllers.split(",") if c.strip()])
    tuned = load_tuned(args.tuned)

    # one bar (a "k/N, about T left" line every 10 s off a terminal), not a line per run
    steps = len(specs) * (len(labels) + (0 if args.no_optimal else 1))
    bar = count_progress(steps, "benchmark", "run", False if args.json else None)
    begun = [False]

    def progress(case: str, label: str) -> None:  # told before each run: the last one is done
        if begun[0]:
            bar.update(1)
        begun[0] = True
        bar.set_postfix_str(f"{case}: {label}", refresh=False)

    try:
        with FmuPlant(_fmu_path(args)) as plant:
            rows = run_benchmark(specs, plant, out, labels, tuned,
                                 optimal=not args.no_optimal, progress=progress)
        if begun[0]:
            bar.update(1)
    finally:
        bar.close()
    csv_path, pq_path = write_tables(rows, out)
    print(format_tables(rows))
    print(f"tables: {csv_path}, {pq_path}; logs: {out / 'logs'}")
    if args.json:
        print(_json_line(rows))
    failed = [r for r in rows if r["status"] == "failed"]
    return 1 if failed else 0


# ---------------------------------------------------------------------------------- tune


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
        _progress(f"tune {controller}: up to {budget} evaluations of {cases} runs each")

    def __call__(self, evaluation: int, cost_s: float, best_s: float) -> None:
        now = self.clock()
        if now - self.last >= self.interval_s or evaluation >= self.budget:
            self.last = now
            _progress(f"tune {self.controller}: evaluation {evaluation}/{self.budget}, "
                      f"objective {cost_s:.3f} s (best {best_s:.3f} s)")


#: A spec's tuning prints its runs one a line up to this many (then their summary only).
_LISTED_RUNS = 20


def _draw_summary(results: Sequence[RunResult | None]) -> dict[str, Any]:
    """The converged count and the mean time to goal (s, of the converged runs) of a tuning's
    runs at its gains."""
    times = [r.time_to_goal_s for r in results
             if r is not None and r.status == "converged" and r.time_to_goal_s is not None]
    return {"converged": len(times),
            "mean_time_to_goal_s": sum(times) / len(times) if times else math.nan}


def _cmd_tune(args: argparse.Namespace) -> int:
    from wmr.adapters.fmi.robot import FmuPlant
    from wmr.apps.benchmark import run_optimal
    from wmr.apps.tune import DEFAULT_BUDGET, batch_cases, default_cases, tune
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
            _progress("tune: no optimal reference times for a spec's runs (a batch with "
                      "optimal = \"time\" gives them)")
            args.no_optimal = True
    elif args.runs is not None:
        raise ConfigError("--runs", "given without --spec", "add --spec SPEC.toml")
    elif args.scenarios:
        for s in args.scenarios:
            specs.extend(load_scenario(s).runs)
    else:
        specs = default_cases()
    controllers = (["pi", "astolfi", "graceful"] if args.controller == "all"
                   else [args.controller])
    saved: dict[str, dict[str, float]] = {}
    out: list[dict[str, Any]] = []
    with FmuPlant(_fmu_path(args)) as plant:
        opt_times: list[float | None] = []
        if not args.no_optimal:
            for i, s in enumerate(specs, 1):
                _progress(f"tune: the optimal time of {s.name} ({i}/{len(specs)})")
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
        print(_json_line(out if len(out) > 1 else out[0]))
    return 0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``optimal``, ``benchmark`` and ``tune`` sub-commands."""
    p = sub.add_parser(
        "optimal", help="the optimal manoeuvre (CasADi), replayed open-loop on the FMU",
        description="Solve the minimum-time (or minimum-effort) rest-to-rest manoeuvre on the "
                    "Modelica model's dynamics, replay its torques open-loop through the FMU "
                    "and log the FMU run to MCAP. Limits: the PI's (torque, wheel speed, v, "
                    "omega) unless --torque-only. Exit status: 0 solved, 3 infeasible, "
                    "1 failed.")
    p.add_argument("scenario", nargs="?", default=None, metavar="SCENARIO",
                   help="the start, goal, robot and limits of this scenario's run (name or "
                        "TOML file, as wmr run takes it; default: the options alone)")
    p.add_argument("--run", metavar="NAME", help="the run of a multi-run scenario")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="override a robot parameter, as wmr run --param")
    p.add_argument("--limit", action="append", metavar="NAME=VALUE",
                   help="override a limit of the PI (torque_max_nm, wheel_speed_max_radps, "
                        "v_max_mps, omega_max_radps), as wmr run --limit")
    p.add_argument("--start", nargs=3, type=float, metavar=("X", "Y", "THETA_DEG"),
                   help="start pose (default 0 0 0)")
    p.add_argument("--goal", nargs=3, type=float, metavar=("X", "Y", "THETA_DEG"),
                   help="goal pose (default 20 10 0)")
    p.add_argument("--objective", choices=("time", "energy"), default="time",
                   help="minimum time (default), or minimum integral of tau^2 in a fixed time")
    p.add_argument("--final-time", type=float, metavar="S",
                   help="duration for --objective energy (default 1.5 x the minimum time)")
    p.add_argument("--torque-limit", type=float, metavar="NM",
                   help="torque limit per wheel, N.m (default the PI's, 8)")
    p.add_argument("--torque-only", action="store_true",
                   help="drop the wheel speed, v and omega limits")
    p.add_argument("--period", type=float, default=0.01, metavar="S",
                   help="longest FMU step of the replay, s (default 0.01)")
    p.add_argument("--out", metavar="FILE.mcap",
                   help="log file (default runs/optimal-OBJECTIVE[-CHANGES].mcap, named after "
                        "the options that change the manoeuvre)")
    p.add_argument("--json", action="store_true", help="the result as JSON on the last line")
    _fmu_options(p)
    p.set_defaults(handler=_cmd_optimal)

    b = sub.add_parser(
        "benchmark", help="PI against the peer stabilisers and the optimum",
        description="Run every case of the scenarios with the PI, the tuned PI, Astolfi's and "
                    "the graceful stabiliser (default and tuned gains) on one FMU, solve the "
                    "minimum-time manoeuvre under the same limits, and tabulate time to goal, "
                    "path, energy, torque and heading error (CSV and Parquet in --out, a log "
                    "per run in --out/logs/CONTROLLER/CASE.mcap).")
    b.add_argument("scenarios", nargs="*", metavar="SCENARIO",
                   help="scenario names or TOML files (default fig9 fig10)")
    b.add_argument("--out", metavar="DIR", help="output folder (default runs/benchmark)")
    b.add_argument("--controllers", metavar="LIST",
                   help="comma-separated subset of pi,pi-tuned,astolfi,astolfi-tuned,"
                        "graceful,graceful-tuned (default all)")
    b.add_argument("--tuned", metavar="FILE.json",
                   help="tuned gains from 'wmr tune --save' (default: the built-in ones)")
    b.add_argument("--no-optimal", action="store_true", help="skip the optimal solves")
    b.add_argument("--limit-cases", type=int, metavar="N", help="only the first N cases")
    b.add_argument("--json", action="store_true",
                   help="the rows as one JSON list on the last line")
    _fmu_options(b)
    b.set_defaults(handler=_cmd_benchmark)

    t = sub.add_parser(
        "tune", help="tune a controller's gains by Nelder-Mead on a scenario set",
        description="Tune the gains of the PI (or a peer) to minimise the mean time to goal "
                    "over a scenario set, with penalties for timeouts, failures and heading "
                    "error; print the gains and the times against the optimal times.")
    t.add_argument("scenarios", nargs="*", metavar="SCENARIO",
                   help="scenario names or TOML files (default: a subset of fig9 + fig10)")
    t.add_argument("--controller", choices=("pi", "astolfi", "graceful", "all"), default="pi",
                   help="controller to tune (default pi)")
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
    _fmu_options(t)
    t.set_defaults(handler=_cmd_tune)

