"""Solve times of the minimum-time OCP on the Fig. 9 goals, with and without the warm start.

For each goal (0, 0, 0 deg) -> (20 m, 10 m, theta_d) the NLP is solved ``--repeats`` times from
the kinematic warm start and from the cold start (poses interpolated at rest, zero torques,
T = 10 s); the table gives the median IPOPT wall time (the NLP is built once per process,
before timing), the iterations, the minimum time found and the ratio cold / warm.

Run: ``python benchmarks/optimal.py [--repeats 5] [--closed-loop-limits]``.

``--batch SPEC [--runs 10]``: the cost of a batch's ``optimal = "time"`` per run, on the first
runs of SPEC (default ``mc_fig10``: its own random starts and robots, the PI's limits), solved
in order as one worker solves them: from the cold start, from the kinematic warm start, and
from the kinematic warm start with the worker's previous solution offered
(:func:`wmr.apps.optimal.optimum_fields`); median and total wall time per run, and the
projection to a 10^4-run batch on one core.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

from wmr.adapters.ocp import (
    DEFAULT_INTERVALS,
    DEFAULT_RK_SUBSTEPS,
    OptimalLimits,
    OptimalProblem,
    SolverOptions,
    _nlp,
    fig9_cases,
    solve_optimal,
)
from wmr.core.plant import Pose


def _median_solve(start: Pose, goal: Pose, warm: bool, repeats: int,
                  limits: OptimalLimits) -> tuple[float, int, float, str]:
    """(median solve s, iterations, final time s, status) over ``repeats`` solves."""
    times, last = [], None
    for _ in range(repeats):
        r = solve_optimal(OptimalProblem(start, goal, limits=limits),
                          SolverOptions(warm_start=warm))
        times.append(r.solve_time_s)
        last = r
    assert last is not None
    return statistics.median(times), last.iterations, last.final_time_s, last.status


def _batch(spec_name: str, n_runs: int) -> None:
    """The per-run cost of the optimum beside a batch's runs (``--batch``)."""
    from wmr.apps.batch import load_batch

    runs = [r.spec for r in load_batch(spec_name).runs[:n_runs]]
    _nlp(DEFAULT_INTERVALS, DEFAULT_RK_SUBSTEPS, 1000, 60.0)  # built once per worker, untimed
    print(f"optimum beside the first {len(runs)} runs of {spec_name} (minimum time, the PI's "
          f"limits, N = {DEFAULT_INTERVALS})")
    for label, warm, chain in (("cold", False, False), ("kinematic", True, False),
                               ("kinematic+previous", True, True)):
        times, iters, status, previous = [], [], [], None
        for spec in runs:
            t0 = time.perf_counter()
            r = solve_optimal(OptimalProblem(spec.start, spec.goal, spec.params,
                                             limits=OptimalLimits.like(spec.limits)),
                              SolverOptions(warm_start=warm),
                              previous=previous if chain else None)
            times.append(time.perf_counter() - t0)  # the integrals after IPOPT included
            iters.append(r.iterations)
            status.append(r.status)
            if r.solved:
                previous = r
        med, mean = statistics.median(times), statistics.mean(times)
        print(f"{label:<19} median {med * 1e3:7.1f} ms/run, mean {mean * 1e3:7.1f} ms, "
              f"median {statistics.median(iters):.0f} iterations, solved "
              f"{status.count('solved')}/{len(runs)}; 10^4 runs: "
              f"{mean * 1e4 / 60:.1f} core-minutes")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--batch", metavar="SPEC",
                        help="the optimum's cost per run on the first runs of SPEC")
    parser.add_argument("--runs", type=int, default=10, help="runs of --batch (default 10)")
    parser.add_argument("--closed-loop-limits", action="store_true",
                        help="torque 8 N.m, wheel speed 10 rad/s, v 1 m/s, omega 1.5 rad/s")
    args = parser.parse_args()
    if args.batch:
        _batch(args.batch, args.runs)
        return
    limits = OptimalLimits()
    if args.closed_loop_limits:
        limits = OptimalLimits(torque_max_nm=8.0, wheel_speed_max_radps=10.0, v_max_mps=1.0,
                               omega_max_radps=1.5)
    t0 = time.perf_counter()
    _nlp(DEFAULT_INTERVALS, DEFAULT_RK_SUBSTEPS, 1000, 60.0)
    build = time.perf_counter() - t0
    print(f"minimum time, Fig. 9 goals, N = {DEFAULT_INTERVALS}, RK4 x {DEFAULT_RK_SUBSTEPS}, "
          f"limits {limits}; NLP build (once per process) {build:.2f} s; "
          f"median of {args.repeats} solves")
    head = (f"{'case':<18} {'warm ms':>8} {'it':>4} {'T warm s':>9} {'cold ms':>8} {'it':>4} "
            f"{'T cold s':>9} {'cold/warm':>9}")
    print(head)
    print("-" * len(head))
    warm_all, cold_all = [], []
    for name, start, goal in fig9_cases():
        tw, iw, Tw, sw = _median_solve(start, goal, True, args.repeats, limits)
        tc, ic, Tc, sc = _median_solve(start, goal, False, args.repeats, limits)
        warm_all.append(tw)
        cold_all.append(tc)
        tw_s = f"{Tw:9.3f}" if sw == "solved" else f"{sw:>9}"
        tc_s = f"{Tc:9.3f}" if sc == "solved" else f"{sc:>9}"
        print(f"{name.removeprefix('fig9 '):<18} {tw * 1e3:8.1f} {iw:4d} {tw_s} {tc * 1e3:8.1f} "
              f"{ic:4d} {tc_s} {tc / tw:9.2f}")
    mw, mc = statistics.median(warm_all), statistics.median(cold_all)
    print("-" * len(head))
    print(f"{'median':<18} {mw * 1e3:8.1f} {'':>4} {'':>9} {mc * 1e3:8.1f} {'':>4} {'':>9} "
          f"{mc / mw:9.2f}")
    if not math.isfinite(mc / mw):  # pragma: no cover - only with a broken solver
        raise SystemExit(1)


if __name__ == "__main__":
    main()
