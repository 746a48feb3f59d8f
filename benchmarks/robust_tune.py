"""Robust tuning against nominal tuning, scored on held-out draws of one Monte Carlo spec.

Tunes the PI on the first ``--runs`` runs of ``--spec`` (``wmr tune --spec``'s objective, the
same draws for every candidate), then runs the default gains, the built-in tuned gains
(the PI's declared ``tuned`` gains, :mod:`wmr.core.control.registry`, tuned on the
nominal robot) and the robust gains on the
next ``--held-out`` runs of the same spec, which the tuning never saw, and prints per gain set
the converged count, the mean time to goal of the converged runs, the objective and the worst
time.  docs/batch.md quotes its output.

Run: ``python benchmarks/robust_tune.py [--spec benchmarks/robust_tune.toml] [--runs 40]
[--held-out 200] [--budget 60]``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from wmr.adapters.fmi.robot import FmuPlant
from wmr.apps.run import default_fmu
from wmr.apps.tune import batch_cases, evaluate, tunable_gains, tune
from wmr.core.control import registry

HERE = Path(__file__).resolve().parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", default=str(HERE / "robust_tune.toml"), metavar="SPEC.toml")
    parser.add_argument("--runs", type=int, default=40, metavar="N", help="tuning draws")
    parser.add_argument("--held-out", type=int, default=200, metavar="N",
                        help="scoring draws, after the tuning draws")
    parser.add_argument("--budget", type=int, default=60, metavar="N")
    args = parser.parse_args()
    every = batch_cases(args.spec)
    if args.runs + args.held_out > len(every):
        parser.error(f"--runs {args.runs} + --held-out {args.held_out} > the spec's "
                     f"{len(every)} runs")
    # the held-out draws are the spec's last: the same set whatever --runs
    train, held_out = every[:args.runs], every[len(every) - args.held_out:]
    with FmuPlant(default_fmu(3)) as plant:
        t0 = time.perf_counter()
        robust = tune("pi", train, plant, budget=args.budget)
        print(f"robust tuning on {len(train)} draws, {robust.evaluations} evaluations, "
              f"{time.perf_counter() - t0:.0f} s: objective {robust.start_cost_s:.3f} s -> "
              f"{robust.cost_s:.3f} s")
        print("  gains: " + ", ".join(f"{k} = {v:.4g}" for k, v in robust.gains.items()))
        sets = {"default": {g.name: g.default for g in tunable_gains("pi")},
                "tuned (nominal robot)": dict(registry.get("pi").tuned),
                "tuned (robust)": robust.gains}
        print(f"held-out draws: {len(held_out)}")
        print(f"{'gains':<22} {'converged':>9} {'mean t_goal s':>13} {'max t_goal s':>12} "
              f"{'objective s':>11}")
        for label, gains in sets.items():
            cost, results = evaluate("pi", gains, held_out, plant)
            times = [r.time_to_goal_s for r in results
                     if r is not None and r.status == "converged" and r.time_to_goal_s is not None]
            print(f"{label:<22} {len(times):>5}/{len(held_out):<3} "
                  f"{statistics.fmean(times) if times else float('nan'):>13.2f} "
                  f"{max(times) if times else float('nan'):>12.2f} {cost:>11.3f}")


if __name__ == "__main__":
    main()
