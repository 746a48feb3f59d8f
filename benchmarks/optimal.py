"""Solve times of the minimum-time OCP on the Fig. 9 goals, with and without the warm start.

For each goal (0, 0, 0 deg) -> (20 m, 10 m, theta_d) the NLP is solved ``--repeats`` times from
the kinematic warm start and from the cold start (poses interpolated at rest, zero torques,
T = 10 s); the table gives the median IPOPT wall time (the NLP is built once per process,
before timing), the iterations, the minimum time found and the ratio cold / warm.

Run: ``python benchmarks/optimal.py [--repeats 5] [--closed-loop-limits]``.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

from wmr.adapters.ocp import DEFAULT_INTERVALS, DEFAULT_RK_SUBSTEPS, _nlp, fig9_cases, solve_optimal


def _median_solve(start: object, goal: object, warm: bool, repeats: int,
                  limits: dict[str, float]) -> tuple[float, int, float, str]:
    """(median solve s, iterations, final time s, status) over ``repeats`` solves."""
    times, last = [], None
    for _ in range(repeats):
        r = solve_optimal(start, goal, warm_start=warm, **limits)  # type: ignore[arg-type]
        times.append(r.solve_time_s)
        last = r
    assert last is not None
    return statistics.median(times), last.iterations, last.final_time_s, last.status


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--closed-loop-limits", action="store_true",
                        help="torque 8 N.m, wheel speed 10 rad/s, v 1 m/s, omega 1.5 rad/s")
    args = parser.parse_args()
    limits: dict[str, float] = {}
    if args.closed_loop_limits:
        limits = {"torque_limit_nm": 8.0, "wheel_speed_limit_radps": 10.0,
                  "speed_limit_mps": 1.0, "omega_limit_radps": 1.5}
    t0 = time.perf_counter()
    _nlp(DEFAULT_INTERVALS, DEFAULT_RK_SUBSTEPS, 1000, 60.0)
    build = time.perf_counter() - t0
    print(f"minimum time, Fig. 9 goals, N = {DEFAULT_INTERVALS}, RK4 x {DEFAULT_RK_SUBSTEPS}, "
          f"limits {limits or 'torque 10 N.m'}; NLP build (once per process) {build:.2f} s; "
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
