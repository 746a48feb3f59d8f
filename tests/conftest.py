"""Shared fixtures: the FMUs are built once per test session (and shared across xdist workers)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from wmr.fmu.build import BuildResult, build_fmus
from wmr.fmu.plant import FmuPlant

os.environ.setdefault("MPLBACKEND", "Agg")  # headless: no figure ever opens a window


@pytest.fixture(scope="session")
def fmu_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One build folder for the whole session; xdist workers share it (the build is locked)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    return root / "fmus"


@pytest.fixture(scope="session")
def built(fmu_dir: Path) -> BuildResult:
    return build_fmus(fmu_dir)


@pytest.fixture(scope="session")
def fmu2(built: BuildResult) -> Path:
    return built.fmus[2]


@pytest.fixture(scope="session")
def fmu3(built: BuildResult) -> Path:
    return built.fmus[3]


@pytest.fixture(params=[2, 3], ids=["fmi2", "fmi3"])
def plant(request: pytest.FixtureRequest, built: BuildResult) -> Iterator[FmuPlant]:
    with FmuPlant(built.fmus[request.param]) as p:
        yield p
