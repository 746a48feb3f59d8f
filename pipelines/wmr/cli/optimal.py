"""``wmr optimal``: the optimal reference manoeuvre, replayed open-loop on the FMU and logged."""

from __future__ import annotations

import argparse
import math

from wmr.cli.shared import add_fmu_options, errors_as_options, json_line, progress_line

#: ``wmr optimal``'s options by the field of the request (and of its errors) they fill.
OPTIMAL_OPTIONS: dict[str, str] = {
    "run": "--run", "start": "--start", "goal": "--goal", "params": "--param",
    "limits": "--limit", "objective": "--objective", "final_time_s": "--final-time",
    "torque_limit_nm": "--torque-limit", "torque_only": "--torque-only",
    "period_s": "--period", "control_period_s": "--period", "out": "--out", "fmi": "--fmi",
    "fmu": "--fmu",
}


def _cmd_optimal(args: argparse.Namespace) -> int:
    from wmr.apps.optimal import OptimalRequest, optimal_command
    from wmr.apps.request import Overrides
    from wmr.cli.run import _key_values, runs_listed

    with errors_as_options(OPTIMAL_OPTIONS), runs_listed(args.scenario):
        request = OptimalRequest(
            args.scenario, run=args.run,
            overrides=Overrides(start=args.start, goal=args.goal,
                                params=_key_values(args.param, "--param"),
                                limits=_key_values(args.limit, "--limit")),
            objective=args.objective, torque_limit_nm=args.torque_limit,
            torque_only=args.torque_only, final_time_s=args.final_time, period_s=args.period,
            out=args.out, fmi=args.fmi, fmu=args.fmu)
        record = optimal_command(request, progress=progress_line)
    out = record["mcap"]
    if args.json:
        print(json_line(record))
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



def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``optimal`` sub-command."""
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
    add_fmu_options(p)
    p.set_defaults(handler=_cmd_optimal)
