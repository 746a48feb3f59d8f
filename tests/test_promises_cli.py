"""The front door's own promises (issue 23, gap 10): every command answers ``--help``, errors
are one line without ``--debug`` and the whole traceback with it."""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from pathlib import Path

import pytest

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
