"""Shared fixtures: the FMUs are built once per test session (and shared across xdist workers)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from wmr.adapters.fmi.robot import FmuPlant
from wmr.build.fmus import BuildResult, build_fmus
from wmr.infra import paths

os.environ.setdefault("MPLBACKEND", "Agg")  # headless: no figure ever opens a window


@pytest.fixture(scope="session", autouse=True)
def fmu_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """One build folder for the whole session; xdist workers share it (the build is locked).

    ``WMR_CACHE_DIR`` points there too, so that everything that builds or reuses the
    project's FMUs (``wmr run`` and its subprocesses included) finds this build, and no test
    writes into the user's cache.
    """
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    old = os.environ.get("WMR_CACHE_DIR")
    os.environ["WMR_CACHE_DIR"] = str(root / "cache")
    yield paths.default_fmu_dir()
    if old is None:
        os.environ.pop("WMR_CACHE_DIR", None)
    else:
        os.environ["WMR_CACHE_DIR"] = old


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
