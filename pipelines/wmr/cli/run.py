"""``wmr run``: one closed-loop co-simulation of the paper's PI stabiliser, logged to MCAP."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from wmr.cli.shared import errors_as_options
from wmr.infra.errors import ConfigError

if TYPE_CHECKING:
    from wmr.config.scenario import Scenario
    from wmr.core.runspec import RunSpec


def _key_values(items: list[str] | None, option: str) -> dict[str, float]:
    """Parse ``NAME=VALUE`` items of a repeated option."""
    out: dict[str, float] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise ConfigError(option, f"{item!r} is not NAME=VALUE", f"e.g. {option} K_ps=0.5")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"{option} {name}", f"{value!r} is not a number") from None
    return out


def add_run_overrides(parser: argparse.ArgumentParser) -> None:
    """Options shared by ``wmr run`` and the commands that run the stabiliser."""
    parser.add_argument("--start", nargs=3, type=float, metavar=("X", "Y", "THETA_DEG"),
                        help="start pose of B: x and y in m, heading in degrees")
    parser.add_argument("--goal", nargs=3, type=float, metavar=("X", "Y", "THETA_DEG"),
                        help="goal pose: x and y in m, desired heading theta_d in degrees")
    parser.add_argument("--gain", action="append", metavar="NAME=VALUE",
                        help="override a gain (K_ps, K_is, K_ptheta, K_itheta, K_pw, K_iw)")
    parser.add_argument("--limit", action="append", metavar="NAME=VALUE",
                        help="override a limit (torque_max_nm, wheel_speed_max_radps, ...)")
    from dataclasses import fields

    from wmr.core.plant import RobotParams

    # the names from the dataclass, so that a new parameter is never missing from the help
    parser.add_argument("--param", action="append", metavar="NAME=VALUE",
                        help="override a robot parameter "
                             f"({', '.join(f.name for f in fields(RobotParams))})")
    parser.add_argument("--period", type=float, metavar="S", help="control period, s")
    parser.add_argument("--stop-radius", type=float, metavar="M",
                        help="stop radius epsilon, m")
    parser.add_argument("--max-time", type=float, metavar="S", help="time limit of a run, s")
    add_fmu_choice(parser)


def add_fmu_choice(parser: argparse.ArgumentParser) -> None:
    """``--fmi``, ``--fmu`` and ``--map``: which robot FMU ``wmr run`` and ``wmr batch`` drive."""
    parser.add_argument("--fmi", type=int, choices=(2, 3), default=3,
                        help="FMI version of the FMU to drive (default 3)")
    parser.add_argument("--fmu", metavar="FILE.fmu",
                        help="drive this FMU instead of the project's own build")
    parser.add_argument("--map", metavar="FILE.toml",
                        help="variable map of an FMU made by another tool: its names and "
                             "units for ours (docs/fmu_map.md)")


def add_log_choice(parser: argparse.ArgumentParser, default: str) -> None:
    """``--log`` and ``--log-every``: which runs keep a log and how much of it (``wmr run``
    and ``wmr batch``)."""
    from wmr.apps.run import LOG_KEEPS

    parser.add_argument("--log", choices=LOG_KEEPS, default=None,
                        help="which runs keep a log: full (all), failed (the runs that did not "
                             "converge: failed and timed out), none (the result alone); "
                             f"default {default}")
    parser.add_argument("--log-every", type=int, default=None, metavar="K",
                        help="log every K-th control step and the last (default 1: every step)")


def add_scenario_choice(parser: argparse.ArgumentParser, doing: str) -> None:
    """``SCENARIO`` and ``--run NAME``: the run that :func:`select_run` picks for ``doing``."""
    parser.add_argument("scenario", nargs="?", default=None, metavar="SCENARIO",
                        help="scenario name (fig9, fig10, fig11) or TOML file (default fig11)")
    parser.add_argument("--run", metavar="NAME",
                        help=f"the run of a multi-run scenario to {doing}")


def result_summary(record: Mapping[str, Any]) -> str:
    """The end of a run's one-line result: final errors, path length and the log file (or
    that none was kept)."""
    def num(key: str, digits: int) -> str:  # None: a run that failed before its first step
        value = record.get(key)
        return "n/a" if value is None else f"{value:.{digits}f}"

    log = "no log kept (--log)" if record.get("mcap") is None else f"log {record['mcap']}"
    # results are in rad while headings are given in degrees: both, so neither is misread
    heading = record.get("final_heading_error_rad")
    in_deg = "" if heading is None else f" ({math.degrees(heading):.3f} deg)"
    return (f"final position error {num('final_position_error_m', 4)} m, heading error "
            f"{num('final_heading_error_rad', 5)} rad{in_deg}, path "
            f"{num('path_length_m', 2)} m; {log}")


def select_run(scenario: Scenario, name: str | None) -> RunSpec:
    """The run ``name`` of ``scenario``, or its only run (:func:`wmr.apps.run.select_run`);
    an error names ``--run``."""
    from wmr.apps.run import select_run as pick

    with errors_as_options({"run": "--run"}), runs_listed(scenario.name):
        return pick(scenario, name)


@contextlib.contextmanager
def runs_listed(scenario: str | Path | None) -> Iterator[None]:
    """An error naming the request's ``run`` inside also says how to list the runs of
    ``scenario`` (default ``fig11``), or run them all: the command line offers both."""
    try:
        yield
    except ConfigError as exc:
        if exc.field != "run":
            raise
        raise ConfigError("run", exc.problem,
                          f"{exc.fix}; all of them: wmr run {scenario or 'fig11'} --list, or "
                          "run them all with 'wmr batch'") from None


def _pose_text(pose: Any) -> str:
    """A pose as ``--start``/``--goal`` take it: ``X Y THETA_DEG`` (heading in degrees)."""
    return (f"{pose.x_m:g} {pose.y_m:g} "
            f"{round(math.degrees(pose.heading_rad), 9):g}")


def list_runs(scenario: str | None, json_line: bool) -> int:
    """``wmr run SCENARIO --list``: the scenario's runs, one a line, each with its start and
    goal as ``--start``/``--goal`` take them (``--json``: one JSON list); nothing is run."""
    import json

    from wmr.config.scenario import load_scenario

    sc = load_scenario(scenario)
    if json_line:
        print(json.dumps([{"name": r.name,
                           "start": [float(v) for v in _pose_text(r.start).split()],
                           "goal": [float(v) for v in _pose_text(r.goal).split()]}
                          for r in sc.runs]))
        return 0
    for r in sc.runs:
        print(f"{r.name}: --start {_pose_text(r.start)} --goal {_pose_text(r.goal)}")
    return 0


#: ``wmr run``'s options by the field of the request (and of its errors) they fill.
RUN_OPTIONS: dict[str, str] = {
    "run": "--run", "start": "--start", "goal": "--goal",
    "params": "--param", "gains": "--gain", "limits": "--limit", "period_s": "--period",
    "stop_radius_m": "--stop-radius", "max_time_s": "--max-time", "controller": "--controller",
    "sensors": "--sensors", "sensor": "--sensor",
    "controller_fmu": "--controller-fmu", "fmi": "--fmi", "fmu": "--fmu", "fmu_map": "--map",
    "out": "--out", "log": "--log", "log_every": "--log-every", "view": "--view",
}


#: Request fields a scenario file gives too.
_SCENARIO_KEYS = frozenset({"start", "goal", "params", "gains", "limits", "period_s",
                            "stop_radius_m", "max_time_s", "controller", "sensors", "sensor",
                            "fmu", "fmu_map"})


def _cmd_run(args: argparse.Namespace) -> int:
    from wmr.apps.request import Overrides, RunRequest
    from wmr.apps.run import run_scenario

    if args.list:
        return list_runs(args.scenario, args.json)

    def warn(field: str, message: str) -> None:
        print(f"wmr: warning: {RUN_OPTIONS.get(field, field)} {message}", file=sys.stderr,
              flush=True)

    # an input the scenario may give too is named by its option only when the option gave it
    # (a scenario's stop_radius_m = 1000 is the scenario's key, not --stop-radius)
    options = {name: option for name, option in RUN_OPTIONS.items()
               if name not in _SCENARIO_KEYS
               or getattr(args, option.lstrip("-").replace("-", "_")) not in (None, [])}
    with errors_as_options(options), runs_listed(args.scenario):
        request = RunRequest(
            args.scenario, run=args.run,
            overrides=Overrides(
                start=args.start, goal=args.goal, params=_key_values(args.param, "--param"),
                gains=_key_values(args.gain, "--gain"),
                limits=_key_values(args.limit, "--limit"), period_s=args.period,
                stop_radius_m=args.stop_radius, max_time_s=args.max_time,
                controller=args.controller, sensors=args.sensors,
                sensor=_sensor_items(args.sensor)),
            controller_fmu=(None if args.controller_fmu is None
                            else args.controller_fmu or True),
            fmi=args.fmi, fmu=args.fmu, fmu_map=args.map, out=args.out, log=args.log,
            log_every=args.log_every, view=args.view)
        record, spec = run_scenario(
            request, progress_bar=lambda name: _progress_bar(name, args.json),
            on_log=getattr(args, "report_log", None), warn=warn)
    print_result(record, args.json, spec.sensors is not None)
    return exit_status(record)


def exit_status(record: Mapping[str, Any]) -> int:
    """The exit status of a command that made one run (``wmr run``, ``wmr rerun``): 0
    converged, 3 timeout, 1 failed."""
    return 0 if record["status"] == "converged" else 3 if record["status"] == "timeout" else 1


def print_result(record: Mapping[str, Any], json_line: bool, sensors: bool) -> None:
    """The result of a run on stdout: its JSON line, or its one line of text."""
    from wmr.apps.run import result_json

    if json_line:
        print(result_json(dict(record)))
        return
    line = f"{record['status']}: {record['message']}; {result_summary(record)}"
    if sensors:
        line += (f"; as estimated: {record['estimated_final_position_error_m']:.4f} m, "
                 f"{record['estimated_final_heading_error_rad']:.5f} rad")
    print(line)


def _supervised(args: argparse.Namespace,
                run: Callable[[Callable[[int], None] | None], int]) -> int:
    """``wmr run`` in a child process (:mod:`wmr.apps.supervise`): a run whose FMU loops in C
    or crashes is still one line, a ``failed`` record and a finished log."""
    from wmr.apps.supervise import GRACE_S, supervise

    if args.list:  # runs nothing: no child to watch
        return run(None)

    def child(channel: Any) -> int:
        args.report_log = channel.log_opened
        return run(channel.signalled)

    outcome = supervise(child)
    if isinstance(outcome, int):
        return outcome
    record = outcome.record
    if outcome.stop_signal is None:  # a crash: the run failed
        print_result(record, args.json, False)
        return 1
    import signal

    what = "terminated" if outcome.stop_signal == signal.SIGTERM else "interrupted"
    log = "" if record["mcap"] is None else f"; log {record['mcap']}"
    print(f"wmr: {what}: the FMU did not return within {GRACE_S:g} s, the run process was killed"
          f"{log}", file=sys.stderr)
    if args.json:
        print_result(record, True, False)
    return 128 + outcome.stop_signal


def _sensor_items(items: list[str] | None) -> dict[str, str]:
    """``--sensor NAME=VALUE`` items as names to their text (checked and converted by the
    ``[sensors]`` table's own rules, :func:`wmr.core.sensing.config.override_sensors`)."""
    out: dict[str, str] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ConfigError("--sensor", f"{item!r} is not NAME=VALUE",
                              "e.g. --sensor gps_sigma_m=0.05")
        out[name.strip()] = value.strip()
    return out


def _progress_bar(name: str, quiet: bool) -> tuple[Callable[[float, float], None],
                                                   Callable[[], None]]:
    """A tqdm bar over simulation time on stderr, shown only for runs longer than ~1 s."""
    from tqdm import tqdm

    bar: list[Any] = []

    def update(t_s: float, t_max_s: float) -> None:
        if not bar:
            bar.append(tqdm(total=round(t_max_s, 2), desc=name, unit="sim s", delay=1.0,
                            file=sys.stderr, leave=False, disable=None,
                            bar_format="{desc}: {n:.1f}/{total:.0f} sim s [{elapsed}]"))
        bar[0].n = round(t_s, 2)
        bar[0].refresh()

    def finish() -> None:
        if bar:
            bar[0].close()

    return update, finish


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "run", help="one closed-loop co-simulation of the paper's PI stabiliser",
        description="Run the paper's PI point stabiliser on the FMU and log the run to MCAP. "
                    "Exit status: 0 converged, 3 timeout, 1 failed.")
    add_scenario_choice(p, "simulate")
    add_run_overrides(p)
    from wmr.core.control.registry import BUILTIN_NAMES, ENTRY_POINT_GROUP

    # the built-in names only: listing the plug-ins would read every installed package's
    # metadata at each start of wmr, for every command
    p.add_argument("--controller", metavar="NAME",
                   help=f"the controller to run: {', '.join(BUILTIN_NAMES)} or an installed "
                        f"plug-in's (entry points {ENTRY_POINT_GROUP}; docs/plugins.md) (scenario "
                        "key controller, with its default gains; docs/control.md)")
    p.add_argument("--controller-fmu", nargs="?", const="", default=None, metavar="FILE.fmu",
                   help="run the stabiliser in the controller FMU (C, FMI --fmi) instead of "
                        "Python: the built one, or FILE.fmu (scenario key controller_fmu)")
    p.add_argument("--sensors", metavar="PRESET", choices=("gps", "raw", "off"),
                   help="measure instead of knowing: gps (2 cm fixes at 10 Hz, 50 ms late, "
                        "encoders, EKF), raw (the same fixes and a compass fed raw), off "
                        "(perfect state feedback); see docs/sensing.md")
    p.add_argument("--sensor", action="append", metavar="NAME=VALUE",
                   help="set one field of the [sensors] table (gps_sigma_m=0.05, "
                        "estimator=ekf, ...)")
    p.add_argument("--out", metavar="FILE.mcap", help="log file (default runs/NAME.mcap)")
    p.add_argument("--list", action="store_true",
                   help="list the scenario's runs, one a line (name, --start, --goal), and "
                        "run nothing")
    add_log_choice(p, "full")
    p.add_argument("--json", action="store_true",
                   help="print the result as one JSON object on the last line")
    p.add_argument("--view", action="store_true",
                   help="show the run live in Rerun (a viewer when there is a screen; always "
                        "also saved as FILE.rrd next to the log)")
    p.set_defaults(handler=_cmd_run, supervisor=_supervised)
