"""Issue 21, "Names and places": where the commands write, and what their names and lists say."""

from __future__ import annotations

import argparse
import re
from dataclasses import fields
from pathlib import Path

import pytest

import wmr
from wmr.adapters.ssp.package import read_package
from wmr.build.fmus import BuildResult
from wmr.cli import main
from wmr.cli.run import add_run_overrides
from wmr.config.naming import LISTED_NAMES, name_list
from wmr.config.scenario import load_scenario
from wmr.core.plant import RobotParams
from wmr.infra.errors import ConfigError


def test_param_help_names_every_robot_parameter() -> None:
    """``wmr run --help`` lists every field of ``RobotParams`` under ``--param`` (``w_c`` was
    missing from a hand-written list)."""
    parser = argparse.ArgumentParser()
    add_run_overrides(parser)
    (param,) = [a for a in parser._actions if a.dest == "param"]
    listed = re.search(r"\(([^)]*)\)", param.help or "")
    assert listed is not None, param.help
    assert listed.group(1).split(", ") == [f.name for f in fields(RobotParams)]


def test_api_run_lists_how_many_runs_and_marks_a_cut_list() -> None:
    """``wmr.run("fig10")`` says it has 12 runs and ends its shortened list with ``...``."""
    names = [r.name for r in load_scenario("fig10").runs]
    assert len(names) > LISTED_NAMES  # else the list is not cut and this test proves nothing
    for kwargs in ({}, {"run": "no-such-run"}):
        with pytest.raises(ConfigError) as info:
            wmr.run("fig10", **kwargs)  # type: ignore[arg-type]
        msg = str(info.value)
        assert f"{len(names)} runs" in msg
        assert msg.endswith(", ...)"), msg
        assert all(n in msg for n in names[:LISTED_NAMES])
        assert names[-1] not in msg


def test_name_list_shows_a_whole_short_list_without_dots() -> None:
    assert name_list(["a", "b"]) == "its 2 runs: a, b"
    assert name_list(["a"], shown=1) == "its 1 run: a"
    assert name_list(["a", "b"], shown=1) == "its 2 runs: a, ..."


def test_wmr_ssp_export_writes_into_ssp_by_default(
        built: BuildResult, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """``ssp/NAME.ssp`` as ``runs/NAME.mcap``, never into the current folder; a variant
    (another goal, FMI 3) is named as ``wmr run`` names it and leaves the scenario's package."""
    monkeypatch.chdir(tmp_path)
    assert main(["ssp", "export", "fig11"]) == 0
    own = Path("ssp", "fig11.ssp")
    assert capsys.readouterr().out.strip() == str(own)
    package = own.read_bytes()
    assert main(["ssp", "export", "fig11", "--goal", "5", "5", "30", "--fmi", "3"]) == 0
    variant = Path("ssp", "fig11-to_5_5_30deg-fmi3.ssp")
    assert capsys.readouterr().out.strip() == str(variant)
    assert read_package(variant).components["robot"].fmi_version.startswith("3")
    assert own.read_bytes() == package
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ssp"]
