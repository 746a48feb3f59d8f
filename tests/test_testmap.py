"""docs/testing.md's map from each module of the package to its tests (``tools/testmap.py``):
every module that holds code has a test, and the table in the docs is the one the tests'
imports give."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]


def _testmap() -> ModuleType:
    spec = importlib.util.spec_from_file_location("testmap", ROOT / "tools" / "testmap.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["testmap"] = module
    spec.loader.exec_module(module)
    return module


def test_every_module_has_a_test_and_the_documented_map_is_current() -> None:
    testmap = _testmap()
    mapping = testmap.test_map()
    assert "wmr.core.physics" in mapping and "wmr.cli.batch" in mapping  # the walk found them
    untested = [module for module, tests in mapping.items() if not tests]
    assert untested == [], f"modules no test tests: {untested}"
    assert testmap.documented_table() == testmap.render(mapping), \
        "docs/testing.md's map is out of date: python tools/testmap.py --write"


def test_a_name_counts_for_the_module_that_defines_it() -> None:
    """``from wmr.core.control import WheelServo`` tests ``wmr.core.control.actuator``, where
    the class lives, and a command run through ``wmr.cli.main`` tests its handler's module."""
    testmap = _testmap()
    mapping = testmap.test_map()
    assert "test_actuator.py" in mapping["wmr.core.control.actuator"]
    assert "test_progress.py" in mapping["wmr.cli.tune"]
    assert mapping["wmr.cli.batch"], "wmr batch is run by tests through wmr.cli.main"
