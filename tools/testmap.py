"""Which test modules test which module of the package: the map of docs/testing.md.

A test module tests a module of ``wmr`` when it imports it, or imports a name defined in it
(``from wmr.core.control import WheelServo`` tests ``wmr.core.control.actuator``, where
``WheelServo`` is defined; ``import wmr`` and ``wmr.run`` test ``wmr.api``), or, for a
command's module under ``wmr/cli``, when it runs the command (it calls ``wmr.cli.main`` or the
``wmr`` executable or ``python -m wmr.cli``, and names the command in a string). The module a
command lives in is the one that defines its handler. A package whose ``__init__`` holds only
its docstring is not in the map.

``python tools/testmap.py`` prints the map's Markdown table; ``--check`` exits 1 when
docs/testing.md's table differs from it or a module has no test (the test suite runs the same
check: ``tests/test_testmap.py``).
"""

from __future__ import annotations

import argparse
import ast
import importlib
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "pipelines" / "wmr"
TESTS = ROOT / "tests"
DOC = ROOT / "docs" / "testing.md"
BEGIN = "<!-- testmap: begin (python tools/testmap.py writes this table) -->"
END = "<!-- testmap: end -->"


def _holds_code(path: Path) -> bool:
    """Whether a module holds more than its docstring (a package's ``__init__`` that only
    describes its package has nothing to test)."""
    body = ast.parse(path.read_text(encoding="utf-8")).body
    return any(not (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant))
               for node in body)


def package_modules() -> list[str]:
    """Every module of ``wmr`` that holds code, by dotted name (packages by their
    ``__init__``), sorted."""
    names = []
    for path in PACKAGE.rglob("*.py"):
        if not _holds_code(path):
            continue
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names.append(".".join(parts))
    return sorted(names)


def _defining_module(module: str, name: str) -> str:
    """The module that defines ``module.name`` (itself when ``name`` is a submodule)."""
    mod = importlib.import_module(module)
    obj = getattr(mod, name, None)
    if obj is None:
        try:
            return importlib.import_module(f"{module}.{name}").__name__
        except ImportError:
            return module
    if hasattr(obj, "__spec__") and getattr(obj, "__name__", "").startswith("wmr"):
        return str(obj.__name__)  # a submodule
    defined = getattr(obj, "__module__", None)
    return defined if isinstance(defined, str) and defined.startswith("wmr") else module


def _command_modules() -> dict[str, str]:
    """``wmr`` sub-command name -> the module of its handler."""
    from wmr.cli import build_parser

    out: dict[str, str] = {}

    def walk(parser: argparse.ArgumentParser, prefix: str) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    handler = sub.get_default("handler")
                    if handler is not None:
                        out[f"{prefix}{name}"] = handler.__module__
                    walk(sub, f"{prefix}{name} ")

    walk(build_parser(), "")
    return out


def _tested_by(test: Path, commands: dict[str, str]) -> set[str]:
    tree = ast.parse(test.read_text(encoding="utf-8"), str(test))
    found: set[str] = set()
    runs_cli = False
    strings: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "wmr":
            found.add(node.module)
            for alias in node.names:
                found.add(_defining_module(node.module, alias.name))
            if node.module == "wmr.cli" and any(a.name == "main" for a in node.names):
                runs_cli = True
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "wmr":
                    found.add(alias.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id == "wmr":
            found.add(_defining_module("wmr", node.attr))
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            strings.add(node.value)
            if node.value == "wmr" or node.value.endswith("/wmr"):
                runs_cli = True
            elif node.value == "wmr.cli":  # python -m wmr.cli
                runs_cli = True
                found.add("wmr.cli.__main__")
    if runs_cli:
        found.update(module for name, module in commands.items()
                     if name.split(" ")[-1] in strings)
    return {m for m in found if m.split(".")[0] == "wmr"}


def test_map() -> dict[str, list[str]]:
    """Module -> the test modules (file names) that test it, for every module of ``wmr``."""
    if str(PACKAGE.parent) not in sys.path:
        sys.path.insert(0, str(PACKAGE.parent))
    commands = _command_modules()
    out: dict[str, list[str]] = {m: [] for m in package_modules()}
    for test in sorted(TESTS.glob("test_*.py")):
        for module in _tested_by(test, commands):
            if module in out:
                out[module].append(test.name)
    return out


def render(mapping: dict[str, list[str]]) -> str:
    """The Markdown table of ``mapping``."""
    lines = ["| module | test modules |", "|---|---|"]
    for module, tests in mapping.items():
        names = ", ".join(t.removesuffix(".py") for t in tests) or "**none**"
        lines.append(f"| `{module}` | {names} |")
    return "\n".join(lines)


def documented_table() -> str:
    """The table between the markers of docs/testing.md."""
    text = DOC.read_text(encoding="utf-8")
    return text.split(BEGIN, 1)[1].split(END, 1)[0].strip()


def main(argv: list[str]) -> int:
    mapping = test_map()
    table = render(mapping)
    if "--write" in argv:
        text = DOC.read_text(encoding="utf-8")
        head, rest = text.split(BEGIN, 1)
        DOC.write_text(f"{head}{BEGIN}\n{table}\n{END}{rest.split(END, 1)[1]}", encoding="utf-8")
        return 0
    if "--check" in argv:
        untested = [m for m, tests in mapping.items() if not tests]
        if untested:
            print("modules no test tests: " + ", ".join(untested))
        if documented_table() != table:
            print("docs/testing.md's map is out of date: python tools/testmap.py --write")
        return 1 if untested or documented_table() != table else 0
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
