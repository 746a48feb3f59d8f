"""Success rate and solve time of ``wmr optimal``'s OCP on short manoeuvres near the start.

A grid of goals close to (0, 0, 0 deg): turns on the spot from -180 to 180 deg and short moves
(5 cm to 1.4 m) with every quarter-turn of goal heading.  Each goal is solved once under the
PI's limits (what ``wmr optimal`` uses) with IPOPT's CPU-time limit ``--max-cpu-time`` (the
command's is 60 s); the NLP is built before timing.  The table gives, per goal, the status, the
minimum time, the iterations, IPOPT's time and the wall time of ``solve_optimal`` (warm start
and any retry together), then the success rate and the median times over the grid.

Run: ``python benchmarks/short_manoeuvres.py [--max-cpu-time 20] [--quick]``.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

from wmr.adapters.ocp import (
    DEFAULT_INTERVALS,
    DEFAULT_RK_SUBSTEPS,
    OptimalProblem,
    SolverOptions,
    _nlp,
    solve_optimal,
)
from wmr.apps.optimal import optimal_limits
from wmr.core.plant import Pose

SPOT_TURNS_DEG = (-180.0, -135.0, -90.0, -45.0, -10.0, 10.0, 45.0, 90.0, 135.0, 180.0)
MOVES_M = ((0.25, 0.0), (0.0, 0.5), (-0.5, 0.0), (1.0, 1.0), (0.05, 0.0), (0.0, -0.05))
MOVE_HEADINGS_DEG = (0.0, 90.0, 180.0, -90.0)


def goals(quick: bool) -> list[Pose]:
    """The grid: spot turns, then each short move with each goal heading."""
    turns = SPOT_TURNS_DEG[::2] if quick else SPOT_TURNS_DEG
    grid = [Pose(0.0, 0.0, math.radians(h)) for h in turns]
    for x, y in MOVES_M[: 2 if quick else None]:
        grid += [Pose(x, y, math.radians(h)) for h in MOVE_HEADINGS_DEG]
    return grid


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-cpu-time", type=float, default=20.0, metavar="S",
                        help="IPOPT's CPU-time limit per solve (default 20)")
    parser.add_argument("--quick", action="store_true", help="a third of the grid")
    args = parser.parse_args()
    start = Pose(0.0, 0.0, 0.0)
    limits = optimal_limits()
    _nlp(DEFAULT_INTERVALS, DEFAULT_RK_SUBSTEPS, 1000, args.max_cpu_time)  # built once, untimed
    times, ipopt, solved = [], [], 0
    print(f"{'goal (m, m, deg)':>24s} {'status':>8s} {'T s':>7s} {'iter':>5s} {'IPOPT s':>8s} "
          f"{'wall s':>7s}")
    grid = goals(args.quick)
    for goal in grid:
        t0 = time.perf_counter()
        r = solve_optimal(OptimalProblem(start, goal, limits=limits),
                          SolverOptions(max_cpu_time_s=args.max_cpu_time))
        wall = time.perf_counter() - t0
        times.append(wall)
        ipopt.append(r.solve_time_s)
        solved += r.status == "solved"
        label = f"({goal.x_m:+.2f}, {goal.y_m:+.2f}, {math.degrees(goal.heading_rad):+4.0f})"
        print(f"{label:>24s} {r.status:>8s} {r.final_time_s:7.3f} {r.iterations:5d} "
              f"{r.solve_time_s:8.2f} {wall:7.2f}", flush=True)
    print(f"solved {solved}/{len(grid)}; IPOPT time median {statistics.median(ipopt):.2f} s, "
          f"max {max(ipopt):.2f} s; wall median {statistics.median(times):.2f} s, "
          f"max {max(times):.2f} s")


if __name__ == "__main__":
    main()
