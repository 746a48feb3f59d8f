"""Every option of ``wmr run``, ``wmr batch``, ``wmr optimal`` and ``wmr replay`` has its keyword
in the API (``docs/api.md``), ``wmr.run`` reaches what ``wmr run`` reaches, and the API's
batch, optimal and replay give the command's one-line errors, naming their keywords."""

from __future__ import annotations

import argparse
import inspect
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

import wmr
from wmr.cli import build_parser
from wmr.infra.errors import ConfigError

#: Options whose keyword has another name (the API's names carry units and plurals).
KEYWORD_OF = {
    "gain": "gains", "limit": "limits", "param": "params", "period": "period_s",
    "stop_radius": "stop_radius_m", "max_time": "max_time_s", "map": "fmu_map",
    "run_timeout": "run_timeout_s", "final_time": "final_time_s",
    "torque_limit": "torque_limit_nm", "no_viewer": "viewer", "read_limit": "read_limit_mib",
}

#: Options with no meaning in the API, each with the reason.
CLI_ONLY = {
    # how the result is printed: the API returns it as an object
    "json",
    # wmr batch --check makes every run and stops: the API's wmr.apps.batch.load_batch
    # (which wmr.batch calls first) does that check
    "check",
    # wmr run --list prints a scenario's runs and runs nothing: the API's
    # wmr.load_scenario(NAME).runs are those runs
    "list",
}

API_OF: dict[str, Callable[..., Any]] = {"run": wmr.run, "batch": wmr.batch,
                                         "optimal": wmr.optimal, "replay": wmr.replay}


def _subparser(command: str) -> argparse.ArgumentParser:
    parser = build_parser()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices[command]  # type: ignore[no-any-return]
    raise AssertionError("the wmr parser has no subcommands")


def missing_keywords(command: str, function: Callable[..., Any]) -> list[str]:
    """The options of ``wmr COMMAND`` that ``function`` has no keyword for."""
    keywords = set(inspect.signature(function).parameters)
    missing = []
    for action in _subparser(command)._actions:
        if isinstance(action, argparse._HelpAction) or action.dest in CLI_ONLY:
            continue
        keyword = KEYWORD_OF.get(action.dest, action.dest)
        if keyword not in keywords:
            missing.append("/".join(action.option_strings) or action.dest)
    return missing


@pytest.mark.parametrize("command", sorted(API_OF))
def test_every_cli_option_has_an_api_keyword(command: str) -> None:
    missing = missing_keywords(command, API_OF[command])
    assert not missing, (f"wmr {command} has options without a keyword of "
                         f"wmr.{command}: {', '.join(missing)}")


#: The executors' test hooks (``wmr.apps.batch.runner._test_hooks``): never a public keyword.
TEST_HOOKS = ("faults", "stop_after")


def test_no_public_batch_signature_carries_a_test_hook() -> None:
    from wmr.apps.batch import BatchOptions, run_batch

    for function in (run_batch, BatchOptions, wmr.batch):
        hooks = set(TEST_HOOKS) & set(inspect.signature(function).parameters)
        assert not hooks, f"{function.__qualname__} has test hooks {sorted(hooks)}"


def test_the_hooks_reach_only_the_batches_inside_their_block(tmp_path: Path) -> None:
    from wmr.apps.batch.runner import _HOOKS, _test_hooks

    with _test_hooks(stop_after=2, faults={"r": "crash"}):
        hooks = _HOOKS.get()
        assert hooks is not None
        assert hooks.stop_after == 2 and dict(hooks.faults) == {"r": "crash"}
    assert _HOOKS.get() is None
    with pytest.raises(ConfigError, match="unknown fault 'melt'"), \
            _test_hooks(faults={"r": "melt"}):
        pass


def test_the_check_names_the_option_without_a_keyword() -> None:
    """The check itself: an API function without ``--sensors`` and ``--map`` is caught, and
    the options are named."""
    def old_run(scenario: str | None = None, *, run: str | None = None) -> None: ...

    missing = missing_keywords("run", old_run)
    assert "--sensors" in missing and "--map" in missing and "--controller-fmu" in missing


def test_api_run_with_sensors_and_the_controller_fmu(tmp_path: Path) -> None:
    """``wmr.run("fig11", sensors="gps", controller_fmu=True)`` gives the one-line error
    ``wmr run --sensors gps --controller-fmu`` gives (the controller FMU takes the true
    state only) — or runs, if the command does."""
    import contextlib
    import io

    from wmr.cli import main

    try:
        record = wmr.run("fig11", sensors="gps", controller_fmu=True, max_time_s=0.5,
                         out=tmp_path / "api.mcap").record
        by_api = (record["status"], record["message"])
    except ConfigError as exc:
        by_api = ("error", f"{exc.problem} ({exc.fix})")
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["run", "fig11", "--sensors", "gps", "--controller-fmu", "--max-time", "0.5",
                     "--out", str(tmp_path / "cli.mcap")])
    by_command = ("error" if code == 1 and "error" in err.getvalue()
                  else {0: "converged", 3: "timeout"}.get(code, "failed"), err.getvalue())
    assert by_api[0] == by_command[0]
    res = None
    if by_api[0] != "error":
        res = wmr.run("fig11", sensors="gps", controller_fmu=True, max_time_s=0.5,
                      out=tmp_path / "r.mcap")
        assert res.log is not None
        run_record = res.log.metadata["run"]
        assert run_record["sensors"]["estimator"]
        assert run_record["controller_fmu_file"].startswith("wmr_controller")


def test_api_run_takes_the_scenarios_fmu_and_the_log_policy(tmp_path: Path) -> None:
    """``wmr.run`` honours the log policy (``log="none"``: no log, the record only) and
    names its errors by keyword (``log_every``, not ``--log-every``)."""
    res = wmr.run("fig11", max_time_s=0.3, log="none", out=tmp_path / "n.mcap")
    assert res.mcap is None and res.log is None and res.status == "timeout"
    assert not (tmp_path / "n.mcap").exists()
    with pytest.raises(ConfigError) as info:
        wmr.run("fig11", log_every=0, out=tmp_path / "k.mcap")
    assert info.value.field == "log_every"


#: Inputs that ``wmr batch``, ``wmr optimal`` and ``wmr replay`` refuse before any work, as
#: command-line arguments and as API keywords, with the field each error names in each.
BAD_INPUTS: list[tuple[list[str], Callable[[], object], str, str]] = [
    (["batch", "fig11", "--max-runs", "0"], lambda: wmr.batch("fig11", max_runs=0),
     "--max-runs", "max_runs"),
    (["batch", "fig11", "--workers", "0"], lambda: wmr.batch("fig11", workers=0),
     "--workers", "workers"),
    (["batch", "fig11", "--workers", "1", "--scheduler", "tcp://127.0.0.1:1"],
     lambda: wmr.batch("fig11", workers=1, scheduler="tcp://127.0.0.1:1"),
     "--workers", "workers"),
    (["batch", "fig11", "--run-timeout", "-1"], lambda: wmr.batch("fig11", run_timeout_s=-1),
     "--run-timeout", "run_timeout_s"),
    (["batch", "fig11", "--scheduler", "nope://x"],
     lambda: wmr.batch("fig11", scheduler="nope://x"), "--scheduler", "scheduler"),
    (["optimal", "--period", "0"], lambda: wmr.optimal(period_s=0.0), "--period", "period_s"),
    (["optimal", "--goal", "1", "nan", "0"], lambda: wmr.optimal(goal=(1.0, math.nan, 0.0)),
     "--goal y", "goal y"),
    (["optimal", "--final-time", "3"], lambda: wmr.optimal(final_time_s=3.0),
     "--final-time", "final_time_s"),
    (["optimal", "--out", "o.txt"], lambda: wmr.optimal(out="o.txt"), "--out", "out"),
    (["optimal", "fig9", "--run", "nope"], lambda: wmr.optimal(scenario="fig9", run="nope"),
     "--run", "run"),
    (["optimal", "--torque-limit", "-1"], lambda: wmr.optimal(torque_limit_nm=-1.0),
     "--torque-limit", "torque_limit_nm"),
    (["run", "--sensors", "gps", "--sensor", "gps_sigma_m=x"],
     lambda: wmr.run(sensors="gps", sensor={"gps_sigma_m": "x"}), "--sensor gps_sigma_m",
     "sensor gps_sigma_m"),
    (["run", "--log-every", "0"], lambda: wmr.run(log_every=0), "--log-every", "log_every"),
    (["batch", "fig11", "--log-every", "0"], lambda: wmr.batch("fig11", log_every=0),
     "--log-every", "log_every"),
    (["replay"], lambda: wmr.replay(), "FILE.mcap|DIR", "logs"),
    (["replay", ".", "--worst", "2", "--status", "failed"],
     lambda: wmr.replay(".", worst=2, status="failed"), "--worst", "worst"),
    (["replay", "x.mcap", "--rrd", "o.txt"], lambda: wmr.replay("x.mcap", rrd="o.txt"),
     "--rrd", "rrd"),
    (["replay", "--blueprint", "o.txt"], lambda: wmr.replay(blueprint="o.txt"),
     "--blueprint", "blueprint"),
    (["replay", "--blueprint-for"], lambda: wmr.replay(blueprint_for=True),
     "--blueprint-for", "blueprint_for"),
]


def _refused_by_both(argv: list[str], call: Callable[[], object], flag: str, keyword: str,
                     tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                     capsys: pytest.CaptureFixture[str]) -> tuple[str, ConfigError]:
    """``wmr ARGV`` fails with one line naming ``flag`` and ``call()`` raises a ConfigError
    naming ``keyword`` (both from ``tmp_path``): the command's problem and the API's error."""
    from wmr.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"wmr: error: {flag}: "), err
    with pytest.raises(ConfigError) as info:
        call()
    assert info.value.field == keyword
    return err[0].removeprefix(f"wmr: error: {flag}: "), info.value


@pytest.mark.parametrize(("argv", "call", "flag", "keyword"), BAD_INPUTS,
                         ids=[" ".join(case[0]) for case in BAD_INPUTS])
def test_the_api_gives_the_command_s_one_line_errors(
        argv: list[str], call: Callable[[], object], flag: str, keyword: str, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """The checks live below the CLI: ``wmr.batch(max_runs=0)`` is refused as ``wmr batch
    --max-runs 0`` is, the same problem and fix, naming ``max_runs`` (issue 22)."""
    problem, error = _refused_by_both(argv, call, flag, keyword, tmp_path, monkeypatch, capsys)
    # the same problem, another option in it named as each front door names it
    for option, keyword_is in (("--scheduler ", "scheduler="), ("--status ", "status=")):
        problem = problem.replace(option, keyword_is)
    assert problem.startswith(error.problem), (problem, error.problem)


def test_an_optimal_error_s_fix_names_the_other_inputs_as_its_front_door_does(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """``apps.optimal`` names every input by its keyword, in the fix too; ``wmr optimal``
    translates them all into its options (no ``command_line`` flag below the CLI)."""
    from wmr.apps.optimal import OptimalRequest
    from wmr.apps.request import Overrides
    from wmr.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["optimal", "--final-time", "3"]) == 1
    assert capsys.readouterr().err.strip() == (
        "wmr: error: --final-time: the time objective leaves the final time free (drop "
        "--final-time or use --objective energy)")
    with pytest.raises(ConfigError) as info:
        wmr.optimal(final_time_s=3.0)
    assert (info.value.field, info.value.fix) == (
        "final_time_s", "drop final_time_s or use objective=energy")
    # a request the optimal manoeuvre cannot honour is refused when made, not ignored
    with pytest.raises(ConfigError) as info:
        OptimalRequest(overrides=Overrides(gains={"K_ps": 1.0}))
    assert info.value.field == "gains"


def _benchmark(**fields: Any) -> object:
    from wmr.apps.benchmark import BenchmarkRequest, benchmark_command

    return benchmark_command(BenchmarkRequest(**fields))


def _tune(**fields: Any) -> object:
    from wmr.apps.tuning import TuneRequest, tune_command

    return tune_command(TuneRequest(**fields))


def _rerun(*args: Any) -> object:
    from wmr.apps.batch.rerun import rerun_run

    return rerun_run(*args)


def _ssp(function: str, *args: Any, **keywords: Any) -> object:
    import wmr.apps.ssp

    return getattr(wmr.apps.ssp, function)(*args, **keywords)


#: Inputs the apps behind ``wmr benchmark``, ``wmr tune``, ``wmr rerun`` and ``wmr ssp`` refuse
#: before any work, as command-line arguments and as the app's request, with the field each names.
APP_INPUTS: list[tuple[list[str], Callable[[], object], str, str]] = [
    (["benchmark", "--controllers", "nope"], lambda: _benchmark(controllers=["nope"]),
     "--controllers", "controllers"),
    (["benchmark", "--out", "o.txt/x", "--tuned", "nothere.json"],
     lambda: _benchmark(out="o.txt/x", tuned="nothere.json"), "--tuned", "tuned"),
    (["tune", "--budget", "0"], lambda: _tune(budget=0), "--budget", "budget"),
    (["tune", "--runs", "3"], lambda: _tune(runs=3), "--runs", "runs"),
    (["tune", "--controller", "nope"], lambda: _tune(controller="nope"),
     "--controller", "controller"),
    (["rerun", ".", "0000-00000000"], lambda: _rerun(".", "0000-00000000"), "DIR", "out_dir"),
    (["ssp", "export", "fig9"], lambda: _ssp("export_package", "fig9"), "--run", "run"),
    (["ssp", "export", "--out", "o.txt"], lambda: _ssp("export_package", out="o.txt"),
     "--out", "out"),
    (["ssp", "run", "x.ssp", "--stop-time", "-1"],
     lambda: _ssp("run_package", "x.ssp", stop_time_s=-1.0), "--stop-time", "stop_time_s"),
]


@pytest.mark.parametrize(("argv", "call", "flag", "keyword"), APP_INPUTS,
                         ids=[" ".join(case[0]) for case in APP_INPUTS])
def test_an_app_names_its_request_s_fields_and_the_command_its_options(
        argv: list[str], call: Callable[[], object], flag: str, keyword: str, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """The front doors only parse and call the apps; the apps name their inputs by the
    request's fields, and each command by its options (issue 29)."""
    problem, error = _refused_by_both(argv, call, flag, keyword, tmp_path, monkeypatch, capsys)
    assert problem.startswith(error.problem.split(" (")[0]), (problem, error.problem)
    assert list(tmp_path.iterdir()) == []  # nothing made
