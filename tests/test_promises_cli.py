"""The front door's own promises (issue 23, gap 10): every command answers ``--help``, errors
are one line without ``--debug`` and the whole traceback with it."""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path

import pytest

import wmr
import wmr.apps.batch.command
from wmr.cli import build_parser, main
from wmr.infra.errors import ConfigError


def _commands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()
              ) -> Iterator[tuple[str, ...]]:
    """Every command path of the parser, e.g. ``("fmu", "build")``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*prefix, name)
                yield from _commands(sub, (*prefix, name))


COMMANDS = sorted(_commands(build_parser()))


def test_the_command_tree_is_found() -> None:
    assert {("run",), ("batch",), ("replay",), ("fmu", "build")} <= set(COMMANDS)


def test_top_level_help_names_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["--help"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: wmr")
    assert "--debug" in out
    for (name,) in (c for c in COMMANDS if len(c) == 1):
        assert name in out, name


@pytest.mark.parametrize("command", COMMANDS, ids=[" ".join(c) for c in COMMANDS])
def test_every_command_answers_help(command: tuple[str, ...],
                                    capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main([*command, "--help"])
    assert stop.value.code == 0
    captured = capsys.readouterr()
    assert captured.out.startswith(f"usage: wmr {' '.join(command)}"), captured.out[:200]
    assert captured.err == ""


def test_a_user_error_is_one_line_and_debug_raises_it(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    args = ["batch", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "o")]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.startswith("wmr: error:") and err.count("\n") == 1, err
    assert "Traceback" not in err
    with pytest.raises(ConfigError):
        main(["--debug", *args])


def test_an_internal_error_is_one_line_exit_2_and_debug_raises_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("a bug\nover two lines")

    monkeypatch.setattr(wmr.apps.batch.command, "load_batch", broken)
    args = ["batch", "fig10", "--out", str(tmp_path / "o")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err.startswith("wmr: internal error: RuntimeError: a bug over two lines")
    assert "--debug" in err
    with pytest.raises(RuntimeError, match="a bug"):
        main(["--debug", *args])


def _parsers(parser: argparse.ArgumentParser) -> Iterator[argparse.ArgumentParser]:
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _parsers(sub)


def test_no_option_of_any_command_is_taken_by_a_prefix(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parsers = list(_parsers(build_parser()))
    assert len(parsers) > len(COMMANDS) and all(not p.allow_abbrev for p in parsers)
    # --controller-f was --controller-fmu, --wor --workers: both refused now, by their command
    for args, prefix in ((["run", "--controller-f", "x"], "--controller-f"),
                         (["batch", str(tmp_path / "s.toml"), "--wor", "2"], "--wor 2")):
        with pytest.raises(SystemExit) as stop:
            main(args)
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith(f"usage: wmr {args[0]} ")
        assert f"wmr {args[0]}: error: unrecognized arguments: {prefix}" in err


def test_run_controller_runs_the_named_controller_and_lists_the_known_ones(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "a.mcap"
    code = main(["run", "--controller", "astolfi", "--max-time", "1", "--out", str(log),
                 "--json"])
    record = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert code == 3 and record["status"] == "timeout" and record["name"] == "fig11-astolfi-tmax=1"
    assert wmr.read_log(log).metadata["run"]["controller"] == "astolfi"
    assert main(["run", "--controller", "bogus", "--out", str(tmp_path / "b.mcap")]) == 1
    err = capsys.readouterr().err
    assert err == ("wmr: error: --controller: unknown controller 'bogus' (one of: pi, astolfi, "
                   "graceful)\n")


@pytest.mark.parametrize("args", [["run", "--bogus"], ["run", "--start", "1", "2"],
                                  ["rerun", "DIR"], ["optimal", "--bogus"]],
                         ids=["unknown", "short", "missing", "optimal"])
def test_a_parse_error_with_json_is_one_json_line_and_exit_1(
        args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main([*args, "--json"])
    assert stop.value.code == 1
    captured = capsys.readouterr()
    record = json.loads(captured.out)
    assert captured.out.count("\n") == 1 and record["status"] == "error"
    assert f"wmr {args[0]}: error: {record['message']}\n" == captured.err
    with pytest.raises(SystemExit) as stop:  # without --json: argparse's usage, exit 2
        main(args)
    assert stop.value.code == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.startswith(f"usage: wmr {args[0]} ")


def test_json_lines_write_nan_and_infinities_as_null() -> None:
    """``cli.shared.json_line``: one line of strict JSON (a NaN in a result is ``null``, never
    ``NaN``, which JSON readers refuse), nested values too. Seen failing with the float
    check removed (``ValueError: Out of range float values``)."""
    import json
    import math

    from wmr.cli.shared import json_line

    line = json_line({"a": math.nan, "b": [1.0, math.inf, {"c": -math.inf}], "d": "x"})
    assert "\n" not in line
    assert json.loads(line) == {"a": None, "b": [1.0, None, {"c": None}], "d": "x"}


def test_a_build_error_names_the_commands_option() -> None:
    """``cli.building.build_for``: an unknown platform is ``--platforms``' one-line error, as
    the user typed it (the build layer names its own field ``platforms``)."""
    import argparse

    from wmr.cli.building import build_for
    from wmr.infra.errors import ConfigError

    with pytest.raises(ConfigError) as err:
        build_for(argparse.Namespace(platforms="x86_64-linux,no-such-os"), None)
    assert err.value.field == "--platforms" and "no-such-os" in str(err.value)
