"""``wmr ssp export`` (the closed loop as an SSP 1.0 package), ``wmr ssp run`` (a package
in libcosim or Ecos, logged to MCAP like ``wmr run``) and ``wmr ssp check`` (a package in every
master here against ``wmr run``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from wmr.infra.errors import ConfigError


def _cmd_export(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from wmr.adapters.fmi.varmap import load_map
    from wmr.adapters.ssp.export import export_ssp
    from wmr.build.fmus import build_fmus
    from wmr.cli.run import select_run
    from wmr.config.naming import default_log_path, fmu_tokens, run_name, variant_name
    from wmr.config.scenario import load_scenario, with_overrides
    from wmr.infra.outputs import check_output

    scenario = load_scenario(args.scenario)
    base = select_run(scenario, args.run)
    spec = with_overrides(base, start=args.start, goal=args.goal)
    # the scenario file is the provenance of its own run only: a variant's package carries
    # its effective scenario instead (export_ssp), as a variant's log of 'wmr run' does
    scenario_file = scenario.path if spec == base else None
    # named as wmr run names a variant: the run (SSD, parameter sets) after what it changes,
    # the file also after the FMI version, so that another goal or FMI version never
    # overwrites the scenario's own package nor passes for it
    spec = replace(spec, name=run_name(base, spec))
    name = variant_name(spec.name, fmu_tokens(args.fmi, args.robot_fmu, 2))
    out = check_output(args.out if args.out else default_log_path(name, "ssp", ".ssp"),
                       "--out", suffix=".ssp")
    built = None
    robot_choice = args.robot_fmu or scenario.fmu
    if robot_choice is None or args.controller_fmu is None:
        built = build_fmus()
    robot = Path(robot_choice) if robot_choice else built.fmus[args.fmi]  # type: ignore[union-attr]
    map_path = Path(args.map) if args.map else scenario.fmu_map
    ctrl = (Path(args.controller_fmu) if args.controller_fmu
            else built.controllers[args.fmi])  # type: ignore[union-attr]
    print(export_ssp(spec, out, robot, ctrl, scenario_file=scenario_file,
                     var_map=load_map(map_path) if map_path is not None else None,
                     steps_per_period=args.steps_per_period))
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from wmr.adapters.ssp.cosim import log_ssp_run, simulate_libcosim
    from wmr.apps.run import result_json
    from wmr.cli.run import result_summary
    from wmr.config.naming import default_log_path
    from wmr.core.runspec import DEFAULT_PERIOD_S, MAX_STEPS
    from wmr.infra.outputs import check_output

    ssp = Path(args.ssp)
    # '-ssp': the package of fig11 must not overwrite runs/fig11.mcap of 'wmr run fig11'
    out = check_output(args.out if args.out else default_log_path(f"{ssp.stem}-ssp"), "--out",
                       suffix=".mcap")
    # the longest run a scenario allows at the default period: libcosim sizes its buffers by it
    longest_s = MAX_STEPS * DEFAULT_PERIOD_S
    if args.stop_time is not None and not 0 < args.stop_time <= longest_s:
        raise ConfigError("--stop-time", f"must be > 0 and at most {longest_s:g} s, got "
                          f"{args.stop_time:g}", "give seconds, e.g. --stop-time 30")
    master = args.master
    if master == "auto":  # libcosim loads FMI 2.0 only
        from wmr.adapters.ssp.package import ROBOT, read_package

        fmi3 = read_package(ssp).component(ROBOT).fmi_version.startswith("3")
        master = "ecos" if fmi3 else "libcosim"
    if master == "ecos":
        from wmr.adapters.ssp.ecos import simulate_ecos

        run = simulate_ecos(ssp, stop_time_s=args.stop_time)
    else:
        run = simulate_libcosim(ssp, stop_time_s=args.stop_time)
    record = log_ssp_run(run, out)
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
