"""The version's one source (``wmr.infra.version``): what the installed distribution says,
what ``wmr.__version__`` says, and what a log stamps are the same string."""

from __future__ import annotations

import importlib.metadata
import tomllib
from pathlib import Path

import wmr
from wmr.adapters.mcap.writer import LIBRARY
from wmr.infra.version import __version__

ROOT = Path(__file__).resolve().parents[1]


def test_the_distribution_the_package_and_the_logs_say_one_version() -> None:
    assert importlib.metadata.version("wmr-cosim") == __version__
    assert wmr.__version__ == __version__
    assert LIBRARY.startswith(f"wmr-cosim/{__version__} ")


def test_pyproject_reads_the_version_from_its_one_source() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    source = ROOT / project["tool"]["hatch"]["version"]["path"]
    assert source.resolve() == Path(wmr.infra.version.__file__).resolve()
