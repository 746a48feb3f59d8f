"""``wmr ssp export`` (the closed loop as an SSP 1.0 package), ``wmr ssp run`` (a package
in libcosim or Ecos, logged to MCAP like ``wmr run``) and ``wmr ssp check`` (a package in every
master here against ``wmr run``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from wmr.cli.shared import errors_as_options

#: ``wmr ssp export``'s and ``wmr ssp run``'s options by the keyword of
#: :mod:`wmr.apps.ssp` (and of its errors) they give.
SSP_OPTIONS: dict[str, str] = {
    "run": "--run", "start": "--start", "goal": "--goal", "fmi": "--fmi",
    "robot_fmu": "--robot-fmu", "controller_fmu": "--controller-fmu", "fmu_map": "--map",
    "out": "--out", "stop_time_s": "--stop-time", "master": "--master",
    "steps_per_period": "--steps-per-period",
}


def _cmd_export(args: argparse.Namespace) -> int:
    from wmr.apps.ssp import export_package
    from wmr.cli.run import runs_listed

    with errors_as_options(SSP_OPTIONS), runs_listed(args.scenario):
        print(export_package(args.scenario, run=args.run, start=args.start, goal=args.goal,
                             fmi=args.fmi, robot_fmu=args.robot_fmu,
                             controller_fmu=args.controller_fmu, fmu_map=args.map,
                             out=args.out, steps_per_period=args.steps_per_period))
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from wmr.apps.run import result_json
    from wmr.apps.ssp import run_package
    from wmr.cli.run import result_summary

    with errors_as_options(SSP_OPTIONS):
        record = run_package(args.ssp, out=args.out, stop_time_s=args.stop_time,
                             master=args.master)
    if args.json:
        print(result_json(record))
    else:
        print(f"{record['status']}: {record['message']} in {record['master']}; "
              f"{result_summary(record)}")
    return 0 if record["status"] == "converged" else 3


def _cmd_check(args: argparse.Namespace) -> int:
    import json

    from wmr.apps.ssp_check import check_package, format_table

    report = check_package(Path(args.ssp))
    print(json.dumps(report.as_dict()) if args.json else format_table(report))
    return 0 if report.agrees else 1


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from wmr.adapters.ssp.export import DEFAULT_STEPS_PER_PERIOD
    from wmr.cli.run import add_scenario_choice

    p = sub.add_parser("ssp", help="the closed loop as an SSP package, run in libcosim or Ecos",
                       description="Export the closed loop (robot and controller FMUs) as an "
                                   "SSP 1.0 package, or run a package in libcosim or Ecos.")
    ssp_sub = p.add_subparsers(dest="ssp_command", metavar="ACTION", required=True)
    ex = ssp_sub.add_parser(
        "export", help="write a scenario's closed loop as an SSP 1.0 package",
        description="Write SCENARIO's run as an SSP 1.0 package: both FMUs, the connections, "
                    "the scenario's parameters as parameter sets, a default experiment.")
    add_scenario_choice(ex, "export")
    ex.add_argument("--start", nargs=3, type=float, metavar=("X", "Y", "THETA_DEG"),
                    help="start pose of B: x and y in m, heading in degrees")
    ex.add_argument("--goal", nargs=3, type=float, metavar=("X", "Y", "THETA_DEG"),
                    help="goal pose: x and y in m, heading in degrees")
    ex.add_argument("--fmi", type=int, choices=(2, 3), default=2,
                    help="FMI version of the FMUs (default 2, what SSP masters take today)")
    ex.add_argument("--robot-fmu", metavar="FILE.fmu",
                    help="robot FMU (default: the scenario's fmu, else our build)")
    ex.add_argument("--controller-fmu", metavar="FILE.fmu",
                    help="controller FMU (default: our build)")
    ex.add_argument("--map", metavar="FILE.toml",
                    help="variable map of a robot FMU made by another tool (docs/fmu_map.md; "
                         "default: the scenario's fmu_map)")
    ex.add_argument("--steps-per-period", type=int, default=DEFAULT_STEPS_PER_PERIOD,
                    metavar="N",
                    help="the masters' fixed step in the package is the control period / N "
                         f"(default {DEFAULT_STEPS_PER_PERIOD}: within 5 mm and 0.2 deg of "
                         "'wmr run' in libcosim and Ecos; 1 lags a whole period, docs/ssp.md)")
    ex.add_argument("--out", metavar="FILE.ssp",
                    help="package file (default ssp/NAME.ssp, NAME the run's name as 'wmr "
                         "run' gives it: fig11, fig11-to_5_5_30deg, fig11-fmi3)")
    ex.set_defaults(handler=_cmd_export)
    run = ssp_sub.add_parser(
        "run", help="run an SSP package in libcosim or Ecos and log it to MCAP",
        description="Run an SSP package of 'wmr ssp export' in libcosim or Ecos (recording "
                    "every step) and log it in the layout of 'wmr run', so that 'wmr replay' "
                    "shows it.  Exit status: 0 converged, 3 not converged.")
    run.add_argument("ssp", metavar="FILE.ssp", help="the package")
    run.add_argument("--out", metavar="FILE.mcap",
                     help="log file (default runs/NAME-ssp.mcap for NAME.ssp, not the "
                          "runs/NAME.mcap of 'wmr run NAME')")
    run.add_argument("--stop-time", type=float, metavar="S",
                     help="end of the run, s (default: the package's stop time)")
    run.add_argument("--master", choices=("auto", "libcosim", "ecos"), default="auto",
                     help="the co-simulation master: libcosim (FMI 2.0), ecos (FMI 2.0 and "
                          "3.0); default auto: libcosim for an FMI 2.0 package, ecos for 3.0")
    run.add_argument("--json", action="store_true",
                     help="print the result as one JSON object on the last line")
    run.set_defaults(handler=_cmd_run)
    check = ssp_sub.add_parser(
        "check", help="run a package in every master installed here and compare with wmr run",
        description="Run an SSP package in every master installed here (libcosim, Ecos, "
                    "fmpy's simulate_ssp, OMSimulator) and 'wmr run' of the package's own "
                    "scenario, and print one table: master, FMI version, converged at, final "
                    "pose and worst path difference from wmr run, what the master said.  Exit "
                    "status: 0 when every master that ran is within the agreement docs/ssp.md "
                    "claims, 1 otherwise (the last line says which).")
    check.add_argument("ssp", metavar="FILE.ssp", help="the package")
    check.add_argument("--json", action="store_true",
                       help="print the report as one JSON object instead of the table")
    check.set_defaults(handler=_cmd_check)
